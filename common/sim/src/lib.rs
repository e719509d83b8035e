//! # dvnav-sim
//!
//! The simulator: rapier2d rooms, the robot, the LiDAR, rewards and termination. It depends on
//! nothing else of dvnav's (no candle, tonic or mcap): the networks, the wire and the logs sit
//! in the crates above it.
//!
//! - [`obs`]: the flat observation layout every other crate agrees on.
//! - [`EnvConfig`]: the task's constants (the `[env]` section of a run's config).
//! - [`Outcome`] and [`score`]: how an episode ends and the paper's score S of it.
//! - [`RoomSpec`] / [`ObstacleSpec`]: rooms as plain data (serde): walls, obstacles (boxes,
//!   circles, convex polygons, compounds), spawn regions, evaluation [`Route`]s and
//!   [`TimedObstacle`]s.
//! - [`room_file`]: the TOML room file format, its loader (errors name the line and the
//!   reason) and the built-in rooms of `rooms/` (Env_0..Env_3, `sac_ri`, `gate`, `dynamic`),
//!   embedded in the binary.
//! - [`grid_map`]: occupancy-grid maps (ROS map_server YAML + PGM/PNG, or a plain image) as
//!   rooms: unknown cells count as obstacles, obstacle cells merge into boxes.
//! - [`room_set`]: a curriculum stage as a set of rooms (`env0|generated:clutter:0..2000`),
//!   one drawn per episode, and deterministic samples of it for evaluation.
//! - [`Footprint`]: the robot's shape (a union of convex parts, LiDAR at the origin), also a
//!   small TOML file.
//! - [`Room`]: one room's geometry behind rapier2d's query pipeline (ray casts, overlap
//!   tests); built once and shared as `Arc<Room>`.
//! - [`Lidar`]: the planar range finder at the robot's axle centre. Scans are cast shape by
//!   shape against the room's flat geometry (`caster.rs`), exact in `f64`; rapier's per-beam
//!   ray casts remain as the reference ([`Lidar::scan_reference`]).
//! - [`NavEnv`]: one episode at a time for a robot of any footprint (the circular meta robot
//!   by default) with unicycle kinematics, the paper's reward, timed obstacles, and the flat
//!   observation of [`obs`].
//! - [`planner`]: paths through a room for a robot's size (A* on the clearance raster
//!   inflated by the footprint, string-pulled), for the meta agent to follow by subgoals.
//! - [`subgoal`]: the subgoal rule that follows a planned path (pure pursuit, replans, the
//!   rotation shim), one implementation for training, evaluation and the controller.
//! - [`VecEnv`]: many [`NavEnv`]s stepped in parallel with rayon.
//!
//! There is no dynamics here: the robot is kinematic (velocity commands are followed exactly),
//! so "physics" is collision detection and ray casting against static shapes. Motion is
//! integrated in closed form and checked for contact at sub-steps so close that no point of the
//! footprint moves more than `EnvConfig::collision_substep` between two checks (turning counts:
//! a long robot turning in place sweeps its corners), so the robot cannot pass through a thin
//! wall however large the control period is.
//!
//! ```
//! use dvnav_sim::{EnvConfig, NavEnv, Room};
//! let room = Room::builtin("env0").unwrap();
//! let mut env = NavEnv::new(room, &EnvConfig::default(), 7);
//! let mut obs = vec![0.0f32; env.obs_dim()];
//! env.write_obs(&mut obs);
//! let out = env.step(0.5, 0.0);
//! assert!(out.reward.is_finite());
//! ```

#![warn(missing_docs)]

mod caster;
mod env;
mod env_config;
mod footprint;
pub mod generate;
pub mod grid;
pub mod grid_map;
pub mod laser_scan;
pub mod latency;
mod lidar;
pub mod obs;
mod outcome;
pub mod planner;
pub mod robustness;
mod room;
pub mod room_file;
pub mod room_set;
pub mod safety;
pub mod sensor;
pub mod spec;
pub mod subgoal;
pub mod transfer;
mod vec_env;

pub use env::{NavEnv, NoTask, RouteStats, StepOutcome};
pub use env_config::{DvstTrainingConfig, EnvConfig, LidarConfig, RewardConfig};
pub use footprint::Footprint;
pub use footprint::MAX_ROBOT_EXTENT_M;
pub use footprint::checked_parts;
pub use lidar::{Lidar, scan_points};
pub use outcome::{Outcome, score};
pub use robustness::{RandomizeConfig, RobustnessConfig};
pub use room::Room;
pub use room_file::SpecFileError;
pub use sensor::{MountedSensor, SensorSpec};
pub use spec::{ObstacleSpec, Point, RoomSpec, Route, SpawnRegion, TimedObstacle, WallSegment};
pub use vec_env::VecEnv;

/// A planar pose: position (m) in the room frame and heading `yaw` (rad, counter-clockwise
/// from +x).
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Pose2 {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
    /// Heading (rad).
    pub yaw: f64,
}

impl Pose2 {
    /// A pose from its parts.
    pub const fn new(x: f64, y: f64, yaw: f64) -> Pose2 {
        Pose2 { x, y, yaw }
    }

    /// The position `[x, y]`.
    pub const fn position(&self) -> [f64; 2] {
        [self.x, self.y]
    }

    /// Bearing of `p` (room frame) seen from this pose (rad, (−π, π], left positive).
    pub fn bearing_to(&self, p: [f64; 2]) -> f64 {
        let [x, y] = self.to_local(p);
        let a = y.atan2(x);
        if a <= -std::f64::consts::PI { std::f64::consts::PI } else { a }
    }

    /// `p` (room frame) in this pose's frame: x ahead, y to the left.
    pub fn to_local(&self, p: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (p[0] - self.x, p[1] - self.y);
        [c * dx + s * dy, -s * dx + c * dy]
    }
}

/// The unicycle's pose after driving `(v, ω)` for `t` seconds from `p`, in closed form.
///
/// The arc's chord has length v·t·sinc(ω·t/2) and points along the mean heading
/// yaw + ω·t/2; written this way it needs no separate straight-line case and stays accurate as
/// ω → 0.
pub(crate) fn advance(p: Pose2, v: f64, omega: f64, t: f64) -> Pose2 {
    let half = 0.5 * omega * t;
    let sinc = if half.abs() < 1e-4 { 1.0 - half * half / 6.0 } else { half.sin() / half };
    let chord = v * t * sinc;
    let (s, c) = (p.yaw + half).sin_cos();
    Pose2 { x: p.x + chord * c, y: p.y + chord * s, yaw: p.yaw + omega * t }
}

/// Euclidean distance between two points (m).
pub(crate) fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// `a` wrapped to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = a - TAU * ((a + PI) / TAU).floor(); // [−π, π)
    if w <= -PI { w + TAU } else { w }
}
