//! MCAP episode logs that open in Foxglove, and the reader behind `dvnav inspect`.
//!
//! Each actor writes its logged episodes with an [`EpisodeLogger`] into rotated, chunked,
//! zstd-compressed files `DIR/{prefix}-{index:05}.mcap`. Every message is protobuf:
//!
//! | topic | schema | when |
//! |---|---|---|
//! | [`/scene`](TOPIC_SCENE) | `foxglove.SceneUpdate` | episode start: walls, obstacles, goal, footprint (and the DVST-scaled footprint when μ ≠ 1) |
//! | [`/path`](TOPIC_PATH) | `foxglove.SceneUpdate` | every [`PATH_EVERY_STEPS`] steps and at the last: the path so far |
//! | [`/plan`](TOPIC_PLAN) | `foxglove.SceneUpdate` | the first step and every replan of an episode with a planned path (`env.subgoals`): the plan, a line strip |
//! | [`/subgoal`](TOPIC_SUBGOAL) | `foxglove.SceneUpdate` | every step that follows a planned path: the point the agent heads for |
//! | [`/tf`](TOPIC_TF) | `foxglove.FrameTransform` | every step: `world` → `robot` (the pose) |
//! | [`/scan`](TOPIC_SCAN) | `foxglove.LaserScan` | every step, frame `robot` |
//! | [`/dvnav/step`](TOPIC_STEP) | `dvnav.v1.StepRecord` | every step: action, reward, goal |
//! | [`/dvnav/episode`](TOPIC_EPISODE) | `dvnav.v1.EpisodeSummary` | episode end |
//!
//! dvnav's own schemas embed [`dvnav_proto::FILE_DESCRIPTOR_SET`], the same definitions the
//! gRPC wire uses, so Foxglove and other protobuf-aware tools decode them without dvnav. Every
//! file starts with an MCAP metadata record named [`METADATA_NAME`] holding [`LogMetadata`] and
//! dvnav's version.
//!
//! Design decisions:
//! - **Log time is simulation time**, on a per-file clock that starts at 0; episodes follow each
//!   other one control period apart and never overlap in a file.
//! - **Crash safety:** the logger closes the chunk and flushes at every episode end, so a killed
//!   actor loses only the episode it was writing; [`read_episodes`] reads unfinished files up to
//!   the damage and warns instead of failing.
//! - **Rotation** by episode count and by size; episodes never straddle files.
//! - **One context per logger** (never Foxglove's global one), so several loggers in one process
//!   never see each other's channels.
//!
//! ```no_run
//! use dvnav_config::LidarConfig;
//! use dvnav_eval::episode_log::{EpisodeLogger, EpisodeStart, LogMetadata, StepLog};
//! use dvnav_sim::RoomSpec;
//! # fn main() -> anyhow::Result<()> {
//! let room = RoomSpec::empty("env0", 8.0);
//! let lidar = LidarConfig::default();
//! let mut log = EpisodeLogger::create("logs".as_ref(), "actor-0", LogMetadata::default(), 50)?;
//! log.begin_episode(&EpisodeStart {
//!     episode_id: 0, room: &room, robot_radius: 0.2, goal: [2.0, 1.0], lidar: &lidar, dt: 0.2,
//!     mu: 1.0,
//! })?;
//! let scan = vec![10.0_f32; lidar.beams];
//! log.log_step(&StepLog {
//!     step: 0, pose: [0.0, 0.0, 0.0], scan: &scan, v: 0.0, omega: 0.0, action: [0.0, 0.0],
//!     reward: 0.0, goal_distance: 2.24, goal_angle: 0.46, subgoal: None, plan: None,
//! })?;
//! log.end_episode(dvnav_proto::EpisodeSummary { steps: 0, ..Default::default() })?;
//! log.close()?;
//! let _episodes = dvnav_eval::episode_log::read_episodes("logs".as_ref())?;
//! # Ok(()) }
//! ```

mod check;
mod proto_msg;
mod reader;
mod scene;
mod writer;

#[cfg(test)]
mod tests;

pub use check::{FileCheck, check_file, check_files};
pub use reader::{
    EpisodeDetail, EpisodeRecord, GroupSummary, episode_detail, read_episodes, read_steps,
    summarize,
};
pub use writer::{EpisodeLogger, EpisodeStart, LogMetadata, PATH_EVERY_STEPS, StepLog};

/// LiDAR scans (`foxglove.LaserScan`, frame `robot`).
pub const TOPIC_SCAN: &str = "/scan";
/// Robot pose (`foxglove.FrameTransform`, `world` → `robot`).
pub const TOPIC_TF: &str = "/tf";
/// Room, goal and footprint (`foxglove.SceneUpdate`).
pub const TOPIC_SCENE: &str = "/scene";
/// The path so far (`foxglove.SceneUpdate`, one line strip in frame `world`).
pub const TOPIC_PATH: &str = "/path";
/// The planned path of a long task (`foxglove.SceneUpdate`, one line strip `plan` in frame
/// `world`; deleted when an episode has none).
pub const TOPIC_PLAN: &str = "/plan";
/// The subgoal the agent heads for (`foxglove.SceneUpdate`, one sphere `subgoal` in frame
/// `world`; deleted when the agent sees the final goal).
pub const TOPIC_SUBGOAL: &str = "/subgoal";
/// Per-step action, reward and goal (`dvnav.v1.StepRecord`).
pub const TOPIC_STEP: &str = "/dvnav/step";
/// Per-episode summary (`dvnav.v1.EpisodeSummary`).
pub const TOPIC_EPISODE: &str = "/dvnav/episode";
/// Name of the MCAP metadata record that holds [`LogMetadata`].
pub const METADATA_NAME: &str = "dvnav";
