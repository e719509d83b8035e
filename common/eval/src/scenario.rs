//! The evaluation scenarios as [`Task`] lists, and their results as report rows.
//!
//! - **training**: per room (Env_0..Env_3) its evaluation route and N random episodes, all
//!   driven by one policy (one batch); one [`RoomSummary`] per room.
//! - **gate**: the gate room's route once per circular robot of the given radii, each robot
//!   driven by its own policy (the plain meta agent, or a DVST wrapper around it); one
//!   [`RobotResult`] per robot, with the way it went ([`GateRoute`]).
//! - **dynamic**: the dynamic room's route (obstacles appear on it mid-episode) once per robot
//!   size; one [`RoomSummary`] per robot.

use super::episode::EpisodeResult;
use super::gate::{GateGeometry, GateRoute};
use super::smoothness::CommandStats;
use super::summary::{RoomSummary, RouteResult, aggregate};
use super::task::{Task, TaskKind, episode_seed};
use dvnav_sim::Outcome;
use dvnav_sim::{Footprint, Room, Route};
use serde::Serialize;
use std::sync::Arc;

/// Name of the evaluation route in the training rooms (design §4).
pub const TRAINING_ROUTE: &str = "eval";

/// Per room: its route named `route` (when it has one) and `episodes` random episodes seeded
/// from `seed`, all driven by policy 0 with the configured robot.
pub fn training_tasks(rooms: &[Arc<Room>], route: &str, episodes: usize, seed: u64) -> Vec<Task> {
    let mut tasks = Vec::new();
    for room in rooms {
        if let Some(r) = room.spec().route(route) {
            tasks.push(Task {
                room: room.clone(),
                footprint: None,
                radius: None,
                kind: TaskKind::Route(r.clone()),
                seed: episode_seed(seed, room.name(), usize::MAX),
                policy: 0,
            });
        }
        tasks.extend((0..episodes).map(|index| Task {
            room: room.clone(),
            footprint: None,
            radius: None,
            kind: TaskKind::Random { index },
            seed: episode_seed(seed, room.name(), index),
            policy: 0,
        }));
    }
    tasks
}

/// `episodes` random episodes in every room for every robot: robot i (a footprint, and the
/// radius reports give it; `None`: the configured robot) is driven by policy i. Episode k of a
/// room starts from the same seed for every robot, so robots of one size meet the same tasks.
pub fn room_tasks(
    rooms: &[Arc<Room>],
    robots: &[Option<(Footprint, f64)>],
    episodes: usize,
    seed: u64,
) -> Vec<Task> {
    let mut tasks = Vec::new();
    for room in rooms {
        for (i, robot) in robots.iter().enumerate() {
            tasks.extend((0..episodes).map(|index| Task {
                room: room.clone(),
                footprint: robot.as_ref().map(|r| r.0.clone()),
                radius: robot.as_ref().map(|r| r.1),
                kind: TaskKind::Random { index },
                seed: episode_seed(seed, room.name(), index),
                policy: i,
            }));
        }
    }
    tasks
}

/// `route` of `room` once per circular robot of `radii`; robot i is driven by policy i.
pub fn robot_tasks(room: &Arc<Room>, route: &Route, radii: &[f64], seed: u64) -> Vec<Task> {
    radii
        .iter()
        .enumerate()
        .map(|(i, &r)| Task {
            room: room.clone(),
            footprint: Some(Footprint::circle(r)),
            radius: Some(r),
            kind: TaskKind::Route(route.clone()),
            seed: episode_seed(seed, room.name(), i),
            policy: i,
        })
        .collect()
}

