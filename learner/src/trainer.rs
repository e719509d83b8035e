//! The training loop, on its own thread: wait for the rate limiter, sample, update, publish
//! weights every `publish_every_updates`, checkpoint every `checkpoint_every_updates`.

use crate::checkpoint::{self, CheckpointMeta};
use crate::replay::Batch;
use crate::sac::SacLearner;
use crate::state::LearnerState;
use rand::SeedableRng;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Runs until the rate limiter closes, then hands the learner back for the final checkpoint.
pub fn train(
    state: Arc<LearnerState>,
    mut learner: SacLearner,
    out_dir: PathBuf,
) -> anyhow::Result<SacLearner> {
    let cfg = state.config().clone();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(cfg.run.seed ^ 0x05ac_1ea7);
    let mut batch = Batch::default();
    let limiter = state.limiter();
    loop {
        if !limiter.wait_to_update(Duration::from_millis(200)) {
            if limiter.is_closed() {
                break;
            }
            continue;
        }
        state.sample(cfg.sac.batch_size, &mut rng, &mut batch);
        let metrics = learner.update(&batch)?;
        limiter.updated();
        state.record_update(metrics);
        let updates = learner.updates();
        if updates.is_multiple_of(cfg.learner.publish_every_updates) {
            let version = state.variables().publish_weights(learner.policy_safetensors()?);
            tracing::debug!(updates, version, "published weights");
        }
        if updates.is_multiple_of(cfg.learner.checkpoint_every_updates) {
            let path = write_checkpoint(&state, &learner, &out_dir)?;
            tracing::info!(updates, path = %path.display(), "checkpoint written");
        }
    }
    Ok(learner)
}

/// Writes a checkpoint with the state's current counters.
pub fn write_checkpoint(
    state: &LearnerState,
    learner: &SacLearner,
    out_dir: &std::path::Path,
) -> anyhow::Result<PathBuf> {
    let st = state.status();
    let meta = CheckpointMeta {
        updates: learner.updates(),
        env_steps: st.transitions_received,
        episodes: st.episodes,
        weight_version: st.weight_version,
        optimizer_steps: learner.optimizer_steps(),
        stage: st.stage,
        run_id: st.run_id.clone(),
    };
    checkpoint::write(out_dir, learner, &meta, state.config_toml())
}
