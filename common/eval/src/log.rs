//! [`EvalLogger`]: evaluation legs into MCAP files (`DIR/{prefix}-NNNNN.mcap`), in the same
//! format as training episodes ([`crate::episode_log`]), so `dvnav inspect`, `dvnav plot
//! trajectories` and Foxglove read them.
//!
//! How the summary fields are used for evaluation: `actor` is the logger's name (`eval`),
//! `stage` the index of the room in its scenario (for the in-training evaluation: its
//! curriculum stage), `env_index` the leg of the route (0 for a random episode), `seed` the
//! task's seed, `policy_version` what the caller gives (0 when unknown), `footprint` the
//! robot's footprint name.

use super::runner::LegDone;
use super::task::Task;
use crate::episode_log::{EpisodeLogger, EpisodeStart, LogMetadata, StepLog};
use dvnav_nav::control::velocity_to_action;
use std::path::Path;

/// Writes evaluation legs (with their kept steps) to MCAP.
#[derive(Debug)]
pub struct EvalLogger {
    logger: EpisodeLogger,
    name: String,
    next_id: u64,
    /// Stamped into every summary.
    pub policy_version: u64,
}

impl EvalLogger {
    /// A logger writing `dir/{prefix}-NNNNN.mcap`, `episodes_per_file` legs per file; `name`
    /// goes into the metadata and every summary's `actor`.
    pub fn create(
        dir: &Path,
        prefix: &str,
        name: &str,
        meta: LogMetadata,
        episodes_per_file: u64,
    ) -> anyhow::Result<EvalLogger> {
        let meta = LogMetadata { actor: name.to_string(), ..meta };
        Ok(EvalLogger {
            logger: EpisodeLogger::create(dir, prefix, meta, episodes_per_file)?,
            name: name.to_string(),
            next_id: 0,
            policy_version: 0,
        })
    }

    /// Logs one leg of `task` as an episode; `stage` as in the module docs. A leg without
    /// kept steps ([`super::RunOptions::samples`] off) is an error.
    pub fn log(&mut self, task: &Task, stage: u32, done: &LegDone<'_>) -> anyhow::Result<()> {
        let samples = done
            .samples
            .ok_or_else(|| anyhow::anyhow!("evaluation steps were not kept for the log"))?;
        let env = done.env;
        let cfg = env.config();
        let r = done.result;
        let id = self.next_id;
        self.next_id += 1;
        self.logger.begin_episode(&EpisodeStart {
            episode_id: id,
            room: env.room().spec(),
            robot_radius: env.robot_radius(),
            goal: r.goal,
            lidar: &cfg.lidar,
            dt: cfg.dt,
            mu: 1.0,
        })?;
        // Samples keep the plan only where it changed; the log is given the current one.
        let mut plan: &[[f64; 2]] = &[];
        for s in samples {
            if let Some(p) = &s.plan {
                plan = p;
            }
            self.logger.log_step(&StepLog {
                step: s.step,
                pose: [s.pose.x, s.pose.y, s.pose.yaw],
                scan: &s.scan,
                v: s.v,
                omega: s.omega,
                action: if s.step == 0 {
                    [-1.0, 0.0]
                } else {
                    velocity_to_action(s.v, s.omega, cfg)
                },
                reward: s.reward,
                goal_distance: s.goal_distance,
                goal_angle: s.goal_angle,
                subgoal: s.subgoal,
                plan: (!plan.is_empty()).then_some(plan),
            })?;
        }
        self.logger.end_episode(dvnav_proto::EpisodeSummary {
            episode_id: id,
            actor: self.name.clone(),
            stage,
            room: r.room.clone(),
            seed: task.seed,
            footprint: env.footprint().name.clone(),
            mu: 1.0,
            outcome: dvnav_link::wire::outcome_to_proto(r.outcome) as i32,
            steps: r.steps,
            episode_return: r.episode_return,
            score: r.score,
            policy_version: self.policy_version,
            start_x: r.start.x,
            start_y: r.start.y,
            goal_x: r.goal[0],
            goal_y: r.goal[1],
            env_index: done.leg as u32,
            ..Default::default()
        })
    }

