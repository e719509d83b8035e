//! The evaluation protocol during training (design §4, issue 5): every
//! `learner.eval_every_updates` updates, the deterministic policy of that moment drives the
//! evaluation route of every curriculum room and `learner.eval_episodes` seeded random episodes
//! per room; one row per room goes to `eval.csv` in the run directory, and the route legs to
//! MCAP (`mcap/eval/eval-NNNNN.mcap`).
//!
//! **Stages that are sets of rooms** (`dvnav_sim::room_set`) are evaluated in
//! [`SET_EVAL_ROOMS`] of their rooms, the set's first ones ([`RoomSet::sample`]): the stage's
//! `learner.eval_episodes` random episodes are spread over them, and a room that has the
//! evaluation route also drives it. `eval.csv` gets a row per evaluated room, the rows of
//! each stage together in stage order.
//!
//! **Never stalls the update loop.** The trainer hands over a snapshot of the policy weights
//! (safetensors bytes, the same the actors get) through a channel that holds one; an
//! evaluator thread builds its own [`MetaAgent`] from them and steps the environments on a
//! one-thread rayon pool, so it takes at most one core from the learner. When an evaluation is
//! still queued when the next falls due, the new one is skipped with a warning, not waited for.
//!
//! **Comparable rows.** The random episodes' starts and goals come from a fixed seed derived
//! from `run.seed`, so every evaluation of a run (and of runs with the same seed) faces the
//! same episodes. Random episodes are not logged to MCAP (they are most of an evaluation's
//! steps, so most of its log); the routes are.
//!
//! **The best agent.** Each evaluation (with the gate test when `learner.eval_gate` asks for
//! it) is offered to [`BestAgent`], which keeps the best-scoring agent in `best/`
//! ([`crate::best_agent`]).

use crate::best_agent::{BestAgent, Measured, Moment, mean_success};
use crate::csv_format::{append_rows, ser_2_decimals, ser_4_decimals_or_nan};
use crate::eval_robots::{clean_env, dvst_agents};
use crate::selection::{SELECT_CSV, append_select_csv, evaluate_selection, selection_rooms};
use dvnav_config::Config;
use dvnav_eval::episode_log::LogMetadata;
use dvnav_eval::{
    EvalLogger, GATE_RADII, GateGeometry, RobotResult, RoomSummary, RunOptions, TRAINING_ROUTE,
    TaskKind, parse_radii, robot_results, robot_tasks, room_summaries, run_tasks, training_tasks,
};
use dvnav_nav::policy::{MetaAgent, NavPolicy};
use dvnav_sim::Room;
use dvnav_sim::room_set::RoomSet;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{self, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Instant;

/// Header of `eval.csv`: [`EvalRow`]'s field names.
pub const EVAL_CSV_HEADER: &str = "updates,env_steps,room,route_completed,score,success_rate,\
collision_rate,timeout_rate,mean_time_s,episodes,mean_score,route_goals_reached,route_time_s,\
policy_version,eval_wall_s";

/// The policy at one moment of training.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Learner updates done.
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// Weight version of these weights (0 when they were never published).
    pub policy_version: u64,
    /// The agent's weights, safetensors bytes: the policy average θ̄ when
    /// `sac.policy_average_tau` > 0, else the online policy.
    pub policy: Vec<u8>,
    /// The online policy's weights when `policy` is an average (its gate test goes to
    /// `gate-online.csv`, so a run shows both side by side); else `None`.
    pub online: Option<Vec<u8>>,
}

/// Called with the path and the error when a write fails.
pub type WriteFailure = Box<dyn Fn(&Path, &str) + Send>;

/// The evaluator thread's handle.
#[derive(Debug)]
pub struct Evaluator {
    tx: Option<SyncSender<Snapshot>>,
    thread: Option<JoinHandle<()>>,
}

impl Evaluator {
    /// Starts the evaluator thread for a run in `out_dir`, or `None` when
    /// `learner.eval_every_updates` is 0.
    pub fn start(cfg: &Config, out_dir: &Path) -> anyhow::Result<Option<Evaluator>> {
        Self::start_reporting(cfg, out_dir, None)
    }

