//! # dvnav-learner
//!
//! The learner process: it serves the `dvnav.v1.Learner` gRPC service, puts the transitions
//! actors stream in into a replay buffer, trains Soft Actor-Critic in candle, publishes
//! versioned policy weights, owns the curriculum and the warm-up phase, and checkpoints.
//!
//! # Layout
//! - [`state`]: [`state::LearnerState`], the domain object (registration, ingestion, counters,
//!   curriculum, budget, end of run), testable without a network, with its own save and
//!   restore; its status types ([`state::status`]) and live recorder ([`state::live`]).
//! - [`service`]: the tonic service, translating only.
//! - [`actor_tokens`]: per-actor tokens (`--actor-tokens`), name → token.
//! - [`replay`]: the replay buffer and the [`replay::Batch`] it samples.
//! - [`rate_limiter`]: keeps updates per environment step fixed; the source of backpressure.
//! - [`sac`]: networks, Adam, the losses ([`sac::learning`]) and [`sac::SacLearner`].
//! - [`variable_source`]: versioned weights out to actors.
//! - [`curriculum`]: the room curriculum rule.
//! - [`device`]: `--device cpu|cuda[:N]`.
//! - [`evaluator`]: the evaluation protocol during training (routes and random episodes of
//!   every curriculum room, on its own thread) into `eval.csv`.
//! - [`trainer`]: the training thread. [`checkpoint`]: atomic checkpoints and exact resume,
//!   assembled from the parts the SAC learner, the state and the trainer save of themselves.
//! - [`metrics`]: live metrics by job: the sampler, Prometheus text, `metrics.csv`, and the
//!   axum router for `/metrics`, `/healthz` and `/readyz`.
//! - [`csv_format`]: how numbers are spelled in `metrics.csv` and `eval.csv`.
//! - [`mod@run`]: a whole learner process, for `dvnav learner` and `dvnav train`.
//! - [`watchdog`]: names the component that stopped making progress (`dvnav_stalled`).
//!
//! No module imports one that imports it back. The end of the run is one shape throughout:
//! the state's `CancellationToken`s (tokio-util), which every task and server stops on.

pub mod actor_tokens;
pub mod alloc_count;
pub mod bench;
pub mod best_agent;
pub mod checkpoint;
pub mod csv_format;
pub mod curriculum;
pub mod denormals;
pub mod device;
pub mod eval_robots;
pub mod evaluator;
pub mod json_f64;
pub mod metrics;
pub mod process_memory;
pub mod rate_limiter;
pub mod replay;
pub mod run;
pub mod sac;
pub mod selection;
pub mod service;
pub mod state;
pub mod trainer;
pub mod variable_source;
pub mod watchdog;

pub use run::{LearnerOptions, LearnerSummary, run};
