//! The training loop, on its own thread: wait for the rate limiter, sample, update, publish
//! weights every `publish_every_updates`, hand a snapshot of the policy to the evaluator every
//! `eval_every_updates`, checkpoint every `checkpoint_every_updates` and every
//! `checkpoint_every_s` ([`CheckpointSchedule`]).

use crate::checkpoint;
use crate::evaluator::{Evaluator, Snapshot};
use crate::replay::Batch;
use crate::sac::{SacLearner, UpdateMetrics};
use crate::state::LearnerState;
use rand::SeedableRng;
use rand_pcg::Pcg64;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// When the trainer writes a checkpoint: every `every_updates` updates, and once `every_s`
/// seconds have passed since the last one if training moved since (a learner killed in its
/// first minutes then still has one to resume from). The time is checked while the trainer
/// waits for data too, so a checkpoint is at most a tick later than due.
#[derive(Debug)]
pub struct CheckpointSchedule {
    every_updates: u64,
    every: Option<Duration>,
    last_at: Instant,
    last_updates: u64,
}

impl CheckpointSchedule {
    /// From `learner.checkpoint_every_updates` and `learner.checkpoint_every_s` (0: off), with
    /// the clock starting now at `updates` (non-zero after a resume).
    pub fn new(every_updates: u64, every_s: f64, updates: u64) -> Self {
        Self {
            every_updates,
            every: (every_s > 0.0).then(|| Duration::from_secs_f64(every_s)),
            last_at: Instant::now(),
            last_updates: updates,
        }
    }

    /// Whether a checkpoint is due at `updates`, as of `now`.
    pub fn due(&self, updates: u64, now: Instant) -> bool {
        if updates == self.last_updates {
            return false;
        }
        updates.is_multiple_of(self.every_updates)
            || self.every.is_some_and(|e| now.duration_since(self.last_at) >= e)
    }

    /// Records a checkpoint attempt at `updates` (a failed one too: it is retried at the next
    /// due time, not at every update).
    pub fn written(&mut self, updates: u64, now: Instant) {
        self.last_at = now;
        self.last_updates = updates;
    }
}

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
    // This thread runs the updates (with one learner thread, all of them).
    crate::denormals::flush_denormals_to_zero();
    let mut batch = Batch::default();
    let limiter = state.limiter();
    let evaluator = {
        let state = state.clone();
        let report: crate::evaluator::WriteFailure =
            Box::new(move |path, e| state.record_write_failure("eval_csv", path, &e));
        Evaluator::start_reporting(&cfg, &out_dir, Some(report))?
    };
    let mut schedule = CheckpointSchedule::new(
        cfg.learner.checkpoint_every_updates,
        cfg.learner.checkpoint_every_s,
        learner.updates(),
    );
    loop {
        if !limiter.wait_to_update(Duration::from_millis(200)) {
            if limiter.is_closed() {
                break;
            }
            if schedule.due(learner.updates(), Instant::now()) {
                checkpoint_now(&state, &learner, &rng, &out_dir, &mut schedule);
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
            let (policy_version, online) = match snapshot {
                Some(s) => s,
                None => (0, learner.policy_safetensors()?),
            };
            // The run's agent is evaluated; with a policy average, the online policy the
            // actors have (`policy_version`) goes along for the gate test beside it.
            let (policy, online) = if learner.averages_policy() {
                (learner.agent_safetensors()?, Some(online))
            } else {
                (online, None)
            };
            let env_steps = state.status().transitions_received;
            ev.submit(Snapshot { updates, env_steps, policy_version, policy, online });
        }
        if schedule.due(updates, Instant::now()) {
            checkpoint_now(&state, &learner, &rng, &out_dir, &mut schedule);
        }
    }
    if let Some(ev) = evaluator {
        ev.finish();
    }
    Ok((learner, rng))
}

/// Writes a checkpoint. A failed one (disk full, unwritable directory) is logged and counted,
/// and training goes on: the state is in memory, the previous checkpoint is intact, and the
/// next one is tried at its usual time.
fn checkpoint_now(
    state: &LearnerState,
    learner: &SacLearner,
    rng: &Pcg64,
    out_dir: &std::path::Path,
    schedule: &mut CheckpointSchedule,
) {
    let updates = learner.updates();
    match checkpoint::save(out_dir, state, learner, rng) {
        Ok(path) => tracing::info!(updates, path = %path.display(), "checkpoint written"),
        Err(e) => state.record_write_failure(
            "checkpoint",
            &out_dir.join("checkpoints"),
            &format!("{e:#}"),
        ),
    }
    schedule.written(updates, Instant::now());
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoints_come_by_updates_and_by_time_once_training_moved() {
        let t0 = Instant::now();
        let s = CheckpointSchedule::new(100, 300.0, 0);
        assert!(s.due(100, t0));
        assert!(!s.due(99, t0 + Duration::from_secs(299)));
        assert!(s.due(99, t0 + Duration::from_secs(301)), "by time");
        let mut s = s;
        s.written(99, t0 + Duration::from_secs(301));
        assert!(!s.due(99, t0 + Duration::from_secs(10_000)), "nothing new to save");
        assert!(!s.due(150, t0 + Duration::from_secs(600)));
        assert!(s.due(150, t0 + Duration::from_secs(602)));
        let by_updates_only = CheckpointSchedule::new(100, 0.0, 0);
        assert!(!by_updates_only.due(99, t0 + Duration::from_secs(1_000_000)));
        // A resumed run does not checkpoint again what it resumed from.
        assert!(!CheckpointSchedule::new(100, 300.0, 200).due(200, t0));
    }
}