    /// [`Evaluator::start`], calling `on_write_failure(path, error)` when `eval.csv` (or `gate.csv`) cannot be
    /// written (the trainer counts it; the row is lost, the next evaluation tries again).
    pub fn start_reporting(
        cfg: &Config,
        out_dir: &Path,
        on_write_failure: Option<WriteFailure>,
    ) -> anyhow::Result<Option<Evaluator>> {
        if cfg.learner.eval_every_updates == 0 {
            return Ok(None);
        }
        let rooms = stage_rooms(cfg)?;
        let selection = cfg
            .learner
            .selection
            .as_ref()
            .map(|sel| selection_rooms(sel).map(|rooms| (sel.clone(), rooms)))
            .transpose()?;
        let (tx, rx) = mpsc::sync_channel::<Snapshot>(1);
        let cfg = cfg.clone();
        let out = out_dir.to_path_buf();
        let thread = std::thread::Builder::new().name("evaluator".into()).spawn(move || {
            let pool = match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
                Ok(p) => p,
                Err(e) => {
                    tracing::error!(error = %e, "evaluator: no thread pool; evaluation is off");
                    return;
                }
            };
            let mut logger = None;
            let gate_bar = cfg.learner.selection.as_ref().map_or(0, |s| s.gate_min_passed);
            let mut best = BestAgent::open(&out).with_gate_bar(gate_bar);
            let config_toml = cfg.to_toml_string();
            for snap in rx {
                if logger.is_none() {
                    logger = open_logger(&cfg, &out)
                        .inspect_err(|e| tracing::warn!(error = %format!("{e:#}"), "evaluation episodes are not logged"))
                        .ok();
                }
                let result = pool.install(|| evaluate(&cfg, &rooms, &snap, logger.as_mut()));
                let csv = out.join("eval.csv");
                let rows = match result {
                    Ok((rows, wall)) => {
                        log_rows(&snap, &rows, wall);
                        report_write(&csv, append_csv(&csv, &snap, &rows, wall), on_write_failure.as_ref());
                        Some(rows)
                    }
                    Err(e) => {
                        tracing::error!(updates = snap.updates, error = %format!("{e:#}"), "evaluation failed");
                        None
                    }
                };
                // The agent's gate test, for the best agent; `None` when it was asked and failed.
                let mut agent_gate: Option<Option<Vec<RobotResult>>> = None;
                if cfg.learner.eval_gate {
                    let mut gates = vec![(GATE_CSV, "agent", &snap.policy)];
                    gates.extend(snap.online.as_ref().map(|w| (GATE_ONLINE_CSV, "online policy", w)));
                    for (file, policy, weights) in gates {
                        let csv = out.join(file);
                        let robots = match pool.install(|| evaluate_gate(&cfg, weights)) {
                            Ok(robots) => {
                                log_gate(&snap, policy, &robots);
                                report_write(&csv, append_gate_csv(&csv, &snap, &robots), on_write_failure.as_ref());
                                Some(robots)
                            }
                            Err(e) => {
                                tracing::error!(updates = snap.updates, policy, error = %format!("{e:#}"), "the gate test failed");
                                None
                            }
                        };
                        if file == GATE_CSV {
                            agent_gate = Some(robots);
                        }
                    }
                }
                let gate = match &agent_gate {
                    None => Some(None),
                    Some(Some(robots)) => Some(Some(robots.as_slice())),
                    Some(None) => None,
                };
                // The best agent's own evaluation; `None` when it was asked and failed.
                let selected: Option<Option<Vec<RoomSummary>>> = match &selection {
                    None => Some(None),
                    Some((sel, sel_rooms)) => {
                        match pool.install(|| evaluate_selection(&cfg, sel, sel_rooms, &snap.policy, eval_seed(cfg.run.seed))) {
                            Ok((sel_rows, wall)) => {
                                log_selection(&snap, &sel.radii, &sel_rows, wall);
                                let csv = out.join(SELECT_CSV);
                                report_write(&csv, append_select_csv(&csv, &moment(&snap), &sel_rows, wall), on_write_failure.as_ref());
                                Some(Some(sel_rows))
                            }
                            Err(e) => {
                                tracing::error!(updates = snap.updates, error = %format!("{e:#}"), "the selection evaluation failed");
                                None
                            }
                        }
                    }
                };
                if let (Some(rows), Some(gate), Some(selected)) = (&rows, gate, &selected) {
                    let at = moment(&snap);
                    let m = Measured { rows, gate, selection: selected.as_deref() };
                    match best.offer(at, &snap.policy, m, &config_toml) {
                        Ok(Some(kept)) => tracing::info!(
                            updates = kept.updates,
                            score = format!("{:.3}", kept.score),
                            rooms_success = format!("{:.3}", kept.rooms_success),
                            gate_passed = kept.gate_passed,
                            select_success = kept.select_success.map_or("-".into(), |s| format!("{s:.3}")),
                            "best agent so far, kept in best/"
                        ),
                        Ok(None) => {}
                        Err(e) => {
                            let path = out.join(crate::best_agent::BEST_DIR);
                            report_write(&path, Err(e), on_write_failure.as_ref());
                        }
                    }
                }
            }
            if let Some(l) = logger
                && let Err(e) = l.close()
            {
                tracing::warn!(error = %format!("{e:#}"), "closing the evaluation log");
            }
        })?;
        Ok(Some(Evaluator { tx: Some(tx), thread: Some(thread) }))
    }

    /// Hands `snap` to the evaluator without waiting; returns false (and warns) when an
    /// earlier evaluation is still queued.
    pub fn submit(&self, snap: Snapshot) -> bool {
        let Some(tx) = &self.tx else { return false };
        match tx.try_send(snap) {
            Ok(()) => true,
            Err(TrySendError::Full(s)) => {
                tracing::warn!(
                    updates = s.updates,
                    "evaluation skipped: the previous one is still queued"
                );
                false
            }
            Err(TrySendError::Disconnected(s)) => {
                tracing::warn!(
                    updates = s.updates,
                    "evaluation skipped: the evaluator has stopped"
                );
                false
            }
        }
    }

    /// Waits for the queued evaluations to finish and stops the thread.
    pub fn finish(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take()
            && t.join().is_err()
        {
            tracing::error!("the evaluator thread panicked");
        }
    }
}

