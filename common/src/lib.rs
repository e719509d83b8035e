//! # dvnav-common
//!
//! Everything the actor and the learner share, testable without a network:
//!
//! - [`config`]: the run configuration (one TOML file, strict loading, documented defaults).
//! - [`sim`]: the rapier2d rooms, the robot, the LiDAR, rewards and termination, and
//!   [`sim::VecEnv`] that steps many environments in parallel with rayon.
//! - [`obs`]: the flat observation layout both processes agree on.
//! - [`nets`]: the policy and critic networks (candle), one definition for acting and learning;
//!   [`fused`]: their fused CPU kernels.
//! - [`control`]: the PID warm-up controller.
//! - [`policy`]: [`policy::NavPolicy`], observation in, velocity out: the trained agent, the
//!   PID baseline, and what DVST wraps.
//! - [`dvst`]: dimension-variable skill transfer: the meta robot, μ, the varied-robot file,
//!   observation and policy transfer, [`dvst::Dvst`] that wraps any policy, and
//!   [`dvst::DvstController`], the controller behind `dvnav serve`.
//! - [`core`]: Acme-style seams: [`core::TransitionBatch`], [`core::Adder`],
//!   [`core::VariableSource`], so an environment loop runs against an in-process learner in
//!   tests and against the gRPC one in production.
//! - [`weights`]: policy weights as safetensors bytes, versioned.
//! - [`wire`]: proto ⇄ domain conversions that validate untrusted input.
//! - [`episode_log`]: MCAP episode logs with Foxglove schemas, and the reader behind
//!   `dvnav inspect`.
//! - [`eval`]: policy evaluation: episodes, the evaluation-route protocol and the paper's
//!   score S, per-room rates, the gate and dynamic scenarios (`dvnav eval`, and the learner's
//!   evaluation during training).
//! - [`tls`]: optional TLS (rustls) for the gRPC services across machines: certificate and
//!   key files checked at start-up, tonic's server and client configs.
//!
//! `common` never depends on the actor or the learner crates.
//!
//! ```
//! use dvnav_common::config::Config;
//! let cfg = Config::default();
//! assert_eq!(cfg.obs_dim(), 544); // 540 beams + goal (d, φ) + (v, ω)
//! ```
#![warn(missing_docs)]

pub mod alloc_count;
pub mod auth;
pub mod config;
pub mod control;
pub mod core;
pub mod dvst;
pub mod episode_log;
pub mod eval;
pub mod fused;
pub mod nets;
pub mod obs;
pub mod policy;
pub mod sim;
pub mod tls;
pub mod weights;
pub mod wire;
