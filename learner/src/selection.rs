//! The best agent's own evaluation (`[learner.selection]`, issue 29): with each training-time
//! evaluation, the agent of that moment drives the local tasks (start and goal 2-5 m
//! apart, a collision-free path at most 1.5x the straight line), clean, for a circular robot of
//! each configured radius through DVST, in rooms of the training distribution; one row per room
//! and robot goes to `select.csv`, and [`crate::best_agent`] keeps the best agent by them.
//!
//! Why a second evaluation: the training-time evaluation's rooms are the curriculum's, its
//! random episodes a few per stage, and only the meta robot drives them (it decides the
//! stages). Its success rate moves by tens of points between two evaluations of the same skill,
//! and a run's agent that loses its big robots in clutter scores the same. Picking the best
//! moment of a run by that score is picking by noise; this evaluation is sized to tell two
//! agents apart where the issue measures them, on training rooms only.
//!
//! **Comparable rows.** The episodes' starts and goals come from one seed (the evaluator's, fixed
//! by `run.seed`), and episode k of a room is the same task for every robot, so every evaluation
//! of a run faces the same tasks.

use crate::best_agent::Moment;
use crate::csv_format::{append_rows, ser_2_decimals, ser_4_decimals_or_nan};
use crate::eval_robots::{clean_env, dvst_agents};
use dvnav_config::{Config, SelectionConfig};
use dvnav_eval::{RoomSummary, RunOptions, room_summaries, room_tasks, run_tasks};
use dvnav_nav::policy::NavPolicy;
use dvnav_sim::room_set::RoomSet;
use dvnav_sim::{Footprint, Room};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// The selection's rows, one per room and robot at each evaluation.
pub const SELECT_CSV: &str = "select.csv";

/// The local tasks: start and goal this far apart (m).
const LOCAL_DISTANCE_M: [f64; 2] = [2.0, 5.0];
/// ... with a collision-free path at most this many times the straight line.
const LOCAL_PATH_RATIO: f64 = 1.5;

/// The selection's rooms: `room_count` rooms of its room set, round-robin over the set's
/// alternatives (the first seeds of each), built once.
pub fn selection_rooms(sel: &SelectionConfig) -> anyhow::Result<Vec<Arc<Room>>> {
    let set = RoomSet::parse(&sel.rooms)?;
    let names = if set.is_single() { vec![sel.rooms.clone()] } else { set.sample(sel.room_count) };
    let mut rooms = Vec::new();
    for name in names {
        let loaded = Room::load(&name)
            .map_err(|e| anyhow::anyhow!("learner.selection.rooms: room `{name}`: {e:#}"))?;
        rooms.extend(loaded);
    }
    Ok(rooms)
}

/// Runs the selection's local tasks in `rooms` ([`selection_rooms`]), drawn from `seed`, with
/// the agent `policy` (safetensors bytes) driving a circular robot of each of `sel.radii`
/// through DVST. Returns one row per room and robot, and the wall time (s).
pub fn evaluate_selection(
    cfg: &Config,
    sel: &SelectionConfig,
    rooms: &[Arc<Room>],
    policy: &[u8],
    seed: u64,
) -> anyhow::Result<(Vec<RoomSummary>, f64)> {
    let started = Instant::now();
    let robots: Vec<Option<(Footprint, f64)>> =
        sel.radii.iter().map(|&r| Some((Footprint::circle(r), r))).collect();
    let tasks = room_tasks(rooms, &robots, sel.episodes, seed);
    let mut owned = dvst_agents(cfg, policy, &sel.radii)?;
    let mut policies: Vec<&mut dyn NavPolicy> =
        owned.iter_mut().map(|p| p as &mut dyn NavPolicy).collect();
    let env = local_task_env(cfg);
    let results =
        run_tasks(&tasks, &env, &mut policies, RunOptions::default(), &mut |_, _| Ok(()))?;
    Ok((room_summaries(&tasks, &results), started.elapsed().as_secs_f64()))
}

/// The run's environment for the selection: local tasks in the clean simulator
/// ([`clean_env`]), the setting `dvnav eval --tasks local` measures the held-out suite in.
fn local_task_env(cfg: &Config) -> dvnav_config::EnvConfig {
    dvnav_config::EnvConfig {
        min_start_goal_distance: LOCAL_DISTANCE_M[0],
        max_start_goal_distance: LOCAL_DISTANCE_M[1],
        max_path_ratio: LOCAL_PATH_RATIO,
        ..clean_env(cfg)
    }
}

/// Header of `select.csv`: [`SelectRow`]'s field names.
pub const SELECT_CSV_HEADER: &str = "updates,env_steps,policy_version,room,radius,episodes,\
success_rate,collision_rate,timeout_rate,reversal_rate,eval_wall_s";

/// One row of `select.csv`: one room and robot at one evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SelectRow {
    /// Learner updates done.
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// Weight version evaluated (0: never published).
    pub policy_version: u64,
    /// Room name.
    pub room: String,
    /// The robot's radius (m).
    pub radius: f64,
    /// Episodes run.
    pub episodes: u64,
    /// Share that reached the goal.
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub success_rate: f64,
    /// Share that collided.
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub collision_rate: f64,
    /// Share that timed out.
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub timeout_rate: f64,
    /// Share of cycles whose ω changed sign.
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub reversal_rate: f64,
    /// Wall time of the whole selection evaluation (s).
    #[serde(serialize_with = "ser_2_decimals")]
    pub eval_wall_s: f64,
}