impl Drop for Evaluator {
    fn drop(&mut self) {
        self.stop();
    }
}

fn open_logger(cfg: &Config, out: &Path) -> anyhow::Result<EvalLogger> {
    let meta = LogMetadata {
        run_id: out.file_name().and_then(|n| n.to_str()).unwrap_or("run").to_string(),
        config_hash: cfg.hash_hex(),
        seed: cfg.run.seed,
        ..Default::default()
    };
    let dir: PathBuf = out.join("mcap").join("eval");
    EvalLogger::create(&dir, "eval", "eval", meta, cfg.logging.episodes_per_file)
}

/// Seed of the evaluation episodes of a run with root seed `seed` (apart from the seeds
/// actors derive from it).
pub fn eval_seed(seed: u64) -> u64 {
    seed ^ 0x5eed_e7a1_0000_0000
}

/// Rooms evaluated for a curriculum stage that is a set of rooms: the set's first ones.
pub const SET_EVAL_ROOMS: usize = 4;

/// The rooms evaluated for each curriculum stage, built: a stage's room (every room of a room
/// file), or [`SET_EVAL_ROOMS`] rooms of a set ([`RoomSet::sample`]).
pub fn stage_rooms(cfg: &Config) -> anyhow::Result<Vec<Vec<Arc<Room>>>> {
    cfg.curriculum
        .rooms
        .iter()
        .enumerate()
        .map(|(i, stage)| {
            let set = RoomSet::parse(stage)?;
            let mut rooms = Vec::new();
            for name in set.sample(SET_EVAL_ROOMS) {
                let loaded = Room::load(&name)
                    .map_err(|e| anyhow::anyhow!("curriculum.rooms[{i}]: room `{name}`: {e:#}"))?;
                rooms.extend(loaded);
            }
            Ok(rooms)
        })
        .collect()
}

/// The evaluation tasks of one stage's `rooms`: each room's route (where it has one), and
/// `episodes` random episodes spread over the rooms (all of them in a stage of one room).
fn stage_tasks(rooms: &[Arc<Room>], episodes: usize, seed: u64) -> Vec<dvnav_eval::Task> {
    let k = rooms.len();
    rooms
        .iter()
        .enumerate()
        .flat_map(|(r, room)| {
            let share = episodes / k + usize::from(r < episodes % k);
            training_tasks(std::slice::from_ref(room), TRAINING_ROUTE, share, seed)
        })
        .collect()
}

/// Evaluates the policy of `snap` in `stages` (the rooms of each curriculum stage,
/// [`stage_rooms`]): their routes and `learner.eval_episodes` random episodes per stage,
/// spread over its rooms. Route legs go to `logger` with each room's curriculum stage (its first).
/// Returns one row per room, stage by stage, and the wall time (s).
pub fn evaluate(
    cfg: &Config,
    stages: &[Vec<Arc<Room>>],
    snap: &Snapshot,
    mut logger: Option<&mut EvalLogger>,
) -> anyhow::Result<(Vec<RoomSummary>, f64)> {
    let started = Instant::now();
    let mut agent = MetaAgent::from_safetensors(&snap.policy, cfg)?;
    let seed = eval_seed(cfg.run.seed);
    let mut tasks = Vec::new();
    let mut blocks = Vec::with_capacity(stages.len());
    for rooms in stages {
        let start = tasks.len();
        tasks.extend(stage_tasks(rooms, cfg.learner.eval_episodes, seed));
        blocks.push(start..tasks.len());
    }
    if let Some(l) = logger.as_deref_mut() {
        l.policy_version = snap.policy_version;
    }
    let opts = RunOptions { samples: logger.is_some(), ..Default::default() };
    // The meta robot's skill decides the stages: no varied robots here (env.dvst).
    let env = dvnav_config::EnvConfig { dvst: None, ..cfg.env.clone() };
    let results = run_tasks(&tasks, &env, &mut [&mut agent], opts, &mut |task, done| match (
        logger.as_deref_mut(),
        &task.kind,
    ) {
        (Some(l), TaskKind::Route(_)) => {
            let name = task.room.name();
            let stage = stages.iter().position(|s| s.iter().any(|r| r.name() == name)).unwrap_or(0);
            l.log(task, stage as u32, &done)
        }
        _ => Ok(()),
    })?;
    // Summarized stage by stage: a room in two stages gets a row in each.
    let rows = blocks.into_iter().flat_map(|b| room_summaries(&tasks[b.clone()], &results[b]));
    Ok((rows.collect(), started.elapsed().as_secs_f64()))
}

