//! DVST, dimension-variable skill transfer (design §5): one meta agent, trained as the meta
//! robot (MR), drives a robot of another size or shape, the dimension-varied robot (DVR).
//!
//! - [`scale`]: the [`MetaRobot`] (a circle or a rectangle about the axle centre) and μ
//!   ([`covering_scale`]), the smallest scale of the meta robot that covers the varied robot
//!   plus a safety margin: the dimension-scaled robot (DSR).
//! - [`footprint_file`]: [`VariedRobot`], the varied robot as a user writes it (a footprint
//!   file with optional margin, velocity bounds and meta robot).
//! - [`transfer`]: observation transfer (lengths divided by μ) and policy transfer (the meta
//!   arc scaled by μ, shortened to the varied robot's bounds with its curvature kept).
//! - [`agent`]: [`Dvst`], any [`crate::policy::NavPolicy`] wrapped for the varied robot, itself
//!   a `NavPolicy`; the footprint can change at run time.
//! - [`laser_scan`]: any LiDAR's scan (ROS `LaserScan`, REP 117), mounted anywhere on the
//!   robot, resampled conservatively to the meta agent's beams.
//! - [`shared_policy`]: [`shared_policy::SharedPolicy`], one policy answering many callers,
//!   batching what arrives together.
//! - [`robots`]: [`robots::RobotTable`], robots by id, bounded, expiring when silent.
//! - [`route`]: a robot's own planner's path, followed by the simulator's subgoal rule
//!   (`SetRoute`).
//! - [`controller`]: [`DvstController`], a meta agent driving many robots for many callers
//!   (`dvnav serve`): checked and bounded requests, per-robot footprints changed atomically,
//!   arrival.
//!
//! ```
//! use dvnav_nav::dvst::{VariedRobot, transfer_policy, VelocityBounds};
//! use dvnav_sim::{Footprint, ObstacleSpec};
//! // The 0.2 m meta robot carrying a 0.3 m disc behind it reaches 0.5 m from the axle.
//! let cargo = ObstacleSpec::Circle { center: [-0.35, 0.0], radius: 0.15 };
//! let robot = VariedRobot::new(Footprint::circle(0.2).with_cargo([cargo]));
//! let mu = robot.mu();
//! assert!((mu - 2.5).abs() < 1e-12);
//! // The meta agent's (0.4 m/s, 1 rad/s) becomes the same arc, 2.5 times larger, shortened to
//! // v_max = 0.5 m/s: ρ = 1 m both times.
//! let bounds = VelocityBounds { v_max: 0.5, omega_max: 1.5 };
//! let (v, w) = transfer_policy(0.4, 1.0, mu, bounds);
//! assert!((v - 0.5).abs() < 1e-12 && (w - 0.5).abs() < 1e-12);
//! ```

pub mod agent;
pub mod controller;
pub mod footprint_file;
pub mod robots;
pub mod route;
pub mod scale;
pub mod shared_policy;
/// Observation and policy transfer live with the simulator, which also trains the meta agent
/// through them (`env.dvst`, [`dvnav_sim::transfer`]).
pub use dvnav_sim::transfer;

/// The resampling of any LiDAR's scan to the meta agent's beams lives with the simulator, which
/// also uses it for `dvnav eval --sensor` ([`dvnav_sim::sensor`]).
pub use dvnav_sim::laser_scan;

pub use agent::Dvst;
pub use controller::DvstController;
pub use footprint_file::VariedRobot;
pub use laser_scan::{BeamLayout, LaserScan, SensorSetup, Uncovered};
pub use scale::{MetaRobot, Reach, covering_scale};
pub use transfer::{VelocityBounds, transfer_observation, transfer_policy};
