//! What `dvnav eval` prints and writes: the table, the JSON rows, the per-episode CSV and the
//! trajectory figure.

use crate::render::trajectories::{RoomPanel, Trajectory, render};
use dvnav_config::EnvConfig;
use dvnav_eval::{EpisodeResult, RobotResult, RoomSummary, Task};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// One robot of the gate test, with how it was driven.
#[derive(Clone, Debug, Serialize)]
pub struct GateRow {
    /// Outcome, path, time, score and the way it went.
    #[serde(flatten)]
    pub robot: RobotResult,
    /// DVST scale factor μ (1 without DVST).
    pub mu: f64,
    /// `dvst`, `none` or `radius` (the robot's radius as the policy's input).
    pub transfer: &'static str,
    /// Passed the paper's gate test ([`RobotResult::passes_gate_test`]), so that scripts read
    /// the rule rather than restate it.
    pub passed: bool,
}

/// The report: one row per room (training, dynamic) or per robot (gate).
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum Rows {
    /// Per room (and robot, in the dynamic scenario).
    Rooms(Vec<RoomSummary>),
    /// Per robot of the gate test.
    Robots(Vec<GateRow>),
}

/// Gate rows with each robot's μ and how it was driven (`transfer`).
pub fn gate_rows(robots: Vec<RobotResult>, mus: &[f64], transfer: &'static str) -> Vec<GateRow> {
    robots
        .into_iter()
        .zip(mus)
        .map(|(robot, &mu)| GateRow { passed: robot.passes_gate_test(), robot, mu, transfer })
        .collect()
}

/// Per task, the index of its group (room, and robot radius when given) in order of first
/// appearance: the `stage` of its MCAP summaries, so `dvnav inspect` groups by room or robot.
pub fn group_index(tasks: &[Task]) -> Vec<usize> {
    let mut keys: Vec<(String, Option<u64>)> = Vec::new();
    tasks
        .iter()
        .map(|t| {
            let k = (t.room.name().to_string(), t.radius.map(f64::to_bits));
            match keys.iter().position(|x| *x == k) {
                Some(i) => i,
                None => {
                    keys.push(k);
                    keys.len() - 1
                }
            }
        })
        .collect()
}

fn pct(x: f64) -> String {
    if x.is_finite() { format!("{:.1}%", 100.0 * x) } else { "-".into() }
}

fn num(x: Option<f64>, digits: usize) -> String {
    match x {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => "-".into(),
    }
}

/// The table for a terminal.
pub fn table(rows: &Rows, mus: &[f64]) -> String {
    let mut s = String::new();
    match rows {
        Rows::Rooms(rooms) => {
            let robots = rooms.iter().any(|r| r.radius.is_some());
            let _ = write!(s, "{:<8}", "room");
            if robots {
                let _ = write!(s, " {:>6} {:>5}", "radius", "mu");
            }
            let _ = writeln!(
                s,
                " {:>8} {:>8} {:>9} {:>8} {:>10} {:>11}  route",
                "episodes", "success", "collision", "timeout", "mean_score", "mean_time_s"
            );
            for (i, r) in rooms.iter().enumerate() {
                let _ = write!(s, "{:<8}", r.room);
                if robots {
                    let mu = mus.get(i).copied();
                    let _ = write!(s, " {:>6} {:>5}", num(r.radius, 2), num(mu, 2));
                }
                let route = match &r.route {
                    Some(x) => format!(
                        "{}/{} goals, score {:.3}{}",
                        x.goals_reached,
                        x.goals,
                        x.score,
                        if x.completed { " (completed)" } else { "" }
                    ),
                    None => "-".into(),
                };
                let rt = &r.rates;
                let route = match &rt.routes {
                    Some(x) => format!(
                        "{route}; subgoals {}, planned {} m, ratio {}, replans {:.2}, blocked {}",
                        x.subgoals,
                        num(x.path_length_m, 1),
                        num(x.path_ratio, 2),
                        x.replans,
                        pct(x.blocked_rate)
                    ),
                    None => route,
                };
                let _ = writeln!(
                    s,
                    " {:>8} {:>8} {:>9} {:>8} {:>10} {:>11}  {route}",
                    rt.episodes,
                    pct(rt.success_rate),
                    pct(rt.collision_rate),
                    pct(rt.timeout_rate),
                    num(Some(rt.mean_score), 3),
                    num(rt.mean_time_s, 1),
                );
            }
        }
        Rows::Robots(robots) => {
            let _ = writeln!(
                s,
                "{:>6} {:>5}  {:<9} {:<5} {:>8} {:>7} {:>7}",
                "radius", "mu", "outcome", "route", "path_m", "time_s", "score"
            );
            for r in robots {
                let x = &r.robot;
                let _ = writeln!(
                    s,
                    "{:>6.2} {:>5.2}  {:<9} {:<5} {:>8.2} {:>7.1} {:>7.3}",
                    x.radius,
                    r.mu,
                    x.outcome.as_str(),
                    x.route.as_str(),
                    x.path_length_m,
                    x.time_s,
                    x.score
                );
            }
        }
    }
    s
}

/// Prints [`table`].
pub fn print_table(rows: &Rows, mus: &[f64]) {
    print!("{}", table(rows, mus));
}

