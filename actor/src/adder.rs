//! The actor's [`Adder`]: collects transitions into batches of `actor.batch_transitions` and
//! hands full batches to the transition stream through a bounded channel. When the learner
//! pushes back, the channel fills and `add` blocks: the environment loop slows down instead of
//! buffering without limit.

use dvnav_common::core::{Adder, EpisodeStats, TransitionBatch};
use dvnav_common::obs::ACTION_DIM;
use tokio::sync::mpsc;

/// Batches transitions for the gRPC stream.
pub struct BatchingAdder {
    batch: TransitionBatch,
    batch_size: usize,
    tx: mpsc::Sender<TransitionBatch>,
    /// Transitions handed to the stream.
    pub handed_over: u64,
}

impl BatchingAdder {
    /// Sends full batches of `batch_size` transitions into `tx`.
    pub fn new(obs_dim: usize, batch_size: usize, tx: mpsc::Sender<TransitionBatch>) -> Self {
        Self {
            batch: TransitionBatch::with_capacity(obs_dim, batch_size),
            batch_size,
            tx,
            handed_over: 0,
        }
    }

    fn send(&mut self) -> anyhow::Result<()> {
        if self.batch.is_empty() && self.batch.episodes.is_empty() {
            return Ok(());
        }
        let fresh = TransitionBatch::with_capacity(self.batch.obs_dim, self.batch_size);
        let full = std::mem::replace(&mut self.batch, fresh);
        let n = full.len() as u64;
        self.tx
            .blocking_send(full)
            .map_err(|_| anyhow::anyhow!("the transition stream to the learner is closed"))?;
        self.handed_over += n;
        Ok(())
    }
}

impl Adder for BatchingAdder {
    fn add(
        &mut self,
        obs: &[f32],
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) -> anyhow::Result<()> {
        self.batch.push(obs, action, reward, next_obs, terminated, truncated, policy_version);
        if self.batch.len() >= self.batch_size {
            self.send()?;
        }
        Ok(())
    }

    fn add_episode(&mut self, stats: EpisodeStats) -> anyhow::Result<()> {
        self.batch.episodes.push(stats);
        Ok(())
    }

    fn flush(&mut self) -> anyhow::Result<()> {
        self.send()
    }
}
