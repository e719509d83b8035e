//! Whether a batch's episode reports can be true of its transitions and of the run.
//!
//! [`crate::wire::batch_from_proto`] checks that a batch is well formed; this module checks that
//! what it *claims* is possible: the learner's curriculum and success metrics are moved by
//! episode reports alone, so a report that no transition backs (sixty "successful" episodes in
//! a one-transition batch) must never reach them. An episode's report travels in the batch that
//! holds its last transition (the actor's adder keeps them together), so within one batch:
//!
//! - as many reports of success or collision as terminated transitions, as many of timeout as
//!   truncated ones;
//! - 1 ≤ steps ≤ T_max (`env.max_steps`), and a success no quicker than the robot can drive from
//!   a start at least `env.min_start_goal_distance` away to within `env.goal_tolerance` of its
//!   goal ([`EpisodeBounds::min_success_steps`]);
//! - the return within `steps` times the bounds of one step's reward under the run's reward
//!   function ([`EpisodeBounds::step_reward`]);
//! - the stage one of the curriculum's.
//!
//! Each refusal names its own reason ([`WireError::field`]), which the learner counts it under.

use crate::core::TransitionBatch;
use crate::wire::WireError;
use dvnav_sim::{EnvConfig, Outcome};

/// What an honest actor's episodes stay within, from the run's configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeBounds {
    /// T_max: no episode is longer.
    pub max_steps: u32,
    /// Lowest and highest reward one step can earn.
    pub step_reward: (f64, f64),
    /// Stages of the curriculum: valid stages are `0..stages`.
    pub stages: u32,
    /// The fewest steps a successful episode can take.
    pub min_success_steps: u32,
}

impl EpisodeBounds {
    /// The bounds of a run with environments `env` and a curriculum of `stages` rooms.
    ///
    /// One step's reward is r_s, r_c, or c1·(d_t − d_{t+1}) − c2 with |d_t − d_{t+1}| ≤
    /// v_max·dt (the goal does not move). The progress bound is doubled: a jittered control
    /// period may run longer than `dt`, and a bound that refuses honest actors would cost
    /// their data, while one twice too wide still refuses every fabricated report of note.
    pub fn new(env: &EnvConfig, stages: usize) -> Self {
        let r = &env.reward;
        let progress = r.progress.abs() * env.v_max * env.dt * 2.0;
        let lo = r.success.min(r.collision).min(-progress - r.time_penalty.abs());
        let hi = r.success.max(r.collision).max(progress);
        // Starts are at least min_start_goal_distance from their goal and success is within
        // goal_tolerance of it; a step moves at most v_max·dt, doubled as above for jitter.
        let need = env.min_start_goal_distance - env.goal_tolerance;
        let per_step = 2.0 * env.v_max * env.dt;
        let min_success_steps = ((need / per_step) - 1e-9).floor().max(1.0) as u32;
        Self {
            max_steps: env.max_steps,
            step_reward: (lo, hi),
            stages: stages as u32,
            min_success_steps,
        }
    }
}

fn refuse(field: &'static str, reason: String) -> WireError {
    WireError { field, reason }
}