impl SelectRow {
    /// The row of `r` in the selection evaluation of the agent of `at` that took `wall_s`.
    pub fn of(at: &Moment, r: &RoomSummary, wall_s: f64) -> Self {
        Self {
            updates: at.updates,
            env_steps: at.env_steps,
            policy_version: at.policy_version,
            room: r.room.clone(),
            radius: r.radius.unwrap_or(f64::NAN),
            episodes: r.rates.episodes as u64,
            success_rate: r.rates.success_rate,
            collision_rate: r.rates.collision_rate,
            timeout_rate: r.rates.timeout_rate,
            reversal_rate: r.rates.reversal_rate,
            eval_wall_s: wall_s,
        }
    }
}

/// Appends the selection evaluation of the agent of `at` to `select.csv` at `path` (the header
/// first in a new file), in one write.
pub fn append_select_csv(
    path: &Path,
    at: &Moment,
    rows: &[RoomSummary],
    wall_s: f64,
) -> anyhow::Result<()> {
    append_rows(path, rows.iter().map(|r| SelectRow::of(at, r, wall_s)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn config() -> (Config, SelectionConfig) {
        let mut cfg = Config::default();
        cfg.env.max_steps = 40;
        let sel = SelectionConfig {
            rooms: "generated:clutter:0..50|generated:paper:0..50".into(),
            room_count: 3,
            radii: vec![0.2, 0.5],
            episodes: 2,
            ..SelectionConfig::default()
        };
        cfg.learner.selection = Some(sel.clone());
        (cfg, sel)
    }

    /// An untrained policy's weights (safetensors bytes).
    fn fresh_policy(cfg: &Config) -> Vec<u8> {
        let nets = crate::sac::SacNetworks::new(cfg, 3, &Device::Cpu).unwrap();
        dvnav_nav::nets::varmap_to_safetensors(&nets.actor.vars).unwrap()
    }

    #[test]
    fn the_rooms_are_drawn_round_robin_from_the_set() {
        let (_, sel) = config();
        let names: Vec<String> =
            selection_rooms(&sel).unwrap().iter().map(|r| r.name().to_string()).collect();
        assert_eq!(names, ["generated:clutter:0", "generated:paper:0", "generated:clutter:1"]);
    }

    #[test]
    fn one_row_per_room_and_robot_on_local_tasks_the_same_at_every_evaluation() {
        let (cfg, sel) = config();
        let rooms = selection_rooms(&sel).unwrap();
        let policy = fresh_policy(&cfg);
        let (rows, wall) = evaluate_selection(&cfg, &sel, &rooms, &policy, 7).unwrap();
        assert!(wall > 0.0);
        let keys: Vec<(String, Option<f64>)> =
            rows.iter().map(|r| (r.room.clone(), r.radius)).collect();
        assert_eq!(keys.len(), 6, "{keys:?}");
        for room in &rooms {
            for r in &sel.radii {
                assert!(keys.contains(&(room.name().to_string(), Some(*r))), "{keys:?}");
            }
        }
        for r in &rows {
            assert_eq!(r.rates.episodes, 2, "{r:?}");
            let shares = r.rates.success_rate + r.rates.collision_rate + r.rates.timeout_rate;
            assert!((shares - 1.0).abs() < 1e-9, "{r:?}");
        }
        // The same tasks and a deterministic policy: the same rows.
        let (again, _) = evaluate_selection(&cfg, &sel, &rooms, &policy, 7).unwrap();
        assert_eq!(format!("{rows:?}"), format!("{again:?}"));
        // A fresh policy in 40 cycles reaches few goals; the mean counts every row.
        let mean = crate::best_agent::mean_success(&rows).unwrap().0;
        let by_hand = rows.iter().map(|r| r.rates.success_rate).sum::<f64>() / 6.0;
        assert!((mean - by_hand).abs() < 1e-12);
    }

    #[test]
    fn select_csv_has_one_header_and_a_row_per_room_and_robot() {
        let (cfg, sel) = config();
        let rooms = selection_rooms(&sel).unwrap();
        let policy = fresh_policy(&cfg);
        let (rows, wall) = evaluate_selection(&cfg, &sel, &rooms[..1], &policy, 7).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(SELECT_CSV);
        for updates in [10, 20] {
            let at = Moment { updates, env_steps: 4 * updates, policy_version: 2 };
            append_select_csv(&path, &at, &rows, wall).unwrap();
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], SELECT_CSV_HEADER);
        assert_eq!(lines.len(), 1 + 2 * 2, "{text}");
        assert!(lines[1].starts_with("10,40,2,generated:clutter:0,0.2,2,"), "{}", lines[1]);
        assert!(lines[4].starts_with("20,80,2,generated:clutter:0,0.5,2,"), "{}", lines[4]);
        assert!(lines.iter().all(|l| l.split(',').count() == SELECT_CSV_HEADER.split(',').count()));
    }
}