    /// Finishes the open file.
    pub fn close(self) -> anyhow::Result<()> {
        self.logger.close()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode_log::{read_episodes, read_steps};
    use crate::{RunOptions, run_tasks, training_tasks};
    use dvnav_config::Config;
    use dvnav_nav::policy::PidPolicy;
    use dvnav_sim::Room;

    #[test]
    fn every_leg_is_logged_and_reads_back() {
        let cfg = Config::default();
        let dir = tempfile::tempdir().unwrap();
        let rooms = vec![Room::builtin("env0").unwrap()];
        let tasks = training_tasks(&rooms, "eval", 2, 3);
        let mut log =
            EvalLogger::create(dir.path(), "eval", "eval", LogMetadata::default(), 100).unwrap();
        log.policy_version = 7;
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        let opts = RunOptions { samples: true, ..Default::default() };
        let results =
            run_tasks(&tasks, &cfg.env, &mut [&mut pid], opts, &mut |t, d| log.log(t, 2, &d))
                .unwrap();
        log.close().unwrap();
        let legs: usize = results.iter().map(Vec::len).sum();
        let records = read_episodes(dir.path()).unwrap();
        assert_eq!(records.len(), legs);
        let all: Vec<_> = results.iter().flatten().collect();
        for rec in &records {
            let s = &rec.summary;
            assert_eq!(
                (s.actor.as_str(), s.stage, s.room.as_str(), s.policy_version),
                ("eval", 2, "env0", 7)
            );
            // Logged in the order legs ended; match by start and goal.
            let r = all
                .iter()
                .find(|r| {
                    r.start.x == s.start_x
                        && r.start.y == s.start_y
                        && r.goal == [s.goal_x, s.goal_y]
                })
                .expect("a logged leg is one of the results");
            assert_eq!((s.steps, s.score), (r.steps, r.score));
            let steps = read_steps(&rec.file, &[s.episode_id].into()).unwrap();
            assert_eq!(steps[&s.episode_id].len(), r.trajectory.len());
        }
    }

    /// With `env.subgoals`, a logged leg has its plan on `/plan` and every step's subgoal in
    /// its step record: what the agent was fed, not the final goal.
    #[test]
    fn legs_along_a_plan_log_it_and_their_subgoals() {
        let mut cfg = Config::default();
        cfg.env.subgoals = Some(dvnav_sim::subgoal::SubgoalConfig::default());
        let dir = tempfile::tempdir().unwrap();
        let rooms = vec![Room::builtin("env2").unwrap()];
        let tasks = training_tasks(&rooms, "eval", 1, 2);
        let mut log =
            EvalLogger::create(dir.path(), "eval", "eval", LogMetadata::default(), 100).unwrap();
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        let opts = RunOptions { samples: true, ..Default::default() };
        let results =
            run_tasks(&tasks, &cfg.env, &mut [&mut pid], opts, &mut |t, d| log.log(t, 0, &d))
                .unwrap();
        log.close().unwrap();
        let legs: Vec<_> = results.iter().flatten().collect();
        assert!(!legs.is_empty() && legs.iter().all(|r| r.plan.len() >= 2));
        let records = read_episodes(dir.path()).unwrap();
        let mut far_subgoals = 0;
        for rec in &records {
            let id = rec.summary.episode_id;
            let steps = read_steps(&rec.file, &[id].into()).unwrap().remove(&id).unwrap();
            let goal = [rec.summary.goal_x, rec.summary.goal_y];
            for s in &steps {
                let sub = s.subgoal.as_ref().expect("every step follows the plan");
                let from_robot = (sub.x - s.x).hypot(sub.y - s.y);
                // The lookahead (1.5 m) past the robot's projection on the path, and the robot
                // stays near the path: never much farther, unless it is the final goal.
                assert!(from_robot <= 2.0 || [sub.x, sub.y] == goal, "{s:?}");
                far_subgoals += usize::from([sub.x, sub.y] != goal);
            }
        }
        assert!(far_subgoals > 0, "some subgoals lie on the path short of the goal");
        let bytes = std::fs::read(&records[0].file).unwrap();
        let plans = mcap::MessageStream::new(&bytes)
            .unwrap()
            .filter(|m| m.as_ref().unwrap().channel.topic == crate::episode_log::TOPIC_PLAN)
            .count();
        assert!(plans >= legs.len(), "{plans} plans for {} legs", legs.len());
    }
}
