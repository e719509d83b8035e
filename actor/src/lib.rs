//! # dvnav-actor
//!
//! The rollout actor: it registers with the learner, steps `actor.envs` rooms in parallel
//! (rayon) with the newest policy it has (the PID controller during the run's warm-up
//! episodes), streams transitions in batches over gRPC, and writes selected episodes to MCAP.
//!
//! # Layout (Acme's vocabulary)
//! - [`environment_loop`]: [`EnvironmentLoop`], reset/step/observe over a `VecEnv`; generic
//!   over the [`dvnav_link::core::Adder`] and [`dvnav_link::core::VariableSource`] seams.
//! - [`adder`]: [`adder::BatchingAdder`], transitions into bounded batches for the stream.
//! - [`credits`]: [`credits::Credits`], how many batches may await an acknowledgement.
//! - [`variable_client`]: [`variable_client::VariableClient`], the newest weights and stage.
//! - [`episode_logger`]: which episodes go to MCAP.
//! - [`learner_link`]: connection, registration, delivery with acknowledgements, reconnection.
//! - [`mod@run`]: a whole actor process for `dvnav actor` and `dvnav train`.

pub mod adder;
pub mod credits;
pub mod environment_loop;
pub mod episode_logger;
pub mod learner_link;
pub mod run;
pub mod variable_client;

pub use environment_loop::EnvironmentLoop;
pub use run::{ActorOptions, ActorSummary, run};
