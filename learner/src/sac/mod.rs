//! Soft Actor-Critic: the networks, the optimizer, the losses and the update.
//!
//! The hyper-parameters are [`dvnav_config::SacConfig`], a section of the run's one
//! config file.

pub mod average;
pub mod learning;
pub mod networks;
pub mod optim;
pub mod shards;

pub use dvnav_config::SacConfig;
pub use learning::{SacLearner, UpdateMetrics, UpdateNoise};
pub use networks::{GaussianPolicy, QFunction, SacNetworks};
