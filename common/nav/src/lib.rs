//! # dvnav-nav
//!
//! The agent: everything that turns an observation into a velocity command, in candle.
//!
//! - [`nets`]: the policy and critic networks, one definition for acting and learning;
//!   [`fused`]: their fused CPU kernels.
//! - [`control`]: the PID warm-up controller.
//! - [`policy`]: [`policy::NavPolicy`], observation in, velocity out: the trained agent
//!   ([`policy::MetaAgent`]), the PID baseline, and what DVST wraps.
//! - [`escape`]: the stall escape, a recovery behaviour that samples the policy's own noise
//!   while a robot makes no progress.
//! - [`weights`]: policy weights as versioned safetensors bytes, rebuilt once per version.
//! - [`dvst`]: dimension-variable skill transfer: the meta robot, μ, the varied-robot file,
//!   observation and policy transfer, [`dvst::Dvst`] that wraps any policy, and
//!   [`dvst::DvstController`], the controller behind `dvnav serve`.
//!
//! It sits on [`dvnav_sim`] (the observation layout, footprints) and [`dvnav_config`] (network
//! sizes, the PID gains); it knows nothing of the wire, the logs or the processes.
//!
//! ```
//! use dvnav_nav::control::pid_velocity;
//! let cfg = dvnav_config::Config::default();
//! // The goal 1 m straight ahead: full speed, no turn.
//! let (v, w) = pid_velocity(1.0, 0.0, &cfg.warmup, &cfg.env);
//! assert_eq!((v, w), (0.5, 0.0));
//! ```
#![warn(missing_docs)]

pub mod bf16;
pub mod control;
pub mod conv;
pub mod dense;
pub mod dvst;
pub mod escape;
pub mod fused;
pub mod nets;
pub mod policy;
pub mod weights;