/// Hands a failed CSV write to `on_write_failure` (the learner counts it), or logs it.
fn report_write(path: &Path, written: anyhow::Result<()>, on_write_failure: Option<&WriteFailure>) {
    if let Err(e) = written {
        let e = format!("{e:#}");
        match on_write_failure {
            Some(report) => report(path, &e),
            None => tracing::error!(path = %path.display(), error = %e, "cannot write a CSV file"),
        }
    }
}

/// The paper's gate test on the policy weights `policy` (safetensors bytes;
/// `learner.eval_gate`): the twelve robots of [`GATE_RADII`] on the gate room's route, each
/// through DVST at μ = R / R_m, in the clean
/// simulator `dvnav eval --scenario gate` uses (no training robustness, varied robots or
/// subgoals). One result per robot, in radius order.
pub fn evaluate_gate(cfg: &Config, policy: &[u8]) -> anyhow::Result<Vec<RobotResult>> {
    let room = Room::builtin("gate")?;
    let route = room
        .spec()
        .route("gate")
        .ok_or_else(|| anyhow::anyhow!("the gate room has no route `gate`"))?
        .clone();
    let geometry = GateGeometry::from_room(room.spec(), &route)?;
    let radii = parse_radii(GATE_RADII)?;
    let tasks = robot_tasks(&room, &route, &radii, eval_seed(cfg.run.seed));
    let mut robots = dvst_agents(cfg, policy, &radii)?;
    let mut policies: Vec<&mut dyn NavPolicy> =
        robots.iter_mut().map(|p| p as &mut dyn NavPolicy).collect();
    let env = clean_env(cfg);
    let results =
        run_tasks(&tasks, &env, &mut policies, RunOptions::default(), &mut |_, _| Ok(()))?;
    Ok(robot_results(&tasks, &results, &geometry))
}

/// The gate test of the run's agent, one row per robot and evaluation.
pub const GATE_CSV: &str = "gate.csv";

/// The gate test of the online policy, written when the agent is a policy average.
pub const GATE_ONLINE_CSV: &str = "gate-online.csv";

/// Header of `gate.csv`: [`GateRow`]'s field names.
pub const GATE_CSV_HEADER: &str =
    "updates,env_steps,policy_version,radius,outcome,route,path_length_m,time_s,passed";

/// One row of `gate.csv`: one robot of the gate test at one evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateRow {
    /// Learner updates done.
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// Weight version evaluated (0: never published).
    pub policy_version: u64,
    /// The robot's radius (m).
    pub radius: f64,
    /// success, collision or timeout.
    pub outcome: String,
    /// gate, left or other.
    pub route: String,
    /// Length of the path driven (m).
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub path_length_m: f64,
    /// Simulated seconds on the route.
    #[serde(serialize_with = "ser_2_decimals")]
    pub time_s: f64,
    /// Passed the paper's test ([`RobotResult::passes_gate_test`]).
    pub passed: bool,
}

impl GateRow {
    /// The row of robot `r` in the evaluation of `snap`.
    pub fn of(snap: &Snapshot, r: &RobotResult) -> Self {
        Self {
            updates: snap.updates,
            env_steps: snap.env_steps,
            policy_version: snap.policy_version,
            radius: r.radius,
            outcome: r.outcome.as_str().to_string(),
            route: r.route.as_str().to_string(),
            path_length_m: r.path_length_m,
            time_s: r.time_s,
            passed: r.passes_gate_test(),
        }
    }
}

/// Appends the gate test of `snap` to `gate.csv` at `path` (the header first in a new file).
pub fn append_gate_csv(path: &Path, snap: &Snapshot, robots: &[RobotResult]) -> anyhow::Result<()> {
    append_rows(path, robots.iter().map(|r| GateRow::of(snap, r)))
}

/// When `snap`'s agent was trained to.
fn moment(snap: &Snapshot) -> Moment {
    Moment { updates: snap.updates, env_steps: snap.env_steps, policy_version: snap.policy_version }
}

fn log_selection(snap: &Snapshot, radii: &[f64], rows: &[RoomSummary], wall_s: f64) {
    let by_radius: Vec<String> = radii
        .iter()
        .map(|&radius| {
            let of: Vec<f64> = rows
                .iter()
                .filter(|r| r.radius == Some(radius) && r.rates.episodes > 0)
                .map(|r| r.rates.success_rate)
                .collect();
            let mean = of.iter().sum::<f64>() / of.len().max(1) as f64;
            format!("R = {radius}: {:.0} %", 100.0 * mean)
        })
        .collect();
    tracing::info!(
        updates = snap.updates,
        success = mean_success(rows).map_or("-".into(), |(s, _)| format!("{s:.3}")),
        by_radius = %by_radius.join(", "),
        wall_s = format!("{wall_s:.1}"),
        "selection evaluation"
    );
}