/// Checks the episode reports of `batch` against its transitions and `bounds` (see the
/// [module docs](self)).
pub fn check_episodes(batch: &TransitionBatch, bounds: &EpisodeBounds) -> Result<(), WireError> {
    let terminated = batch.terminated.iter().filter(|&&t| t).count();
    let truncated = batch.truncated.iter().filter(|&&t| t).count();
    let ended = batch.episodes.iter().filter(|e| e.outcome.is_terminal()).count();
    let timed_out = batch.episodes.iter().filter(|e| e.outcome == Outcome::Timeout).count();
    if ended != terminated || timed_out != truncated {
        return Err(refuse(
            "episode_count",
            format!(
                "{ended} success/collision and {timed_out} timeout reports for {terminated} \
                 terminated and {truncated} truncated transitions"
            ),
        ));
    }
    let (lo, hi) = bounds.step_reward;
    for (i, e) in batch.episodes.iter().enumerate() {
        if e.stage >= bounds.stages {
            return Err(refuse(
                "episode_stage",
                format!(
                    "episode {i} ran in stage {}; the curriculum has {}",
                    e.stage, bounds.stages
                ),
            ));
        }
        if e.steps == 0 || e.steps > bounds.max_steps {
            return Err(refuse(
                "episode_steps",
                format!("episode {i} took {} steps; T_max is {}", e.steps, bounds.max_steps),
            ));
        }
        if e.outcome == Outcome::Success && e.steps < bounds.min_success_steps {
            return Err(refuse(
                "episode_steps",
                format!(
                    "episode {i} reached its goal in {} steps; from the closest start allowed \
                     that takes at least {}",
                    e.steps, bounds.min_success_steps
                ),
            ));
        }
        let steps = e.steps as f64;
        let ret = e.episode_return as f64;
        // f32 sums of up to T_max rewards: a little slack for rounding.
        let slack = 1e-3 * (1.0 + ret.abs());
        if ret < steps * lo - slack || ret > steps * hi + slack {
            return Err(refuse(
                "episode_return",
                format!(
                    "episode {i} returned {ret} in {} steps, outside [{}, {}]",
                    e.steps,
                    steps * lo,
                    steps * hi
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::EpisodeStats;

    fn bounds() -> EpisodeBounds {
        EpisodeBounds::new(&EnvConfig::default(), 4)
    }

    fn episode(outcome: Outcome, steps: u32, episode_return: f32, stage: u32) -> EpisodeStats {
        EpisodeStats {
            env_index: 0,
            stage,
            room: "env0".into(),
            outcome,
            steps,
            episode_return,
            policy_version: 1,
            warmup: false,
            varied: false,
        }
    }

    /// Three transitions: the first ends in `end` (terminated, truncated or neither).
    fn batch(end: (bool, bool), episodes: Vec<EpisodeStats>) -> TransitionBatch {
        let mut b = TransitionBatch::with_capacity(1, 3);
        b.push(&[0.0], [0.0, 0.0], 10.0, &[1.0], end.0, end.1, 1);
        b.push(&[2.0], [0.0, 0.0], 0.1, &[3.0], false, false, 1);
        b.push(&[3.0], [0.0, 0.0], 0.1, &[4.0], false, false, 1);
        b.episodes = episodes;
        b
    }

    fn reason(b: &TransitionBatch) -> &'static str {
        check_episodes(b, &bounds()).unwrap_err().field
    }

    #[test]
    fn honest_reports_pass() {
        let ok = batch((true, false), vec![episode(Outcome::Success, 40, 12.5, 3)]);
        assert_eq!(check_episodes(&ok, &bounds()), Ok(()));
        let ok = batch((false, true), vec![episode(Outcome::Timeout, 400, -4.0, 0)]);
        assert_eq!(check_episodes(&ok, &bounds()), Ok(()));
        assert_eq!(check_episodes(&batch((false, false), vec![]), &bounds()), Ok(()));
    }

    #[test]
    fn reports_without_their_transitions_are_refused() {
        let sixty = vec![episode(Outcome::Success, 40, 10.0, 0); 60];
        assert_eq!(reason(&batch((true, false), sixty)), "episode_count");
        assert_eq!(
            reason(&batch((false, false), vec![episode(Outcome::Collision, 5, -10.0, 0)])),
            "episode_count"
        );
        // A timeout report for a terminated transition.
        assert_eq!(
            reason(&batch((true, false), vec![episode(Outcome::Timeout, 400, 0.0, 0)])),
            "episode_count"
        );
        // A terminated transition with no report.
        assert_eq!(reason(&batch((true, false), vec![])), "episode_count");
    }

    #[test]
    fn impossible_steps_returns_and_stages_are_refused() {
        let one = |e| batch((true, false), vec![e]);
        assert_eq!(reason(&one(episode(Outcome::Success, 0, 10.0, 0))), "episode_steps");
        assert_eq!(reason(&one(episode(Outcome::Success, 401, 10.0, 0))), "episode_steps");
        // 1 m to within 0.2 m at 0.5 m/s and 0.2 s a step (doubled for jitter): 4 steps; a
        // success in fewer than 3 is refused, a collision in one step is not.
        assert_eq!(bounds().min_success_steps, 3);
        assert_eq!(reason(&one(episode(Outcome::Success, 2, 10.0, 0))), "episode_steps");
        assert!(check_episodes(&one(episode(Outcome::Success, 3, 10.0, 0)), &bounds()).is_ok());
        assert!(check_episodes(&one(episode(Outcome::Collision, 1, -10.0, 0)), &bounds()).is_ok());
        // Ten steps cannot return more than ten successes' worth.
        assert_eq!(reason(&one(episode(Outcome::Success, 10, 1e4, 0))), "episode_return");
        assert_eq!(reason(&one(episode(Outcome::Success, 10, -101.0, 0))), "episode_return");
        assert_eq!(reason(&one(episode(Outcome::Success, 10, 10.0, 4))), "episode_stage");
        assert_eq!(reason(&one(episode(Outcome::Success, 10, 10.0, 300))), "episode_stage");
    }
}