/// One row per room and robot (in the tasks' order): rates over the random episodes and the
/// route's result. A room evaluated by its route alone (the dynamic scenario, or no random
/// episodes) gets its rates over the route's legs instead, and `episodes` says how many.
pub fn room_summaries(tasks: &[Task], results: &[Vec<EpisodeResult>]) -> Vec<RoomSummary> {
    let mut keys: Vec<(String, Option<u64>)> = Vec::new();
    let key = |t: &Task| (t.room.name().to_string(), t.radius.map(f64::to_bits));
    for t in tasks {
        if !keys.contains(&key(t)) {
            keys.push(key(t));
        }
    }
    keys.into_iter()
        .map(|k| {
            let mut random = Vec::new();
            let mut route = None;
            let mut route_legs: Vec<EpisodeResult> = Vec::new();
            for (t, legs) in tasks.iter().zip(results).filter(|(t, _)| key(t) == k) {
                match &t.kind {
                    TaskKind::Random { .. } => random.extend(legs.iter().cloned()),
                    TaskKind::Route(r) => {
                        route = Some(RouteResult::new(&r.name, &r.goals, legs));
                        route_legs.extend(legs.iter().cloned());
                    }
                }
            }
            let rates = if random.is_empty() { aggregate(&route_legs) } else { aggregate(&random) };
            RoomSummary { room: k.0, radius: k.1.map(f64::from_bits), rates, route }
        })
        .collect()
}

/// One robot of the gate test.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RobotResult {
    /// Room name.
    pub room: String,
    /// The robot's radius (m).
    pub radius: f64,
    /// How its route ended: success when every goal was reached, else the failed leg's
    /// outcome.
    pub outcome: Outcome,
    /// Control steps over the route.
    pub steps: u32,
    /// Simulated seconds over the route.
    pub time_s: f64,
    /// Length of the path driven (m).
    pub path_length_m: f64,
    /// The route's score ([`RouteResult::score`]).
    pub score: f64,
    /// Which way it went.
    pub route: GateRoute,
    /// Share of the route's control cycles where ω changed sign by more than ω_max.
    pub reversal_rate: f64,
    /// Mean |Δω| per control cycle over the route (rad/s).
    pub mean_abs_domega: f64,
}

/// The paper's twelve gate-test robots (design §2): R = 0.20, 0.25, …, 0.75 m.
pub const GATE_RADII: &str = "0.20:0.75:0.05";

/// Longest path (m) of a robot that passes the gate test through the gate: the straight line
/// from start to goal is 3.0 m.
pub const GATE_STRAIGHT_M: f64 = 3.2;

impl RobotResult {
    /// The route the paper's gate test asks of a robot of this size: through the gate at
    /// R ≤ 0.25 m (it fits), round the wall's left end above.
    pub fn expected_gate_route(&self) -> GateRoute {
        if self.radius <= 0.25 + 1e-9 { GateRoute::Gate } else { GateRoute::Left }
    }

    /// Whether this robot passed the paper's gate test: it arrived, by
    /// [`RobotResult::expected_gate_route`], and through the gate on a near-straight path
    /// (shorter than [`GATE_STRAIGHT_M`]).
    pub fn passes_gate_test(&self) -> bool {
        let want = self.expected_gate_route();
        self.outcome == Outcome::Success
            && self.route == want
            && (want == GateRoute::Left || self.path_length_m < GATE_STRAIGHT_M)
    }
}

/// One row per route task of `tasks` (a robot of the gate test), classified by `geometry`.
pub fn robot_results(
    tasks: &[Task],
    results: &[Vec<EpisodeResult>],
    geometry: &GateGeometry,
) -> Vec<RobotResult> {
    tasks
        .iter()
        .zip(results)
        .filter_map(|(t, legs)| {
            let TaskKind::Route(r) = &t.kind else { return None };
            let summary = RouteResult::new(&r.name, &r.goals, legs);
            let outcome = match legs.last() {
                Some(l) if !summary.completed => l.outcome,
                _ => Outcome::Success,
            };
            let path: Vec<[f64; 2]> = legs.iter().flat_map(|l| l.points()).collect();
            let commands = legs.iter().fold(CommandStats::default(), |a, l| a.pooled(l.commands));
            Some(RobotResult {
                room: t.room.name().to_string(),
                radius: t.radius.unwrap_or(f64::NAN),
                outcome,
                steps: legs.iter().map(|l| l.steps).sum(),
                time_s: summary.time_s,
                path_length_m: summary.path_length_m,
                score: summary.score,
                route: geometry.classify(&path),
                reversal_rate: commands.reversal_rate(),
                mean_abs_domega: commands.mean_abs_domega(),
            })
        })
        .collect()
}