fn log_gate(snap: &Snapshot, policy: &str, robots: &[RobotResult]) {
    let failed: Vec<String> = robots
        .iter()
        .filter(|r| !r.passes_gate_test())
        .map(|r| format!("R = {:.2}: {} by {}", r.radius, r.outcome.as_str(), r.route.as_str()))
        .collect();
    tracing::info!(
        updates = snap.updates,
        policy,
        passed = robots.len() - failed.len(),
        robots = robots.len(),
        failed = %failed.join("; "),
        "gate test"
    );
}

/// One row of `eval.csv`: a room's results at one evaluation. Route fields are empty (or NaN)
/// for a room without an evaluation route. Read by column name: of an older or hand-made file
/// only the [`EvalRow::REQUIRED`] columns must be there; a missing number reads as NaN (a
/// missing count as 0).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    /// Learner updates done.
    #[serde(default)]
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// Room name.
    pub room: String,
    /// The route was driven to its end.
    pub route_completed: Option<bool>,
    /// The paper's score S of the route, in [−1, 1].
    #[serde(serialize_with = "ser_4_decimals_or_nan")]
    pub score: f64,
    /// Share of the random episodes that succeeded.
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub success_rate: f64,
    /// Share that collided.
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub collision_rate: f64,
    /// Share that timed out.
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub timeout_rate: f64,
    /// Mean time of the successful episodes (s).
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub mean_time_s: f64,
    /// Random episodes run.
    #[serde(default)]
    pub episodes: u64,
    /// Mean score of the random episodes.
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub mean_score: f64,
    /// Route goals reached.
    pub route_goals_reached: Option<u64>,
    /// Time on the route (s).
    #[serde(serialize_with = "ser_4_decimals_or_nan", default = "crate::json_f64::nan")]
    pub route_time_s: f64,
    /// Weight version evaluated (0: never published).
    #[serde(default)]
    pub policy_version: u64,
    /// Wall time of the whole evaluation (s).
    #[serde(serialize_with = "ser_2_decimals", default = "crate::json_f64::nan")]
    pub eval_wall_s: f64,
}

impl EvalRow {
    /// The row of room `r` in the evaluation of `snap` that took `wall_s`.
    pub fn of(snap: &Snapshot, r: &RoomSummary, wall_s: f64) -> Self {
        let route = r.route.as_ref();
        Self {
            updates: snap.updates,
            env_steps: snap.env_steps,
            room: r.room.clone(),
            route_completed: route.map(|x| x.completed),
            score: route.map_or(f64::NAN, |x| x.score),
            success_rate: r.rates.success_rate,
            collision_rate: r.rates.collision_rate,
            timeout_rate: r.rates.timeout_rate,
            mean_time_s: r.rates.mean_time_s.unwrap_or(f64::NAN),
            episodes: r.rates.episodes as u64,
            mean_score: r.rates.mean_score,
            route_goals_reached: route.map(|x| x.goals_reached as u64),
            route_time_s: route.map_or(f64::NAN, |x| x.time_s),
            policy_version: snap.policy_version,
            eval_wall_s: wall_s,
        }
    }

    /// The columns an `eval.csv` must have to be read (the fields without a default).
    pub const REQUIRED: [&str; 3] = ["env_steps", "room", "score"];

