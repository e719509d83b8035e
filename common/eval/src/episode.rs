//! One evaluation episode: what it produced ([`EpisodeResult`]), how its steps are recorded
//! ([`Recorder`]), and [`run_episode`], which plays a [`NavEnv`]'s current episode to its end
//! with one policy.

use super::smoothness::{CommandCounter, CommandStats};
use dvnav_nav::policy::NavPolicy;
use dvnav_sim::{NavEnv, Pose2, RouteStats};
use dvnav_sim::{Outcome, score};
use serde::Serialize;

/// How one evaluation episode (or one leg of a route) went.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EpisodeResult {
    /// Room name.
    pub room: String,
    /// Where the episode started.
    pub start: Pose2,
    /// Its goal (m).
    pub goal: [f64; 2],
    /// Success, collision or timeout.
    pub outcome: Outcome,
    /// Control steps taken (T_s on success).
    pub steps: u32,
    /// Simulated seconds: `steps · dt`.
    pub time_s: f64,
    /// Length of the path the robot's centre drove (m).
    pub path_length_m: f64,
    /// The paper's score S: 1 − 2·T_s/T_max on success, −1 otherwise ([`dvnav_sim::score`]).
    pub score: f64,
    /// Undiscounted sum of rewards.
    pub episode_return: f64,
    /// The planned route of a long task (`env.subgoals`): its planned length, replans, whether
    /// it was blocked. Absent without subgoals.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub route: Option<RouteStats>,
    /// How smooth its angular commands were.
    #[serde(skip)]
    pub commands: CommandStats,
    /// The start pose, then the pose after every step (for figures and logs).
    #[serde(skip)]
    pub trajectory: Vec<Pose2>,
    /// The planned path the episode started with (`env.subgoals`; empty without one).
    #[serde(skip)]
    pub plan: Vec<[f64; 2]>,
}

impl EpisodeResult {
    /// The trajectory's positions (m).
    pub fn points(&self) -> Vec<[f64; 2]> {
        self.trajectory.iter().map(Pose2::position).collect()
    }
}

/// What an episode log needs of one step beyond the pose (kept only when logging).
#[derive(Clone, Debug, PartialEq)]
pub struct StepSample {
    /// Step number (0: the pose after the reset).
    pub step: u32,
    /// The robot's pose.
    pub pose: Pose2,
    /// The scan at that pose (m).
    pub scan: Vec<f32>,
    /// The command that led here (clamped), m/s and rad/s; 0 at step 0.
    pub v: f64,
    /// Angular part of the command (rad/s).
    pub omega: f64,
    /// Reward of the step that led here (0 at step 0).
    pub reward: f32,
    /// Distance to the goal (m).
    pub goal_distance: f64,
    /// Goal bearing in the robot frame (rad).
    pub goal_angle: f64,
    /// The subgoal the agent observed (`env.subgoals`); `None` when it saw the final goal.
    pub subgoal: Option<[f64; 2]>,
    /// The planned path, at the first step and at every step where it changed (a replan; an
    /// empty one when a replan found none); `None` when unchanged.
    pub plan: Option<Vec<[f64; 2]>>,
}

/// Records one episode of a [`NavEnv`] step by step: the trajectory, the path length and, when
/// asked, every step's scan and command for an episode log.
#[derive(Clone, Debug)]
pub struct Recorder {
    trajectory: Vec<Pose2>,
    path_length: f64,
    commands: CommandCounter,
    samples: Option<Vec<StepSample>>,
    plan: Vec<[f64; 2]>,
    /// The plan as the last kept sample saw it.
    sampled_plan: Vec<[f64; 2]>,
}

impl Recorder {
    /// Starts recording the episode `env` has just been reset to; `samples` keeps every step
    /// for a log.
    pub fn begin(env: &NavEnv, samples: bool) -> Recorder {
        let mut r = Recorder {
            trajectory: Vec::with_capacity(64),
            path_length: 0.0,
            commands: CommandCounter::new(env.config().omega_max),
            samples: samples.then(Vec::new),
            plan: env.planned_path().map(|p| p.points.clone()).unwrap_or_default(),
            sampled_plan: Vec::new(),
        };
        r.trajectory.push(env.pose());
        r.sample(env, 0.0);
        r
    }

    /// Records the state after a step that paid `reward`.
    pub fn record(&mut self, env: &NavEnv, reward: f32) {
        let p = env.pose();
        if let Some(last) = self.trajectory.last() {
            self.path_length += (p.x - last.x).hypot(p.y - last.y);
        }
        self.trajectory.push(p);
        self.commands.push(env.velocity().1);
        self.sample(env, reward);
    }

    fn sample(&mut self, env: &NavEnv, reward: f32) {
        if let Some(s) = &mut self.samples {
            let (v, omega) = env.velocity();
            let plan = env.planned_path().map_or(&[][..], |p| p.points.as_slice());
            let changed = plan != self.sampled_plan.as_slice();
            if changed {
                self.sampled_plan = plan.to_vec();
            }
            s.push(StepSample {
                step: env.steps(),
                pose: env.pose(),
                scan: env.scan().to_vec(),
                v,
                omega,
                reward,
                goal_distance: env.goal_distance(),
                goal_angle: env.goal_angle(),
                subgoal: env.subgoal(),
                plan: changed.then(|| plan.to_vec()),
            });
        }
    }

