//! [`Task`]: one evaluation job described as data (room, robot, route or random episode,
//! seed, policy), and [`run_tasks`], which builds their environments and runs them through
//! [`super::run_jobs`].

use super::episode::EpisodeResult;
use super::runner::{Job, LegDone, Plan, RunOptions, run_jobs};
use dvnav_config::EnvConfig;
use dvnav_nav::policy::NavPolicy;
use dvnav_sim::{Footprint, NavEnv, Room, Route};
use std::sync::Arc;

/// What a task plays.
#[derive(Clone, Debug, PartialEq)]
pub enum TaskKind {
    /// A room's route (see [`Plan::Route`]).
    Route(Route),
    /// Random episode number `index` of its room (start and goal from the task's seed).
    Random {
        /// Index among the room's random episodes.
        index: usize,
    },
}

/// One evaluation job.
#[derive(Clone, Debug)]
pub struct Task {
    /// The room.
    pub room: Arc<Room>,
    /// The robot: `None` for the configured one (the meta robot, or `env.footprint`).
    pub footprint: Option<Footprint>,
    /// Radius of a circular robot given per task (gate, dynamic), for reports.
    pub radius: Option<f64>,
    /// Route or random episode.
    pub kind: TaskKind,
    /// Seed of the task's environment: its random start and goal, and LiDAR noise.
    pub seed: u64,
    /// Index of the policy that drives (into the policies given to [`run_tasks`]).
    pub policy: usize,
}

impl Task {
    /// The footprint's radius for drawings and logs: the given radius, else the footprint's
    /// bounding radius, else the configured robot's.
    pub fn robot_radius(&self, cfg: &EnvConfig) -> f64 {
        self.radius.unwrap_or_else(|| match (&self.footprint, &cfg.footprint) {
            (Some(f), _) | (None, Some(f)) => f.bounding_radius(),
            (None, None) => cfg.robot_radius,
        })
    }

    /// `route` or `random`.
    pub fn kind_name(&self) -> &'static str {
        match self.kind {
            TaskKind::Route(_) => "route",
            TaskKind::Random { .. } => "random",
        }
    }

    /// The task's job; `Err` when its room has no task for its robot (a robot too big for
    /// the room, or no two points far enough apart that it can drive between).
    fn job(&self, cfg: &EnvConfig) -> Result<Job, dvnav_sim::NoTask> {
        let env = NavEnv::try_new(self.room.clone(), cfg, self.seed, self.footprint.clone())?;
        let plan = match &self.kind {
            TaskKind::Route(r) => Plan::Route { start: r.start_pose(), goals: r.goals.clone() },
            TaskKind::Random { .. } => Plan::Random,
        };
        Ok(Job { env, plan, policy: self.policy })
    }
}

/// The seed of random episode `index` in room `room` for evaluation seed `seed`: independent
/// of the other tasks, so an episode's start and goal never depend on how many episodes run or
/// in which order.
pub fn episode_seed(seed: u64, room: &str, index: usize) -> u64 {
    let mut h = fnv::FnvHasher::default();
    std::hash::Hasher::write(&mut h, room.as_bytes());
    let h = std::hash::Hasher::finish(&h);
    splitmix64(seed ^ splitmix64(h ^ splitmix64(index as u64)))
}

fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Runs `tasks` with `policies` (see [`run_jobs`]); `on_leg` sees each leg with its task.
/// Returns each task's legs, in task order. A task whose room has no task for its robot (see
/// [`NavEnv::try_reset`]) is skipped with a warning on stderr, once per room and robot size,
/// and has no legs: its row reports 0 episodes.
pub fn run_tasks(
    tasks: &[Task],
    cfg: &EnvConfig,
    policies: &mut [&mut dyn NavPolicy],
    opts: RunOptions,
    on_leg: &mut dyn FnMut(&Task, LegDone<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<Vec<EpisodeResult>>> {
    for t in tasks {
        if let Some(f) = &t.footprint {
            f.validate()?;
        }
    }
    let mut warned = std::collections::HashSet::new();
    let mut runnable = Vec::new();
    let mut index = Vec::new();
    for (i, t) in tasks.iter().enumerate() {
        match t.job(cfg) {
            Ok(job) => {
                runnable.push(job);
                index.push(i);
            }
            Err(e) => {
                if warned.insert((t.room.name().to_string(), t.robot_radius(cfg).to_bits())) {
                    eprintln!(
                        "warning: skipped, no task for a robot of radius {} m: {e}",
                        t.robot_radius(cfg)
                    );
                }
            }
        }
    }
    let ran = run_jobs(runnable, policies, opts, &mut |d| {
        on_leg(&tasks[index[d.job]], LegDone { job: index[d.job], ..d })
    })?;
    let mut out: Vec<Vec<EpisodeResult>> = (0..tasks.len()).map(|_| Vec::new()).collect();
    for (legs, i) in ran.into_iter().zip(index) {
        out[i] = legs;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episode_seeds_differ_by_room_index_and_seed() {
        let a = episode_seed(1, "env0", 0);
        assert_eq!(a, episode_seed(1, "env0", 0));
        assert_ne!(a, episode_seed(1, "env0", 1));
        assert_ne!(a, episode_seed(1, "env1", 0));
        assert_ne!(a, episode_seed(2, "env0", 0));
    }

    #[test]
    fn robot_radius_prefers_the_task_then_the_footprint_then_the_config() {
        let cfg = EnvConfig::default();
        let mut t = Task {
            room: Room::builtin("gate").unwrap(),
            footprint: None,
            radius: None,
            kind: TaskKind::Random { index: 0 },
            seed: 0,
            policy: 0,
        };
        assert_eq!(t.robot_radius(&cfg), 0.2);
        t.footprint = Some(Footprint::rectangle(0.6, 0.8));
        assert!((t.robot_radius(&cfg) - 0.5).abs() < 1e-12);
        t.radius = Some(0.35);
        assert_eq!(t.robot_radius(&cfg), 0.35);
    }
}
