//! [`run_jobs`]: many evaluation episodes stepped in lockstep, with one batched policy call per
//! policy per control step and the environments stepped in parallel (rayon).
//!
//! A [`Job`] is an environment, a [`Plan`] (a random episode, or a route of goals visited in
//! order) and the index of the policy that drives it. Up to `window` jobs run at once; each
//! step, the observations of all running jobs of one policy go through that policy in one
//! [`NavPolicy::act_batch`] call (the network's fast path: one forward pass for many
//! observations), then every environment steps on the rayon pool. Jobs are independent, so the
//! results do not depend on the number of threads; they are returned in job order.

use super::episode::{EpisodeResult, Recorder, StepSample};
use dvnav_nav::escape::StallEscape;
use dvnav_nav::policy::NavPolicy;
use dvnav_sim::Outcome;
use dvnav_sim::laser_scan::BeamLayout;
use dvnav_sim::safety;
use dvnav_sim::{NavEnv, Pose2};
use rayon::prelude::*;
use std::collections::VecDeque;

/// What a job plays.
#[derive(Clone, Debug, PartialEq)]
pub enum Plan {
    /// One episode: the next random start and goal of the environment's seeded generator
    /// ([`NavEnv::reset`]).
    Random,
    /// A route: from `start`, each goal in turn. Every goal is a leg of its own with the
    /// episode's step limit T_max; a leg that reaches its goal starts the next leg from the
    /// pose where it ended (velocities back to 0, timed obstacles restarted). The route ends
    /// at its first failed leg; the goals after it are not attempted.
    Route {
        /// Start pose.
        start: Pose2,
        /// Goals in the order they are visited (m).
        goals: Vec<[f64; 2]>,
    },
}

impl Plan {
    fn legs(&self) -> usize {
        match self {
            Plan::Random => 1,
            Plan::Route { goals, .. } => goals.len(),
        }
    }
}

/// One environment, what to play in it, and which policy drives.
#[derive(Debug)]
pub struct Job {
    /// The environment (room, robot footprint, seed, constants).
    pub env: NavEnv,
    /// What to play.
    pub plan: Plan,
    /// Index into the `policies` given to [`run_jobs`].
    pub policy: usize,
}

/// Options of [`run_jobs`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunOptions {
    /// Jobs running at once: the largest batch a policy sees. 64 keeps a batch's forward pass
    /// efficient while bounding the memory of kept steps.
    pub window: usize,
    /// Keep every step's scan and command ([`StepSample`]) for episode logs.
    pub samples: bool,
    /// The collision monitor's horizon (s, [`dvnav_sim::safety`]): each policy command's v is
    /// scaled down so that the meta robot would not reach a return of its observed scan within
    /// it. 0: off.
    pub safety_horizon_s: f64,
    /// The stall escape ([`dvnav_nav::escape`]): after this many seconds without progress
    /// towards its goal a robot samples its policy's own noise for as long. Not for a robot
    /// that follows a planned path (`env.subgoals`): it replans after a stall. 0: off.
    pub escape_after_s: f64,
}

/// Folded with a job's index into its stall escape's seed.
const ESCAPE_SEED: u64 = 0x657363_61706521;

impl Default for RunOptions {
    fn default() -> Self {
        Self { window: 64, samples: false, safety_horizon_s: 0.0, escape_after_s: 0.0 }
    }
}

/// A leg (or random episode) that has just ended, handed to the callback of [`run_jobs`].
#[derive(Clone, Copy, Debug)]
pub struct LegDone<'a> {
    /// Index of its job.
    pub job: usize,
    /// Index of the leg within the job (0 for a random episode).
    pub leg: usize,
    /// The job has no further leg.
    pub job_done: bool,
    /// The environment, at the end of the leg.
    pub env: &'a NavEnv,
    /// How it went.
    pub result: &'a EpisodeResult,
    /// Every step, when [`RunOptions::samples`] is on.
    pub samples: Option<&'a [StepSample]>,
}

