//! # dvnav-eval
//!
//! Evaluation of a navigation policy (design §4): episodes, the evaluation-route protocol, the
//! paper's score S, per-room rates, and the gate and dynamic scenarios of design §2. Used by
//! `dvnav eval` and by the learner's evaluation during training; no network needed.
//!
//! # Layout
//! - [`episode`]: one episode's [`EpisodeResult`] (outcome, steps, time, path length, score,
//!   trajectory), the [`Recorder`] that builds it, and [`run_episode`] (one policy, one
//!   observation at a time).
//! - [`runner`]: [`run_jobs`], many episodes in lockstep, one batched policy call per step.
//! - [`task`]: [`Task`], an evaluation job as data (room, robot, route or random episode,
//!   seed, policy), and [`run_tasks`].
//! - [`scenario`]: the training, gate and dynamic scenarios as task lists, and their rows
//!   ([`RoomSummary`], [`RobotResult`]).
//! - [`summary`]: [`Rates`], [`RouteResult`], [`RoomSummary`].
//! - [`gate`]: which way a robot went in the gate room ([`GateRoute`]).
//! - [`log`]: [`EvalLogger`], evaluation legs to MCAP.
//!
//! # Design decisions
//! - **Score.** S = 1 − 2·T_s/T_max on success, −1 on collision or timeout
//!   ([`dvnav_sim::score`]), per episode and per leg.
//! - **The route protocol.** The paper has the robot "sequentially reach four goal points from
//!   the original point" and scores with T_max = 400 steps, the episode limit. Here each goal
//!   is a leg with its own T_max, the next leg starts where the previous one ended (velocities
//!   back to 0), and the route ends at its first failed leg. A route's score is the mean of
//!   its legs' scores over all its goals, with −1 for every goal not reached, so it lies in
//!   [−1, 1] like an episode's and a route that fails early scores lower than one that fails
//!   late. Per-leg limits keep a leg's score on the same scale as a training episode's.
//! - **Random episodes** are seeded per room and index ([`episode_seed`]): an episode's start
//!   and goal do not depend on how many episodes run, in which order, or on how many threads.
//! - **Time** (`mean_time_s`) is averaged over successful episodes only; a collision's time
//!   says nothing about speed. It is `None` (`null`) when nothing succeeded.
//! - **Speed.** Jobs run in lockstep, up to [`RunOptions::window`] at once: each step one
//!   [`dvnav_nav::policy::NavPolicy::act_batch`] per policy (the network's forward pass over the
//!   batch) and the environments stepped on the rayon pool. Policies stay on the calling
//!   thread, so they need not be `Send`.
//!
//! ```
//! use dvnav_config::Config;
//! use dvnav_eval::{RunOptions, room_summaries, run_tasks, training_tasks};
//! use dvnav_nav::policy::PidPolicy;
//! use dvnav_sim::Room;
//! let cfg = Config::default();
//! let rooms = vec![Room::builtin("env0").unwrap()];
//! let tasks = training_tasks(&rooms, "eval", 4, 1); // the route and 4 random episodes
//! let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
//! let results =
//!     run_tasks(&tasks, &cfg.env, &mut [&mut pid], RunOptions::default(), &mut |_, _| Ok(()))
//!         .unwrap();
//! let rows = room_summaries(&tasks, &results);
//! assert_eq!((rows[0].room.as_str(), rows[0].rates.episodes), ("env0", 4));
//! ```
#![warn(missing_docs)]

pub mod episode;
pub mod episode_log;
pub mod gate;
pub mod log;
pub mod runner;
pub mod scenario;
pub mod smoothness;
pub mod summary;
pub mod task;

pub use episode::{EpisodeResult, Recorder, StepSample, run_episode};
pub use gate::{GateGeometry, GateRoute};
pub use log::EvalLogger;
pub use runner::{Job, LegDone, Plan, RunOptions, run_jobs};
pub use scenario::{
    GATE_RADII, GATE_STRAIGHT_M, RobotResult, TRAINING_ROUTE, parse_radii, robot_results,
    robot_tasks, room_summaries, room_tasks, training_tasks,
};
pub use smoothness::{CommandCounter, CommandStats};
pub use summary::{LegSummary, Rates, RoomSummary, RouteResult, aggregate};
pub use task::{Task, TaskKind, episode_seed, run_tasks};