    /// The result of the finished episode, and its steps when they were kept.
    ///
    /// # Panics
    /// If the episode of `env` has not ended.
    pub fn finish(self, env: &NavEnv) -> (EpisodeResult, Option<Vec<StepSample>>) {
        let outcome = env.done().expect("the episode has ended");
        let steps = env.steps();
        let cfg = env.config();
        let result = EpisodeResult {
            room: env.room().name().to_string(),
            start: env.start(),
            goal: env.goal(),
            outcome,
            steps,
            time_s: steps as f64 * cfg.dt,
            path_length_m: self.path_length,
            score: score(outcome, steps, cfg.max_steps),
            episode_return: env.episode_return(),
            route: env.route_stats(),
            commands: self.commands.stats(),
            trajectory: self.trajectory,
            plan: self.plan,
        };
        (result, self.samples)
    }
}

/// Plays the current episode of `env` (just reset, by [`NavEnv::reset`] or
/// [`NavEnv::reset_to`]) to its end with `policy`, one observation at a time.
pub fn run_episode(env: &mut NavEnv, policy: &mut dyn NavPolicy) -> anyhow::Result<EpisodeResult> {
    anyhow::ensure!(
        policy.beams() == env.lidar().beams(),
        "the policy expects {} beams, the environment has {}",
        policy.beams(),
        env.lidar().beams()
    );
    anyhow::ensure!(
        policy.obs_dim() == env.obs_dim(),
        "the policy takes observations of {} values, the environment writes {}",
        policy.obs_dim(),
        env.obs_dim()
    );
    let mut obs = vec![0.0f32; env.obs_dim()];
    let mut rec = Recorder::begin(env, false);
    while env.done().is_none() {
        env.write_obs(&mut obs);
        let (v, omega) = policy.act(&obs)?;
        let out = env.step(v, omega);
        rec.record(env, out.reward);
    }
    Ok(rec.finish(env).0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_config::{Config, EnvConfig};
    use dvnav_nav::policy::PidPolicy;
    use dvnav_sim::{Room, RoomSpec};
    use std::sync::Arc;

    /// Drives straight ahead at a fixed speed whatever it sees.
    struct Straight(f64);
    impl NavPolicy for Straight {
        fn beams(&self) -> usize {
            540
        }
        fn act(&mut self, _: &[f32]) -> anyhow::Result<(f64, f64)> {
            Ok((self.0, 0.0))
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (0.5, 1.0)
        }
    }

    fn empty() -> Arc<Room> {
        Arc::new(Room::new(RoomSpec::empty("empty", 8.0)))
    }

    #[test]
    fn pid_reaches_a_goal_ahead_with_the_expected_time_path_and_score() {
        let cfg = Config::default();
        let mut env = NavEnv::new(empty(), &cfg.env, 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 0.0]);
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        let r = run_episode(&mut env, &mut pid).unwrap();
        assert_eq!(r.outcome, Outcome::Success);
        // 0.1 m per step at full speed to x = 1.5, then v = x_g (kp 1): each step covers
        // 0.2 of the remaining 0.5 m, and the goal (0.2 m tolerance) is within reach after
        // 5 more steps, at 2 − 0.5·0.8⁵ = 1.83616 m.
        assert_eq!(r.steps, 20);
        assert!((r.time_s - 4.0).abs() < 1e-9);
        assert!((r.path_length_m - 1.83616).abs() < 1e-6, "{}", r.path_length_m);
        assert!((r.score - (1.0 - 2.0 * 20.0 / 400.0)).abs() < 1e-12);
        assert_eq!(r.trajectory.len(), 21);
        assert_eq!(r.trajectory[0], Pose2::new(0.0, 0.0, 0.0));
        assert_eq!(r.room, "empty");
    }

    #[test]
    fn driving_into_a_wall_collides_and_standing_still_times_out() {
        let cfg = EnvConfig { max_steps: 50, ..EnvConfig::default() };
        let mut env = NavEnv::new(empty(), &cfg, 1);
        // Facing the wall at x = 4, goal behind.
        env.reset_to(Pose2::new(2.0, 0.0, 0.0), [-2.0, 0.0]);
        let r = run_episode(&mut env, &mut Straight(0.5)).unwrap();
        assert_eq!(r.outcome, Outcome::Collision);
        assert_eq!(r.score, -1.0);
        // The nose (x + 0.2) stops at the wall (x = 4), in contact, within one sub-step.
        let x = r.trajectory.last().unwrap().x;
        assert!((3.8 - 1e-9..=3.82 + 1e-9).contains(&x), "{x}");
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 0.0]);
        let r = run_episode(&mut env, &mut Straight(0.0)).unwrap();
        assert_eq!(
            (r.outcome, r.steps, r.score, r.path_length_m),
            (Outcome::Timeout, 50, -1.0, 0.0)
        );
    }

    #[test]
    fn recorder_keeps_samples_only_when_asked() {
        let cfg = EnvConfig::default();
        let mut env = NavEnv::new(empty(), &cfg, 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [1.0, 0.0]);
        let mut with = Recorder::begin(&env, true);
        let without = Recorder::begin(&env, false);
        let out = env.step(0.5, 0.1);
        with.record(&env, out.reward);
        assert!(without.samples.is_none());
        let s = with.samples.as_ref().unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!((s[0].step, s[0].v, s[0].reward), (0, 0.0, 0.0));
        assert_eq!((s[1].step, s[1].v, s[1].omega, s[1].reward), (1, 0.5, 0.1, out.reward));
        assert_eq!(s[1].scan.len(), 540);
    }

    #[test]
    fn a_policy_for_another_scan_is_refused() {
        let cfg = Config::default();
        let mut env = NavEnv::new(empty(), &cfg.env, 1);
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        pid.env.lidar.beams = 100;
        assert!(run_episode(&mut env, &mut pid).is_err());
    }
}