/// A running job.
struct Slot {
    job: usize,
    env: NavEnv,
    plan: Plan,
    policy: usize,
    leg: usize,
    recorder: Recorder,
    legs: Vec<EpisodeResult>,
    escape: Option<StallEscape>,
}

impl Slot {
    /// The job's first episode; `Err` when its room has no random task for its robot.
    fn start(job: usize, j: Job, opts: &RunOptions) -> Result<Slot, dvnav_sim::NoTask> {
        let Job { mut env, plan, policy } = j;
        match &plan {
            Plan::Random => env.try_reset()?,
            Plan::Route { start, goals } => env.reset_to(*start, goals[0]),
        }
        let recorder = Recorder::begin(&env, opts.samples);
        // Seeded by the job: the same jobs replay the same escapes.
        let escape = (opts.escape_after_s > 0.0).then(|| {
            StallEscape::for_radius(
                opts.escape_after_s,
                env.robot_radius(),
                ESCAPE_SEED ^ job as u64,
            )
            .expect("escape settings checked by run_jobs")
        });
        Ok(Slot { job, env, plan, policy, leg: 0, recorder, legs: Vec::new(), escape })
    }
}

/// Runs every job to its end and returns each job's legs (one result for a random episode;
/// the legs attempted, in order, for a route). `on_leg` sees every leg as it ends, on the
/// calling thread, for logs and progress; an error from it stops the run.
///
/// Policies are called on the calling thread only (they need not be `Send`); environments
/// step on the rayon pool.
pub fn run_jobs(
    jobs: Vec<Job>,
    policies: &mut [&mut dyn NavPolicy],
    opts: RunOptions,
    on_leg: &mut dyn FnMut(LegDone<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<Vec<EpisodeResult>>> {
    anyhow::ensure!(opts.window > 0, "the evaluation window must hold at least one job");
    if opts.escape_after_s != 0.0 {
        StallEscape::for_radius(opts.escape_after_s, 1.0, 0)?;
    }
    for (i, j) in jobs.iter().enumerate() {
        let p = policies.get(j.policy).ok_or_else(|| {
            anyhow::anyhow!("job {i}: policy {} of {} does not exist", j.policy, policies.len())
        })?;
        anyhow::ensure!(
            p.beams() == j.env.lidar().beams(),
            "job {i}: the policy expects {} beams, the environment has {}",
            p.beams(),
            j.env.lidar().beams()
        );
        anyhow::ensure!(
            p.obs_dim() == j.env.obs_dim(),
            "job {i}: the policy takes observations of {} values, the environment writes {} \
             (env.radius_input differs)",
            p.obs_dim(),
            j.env.obs_dim()
        );
        anyhow::ensure!(j.plan.legs() > 0, "job {i}: a route needs at least one goal");
    }
    let mut results: Vec<Vec<EpisodeResult>> = (0..jobs.len()).map(|_| Vec::new()).collect();
    let mut pending: VecDeque<(usize, Job)> = jobs.into_iter().enumerate().collect();
    let mut slots: Vec<Slot> = Vec::with_capacity(opts.window);
    let mut obs = Vec::new();
    let mut commands: Vec<(f64, f64)> = Vec::new();
    let mut group: Vec<usize> = Vec::new();
    let mut noise: Vec<Option<[f32; 2]>> = Vec::new();
    loop {
        while slots.len() < opts.window {
            let Some((i, j)) = pending.pop_front() else { break };
            match Slot::start(i, j, &opts) {
                Ok(slot) => slots.push(slot),
                // Drawn once when the environment was made, not again: a room where tasks are
                // that rare for the robot. The job has no legs.
                Err(e) => eprintln!("warning: job {i} skipped: {e}"),
            }
        }
        if slots.is_empty() {
            break;
        }
        // One batched call per policy over its running jobs.
        commands.clear();
        commands.resize(slots.len(), (0.0, 0.0));
        for (p, policy) in policies.iter_mut().enumerate() {
            group.clear();
            group.extend((0..slots.len()).filter(|&k| slots[k].policy == p));
            if group.is_empty() {
                continue;
            }
            let d = slots[group[0]].env.obs_dim();
            obs.resize(group.len() * d, 0.0);
            for (n, &k) in group.iter().enumerate() {
                slots[k].env.write_obs(&mut obs[n * d..(n + 1) * d]);
            }
            let out = if opts.escape_after_s > 0.0 {
                noise.clear();
                noise.extend(group.iter().map(|&k| {
                    let s = &mut slots[k];
                    // A robot following a planned path replans after a stall instead, as in
                    // `dvnav serve` (and its subgoal stays a lookahead away).
                    if s.env.subgoal().is_some() {
                        return None;
                    }
                    let t = s.env.steps() as f64 * s.env.config().dt;
                    let d = s.env.goal_distance();
                    s.escape.as_mut().and_then(|e| e.noise(t, d))
                }));
                policy.act_batch_noisy(&obs, &noise)?
            } else {
                policy.act_batch(&obs)?
            };
            anyhow::ensure!(
                out.len() == group.len(),
                "policy {p} returned {} commands for {} observations",
                out.len(),
                group.len()
            );
            for (n, (&k, c)) in group.iter().zip(out).enumerate() {
                commands[k] = c;
                if opts.safety_horizon_s > 0.0 {
                    let env = &slots[k].env;
                    let cfg = env.config();
                    let layout = BeamLayout::new(cfg.lidar.beams, cfg.lidar.fov_deg);
                    let scan = &obs[n * d..n * d + layout.beams];
                    // The observation's frame: the meta robot's when the environment runs DVST.
                    let radius = env.robot_radius() / env.dvst_scale();
                    let v = safety::safe_speed(
                        scan,
                        layout,
                        cfg.lidar.range_max,
                        radius,
                        c,
                        opts.safety_horizon_s,
                    );
                    commands[k].0 = v;
                }
            }
        }
        // The rotation shim (env.subgoals) holds a robot that has just been given a plan.
        for (s, c) in slots.iter().zip(commands.iter_mut()) {
            if let Some(shim) = s.env.shim_command() {
                *c = shim;
            }
        }
        slots.par_iter_mut().zip(commands.par_iter()).for_each(|(s, &(v, omega))| {
            let out = s.env.step(v, omega);
            s.recorder.record(&s.env, out.reward);
        });
        // Legs that ended: report them, go on to the next leg or retire the job.
        let mut k = 0;
        while k < slots.len() {
            let Some(outcome) = slots[k].env.done() else {
                k += 1;
                continue;
            };
            let s = &mut slots[k];
            let next_goal = match &s.plan {
                Plan::Route { goals, .. } if outcome == Outcome::Success => {
                    goals.get(s.leg + 1).copied()
                }
                _ => None,
            };
            let recorder = std::mem::replace(&mut s.recorder, Recorder::begin(&s.env, false));
            let (result, samples) = recorder.finish(&s.env);
            on_leg(LegDone {
                job: s.job,
                leg: s.leg,
                job_done: next_goal.is_none(),
                env: &s.env,
                result: &result,
                samples: samples.as_deref(),
            })?;
            s.legs.push(result);
            match next_goal {
                Some(goal) => {
                    let at = s.env.pose();
                    s.env.reset_to(at, goal);
                    if let Some(e) = &mut s.escape {
                        e.reset();
                    }
                    s.leg += 1;
                    s.recorder = Recorder::begin(&s.env, opts.samples);
                    k += 1;
                }
                None => {
                    let done = slots.swap_remove(k);
                    results[done.job] = done.legs;
                }
            }
        }
    }
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_config::Config;
    use dvnav_nav::policy::PidPolicy;
    use dvnav_sim::{Room, RoomSpec};
    use std::sync::Arc;

    fn pid(cfg: &Config) -> PidPolicy {
        PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() }
    }

    /// Counts its batched calls and the observations in them.
    struct Counting {
        inner: PidPolicy,
        calls: usize,
        largest: usize,
    }
    impl NavPolicy for Counting {
        fn beams(&self) -> usize {
            self.inner.beams()
        }
        fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
            self.inner.act(obs)
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            self.inner.velocity_bounds()
        }
        fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
            self.calls += 1;
            self.largest = self.largest.max(obs.len() / dvnav_sim::obs::obs_dim(self.beams()));
            obs.chunks_exact(dvnav_sim::obs::obs_dim(self.beams())).map(|o| self.act(o)).collect()
        }
    }

    #[test]
    fn pid_in_an_empty_room_visits_every_goal_of_a_route() {
        let cfg = Config::default();
        let room = Arc::new(Room::new(RoomSpec::empty("empty", 8.0)));
        let goals = vec![[0.0, 2.0], [2.5, 0.0], [-2.0, -2.5], [-2.5, 2.5]];
        let job = Job {
            env: NavEnv::new(room, &cfg.env, 3),
            plan: Plan::Route { start: Pose2::new(0.0, 0.0, 0.5), goals: goals.clone() },
            policy: 0,
        };
        let mut p = pid(&cfg);
        let mut seen = Vec::new();
        let out = run_jobs(vec![job], &mut [&mut p], RunOptions::default(), &mut |d| {
            seen.push((d.job, d.leg, d.job_done, d.samples.is_some()));
            Ok(())
        })
        .unwrap();
        assert_eq!(out.len(), 1);
        let legs = &out[0];
        assert_eq!(legs.len(), 4);
        for (leg, goal) in legs.iter().zip(&goals) {
            assert_eq!(leg.outcome, Outcome::Success);
            assert_eq!(leg.goal, *goal);
            let end = leg.trajectory.last().unwrap();
            assert!((end.x - goal[0]).hypot(end.y - goal[1]) <= cfg.env.goal_tolerance);
        }
        // Each leg starts where the previous one ended.
        for w in legs.windows(2) {
            assert_eq!(w[1].start, *w[0].trajectory.last().unwrap());
        }
        assert_eq!(legs[0].start, Pose2::new(0.0, 0.0, 0.5));
        assert_eq!(
            seen,
            vec![
                (0, 0, false, false),
                (0, 1, false, false),
                (0, 2, false, false),
                (0, 3, true, false)
            ]
        );
    }

    /// An 8 m room with a wall across x = 1.5 (faces at 1.4 and 1.6), 4 m long.
    fn walled_room() -> Arc<Room> {
        let mut spec = RoomSpec::empty("walled", 8.0);
        spec.obstacles.push(dvnav_sim::ObstacleSpec::Box {
            center: [1.5, 0.0],
            half_extents: [0.1, 2.0],
            angle: 0.0,
        });
        Arc::new(Room::new(spec))
    }

    #[test]
    fn a_route_stops_at_its_first_failed_leg() {
        let cfg = Config::default();
        // A wall between the first and the second goal: PID drives straight into it.
        let room = walled_room();
        let job = Job {
            env: NavEnv::new(room, &cfg.env, 3),
            plan: Plan::Route {
                start: Pose2::new(0.0, 0.0, 0.0),
                goals: vec![[0.5, 0.0], [3.0, 0.0], [0.0, 3.0]],
            },
            policy: 0,
        };
        let mut p = pid(&cfg);
        let out =
            run_jobs(vec![job], &mut [&mut p], RunOptions::default(), &mut |_| Ok(())).unwrap();
        let outcomes: Vec<_> = out[0].iter().map(|l| l.outcome).collect();
        assert_eq!(outcomes, vec![Outcome::Success, Outcome::Collision]);
    }

    /// The collision monitor: PID drives straight at a wall between it and its goal; with the
    /// monitor it approaches and stops short (a timeout) instead of hitting it.
    #[test]
    fn the_collision_monitor_turns_a_drive_into_a_wall_into_a_stop_before_it() {
        let mut cfg = Config::default();
        cfg.env.max_steps = 150;
        let room = walled_room();
        let run = |horizon: f64| {
            let job = Job {
                env: NavEnv::new(room.clone(), &cfg.env, 3),
                plan: Plan::Route { start: Pose2::new(0.0, 0.0, 0.0), goals: vec![[3.0, 0.0]] },
                policy: 0,
            };
            let opts = RunOptions { safety_horizon_s: horizon, ..Default::default() };
            let mut p = pid(&cfg);
            let mut end = None;
            let out = run_jobs(vec![job], &mut [&mut p], opts, &mut |d| {
                end = Some(d.env.pose());
                Ok(())
            })
            .unwrap();
            (out[0][0].outcome, end.unwrap())
        };
        assert_eq!(run(0.0).0, Outcome::Collision);
        let (outcome, at) = run(0.6);
        assert_eq!(outcome, Outcome::Timeout);
        // The wall's face is at x = 1.4; the 0.2 m robot stops within a few centimetres of it.
        assert!(at.x > 1.1 && at.x < 1.2, "stopped at x = {}", at.x);
    }

    /// Stands still when acting deterministically; with noise, the PID controller's command.
    /// Counts the cycles it was given noise.
    struct FrozenUnlessNoisy {
        inner: PidPolicy,
        noisy_cycles: usize,
    }
    impl NavPolicy for FrozenUnlessNoisy {
        fn beams(&self) -> usize {
            self.inner.beams()
        }
        fn act(&mut self, _obs: &[f32]) -> anyhow::Result<(f64, f64)> {
            Ok((0.0, 0.0))
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            self.inner.velocity_bounds()
        }
        fn act_batch_noisy(
            &mut self,
            obs: &[f32],
            noise: &[Option<[f32; 2]>],
        ) -> anyhow::Result<Vec<(f64, f64)>> {
            let d = dvnav_sim::obs::obs_dim(self.beams());
            let mut out = Vec::new();
            for (o, n) in obs.chunks_exact(d).zip(noise) {
                self.noisy_cycles += n.is_some() as usize;
                out.push(if n.is_some() { self.inner.act(o)? } else { (0.0, 0.0) });
            }
            Ok(out)
        }
    }

    /// The stall escape: a policy frozen in place times out without it; with it, after the
    /// delay without progress the robot is driven by its policy's noisy action for as long,
    /// then freezes again until the next escape, 2 s after the last progress.
    #[test]
    fn the_stall_escape_moves_a_frozen_robot_after_the_delay() {
        let cfg = Config::default();
        let room = Arc::new(Room::new(RoomSpec::empty("empty", 8.0)));
        let run = |after_s: f64| {
            let job = Job {
                env: NavEnv::new(room.clone(), &cfg.env, 3),
                plan: Plan::Route { start: Pose2::new(0.0, 0.0, 0.0), goals: vec![[2.0, 0.0]] },
                policy: 0,
            };
            let mut p = FrozenUnlessNoisy { inner: pid(&cfg), noisy_cycles: 0 };
            let opts = RunOptions { escape_after_s: after_s, ..Default::default() };
            let out = run_jobs(vec![job], &mut [&mut p], opts, &mut |_| Ok(())).unwrap();
            (out[0][0].outcome, out[0][0].steps, p.noisy_cycles)
        };
        let (outcome, steps, noisy) = run(0.0);
        assert_eq!((outcome, steps, noisy), (Outcome::Timeout, cfg.env.max_steps, 0));
        // Following a planned path, the robot replans instead: never an escape.
        let mut planned = cfg.clone();
        planned.env.subgoals = Some(Default::default());
        let job = Job {
            env: NavEnv::new(room.clone(), &planned.env, 3),
            plan: Plan::Route { start: Pose2::new(0.0, 0.0, 0.0), goals: vec![[2.0, 0.0]] },
            policy: 0,
        };
        let mut p = FrozenUnlessNoisy { inner: pid(&planned), noisy_cycles: 0 };
        let opts = RunOptions { escape_after_s: 2.0, ..Default::default() };
        let out = run_jobs(vec![job], &mut [&mut p], opts, &mut |_| Ok(())).unwrap();
        assert_eq!((out[0][0].outcome, p.noisy_cycles), (Outcome::Timeout, 0));
        let (outcome, steps, noisy) = run(2.0);
        assert_eq!(outcome, Outcome::Success);
        // Frozen for 10 cycles (2 s), escaping for 10 (~1 m at 0.5 m/s), frozen until 2 s after
        // the escape's last progress, escaping again for the remaining ~0.8 m.
        assert!((35..=42).contains(&steps), "{steps} steps");
        assert!((17..=21).contains(&noisy), "{noisy} noisy cycles");
        assert!((19..=21).contains(&(steps - noisy as u32)), "{steps} steps, {noisy} noisy");
        let bad = run_jobs(
            Vec::new(),
            &mut [],
            RunOptions { escape_after_s: -1.0, ..Default::default() },
            &mut |_| Ok(()),
        );
        assert!(bad.unwrap_err().to_string().contains("-1"));
    }

    #[test]
    fn lockstep_batches_match_one_by_one_and_results_keep_job_order() {
        let cfg = Config::default();
        let room = Room::builtin("env1").unwrap();
        let jobs = |n: u64| -> Vec<Job> {
            (0..n)
                .map(|i| Job {
                    env: NavEnv::new(room.clone(), &cfg.env, 100 + i),
                    plan: Plan::Random,
                    policy: 0,
                })
                .collect()
        };
        let mut batched = Counting { inner: pid(&cfg), calls: 0, largest: 0 };
        let opts = RunOptions { window: 4, samples: true, ..Default::default() };
        let mut logged = 0;
        let a = run_jobs(jobs(10), &mut [&mut batched], opts, &mut |d| {
            let s = d.samples.unwrap();
            assert_eq!(s.len() as u32, d.result.steps + 1);
            logged += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(logged, 10);
        assert_eq!(batched.largest, 4, "the window bounds the batch");
        let mut single = Counting { inner: pid(&cfg), calls: 0, largest: 0 };
        let b = run_jobs(
            jobs(10),
            &mut [&mut single],
            RunOptions { window: 1, samples: false, ..Default::default() },
            &mut |_| Ok(()),
        )
        .unwrap();
        assert_eq!(single.largest, 1);
        assert!(batched.calls < single.calls);
        assert_eq!(a, b);
        // Job i is the first episode after a reset of an environment seeded 100 + i.
        for (i, legs) in b.iter().enumerate() {
            let mut env = NavEnv::new(room.clone(), &cfg.env, 100 + i as u64);
            env.reset();
            assert_eq!((legs[0].start, legs[0].goal), (env.start(), env.goal()));
        }
    }

    #[test]
    fn two_policies_each_drive_their_own_jobs() {
        let cfg = Config::default();
        let room = Arc::new(Room::new(RoomSpec::empty("empty", 8.0)));
        let job = |policy| Job {
            env: NavEnv::new(room.clone(), &cfg.env, 1),
            plan: Plan::Route { start: Pose2::new(0.0, 0.0, 0.0), goals: vec![[2.0, 0.0]] },
            policy,
        };
        let mut go = pid(&cfg);
        let mut stay = PidPolicy {
            env: dvnav_config::EnvConfig { v_max: 1e-9, ..cfg.env.clone() },
            ..pid(&cfg)
        };
        let out = run_jobs(
            vec![job(0), job(1), job(0)],
            &mut [&mut go, &mut stay],
            RunOptions::default(),
            &mut |_| Ok(()),
        )
        .unwrap();
        let outcomes: Vec<_> = out.iter().map(|l| l[0].outcome).collect();
        assert_eq!(outcomes, vec![Outcome::Success, Outcome::Timeout, Outcome::Success]);
        let bad = Job { policy: 2, ..job(0) };
        assert!(
            run_jobs(vec![bad], &mut [&mut go], RunOptions::default(), &mut |_| Ok(())).is_err()
        );
    }
}