/// Radii `START:STOP:STEP` (m), both ends included: `0.20:0.75:0.05` is the paper's twelve
/// robots. A single number is one radius.
pub fn parse_radii(s: &str) -> anyhow::Result<Vec<f64>> {
    let bad = |why: &str| {
        anyhow::anyhow!(
            "radii `{s}`: {why} (expected START:STOP:STEP, e.g. 0.20:0.75:0.05, or a list, \
             e.g. 0.2,0.3,0.4,0.6)"
        )
    };
    if s.contains(',') {
        let radii: Vec<f64> = s
            .split(',')
            .map(|p| p.trim().parse::<f64>().map_err(|_| bad(&format!("`{p}` is not a number"))))
            .collect::<anyhow::Result<_>>()?;
        if let Some(r) = radii.iter().find(|r| !(r.is_finite() && **r > 0.0)) {
            return Err(bad(&format!("radii must be above 0, got {r}")));
        }
        return Ok(radii);
    }
    let parts: Vec<f64> = s
        .split(':')
        .map(|p| p.trim().parse::<f64>().map_err(|_| bad(&format!("`{p}` is not a number"))))
        .collect::<anyhow::Result<_>>()?;
    let (start, stop, step) = match parts.as_slice() {
        [r] => (*r, *r, 1.0),
        [a, b, c] => (*a, *b, *c),
        _ => return Err(bad("give one radius or three numbers")),
    };
    if !(start.is_finite() && start > 0.0) {
        return Err(bad("radii must be above 0"));
    }
    if !(stop.is_finite() && stop >= start) {
        return Err(bad("STOP must not be below START"));
    }
    if !(step.is_finite() && step > 0.0) {
        return Err(bad("STEP must be above 0"));
    }
    // Count with a tolerance, so 0.20:0.75:0.05 includes 0.75 despite rounding.
    let n = ((stop - start) / step + 1e-6).floor() as usize + 1;
    if n > 1000 {
        return Err(bad("more than 1000 radii"));
    }
    // Rounded to 1e-9 m: 0.2 + 3·0.05 prints as 0.35, not 0.35000000000000003.
    Ok((0..n).map(|i| ((start + i as f64 * step) * 1e9).round() / 1e9).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{RunOptions, run_tasks};
    use dvnav_config::Config;
    use dvnav_nav::policy::{NavPolicy, PidPolicy};
    use dvnav_sim::Pose2;

    #[test]
    fn radii_ranges_include_both_ends_and_refuse_nonsense() {
        let r = parse_radii("0.20:0.75:0.05").unwrap();
        assert_eq!(r.len(), 12);
        assert_eq!((r[0], r[3], r[11]), (0.2, 0.35, 0.75));
        assert_eq!(parse_radii("0.4").unwrap(), vec![0.4]);
        assert_eq!(parse_radii("0.2:0.6:0.2").unwrap(), vec![0.2, 0.4, 0.6]);
        assert_eq!(parse_radii("0.2, 0.3,0.6").unwrap(), vec![0.2, 0.3, 0.6]);
        assert!(parse_radii("0.2,-1").unwrap_err().to_string().contains("above 0"));
        for bad in ["", "a:b:c", "0.2:0.1:0.05", "0.2:0.5:0", "0:0.5:0.1", "0.2:0.5", "-1"] {
            let e = parse_radii(bad).unwrap_err().to_string();
            assert!(e.contains("radii") && e.contains("START:STOP:STEP"), "{bad}: {e}");
        }
        assert!(parse_radii("0.1:1000:0.1").is_err());
    }

    /// The PID controller that also records the radius at the end of each observation.
    struct RadiusProbe {
        pid: PidPolicy,
        seen: Vec<f32>,
    }
    impl NavPolicy for RadiusProbe {
        fn beams(&self) -> usize {
            self.pid.beams()
        }
        fn obs_dim(&self) -> usize {
            self.pid.obs_dim()
        }
        fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
            self.seen.push(obs[obs.len() - 1]);
            self.pid.act(obs)
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            self.pid.velocity_bounds()
        }
    }

    #[test]
    fn gate_robots_of_a_radius_input_policy_each_see_their_own_radius() {
        let mut cfg = Config::default();
        cfg.env.radius_input = true;
        cfg.env.max_steps = 30;
        let room = Room::builtin("gate").unwrap();
        let route = room.spec().route("gate").unwrap().clone();
        let radii = [0.2, 0.45, 0.7];
        let tasks = robot_tasks(&room, &route, &radii, 0);
        let pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        let mut probes: Vec<RadiusProbe> =
            radii.iter().map(|_| RadiusProbe { pid: pid.clone(), seen: Vec::new() }).collect();
        let mut policies: Vec<&mut dyn NavPolicy> =
            probes.iter_mut().map(|p| p as &mut dyn NavPolicy).collect();
        run_tasks(&tasks, &cfg.env, &mut policies, RunOptions::default(), &mut |_, _| Ok(()))
            .unwrap();
        for (p, &r) in probes.iter().zip(&radii) {
            assert!(!p.seen.is_empty());
            assert!(p.seen.iter().all(|&x| x == r as f32), "robot {r}: {:?}", &p.seen[..3]);
        }
        // A policy of the standard layout is refused before anything runs.
        let mut plain = pid.clone();
        plain.env.radius_input = false;
        let e = run_tasks(
            &tasks[..1],
            &cfg.env,
            &mut [&mut plain],
            RunOptions::default(),
            &mut |_, _| Ok(()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("545"), "{e}");
    }

    #[test]
    fn training_tasks_put_each_rooms_route_first_and_seed_episodes_apart() {
        let rooms: Vec<_> = ["env0", "env1"].iter().map(|n| Room::builtin(n).unwrap()).collect();
        let tasks = training_tasks(&rooms, TRAINING_ROUTE, 3, 7);
        assert_eq!(tasks.len(), 8);
        assert!(matches!(&tasks[0].kind, TaskKind::Route(r) if r.goals.len() == 4));
        assert!(matches!(tasks[1].kind, TaskKind::Random { index: 0 }));
        assert_eq!(tasks[4].room.name(), "env1");
        let seeds: std::collections::BTreeSet<u64> = tasks.iter().map(|t| t.seed).collect();
        assert_eq!(seeds.len(), 8);
        // The same seed gives the same tasks; another seed other starts.
        let again = training_tasks(&rooms, TRAINING_ROUTE, 3, 7);
        assert!(tasks.iter().zip(&again).all(|(a, b)| a.seed == b.seed));
        assert_ne!(training_tasks(&rooms, TRAINING_ROUTE, 3, 8)[1].seed, tasks[1].seed);
    }

    /// Turns in place: never collides, never arrives.
    struct Spin;
    impl NavPolicy for Spin {
        fn beams(&self) -> usize {
            540
        }
        fn act(&mut self, _: &[f32]) -> anyhow::Result<(f64, f64)> {
            Ok((0.0, 1.0))
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (0.5, 1.0)
        }
    }

    #[test]
    fn a_spinning_robot_times_out_everywhere_and_the_summary_says_so() {
        let cfg = Config::default();
        let env = dvnav_config::EnvConfig { max_steps: 20, ..cfg.env.clone() };
        let rooms = vec![Room::builtin("env3").unwrap()];
        let tasks = training_tasks(&rooms, TRAINING_ROUTE, 5, 1);
        let results =
            run_tasks(&tasks, &env, &mut [&mut Spin], RunOptions::default(), &mut |_, _| Ok(()))
                .unwrap();
        let rows = room_summaries(&tasks, &results);
        assert_eq!(rows.len(), 1);
        let row = &rows[0];
        assert_eq!((row.room.as_str(), row.rates.episodes), ("env3", 5));
        assert_eq!(
            (row.rates.timeout_rate, row.rates.mean_score, row.rates.mean_time_s),
            (1.0, -1.0, None)
        );
        let route = row.route.as_ref().unwrap();
        assert!(!route.completed);
        assert_eq!((route.goals_reached, route.score, route.legs.len()), (0, -1.0, 4));
    }

    #[test]
    fn pid_on_the_gate_route_goes_through_the_gate_when_it_fits() {
        // PID drives straight at the goal: a 0.2 m robot passes the 0.55 m gate, a 0.35 m
        // robot hits the wall beside it; both are classified from their paths.
        let cfg = Config::default();
        let room = Room::builtin("gate").unwrap();
        let route = room.spec().route("gate").unwrap().clone();
        let tasks = robot_tasks(&room, &route, &[0.2, 0.35], 0);
        let mut a = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        let mut b = a.clone();
        let results = run_tasks(
            &tasks,
            &cfg.env,
            &mut [&mut a, &mut b],
            RunOptions::default(),
            &mut |_, _| Ok(()),
        )
        .unwrap();
        let geometry = GateGeometry::from_room(room.spec(), &route).unwrap();
        let rows = robot_results(&tasks, &results, &geometry);
        assert_eq!(rows.len(), 2);
        assert_eq!(
            (rows[0].radius, rows[0].outcome, rows[0].route),
            (0.2, Outcome::Success, GateRoute::Gate)
        );
        assert!((rows[0].path_length_m - 2.8).abs() < 0.11, "{}", rows[0].path_length_m);
        assert_eq!(
            (rows[1].radius, rows[1].outcome, rows[1].route),
            (0.35, Outcome::Collision, GateRoute::Other)
        );
        // It touches the gate's corners (±0.275, −0.1) when its centre is at
        // y = −0.1 − √(0.35² − 0.275²) ≈ −0.3165.
        let end = results[1][0].trajectory.last().unwrap();
        let contact = -0.1 - (0.35f64.powi(2) - 0.275f64.powi(2)).sqrt();
        assert!(end.x.abs() < 1e-6 && (end.y - contact).abs() < 0.021, "{end:?}");
        assert_eq!(results[1][0].start, Pose2::new(0.0, -1.5, std::f64::consts::FRAC_PI_2));
        // Dynamic-style summaries: one row per robot, rates over the route's legs.
        let summaries = room_summaries(&tasks, &results);
        assert_eq!(summaries.len(), 2);
        assert_eq!((summaries[1].radius, summaries[1].rates.episodes), (Some(0.35), 1));
        assert_eq!(summaries[1].rates.collision_rate, 1.0);
    }

    #[test]
    fn the_gate_test_asks_the_gate_of_small_robots_on_a_straight_path_and_the_left_of_others() {
        let robot =
            |radius: f64, outcome: Outcome, route: GateRoute, path_length_m: f64| RobotResult {
                room: "gate".into(),
                radius,
                outcome,
                steps: 0,
                time_s: 0.0,
                path_length_m,
                score: 0.0,
                route,
                reversal_rate: 0.0,
                mean_abs_domega: 0.0,
            };
        let radii = parse_radii(GATE_RADII).unwrap();
        assert_eq!(
            radii.len(),
            dvnav_config::GATE_ROBOTS,
            "the gate bar (learner.selection) counts them"
        );
        assert!(robot(0.25, Outcome::Success, GateRoute::Gate, 3.0).passes_gate_test());
        assert!(!robot(0.25, Outcome::Success, GateRoute::Gate, 3.5).passes_gate_test());
        assert!(!robot(0.25, Outcome::Success, GateRoute::Left, 6.0).passes_gate_test());
        assert!(robot(0.30, Outcome::Success, GateRoute::Left, 6.0).passes_gate_test());
        assert!(!robot(0.30, Outcome::Success, GateRoute::Gate, 3.0).passes_gate_test());
        assert!(!robot(0.50, Outcome::Timeout, GateRoute::Left, 6.0).passes_gate_test());
        assert!(!robot(0.50, Outcome::Success, GateRoute::Other, 6.0).passes_gate_test());
    }
}