/// Header of `episodes.csv`.
pub const EPISODES_CSV_HEADER: &str = "scenario,room,radius,kind,task,leg,seed,start_x,start_y,\
start_yaw,goal_x,goal_y,outcome,steps,time_s,path_length_m,score,episode_return";

/// One row per episode (route legs and random episodes).
pub fn write_csv(
    path: &Path,
    scenario: &str,
    tasks: &[Task],
    results: &[Vec<EpisodeResult>],
) -> anyhow::Result<()> {
    let mut s = String::from(EPISODES_CSV_HEADER);
    s.push('\n');
    for (i, (t, legs)) in tasks.iter().zip(results).enumerate() {
        for (leg, e) in legs.iter().enumerate() {
            let radius = t.radius.map_or(String::new(), |r| r.to_string());
            let _ = writeln!(
                s,
                "{scenario},{},{radius},{},{i},{leg},{},{:.4},{:.4},{:.4},{:.4},{:.4},{},{},{:.1},{:.4},{:.4},{:.4}",
                e.room,
                t.kind_name(),
                t.seed,
                e.start.x,
                e.start.y,
                e.start.yaw,
                e.goal[0],
                e.goal[1],
                e.outcome.as_str(),
                e.steps,
                e.time_s,
                e.path_length_m,
                e.score,
                e.episode_return
            );
        }
    }
    std::fs::write(path, s).map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}

/// Every trajectory over its room, one panel per room, coloured by outcome.
pub fn draw(
    png: &Path,
    tasks: &[Task],
    results: &[Vec<EpisodeResult>],
    cfg: &EnvConfig,
) -> anyhow::Result<()> {
    let mut panels: Vec<RoomPanel> = Vec::new();
    for (t, legs) in tasks.iter().zip(results) {
        let name = t.room.name();
        let i = match panels.iter().position(|p| p.name == name) {
            Some(i) => i,
            None => {
                panels.push(RoomPanel {
                    name: name.to_string(),
                    room: Some(t.room.spec().clone()),
                    trajectories: Vec::new(),
                });
                panels.len() - 1
            }
        };
        for e in legs {
            panels[i].trajectories.push(Trajectory {
                points: e.points(),
                outcome: Some(e.outcome),
                goal: e.goal,
                radius: Some(t.robot_radius(cfg)),
                plan: e.plan.clone(),
            });
        }
    }
    let canvas = render(&panels, 640)?;
    if let Some(dir) = png.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(png, canvas.encode_png()?)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", png.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_eval::{GateRoute, Rates, TaskKind};
    use dvnav_sim::Outcome;
    use dvnav_sim::Room;

    fn task(room: &str, radius: Option<f64>) -> Task {
        Task {
            room: Room::builtin(room).unwrap(),
            footprint: None,
            radius,
            kind: TaskKind::Random { index: 0 },
            seed: 1,
            policy: 0,
        }
    }

    #[test]
    fn groups_follow_rooms_and_robots_in_order() {
        let tasks = [
            task("env0", None),
            task("env0", None),
            task("env1", None),
            task("gate", Some(0.2)),
            task("gate", Some(0.25)),
            task("env0", None),
        ];
        assert_eq!(group_index(&tasks), vec![0, 0, 1, 2, 3, 0]);
    }

    #[test]
    fn gate_rows_serialize_with_the_field_names_of_the_issue() {
        let robot = RobotResult {
            room: "gate".into(),
            radius: 0.35,
            outcome: Outcome::Success,
            steps: 60,
            time_s: 12.0,
            path_length_m: 5.1,
            score: 0.7,
            route: GateRoute::Left,
            reversal_rate: 0.0,
            mean_abs_domega: 0.25,
        };
        let rows = Rows::Robots(gate_rows(vec![robot], &[1.75], "dvst"));
        let v = serde_json::to_value(&rows).unwrap();
        let o = &v[0];
        for k in [
            "radius",
            "outcome",
            "path_length_m",
            "time_s",
            "route",
            "mu",
            "reversal_rate",
            "mean_abs_domega",
        ] {
            assert!(o.get(k).is_some(), "{k} in {o}");
        }
        assert_eq!((o["outcome"].as_str(), o["route"].as_str()), (Some("success"), Some("left")));
        let t = table(&rows, &[]);
        assert!(t.contains("left") && t.contains("0.35") && t.contains("1.75"), "{t}");
    }

    #[test]
    fn the_room_table_shows_rates_and_dashes_for_missing_times() {
        let rates = Rates {
            episodes: 4,
            success_rate: 0.0,
            collision_rate: 0.75,
            timeout_rate: 0.25,
            mean_score: -1.0,
            mean_time_s: None,
            mean_path_length_m: None,
            reversal_rate: 0.02,
            mean_abs_domega: 0.3,
            routes: None,
        };
        let rows = Rows::Rooms(vec![RoomSummary {
            room: "env2".into(),
            radius: None,
            rates,
            route: None,
        }]);
        let t = table(&rows, &[]);
        let line = t.lines().nth(1).unwrap();
        assert!(line.starts_with("env2") && line.contains("75.0%") && line.contains(" - "), "{t}");
        assert!(!t.contains("radius"));
    }
}