    /// Reads the rows of the `eval.csv` at `path`, by column name; a row that does not parse
    /// (a torn last line) is skipped.
    pub fn read(path: &Path) -> anyhow::Result<Vec<EvalRow>> {
        let mut r = csv::Reader::from_path(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        let names = r.headers().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        if let Some(c) = Self::REQUIRED.iter().find(|c| !names.iter().any(|n| n == **c)) {
            anyhow::bail!("{}: no `{c}` column", path.display());
        }
        Ok(r.deserialize().filter_map(Result::ok).collect())
    }
}

/// Appends the rows to `path`, writing the header first when the file is new or empty (a
/// resumed run keeps appending to its file). The rows go out in one write.
pub fn append_csv(
    path: &Path,
    snap: &Snapshot,
    rows: &[RoomSummary],
    wall_s: f64,
) -> anyhow::Result<()> {
    append_rows(path, rows.iter().map(|r| EvalRow::of(snap, r, wall_s)))
}

fn log_rows(snap: &Snapshot, rows: &[RoomSummary], wall_s: f64) {
    for r in rows {
        let route = r.route.as_ref();
        tracing::info!(
            updates = snap.updates,
            env_steps = snap.env_steps,
            room = %r.room,
            route_completed = route.is_some_and(|x| x.completed),
            route_goals = %route.map_or("-".into(), |x| format!("{}/{}", x.goals_reached, x.goals)),
            route_score = route.map_or(f64::NAN, |x| x.score),
            success_rate = r.rates.success_rate,
            collision_rate = r.rates.collision_rate,
            mean_score = r.rates.mean_score,
            "evaluation"
        );
    }
    tracing::debug!(updates = snap.updates, wall_s, "evaluation done");
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// A snapshot of one policy (no policy average).
    fn snapshot(updates: u64, env_steps: u64, policy_version: u64, policy: Vec<u8>) -> Snapshot {
        Snapshot { updates, env_steps, policy_version, policy, online: None }
    }

    fn tiny_config() -> Config {
        let mut cfg = Config::default();
        cfg.env.max_steps = 30;
        cfg.learner.eval_every_updates = 10;
        cfg.learner.eval_episodes = 2;
        cfg.curriculum.rooms = vec!["env0".into(), "env3".into()];
        cfg
    }

    fn fresh_policy(cfg: &Config) -> Vec<u8> {
        let nets = crate::sac::SacNetworks::new(cfg, 3, &Device::Cpu).unwrap();
        dvnav_nav::nets::varmap_to_safetensors(&nets.actor.vars).unwrap()
    }

    #[test]
    fn the_evaluator_thread_appends_one_row_per_room_and_logs_the_routes() {
        let cfg = tiny_config();
        let dir = tempfile::tempdir().unwrap();
        let ev = Evaluator::start(&cfg, dir.path()).unwrap().unwrap();
        let policy = fresh_policy(&cfg);
        assert!(ev.submit(snapshot(10, 40, 3, policy.clone())));
        ev.finish();
        let ev = Evaluator::start(&cfg, dir.path()).unwrap().unwrap();
        assert!(ev.submit(snapshot(20, 80, 0, policy)));
        drop(ev);
        let text = std::fs::read_to_string(dir.path().join("eval.csv")).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], EVAL_CSV_HEADER, "one header, even after a restart");
        assert_eq!(lines.len(), 5, "{text}");
        let cols = EVAL_CSV_HEADER.split(',').count();
        let first: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(first.len(), cols);
        assert_eq!(&first[..3], ["10", "40", "env0"]);
        assert_eq!(first[9], "2", "episodes");
        assert!(lines[2].starts_with("10,40,env3,") && lines[4].starts_with("20,80,env3,"));
        // Rates are shares, the score is in [−1, 1].
        for l in &lines[1..] {
            let c: Vec<&str> = l.split(',').collect();
            let rates: f64 = c[5..8].iter().map(|x| x.parse::<f64>().unwrap()).sum();
            assert!((rates - 1.0).abs() < 1e-3, "{l}");
            let s: f64 = c[4].parse().unwrap();
            assert!((-1.0..=1.0).contains(&s), "{l}");
        }
        let logged = dvnav_eval::episode_log::read_episodes(&dir.path().join("mcap/eval")).unwrap();
        assert!(!logged.is_empty());
        assert!(logged.iter().all(|r| r.summary.actor == "eval"));
        assert!(logged.iter().any(|r| r.summary.policy_version == 3 && r.summary.stage == 0));
        assert!(logged.iter().any(|r| r.summary.room == "env3" && r.summary.stage == 1));
    }

    #[test]
    fn the_shipped_agent_passes_the_gate_test_in_training_evaluation_and_a_fresh_one_does_not() {
        // The same test as tests/shipped_model.rs runs through `dvnav eval --scenario gate`:
        // the shipped agent's twelve robots all arrive by the paper's routes.
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meta-r0.2");
        let model = dvnav_nav::policy::read_policy(&root).unwrap();
        let robots = evaluate_gate(&model.config, &model.weights).unwrap();
        let radii: Vec<f64> = robots.iter().map(|r| r.radius).collect();
        assert_eq!(radii.len(), 12, "{radii:?}");
        assert!((radii[0] - 0.20).abs() < 1e-9 && (radii[11] - 0.75).abs() < 1e-9, "{radii:?}");
        let failed: Vec<_> = robots.iter().filter(|r| !r.passes_gate_test()).collect();
        assert!(failed.is_empty(), "{failed:?}");
        // An untrained policy does not pass it.
        let cfg = tiny_config();
        let fresh = evaluate_gate(&cfg, &fresh_policy(&cfg)).unwrap();
        assert!(fresh.iter().filter(|r| r.passes_gate_test()).count() < 12);
    }

    #[test]
    fn with_a_selection_the_evaluator_writes_select_csv_and_keeps_the_best_agent_by_it() {
        let mut cfg = tiny_config();
        cfg.curriculum.rooms = vec!["env0".into()];
        cfg.learner.selection = Some(dvnav_config::SelectionConfig {
            rooms: "generated:paper:0..10".into(),
            room_count: 2,
            radii: vec![0.2, 0.4],
            episodes: 2,
            gate_min_passed: 12,
        });
        cfg.learner.eval_gate = true;
        let dir = tempfile::tempdir().unwrap();
        let ev = Evaluator::start(&cfg, dir.path()).unwrap().unwrap();
        assert!(ev.submit(snapshot(10, 40, 3, fresh_policy(&cfg))));
        ev.finish();
        let text = std::fs::read_to_string(dir.path().join(SELECT_CSV)).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], crate::selection::SELECT_CSV_HEADER);
        assert_eq!(lines.len(), 1 + 2 * 2, "two rooms, two robots: {text}");
        let best = crate::best_agent::BestAgent::open(dir.path());
        let kept = best.kept().expect("the first evaluation is kept");
        assert_eq!((kept.updates, kept.gate_bar, kept.gate_robots), (10, Some(12), Some(12)));
        // With the gate as a bar, the selection alone is the score.
        assert_eq!(kept.select_success, Some(kept.score));
    }

    #[test]
    fn the_evaluator_appends_the_gate_test_to_gate_csv_when_asked() {
        let mut cfg = tiny_config();
        cfg.curriculum.rooms = vec!["env0".into()];
        cfg.learner.eval_gate = true;
        let dir = tempfile::tempdir().unwrap();
        for updates in [10, 20] {
            let ev = Evaluator::start(&cfg, dir.path()).unwrap().unwrap();
            let policy = fresh_policy(&cfg);
            // At 20 the agent is an average: the online policy's test goes to gate-online.csv.
            let online = (updates == 20).then(|| policy.clone());
            assert!(ev.submit(Snapshot {
                updates,
                env_steps: 4 * updates,
                policy_version: 3,
                policy,
                online
            }));
            ev.finish();
        }
        let text = std::fs::read_to_string(dir.path().join("gate.csv")).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], GATE_CSV_HEADER, "one header, even after a restart");
        assert_eq!(lines.len(), 1 + 2 * 12, "{text}");
        assert!(lines[1].starts_with("10,40,3,0.2,") && lines[24].starts_with("20,80,3,0.75"));
        for l in &lines[1..] {
            let c: Vec<&str> = l.split(',').collect();
            assert_eq!(c.len(), GATE_CSV_HEADER.split(',').count(), "{l}");
            assert!(["success", "collision", "timeout"].contains(&c[4]), "{l}");
            assert!(["gate", "left", "other"].contains(&c[5]), "{l}");
            // A robot that did not arrive never passes.
            assert!(c[4] == "success" || c[8] == "false", "{l}");
        }
        let online = std::fs::read_to_string(dir.path().join(GATE_ONLINE_CSV)).unwrap();
        let online: Vec<&str> = online.lines().collect();
        assert_eq!(online[0], GATE_CSV_HEADER);
        assert_eq!(online.len(), 1 + 12, "only the evaluation with an average");
        // The same weights here, so the same rows as gate.csv's at 20 updates.
        assert_eq!(online[1..], lines[13..]);
        // The best agent is the same policy scoring the same at 20: the later one is kept,
        // scored with the gate, and loads as a checkpoint.
        let best = dir.path().join(crate::best_agent::BEST_DIR);
        let record: crate::best_agent::BestRecord =
            serde_json::from_slice(&std::fs::read(best.join("best.json")).unwrap()).unwrap();
        assert_eq!((record.updates, record.gate_robots), (20, Some(12)));
        let passed = lines[13..].iter().filter(|l| l.ends_with(",true")).count();
        assert_eq!(record.gate_passed, Some(passed));
        let expected = (record.rooms_success + passed as f64 / 12.0) / 2.0;
        assert!((record.score - expected).abs() < 1e-12, "{record:?}");
        let kept = dvnav_nav::policy::read_policy(&best).unwrap();
        assert_eq!(kept.config.learner.eval_gate, cfg.learner.eval_gate);
        MetaAgent::from_policy_file(&kept).unwrap();
        // Off: no gate.csv.
        cfg.learner.eval_gate = false;
        let dir = tempfile::tempdir().unwrap();
        let ev = Evaluator::start(&cfg, dir.path()).unwrap().unwrap();
        assert!(ev.submit(snapshot(10, 40, 3, fresh_policy(&cfg))));
        ev.finish();
        assert!(dir.path().join("eval.csv").exists() && !dir.path().join("gate.csv").exists());
        assert!(!dir.path().join(GATE_ONLINE_CSV).exists());
    }

    #[test]
    fn eval_rows_read_back_as_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("eval.csv");
        let rates = dvnav_eval::Rates {
            episodes: 2,
            success_rate: 0.5,
            collision_rate: 0.5,
            timeout_rate: 0.0,
            mean_score: 0.0,
            mean_time_s: None,
            mean_path_length_m: None,
            reversal_rate: f64::NAN,
            mean_abs_domega: f64::NAN,
            routes: None,
        };
        let room = |name: &str| RoomSummary {
            room: name.into(),
            radius: None,
            rates: rates.clone(),
            route: None,
        };
        let snap = snapshot(10, 40, 3, vec![]);
        append_csv(&path, &snap, &[room("env0"), room("env3")], 1.234).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text.lines().collect::<Vec<_>>(),
            [
                EVAL_CSV_HEADER,
                "10,40,env0,,NaN,0.5000,0.5000,0.0000,NaN,2,0.0000,,NaN,3,1.23",
                "10,40,env3,,NaN,0.5000,0.5000,0.0000,NaN,2,0.0000,,NaN,3,1.23"
            ]
        );
        let rows = EvalRow::read(&path).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            (rows[1].room.as_str(), rows[1].episodes, rows[1].route_completed),
            ("env3", 2, None)
        );
        assert!(rows[0].score.is_nan() && rows[0].success_rate == 0.5);
    }

    #[test]
    fn evaluation_is_off_at_zero_and_bad_weights_fail_cleanly() {
        let mut cfg = tiny_config();
        cfg.learner.eval_every_updates = 0;
        assert!(Evaluator::start(&cfg, Path::new("/nonexistent")).unwrap().is_none());
        let cfg = tiny_config();
        let rooms = vec![vec![Room::builtin("env0").unwrap()]];
        let snap = snapshot(1, 1, 0, b"junk".to_vec());
        assert!(evaluate(&cfg, &rooms, &snap, None).is_err());
    }

    #[test]
    fn a_set_stage_is_evaluated_in_its_first_rooms_with_the_episodes_spread_over_them() {
        let mut cfg = tiny_config();
        cfg.learner.eval_episodes = 6;
        cfg.curriculum.rooms = vec!["env0|generated:clutter:0..100:size=5".into(), "env3".into()];
        let stages = stage_rooms(&cfg).unwrap();
        let names = |s: &[Arc<Room>]| s.iter().map(|r| r.name().to_string()).collect::<Vec<_>>();
        assert_eq!(
            names(&stages[0]),
            [
                "env0",
                "generated:clutter:0:size=5",
                "generated:clutter:1:size=5",
                "generated:clutter:2:size=5"
            ]
        );
        assert_eq!(names(&stages[1]), ["env3"]);
        let snap = snapshot(1, 1, 0, fresh_policy(&cfg));
        let (rows, wall) = evaluate(&cfg, &stages, &snap, None).unwrap();
        // One row per evaluated room, stage 0's first; its 6 episodes spread 2, 2, 1, 1; the
        // route where the room has one (env0, env3; generated rooms have none).
        let got: Vec<(&str, usize, bool)> =
            rows.iter().map(|r| (r.room.as_str(), r.rates.episodes, r.route.is_some())).collect();
        assert_eq!(
            got,
            [
                ("env0", 2, true),
                ("generated:clutter:0:size=5", 2, false),
                ("generated:clutter:1:size=5", 1, false),
                ("generated:clutter:2:size=5", 1, false),
                ("env3", 6, true),
            ]
        );
        // The single-room stage is evaluated as before: alone, it gives the same episodes
        // (to rounding: the policy's batch holds other episodes then).
        let outcomes = |r: &RoomSummary| {
            let route = r.route.as_ref().map(|x| (x.goals_reached, x.legs.clone()));
            let rates = &r.rates;
            (r.room.clone(), rates.episodes, rates.success_rate, rates.collision_rate, route)
        };
        let (alone, _) = evaluate(&cfg, &stages[1..], &snap, None).unwrap();
        assert_eq!(alone.iter().map(outcomes).collect::<Vec<_>>(), [outcomes(&rows[4])]);
        // eval.csv keeps its columns.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("eval.csv");
        append_csv(&path, &snap, &rows, wall).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().next(), Some(EVAL_CSV_HEADER));
        assert_eq!(EvalRow::read(&path).unwrap().len(), 5);
        // A room in two stages gets a row in each.
        cfg.curriculum.rooms = vec!["env3".into(), "env3".into()];
        let (rows, _) = evaluate(&cfg, &stage_rooms(&cfg).unwrap(), &snap, None).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(outcomes(&rows[0]), outcomes(&rows[1]));
    }

    #[test]
    fn the_same_policy_scores_the_same_every_time() {
        let cfg = tiny_config();
        let rooms = vec![vec![Room::builtin("env1").unwrap()]];
        let snap = snapshot(1, 1, 0, fresh_policy(&cfg));
        let (a, _) = evaluate(&cfg, &rooms, &snap, None).unwrap();
        let (b, _) = evaluate(&cfg, &rooms, &snap, None).unwrap();
        assert_eq!(a, b);
        assert_eq!(a[0].rates.episodes, 2);
        assert_eq!(a[0].route.as_ref().unwrap().goals, 4);
    }
}
