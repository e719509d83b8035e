//! The training loop, on its own thread: wait for the rate limiter, sample, update, publish
//! weights every `publish_every_updates`, hand a snapshot of the policy to the evaluator every
//! `eval_every_updates`, checkpoint every `checkpoint_every_updates`.

use crate::checkpoint;
use crate::evaluator::{Evaluator, Snapshot};
use crate::replay::Batch;
use crate::sac::{SacLearner, UpdateMetrics};
use crate::state::LearnerState;
use rand::SeedableRng;
use rand_pcg::Pcg64;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// The batch-sampling generator of a fresh run with root seed `seed`.
pub fn sample_rng(seed: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed ^ 0x05ac_1ea7)
}

/// Runs until the rate limiter closes, then hands the learner and the sampling generator back
/// for the final checkpoint.
pub fn train(
    state: Arc<LearnerState>,
    mut learner: SacLearner,
    mut rng: Pcg64,
    out_dir: PathBuf,
) -> anyhow::Result<(SacLearner, Pcg64)> {
    let cfg = state.config().clone();
    let mut batch = Batch::default();
    let limiter = state.limiter();
    let evaluator = {
        let state = state.clone();
        let report: crate::evaluator::WriteFailure =
            Box::new(move |path, e| state.record_write_failure("eval_csv", path, &e));
        Evaluator::start_reporting(&cfg, &out_dir, Some(report))?
    };
    loop {
        if !limiter.wait_to_update(Duration::from_millis(200)) {
            if limiter.is_closed() {
                break;
            }
            continue;
        }
        train_step(&state, &mut learner, &mut rng, &mut batch)?;
        let updates = learner.updates();
        let eval_due =
            evaluator.is_some() && updates.is_multiple_of(cfg.learner.eval_every_updates);
        // The evaluator's snapshot: the published weights when they are published now.
        let mut snapshot = None;
        if updates.is_multiple_of(cfg.learner.publish_every_updates) {
            let policy = learner.policy_safetensors()?;
            let for_eval = eval_due.then(|| policy.clone());
            let version = state.variables().publish_weights(policy);
            tracing::debug!(updates, version, "published weights");
            snapshot = for_eval.map(|p| (version, p));
        }
        if let Some(ev) = evaluator.as_ref().filter(|_| eval_due) {
            let (policy_version, policy) = match snapshot {
                Some(s) => s,
                None => (0, learner.policy_safetensors()?),
            };
            let env_steps = state.status().transitions_received;
            ev.submit(Snapshot { updates, env_steps, policy_version, policy });
        }
        if updates.is_multiple_of(cfg.learner.checkpoint_every_updates) {
            // A failed checkpoint (disk full, unwritable directory) is logged and counted, and
            // training goes on: the state is in memory, the previous checkpoint is intact, and
            // the next one is tried at its usual time.
            match checkpoint::save(&out_dir, &state, &learner, &rng) {
                Ok(path) => tracing::info!(updates, path = %path.display(), "checkpoint written"),
                Err(e) => state.record_write_failure(
                    "checkpoint",
                    &out_dir.join("checkpoints"),
                    &format!("{e:#}"),
                ),
            }
        }
    }
    if let Some(ev) = evaluator {
        ev.finish();
    }
    Ok((learner, rng))
}

/// One update: sample a batch with `rng`, update, count it.
pub fn train_step(
    state: &LearnerState,
    learner: &mut SacLearner,
    rng: &mut Pcg64,
    batch: &mut Batch,
) -> anyhow::Result<UpdateMetrics> {
    state.sample(state.config().sac.batch_size, rng, batch);
    let metrics = learner.update(batch)?;
    state.limiter().updated();
    state.record_update(metrics);
    Ok(metrics)
}
