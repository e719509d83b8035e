//! Acme-style seams between acting and learning.
//!
//! An environment loop hands each step to an [`Adder`], which turns steps into
//! [`TransitionBatch`]es for the learner; it reads the newest policy from a [`VariableSource`].
//! The actor implements both over gRPC; tests implement them in process, so the same loop runs
//! with or without a network.

use dvnav_sim::Outcome;
use dvnav_sim::obs::ACTION_DIM;
use std::sync::Arc;

/// What an actor reports about a finished episode.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeStats {
    /// Index of the environment within its actor.
    pub env_index: u32,
    /// Curriculum stage the episode ran in.
    pub stage: u32,
    /// Room name.
    pub room: String,
    /// How it ended.
    pub outcome: Outcome,
    /// Control steps taken.
    pub steps: u32,
    /// Undiscounted sum of rewards.
    pub episode_return: f32,
    /// Weight version at the last step (0 for the PID controller).
    pub policy_version: u64,
    /// Driven by the PID warm-up controller.
    pub warmup: bool,
}

/// Transitions in structure-of-arrays layout, as they travel and as the replay buffer takes them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TransitionBatch {
    /// Length of one observation.
    pub obs_dim: usize,
    /// `len() * obs_dim` floats.
    pub observations: Vec<f32>,
    /// `len() * ACTION_DIM` floats in [-1, 1].
    pub actions: Vec<f32>,
    /// One reward per transition.
    pub rewards: Vec<f32>,
    /// `len() * obs_dim` floats.
    pub next_observations: Vec<f32>,
    /// Success or collision: no bootstrap.
    pub terminated: Vec<bool>,
    /// Timeout: bootstrap through it.
    pub truncated: Vec<bool>,
    /// Weight version that chose each action (0: PID).
    pub policy_versions: Vec<u64>,
    /// Episodes that ended inside this batch.
    pub episodes: Vec<EpisodeStats>,
}

impl TransitionBatch {
    /// An empty batch with room for `capacity` transitions.
    pub fn with_capacity(obs_dim: usize, capacity: usize) -> Self {
        Self {
            obs_dim,
            observations: Vec::with_capacity(capacity * obs_dim),
            actions: Vec::with_capacity(capacity * ACTION_DIM),
            rewards: Vec::with_capacity(capacity),
            next_observations: Vec::with_capacity(capacity * obs_dim),
            terminated: Vec::with_capacity(capacity),
            truncated: Vec::with_capacity(capacity),
            policy_versions: Vec::with_capacity(capacity),
            episodes: Vec::new(),
        }
    }

    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    /// True when there are no transitions (there may still be episode reports).
    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }

    /// Appends one transition.
    #[allow(clippy::too_many_arguments)]
    pub fn push(
        &mut self,
        obs: &[f32],
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) {
        debug_assert_eq!(obs.len(), self.obs_dim);
        debug_assert_eq!(next_obs.len(), self.obs_dim);
        self.observations.extend_from_slice(obs);
        self.actions.extend_from_slice(&action);
        self.rewards.push(reward);
        self.next_observations.extend_from_slice(next_obs);
        self.terminated.push(terminated);
        self.truncated.push(truncated);
        self.policy_versions.push(policy_version);
    }

    /// Empties the batch, keeping its allocations.
    pub fn clear(&mut self) {
        self.observations.clear();
        self.actions.clear();
        self.rewards.clear();
        self.next_observations.clear();
        self.terminated.clear();
        self.truncated.clear();
        self.policy_versions.clear();
        self.episodes.clear();
    }
}

/// Turns environment steps into transitions for the learner (Acme's Adder).
pub trait Adder {
    /// Records one transition.
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        obs: &[f32],
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) -> anyhow::Result<()>;
    /// Records a finished episode; it travels with the transitions around it.
    fn add_episode(&mut self, stats: EpisodeStats) -> anyhow::Result<()>;
    /// Sends whatever is buffered.
    fn flush(&mut self) -> anyhow::Result<()>;
}

/// What the learner tells its actors: weights, the stage to run, and the run's phase.
#[derive(Clone, Debug, PartialEq)]
pub struct Variables {
    /// Weight version, increasing from 1.
    pub version: u64,
    /// Policy weights as safetensors bytes (see `dvnav_nav::weights`), serialized once per
    /// version; every actor's stream sends this one buffer ([`crate::wire::policy_bytes`]).
    pub policy: Arc<Vec<u8>>,
    /// Curriculum stage this actor should run.
    pub stage: u32,
    /// Room of that stage.
    pub room: String,
    /// The run is still in its PID warm-up episodes.
    pub warmup: bool,
    /// The run is over: flush and stop.
    pub stop: bool,
}

/// Where an actor gets its newest variables from (Acme's VariableSource).
pub trait VariableSource {
    /// The newest variables, if any have been published yet. Never blocks.
    fn latest(&self) -> Option<Arc<Variables>>;
}
