//! The learner's domain state, independent of gRPC: registration, ingestion into the replay
//! buffer, counters per actor, the curriculum, the warm-up phase and the step budget. The gRPC
//! service ([`crate::service`]) only translates to and from these calls.

use crate::curriculum::{Curriculum, StageChange};
use crate::rate_limiter::RateLimiter;
use crate::replay::{Batch, ObsCodec, ReplayBuffer};
use crate::variable_source::VariableSource;
use dvnav_config::Config;
use dvnav_link::core::Variables;
use dvnav_link::wire::{self, WireError};
use dvnav_proto as pb;
use dvnav_sim::Outcome;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::watch;

/// Why the learner refused a request; mapped to a gRPC status in one place.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// The actor speaks another protocol version.
    #[error("protocol version {got} is not supported; this learner speaks {expected}")]
    ProtocolMismatch {
        /// What the actor sent.
        got: u32,
        /// What the learner speaks.
        expected: u32,
    },
    /// Missing or wrong shared token.
    #[error("missing or wrong access token")]
    Unauthenticated,
    /// A batch from an actor id that never registered.
    #[error("unknown actor id {0}; register first")]
    UnknownActor(u32),
    /// A malformed batch.
    #[error("malformed transition batch: {0}")]
    Malformed(#[from] WireError),
    /// An invalid request field.
    #[error("invalid request: {0}")]
    InvalidRequest(String),
    /// The learner is shutting down.
    #[error("the learner is shutting down")]
    ShuttingDown,
}

impl LearnerError {
    /// The `reason` label this refusal is counted under (`dvnav_requests_rejected_total`):
    /// the offending field for a malformed batch, else the kind of refusal.
    pub fn reason(&self) -> &'static str {
        match self {
            LearnerError::ProtocolMismatch { .. } => "protocol_version",
            LearnerError::Unauthenticated => "unauthenticated",
            LearnerError::UnknownActor(_) => "unknown_actor",
            LearnerError::Malformed(e) => e.field,
            LearnerError::InvalidRequest(_) => "invalid_request",
            LearnerError::ShuttingDown => "shutting_down",
        }
    }
}

/// Counters of one actor.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ActorCounters {
    /// Actor id given at registration.
    pub actor_id: u32,
    /// Name the actor gave.
    pub name: String,
    /// Transitions accepted into the replay buffer.
    pub transitions_received: u64,
    /// Transitions refused (malformed batches).
    pub transitions_rejected: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Batches accepted.
    pub batches: u64,
    /// A transition stream is open.
    pub connected: bool,
    /// Transition streams open for this actor id (a restarted process under the same name may
    /// open its stream before the learner has seen the old one end).
    #[serde(skip)]
    pub open_streams: u32,
    /// Registrations (more than 1 after reconnects).
    pub registrations: u64,
    /// Smallest and largest weight version seen on this actor's transitions (0: PID).
    pub min_policy_version: u64,
    /// Largest weight version seen on this actor's transitions.
    pub max_policy_version: u64,
    /// Episodes by outcome.
    pub successes: u64,
    /// Episodes that ended in a collision.
    pub collisions: u64,
    /// Episodes that timed out.
    pub timeouts: u64,
    /// Sequence number expected next; lower ones are resends of batches already inserted.
    pub next_sequence: u64,
    /// Resent batches recognised and acknowledged without inserting them again.
    pub duplicate_batches: u64,
    /// The last refusal or stream error of this actor (the watchdog reports it with a stall).
    pub last_error: Option<String>,
}

/// What `Status` returns and the run summary is built from.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StatusSnapshot {
    /// Run id.
    pub run_id: String,
    /// Transitions accepted.
    pub transitions_received: u64,
    /// Transitions refused.
    pub transitions_rejected: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Learner updates done.
    pub updates: u64,
    /// Newest weight version.
    pub weight_version: u64,
    /// Transitions in the replay buffer.
    pub replay_size: u64,
    /// Curriculum stage.
    pub stage: u32,
    /// Success rate over the curriculum window.
    pub success_rate: f64,
    /// Last critic loss.
    pub critic_loss: f64,
    /// Last actor loss.
    pub actor_loss: f64,
    /// Temperature α.
    pub alpha: f64,
    /// The step budget is reached (or shutdown began).
    pub done: bool,
    /// The step budget.
    pub step_budget: u64,
    /// Per actor.
    pub actors: Vec<ActorCounters>,
    /// Stage changes so far.
    pub stage_changes: Vec<StageChange>,
    /// When the last room first reached the threshold over a full window.
    pub skilled: Option<StageChange>,
    /// Every loss seen so far was finite.
    pub losses_finite: bool,
    /// Rates, policy lag and per-stage outcomes ([`crate::metrics`]).
    pub live: crate::metrics::LiveSnapshot,
    /// Refused requests and batches by reason ([`LearnerError::reason`]; `stream_oversized`
    /// for a message over the size limit, `stream_broken` for a stream that broke).
    pub rejected_by_reason: BTreeMap<String, u64>,
    /// Failed writes by output (`checkpoint`, `metrics_csv`, `eval_csv`); training goes on.
    pub write_failures: BTreeMap<String, u64>,
    /// The last failed write: output, path and OS error.
    pub last_write_error: Option<String>,
    /// The trainer's last error (a failed checkpoint, for one).
    pub trainer_last_error: Option<String>,
    /// Components the watchdog finds stuck now ([`crate::watchdog`]).
    pub stalled: Vec<crate::watchdog::Stall>,
}

#[derive(Debug)]
struct Counters {
    next_actor_id: u32,
    actors: BTreeMap<u32, ActorCounters>,
    received: u64,
    rejected: u64,
    episodes: u64,
    curriculum: Curriculum,
    metrics: crate::sac::UpdateMetrics,
    losses_finite: bool,
    done: bool,
    rejected_by_reason: BTreeMap<String, u64>,
    write_failures: BTreeMap<String, u64>,
    last_write_error: Option<String>,
    trainer_last_error: Option<String>,
    stalled: Vec<crate::watchdog::Stall>,
}

/// What an actor gets back from registration.
#[derive(Clone, Debug)]
pub struct Registration {
    /// Its id.
    pub actor_id: u32,
    /// Seed for its environments.
    pub actor_seed: u64,
    /// The batch sequence number expected next from this actor name.
    pub next_sequence: u64,
}

/// Whether the learner takes actors now (`GET /readyz`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Readiness {
    /// The gRPC service is not up yet.
    Starting,
    /// Serving: actors may register and stream.
    Ready,
    /// The step budget is reached or shutdown began: no new actors wanted.
    Finished,
}

/// The learner's answer to one batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ack {
    /// Transitions inserted into the replay buffer.
    pub accepted: u32,
    /// The batch was a resend of one already inserted; nothing was inserted.
    pub duplicate: bool,
}

/// The learner's shared state (see the module docs).
pub struct LearnerState {
    cfg: Config,
    config_toml: String,
    run_id: String,
    token: Option<String>,
    replay: Mutex<ReplayBuffer>,
    limiter: RateLimiter,
    counters: Mutex<Counters>,
    variables: VariableSource,
    done_tx: watch::Sender<bool>,
    shutdown_tx: watch::Sender<bool>,
    live: crate::metrics::LiveMetrics,
    serving: AtomicBool,
}

impl LearnerState {
    /// Fresh state for a run; `initial_policy` is version 1 of the weights.
    pub fn new(
        cfg: Config,
        run_id: String,
        token: Option<String>,
        initial_policy: Vec<u8>,
    ) -> Self {
        let curriculum = Curriculum::new(cfg.curriculum.clone());
        let variables = VariableSource::new(Variables {
            version: 1,
            policy: Arc::new(initial_policy),
            stage: 0,
            room: curriculum.room().to_string(),
            warmup: cfg.warmup.pid_episodes > 0,
            stop: false,
        });
        Self {
            limiter: RateLimiter::new(
                cfg.sac.updates_per_env_step,
                cfg.sac.learning_starts,
                cfg.learner.max_steps_ahead,
            ),
            replay: Mutex::new(ReplayBuffer::new(ObsCodec::for_config(&cfg), cfg.replay.capacity)),
            counters: Mutex::new(Counters {
                next_actor_id: 0,
                actors: BTreeMap::new(),
                received: 0,
                rejected: 0,
                episodes: 0,
                curriculum,
                metrics: Default::default(),
                losses_finite: true,
                done: false,
                rejected_by_reason: BTreeMap::new(),
                write_failures: BTreeMap::new(),
                last_write_error: None,
                trainer_last_error: None,
                stalled: Vec::new(),
            }),
            config_toml: cfg.to_toml_string(),
            cfg,
            run_id,
            token,
            variables,
            done_tx: watch::channel(false).0,
            shutdown_tx: watch::channel(false).0,
            live: Default::default(),
            serving: AtomicBool::new(false),
        }
    }

    /// The run's configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The run id.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// The replay-ratio keeper.
    pub fn limiter(&self) -> &RateLimiter {
        &self.limiter
    }

    /// Weight distribution.
    pub fn variables(&self) -> &VariableSource {
        &self.variables
    }

    /// Live metrics (policy lag, per-stage outcomes, rates) for `/metrics` and `metrics.csv`.
    pub fn live(&self) -> &crate::metrics::LiveMetrics {
        &self.live
    }

    /// Checks the shared token, when one is configured.
    pub fn authorize(&self, presented: Option<&str>) -> Result<(), LearnerError> {
        if dvnav_tls::auth::token_accepted(self.token.as_deref(), presented) {
            Ok(())
        } else {
            Err(LearnerError::Unauthenticated)
        }
    }

    /// Registers an actor.
    pub fn register(
        &self,
        name: &str,
        protocol_version: u32,
    ) -> Result<Registration, LearnerError> {
        self.register_checked(name, protocol_version).inspect_err(|e| {
            self.count_rejection(None, e.reason(), &e.to_string());
            tracing::warn!(name, error = %e, "refused a registration");
        })
    }

    fn register_checked(
        &self,
        name: &str,
        protocol_version: u32,
    ) -> Result<Registration, LearnerError> {
        if protocol_version != dvnav_proto::PROTOCOL_VERSION {
            return Err(LearnerError::ProtocolMismatch {
                got: protocol_version,
                expected: dvnav_proto::PROTOCOL_VERSION,
            });
        }
        if name.is_empty() || name.len() > 128 {
            return Err(LearnerError::InvalidRequest("actor_name must be 1 to 128 bytes".into()));
        }
        if *self.shutdown_tx.borrow() {
            return Err(LearnerError::ShuttingDown);
        }
        let mut c = self.counters.lock().expect("counters lock");
        // An actor that comes back under the same name keeps its id and counters.
        let existing = c.actors.values().find(|a| a.name == name).map(|a| a.actor_id);
        let actor_id = existing.unwrap_or_else(|| {
            let id = c.next_actor_id;
            c.next_actor_id += 1;
            id
        });
        let entry = c.actors.entry(actor_id).or_insert_with(|| ActorCounters {
            actor_id,
            name: name.to_string(),
            min_policy_version: u64::MAX,
            ..Default::default()
        });
        entry.registrations += 1;
        let next_sequence = entry.next_sequence;
        tracing::info!(actor_id, name, registrations = entry.registrations, "actor registered");
        let actor_seed =
            self.cfg.run.seed.wrapping_mul(1_000_003).wrapping_add(actor_id as u64 + 1);
        Ok(Registration { actor_id, actor_seed, next_sequence })
    }

    /// Counts a refused request or batch under `reason`, and remembers `error` as the actor's
    /// last error when the actor is known.
    pub fn count_rejection(&self, actor_id: Option<u32>, reason: &str, error: &str) {
        let mut c = self.counters.lock().expect("counters lock");
        *c.rejected_by_reason.entry(reason.to_string()).or_default() += 1;
        if let Some(a) = actor_id.and_then(|id| c.actors.get_mut(&id)) {
            a.last_error = Some(error.to_string());
        }
    }

    /// Records a failed write of `output` (`checkpoint`, `metrics_csv`, `eval_csv`) to `path`:
    /// logs it at error level with the path and the OS error, and counts it. The caller goes
    /// on (training state stays in memory) and tries again at the next opportunity.
    pub fn record_write_failure(
        &self,
        output: &str,
        path: &std::path::Path,
        error: &dyn std::fmt::Display,
    ) {
        let message = format!("{output}: cannot write {}: {error}", path.display());
        tracing::error!(output, path = %path.display(), error = %error, "write failed; training goes on, next attempt at the next opportunity");
        let mut c = self.counters.lock().expect("counters lock");
        *c.write_failures.entry(output.to_string()).or_default() += 1;
        if output == "checkpoint" {
            c.trainer_last_error = Some(message.clone());
        }
        c.last_write_error = Some(message);
    }

    /// Remembers the trainer's last error (reported by the watchdog with a trainer stall).
    pub fn record_trainer_error(&self, error: String) {
        self.counters.lock().expect("counters lock").trainer_last_error = Some(error);
    }

    /// Sets what the watchdog found stuck at its last heartbeat.
    pub fn set_stalled(&self, stalled: Vec<crate::watchdog::Stall>) {
        self.counters.lock().expect("counters lock").stalled = stalled;
    }

    /// What the watchdog found stuck at its last sample.
    pub fn stalled(&self) -> Vec<crate::watchdog::Stall> {
        self.counters.lock().expect("counters lock").stalled.clone()
    }

    /// Whether the learner is live (`GET /healthz`): not when the trainer or the rate limiter,
    /// the parts only a restart can unstick, has been stalled for `learner.liveness_stall_s`.
    /// A stalled ingest or actor is the actors' side; restarting the learner would not help.
    pub fn liveness(&self) -> Result<(), String> {
        let limit = self.cfg.learner.liveness_stall_s;
        if limit <= 0.0 {
            return Ok(());
        }
        let c = self.counters.lock().expect("counters lock");
        let wedged = c.stalled.iter().find(|s| {
            matches!(s.component.as_str(), "trainer" | "rate_limiter") && s.for_s >= limit
        });
        match wedged {
            None => Ok(()),
            Some(s) => Err(format!(
                "{} stalled for {:.0} s (learner.liveness_stall_s = {limit}): {}; last error: {}",
                s.component,
                s.for_s,
                s.what,
                s.last_error.as_deref().unwrap_or("none")
            )),
        }
    }

    /// The config text sent to actors.
    pub fn config_toml(&self) -> &str {
        &self.config_toml
    }

    /// Marks a transition stream of an actor opened or closed; the actor counts as connected
    /// while any of its streams is open. Returns the actor's counters after the change.
    pub fn set_connected(&self, actor_id: u32, connected: bool) -> Option<ActorCounters> {
        let mut c = self.counters.lock().expect("counters lock");
        let a = c.actors.get_mut(&actor_id)?;
        a.open_streams =
            if connected { a.open_streams + 1 } else { a.open_streams.saturating_sub(1) };
        a.connected = a.open_streams > 0;
        Some(a.clone())
    }

    /// Records that a gRPC service serves this state (see [`LearnerState::readiness`]).
    pub fn set_serving(&self) {
        self.serving.store(true, Ordering::SeqCst);
    }

    /// Whether the learner takes actors now: ready from the moment its gRPC service exists
    /// until the step budget is reached or shutdown begins.
    pub fn readiness(&self) -> Readiness {
        if *self.shutdown_tx.borrow() || *self.done_tx.borrow() {
            Readiness::Finished
        } else if self.serving.load(Ordering::SeqCst) {
            Readiness::Ready
        } else {
            Readiness::Starting
        }
    }

    /// Validates a batch and inserts it into the replay buffer, waiting first while ingestion is
    /// ahead of training (backpressure). A batch whose sequence number was already inserted (a
    /// resend after a reconnect) is acknowledged as a duplicate and not inserted again.
    pub async fn ingest(&self, msg: pb::TransitionBatch) -> Result<Ack, LearnerError> {
        let actor_id = msg.actor_id;
        let claimed = msg.count as u64;
        let sequence = msg.sequence;
        {
            let mut c = self.counters.lock().expect("counters lock");
            let Some(a) = c.actors.get_mut(&actor_id) else {
                let e = LearnerError::UnknownActor(actor_id);
                *c.rejected_by_reason.entry(e.reason().to_string()).or_default() += 1;
                tracing::warn!(actor_id, error = %e, "refused a batch");
                return Err(e);
            };
            if sequence < a.next_sequence {
                a.duplicate_batches += 1;
                tracing::debug!(actor_id, sequence, "duplicate batch acknowledged, not inserted");
                return Ok(Ack { accepted: 0, duplicate: true });
            }
        }
        let batch = match wire::batch_from_proto(msg, self.cfg.obs_dim()) {
            Ok(b) => b,
            Err(e) => {
                let mut c = self.counters.lock().expect("counters lock");
                // A batch refused for its count claims an untrusted number of transitions:
                // count at most the largest batch there can be.
                let claimed = claimed.min(wire::MAX_BATCH_TRANSITIONS as u64);
                c.rejected += claimed;
                *c.rejected_by_reason.entry(e.field.to_string()).or_default() += 1;
                if let Some(a) = c.actors.get_mut(&actor_id) {
                    a.transitions_rejected += claimed;
                    a.last_error = Some(format!("malformed transition batch: {e}"));
                }
                tracing::warn!(actor_id, error = %e, "refused a malformed batch");
                return Err(e.into());
            }
        };
        // Cancelling this future here (the actor's stream broke while the batch waited) leaves
        // nothing behind: the batch is neither inserted nor counted, and the actor, which got
        // no acknowledgement, resends it if it is still alive.
        self.limiter.wait_to_insert().await;
        {
            // Claim the sequence number before inserting: a second stream of the same actor
            // id (a restarted process, or a reconnect before the old stream ended) may have
            // inserted this batch while it waited.
            let mut c = self.counters.lock().expect("counters lock");
            let a = c.actors.get_mut(&actor_id).ok_or(LearnerError::UnknownActor(actor_id))?;
            if sequence < a.next_sequence {
                a.duplicate_batches += 1;
                return Ok(Ack { accepted: 0, duplicate: true });
            }
            a.next_sequence = sequence + 1;
        }
        self.replay.lock().expect("replay lock").insert(&batch);
        let n = batch.len() as u64;
        self.limiter.inserted(n);
        self.live.record_batch(&batch, self.variables.current().version);

        let (_, updates) = self.limiter.counters();
        let mut c = self.counters.lock().expect("counters lock");
        c.received += n;
        let received = c.received;
        let a = c.actors.get_mut(&actor_id).expect("checked above");
        a.transitions_received += n;
        a.batches += 1;
        a.episodes += batch.episodes.len() as u64;
        for &v in &batch.policy_versions {
            a.min_policy_version = a.min_policy_version.min(v);
            a.max_policy_version = a.max_policy_version.max(v);
        }
        for e in &batch.episodes {
            match e.outcome {
                Outcome::Success => a.successes += 1,
                Outcome::Collision => a.collisions += 1,
                Outcome::Timeout => a.timeouts += 1,
            }
        }
        let was_skilled = c.curriculum.skilled().is_some();
        for e in &batch.episodes {
            c.episodes += 1;
            let success = e.outcome == Outcome::Success;
            if let Some(change) = c.curriculum.record(e.stage, success, e.warmup, received, updates)
            {
                tracing::info!(stage = change.stage, room = %change.room, env_steps = received, "curriculum: next stage");
            }
            if !was_skilled && let Some(s) = c.curriculum.skilled() {
                tracing::info!(room = %s.room, env_steps = s.env_steps, updates = s.updates, "curriculum: last room at the threshold (skilled)");
            }
        }
        let skilled_stop =
            self.cfg.curriculum.stop_when_skilled && c.curriculum.skilled().is_some();
        if (received >= self.cfg.run.steps || skilled_stop) && !c.done {
            c.done = true;
            if skilled_stop {
                tracing::info!(
                    received,
                    "skilled and curriculum.stop_when_skilled; stopping actors"
                );
            } else {
                tracing::info!(
                    received,
                    budget = self.cfg.run.steps,
                    "step budget reached; stopping actors"
                );
            }
            self.done_tx.send_replace(true);
            // Training ends with the budget; what actors still have in flight is accepted
            // without waiting, so they can flush and leave.
            self.limiter.close();
        }
        let warmup = c.episodes < self.cfg.warmup.pid_episodes;
        let (stage, room, done) = (c.curriculum.stage(), c.curriculum.room().to_string(), c.done);
        drop(c);
        self.variables.set_run_state(stage, &room, warmup, done);
        Ok(Ack { accepted: n as u32, duplicate: false })
    }

    /// Samples a training batch.
    pub fn sample(&self, size: usize, rng: &mut impl rand::Rng, out: &mut Batch) {
        self.replay.lock().expect("replay lock").sample_into(size, rng, out);
    }

    /// Runs `f` on the replay buffer (checkpoints write it); ingestion waits meanwhile.
    pub fn with_replay<R>(&self, f: impl FnOnce(&ReplayBuffer) -> R) -> R {
        f(&self.replay.lock().expect("replay lock"))
    }

    /// The curriculum's stage, window and history, for a checkpoint.
    pub fn curriculum_state(&self) -> crate::curriculum::CurriculumState {
        self.counters.lock().expect("counters lock").curriculum.snapshot()
    }

    /// Continues a run from a checkpoint (`--resume`), before any actor connects: counters,
    /// curriculum, weight version (`policy` is the restored policy) and, when the checkpoint
    /// holds one, the replay buffer. Without a saved buffer ingestion refills it, and the rate
    /// limiter holds training back until `sac.learning_starts` new transitions are in, then
    /// keeps the replay ratio from there.
    pub fn restore(
        &self,
        meta: &crate::checkpoint::CheckpointMeta,
        replay: Option<ReplayBuffer>,
        policy: Vec<u8>,
    ) {
        let mut c = self.counters.lock().expect("counters lock");
        c.received = meta.env_steps;
        c.episodes = meta.episodes;
        let curriculum = meta.curriculum.clone().unwrap_or(crate::curriculum::CurriculumState {
            stage: meta.stage,
            ..Default::default()
        });
        c.curriculum = Curriculum::restore(self.cfg.curriculum.clone(), curriculum);
        let inserted = match replay {
            Some(r) => {
                *self.replay.lock().expect("replay lock") = r;
                meta.env_steps
            }
            // The count at which the updates done so far are exactly what the ratio allows
            // once `learning_starts` more transitions arrive (see `RateLimiter::updates_allowed`).
            None => ((meta.updates as f64 / self.cfg.sac.updates_per_env_step).ceil() as u64)
                .saturating_sub(1),
        };
        self.limiter.restore(inserted, meta.updates);
        let warmup = c.episodes < self.cfg.warmup.pid_episodes;
        let (stage, room) = (c.curriculum.stage(), c.curriculum.room().to_string());
        drop(c);
        self.variables.restore(meta.weight_version, policy);
        self.variables.set_run_state(stage, &room, warmup, false);
    }

    /// Records the metrics of a finished update.
    pub fn record_update(&self, m: crate::sac::UpdateMetrics) {
        let mut c = self.counters.lock().expect("counters lock");
        if !(m.critic_loss.is_finite() && m.actor_loss.is_finite() && m.alpha.is_finite()) {
            c.losses_finite = false;
        }
        c.metrics = m;
    }

    /// Resolves when the step budget is reached.
    pub fn done_signal(&self) -> watch::Receiver<bool> {
        self.done_tx.subscribe()
    }

    /// Ends the run early (Ctrl-C): actors are told to stop.
    pub fn finish(&self) {
        self.limiter.close();
        let mut c = self.counters.lock().expect("counters lock");
        c.done = true;
        let (stage, room) = (c.curriculum.stage(), c.curriculum.room().to_string());
        drop(c);
        self.done_tx.send_replace(true);
        let warmup = self.variables.current().warmup;
        self.variables.set_run_state(stage, &room, warmup, true);
    }

    /// Starts shutdown: streams end, registration is refused, waiters are released.
    pub fn begin_shutdown(&self) {
        self.finish();
        self.limiter.close();
        self.shutdown_tx.send_replace(true);
    }

    /// Resolves when shutdown begins (for stream handlers).
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown_tx.subscribe()
    }

    /// A consistent snapshot of every counter.
    pub fn status(&self) -> StatusSnapshot {
        let replay_size = self.replay.lock().expect("replay lock").len() as u64;
        let (_, updates) = self.limiter.counters();
        let c = self.counters.lock().expect("counters lock");
        StatusSnapshot {
            run_id: self.run_id.clone(),
            transitions_received: c.received,
            transitions_rejected: c.rejected,
            episodes: c.episodes,
            updates,
            weight_version: self.variables.current().version,
            replay_size,
            stage: c.curriculum.stage(),
            success_rate: c.curriculum.success_rate(),
            critic_loss: c.metrics.critic_loss,
            actor_loss: c.metrics.actor_loss,
            alpha: c.metrics.alpha,
            done: c.done,
            step_budget: self.cfg.run.steps,
            actors: c
                .actors
                .values()
                .cloned()
                .map(|mut a| {
                    if a.min_policy_version == u64::MAX {
                        a.min_policy_version = 0;
                    }
                    a
                })
                .collect(),
            stage_changes: c.curriculum.changes().to_vec(),
            skilled: c.curriculum.skilled().cloned(),
            losses_finite: c.losses_finite,
            live: self.live.snapshot(),
            rejected_by_reason: c.rejected_by_reason.clone(),
            write_failures: c.write_failures.clone(),
            last_write_error: c.last_write_error.clone(),
            trainer_last_error: c.trainer_last_error.clone(),
            stalled: c.stalled.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_link::core::TransitionBatch;

    fn small_config() -> Config {
        let mut cfg = Config::default();
        cfg.run.steps = 6;
        cfg.sac.batch_size = 2;
        cfg.sac.learning_starts = 2;
        cfg.replay.capacity = 16;
        cfg.actor.batch_transitions = 2;
        cfg.learner.max_steps_ahead = 1_000;
        cfg.warmup.pid_episodes = 1;
        cfg
    }

    fn batch(cfg: &Config, n: usize, actor_id: u32, seq: u64) -> pb::TransitionBatch {
        let d = cfg.obs_dim();
        let mut b = TransitionBatch::with_capacity(d, n);
        for _ in 0..n {
            b.push(&vec![1.0; d], [0.0, 0.0], 0.5, &vec![1.0; d], false, false, 1);
        }
        b.episodes.push(dvnav_link::core::EpisodeStats {
            env_index: 0,
            stage: 0,
            room: "env0".into(),
            outcome: Outcome::Timeout,
            steps: 3,
            episode_return: 1.0,
            policy_version: 1,
            warmup: true,
        });
        wire::batch_to_proto(&b, actor_id, seq)
    }

    #[tokio::test]
    async fn counts_accepted_and_rejected_and_stops_at_the_budget() {
        let cfg = small_config();
        let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
        let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        assert!(matches!(s.ingest(batch(&cfg, 2, 9, 0)).await, Err(LearnerError::UnknownActor(9))));
        assert_eq!(s.ingest(batch(&cfg, 3, id, 0)).await.unwrap().accepted, 3);
        assert!(!s.variables().current().warmup, "one warm-up episode was configured");
        let mut bad = batch(&cfg, 2, id, 1);
        bad.rewards[0] = f32::INFINITY;
        assert!(matches!(s.ingest(bad).await, Err(LearnerError::Malformed(_))));
        assert!(!*s.done_signal().borrow());
        // A resend of batch 0 (after a reconnect) is acknowledged but not inserted again.
        let dup = s.ingest(batch(&cfg, 3, id, 0)).await.unwrap();
        assert_eq!(dup, Ack { accepted: 0, duplicate: true });
        s.ingest(batch(&cfg, 3, id, 2)).await.unwrap();
        // A restarted actor process is told where to continue its numbering.
        assert_eq!(s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().next_sequence, 3);
        let st = s.status();
        assert_eq!((st.transitions_received, st.transitions_rejected, st.episodes), (6, 2, 2));
        assert_eq!(st.actors[0].transitions_received, 6);
        assert_eq!(st.actors[0].transitions_rejected, 2);
        assert_eq!(st.actors[0].duplicate_batches, 1);
        assert!(st.done && *s.done_signal().borrow());
        assert!(s.variables().current().stop);
    }

    /// Two streams of one actor id (a restarted process under the same name while the learner
    /// has not yet seen the old stream end) both wait under backpressure with batch 1: it is
    /// inserted once, the other copy is acknowledged as a duplicate.
    #[tokio::test]
    async fn a_sequence_number_is_inserted_once_across_streams_of_one_actor() {
        let mut cfg = small_config();
        cfg.run.steps = 1_000;
        cfg.sac.learning_starts = 0;
        cfg.learner.max_steps_ahead = 3;
        let s = Arc::new(LearnerState::new(cfg.clone(), "r".into(), None, vec![]));
        let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        assert_eq!(s.ingest(batch(&cfg, 3, id, 0)).await.unwrap().accepted, 3);
        // No updates: the next batches wait for room.
        let send = |seq| {
            let (s, b) = (s.clone(), batch(&cfg, 3, id, seq));
            tokio::spawn(async move { s.ingest(b).await.unwrap() })
        };
        let (first, second) = (send(1), send(1));
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
        assert!(!first.is_finished() && !second.is_finished(), "both wait under backpressure");
        assert_eq!(s.status().transitions_received, 3);
        s.limiter().close();
        let mut acks = [first.await.unwrap(), second.await.unwrap()];
        acks.sort_by_key(|a| a.duplicate);
        assert_eq!(
            acks,
            [Ack { accepted: 3, duplicate: false }, Ack { accepted: 0, duplicate: true }]
        );
        let st = s.status();
        assert_eq!((st.transitions_received, st.replay_size), (6, 6));
        assert_eq!(st.actors[0].duplicate_batches, 1);
    }

    /// Bad input, fuzzed: thousands of well-formed but invalid batches (unknown actor, wrong
    /// sizes, NaN/Inf, rewards and actions out of bounds, huge declared counts, contradictory
    /// flags, unknown outcomes) and registrations with wrong protocol versions, mixed with valid
    /// batches. Each invalid one is refused with the status code the service returns and
    /// counted under its reason; the replay buffer grows by exactly the valid ones.
    #[tokio::test]
    async fn random_invalid_batches_are_refused_by_reason_and_never_reach_the_replay_buffer() {
        use rand::{Rng, SeedableRng};
        use tonic::Code;
        let mut cfg = small_config();
        cfg.run.steps = 1 << 40;
        cfg.replay.capacity = 1 << 14;
        cfg.sac.learning_starts = 1 << 40;
        let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
        let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
        let (mut seq, mut replay, mut rejected) = (0u64, 0u64, 0u64);
        let mut by_reason: BTreeMap<String, u64> = BTreeMap::new();
        let d = cfg.obs_dim();
        let bad = |rng: &mut rand_pcg::Pcg64| match rng.random_range(0..3) {
            0 => f32::NAN,
            1 => f32::INFINITY,
            _ => f32::NEG_INFINITY,
        };
        for i in 0..6_000 {
            let n = rng.random_range(1..5usize);
            let mut m = batch(&cfg, n, id, seq);
            let sign = if rng.random() { 1.0 } else { -1.0 };
            let expect: Option<(&str, Code)> = match i % 13 {
                0 => {
                    m.actor_id = rng.random_range(id + 1..=u32::MAX);
                    Some(("unknown_actor", Code::InvalidArgument))
                }
                1 => {
                    let k = rng.random_range(1..=d);
                    if rng.random() {
                        m.observations.truncate(n * d - k)
                    } else {
                        m.observations.extend(std::iter::repeat_n(0.0, k))
                    }
                    Some(("observations", Code::InvalidArgument))
                }
                2 => {
                    m.next_observations.pop();
                    Some(("next_observations", Code::InvalidArgument))
                }
                3 => {
                    let j = rng.random_range(0..n * d);
                    m.observations[j] = bad(&mut rng);
                    Some(("observations", Code::InvalidArgument))
                }
                4 => {
                    m.rewards[rng.random_range(0..n)] = bad(&mut rng);
                    Some(("rewards", Code::InvalidArgument))
                }
                5 => {
                    m.rewards[rng.random_range(0..n)] =
                        sign * wire::MAX_ABS_REWARD * rng.random_range(1.001..1e6f32);
                    Some(("rewards", Code::InvalidArgument))
                }
                6 => {
                    m.actions[rng.random_range(0..2 * n)] = sign * rng.random_range(1.0001..1e6f32);
                    Some(("actions", Code::InvalidArgument))
                }
                7 => {
                    m.count = rng.random_range(wire::MAX_BATCH_TRANSITIONS as u32 + 1..=u32::MAX);
                    Some(("count", Code::InvalidArgument))
                }
                8 => {
                    m.count += rng.random_range(1..1000);
                    Some(("observations", Code::InvalidArgument))
                }
                9 => {
                    let j = rng.random_range(0..n);
                    (m.terminated[j], m.truncated[j]) = (true, true);
                    Some(("truncated", Code::InvalidArgument))
                }
                10 => {
                    m.episodes[0].outcome = rng.random_range(3..i32::MAX);
                    Some(("episodes", Code::InvalidArgument))
                }
                11 => {
                    let v = rng.random_range(0..u32::MAX);
                    let v = if v == dvnav_proto::PROTOCOL_VERSION { v + 1 } else { v };
                    let e = s.register("b", v).unwrap_err();
                    assert_eq!(tonic::Status::from(e).code(), Code::FailedPrecondition);
                    *by_reason.entry("protocol_version".into()).or_default() += 1;
                    None
                }
                _ => None,
            };
            if i % 13 == 11 {
                continue;
            }
            let claimed = (m.count as u64).min(wire::MAX_BATCH_TRANSITIONS as u64);
            match (s.ingest(m).await, expect) {
                (Ok(ack), None) => {
                    assert_eq!(ack, Ack { accepted: n as u32, duplicate: false });
                    seq += 1;
                    replay += n as u64;
                }
                (Err(e), Some((reason, code))) => {
                    assert_eq!(e.reason(), reason, "case {i}: {e}");
                    assert_eq!(tonic::Status::from(e).code(), code, "case {i}");
                    *by_reason.entry(reason.into()).or_default() += 1;
                    if reason != "unknown_actor" {
                        rejected += claimed;
                    }
                }
                (r, expect) => panic!("case {i}: got {r:?}, expected {expect:?}"),
            }
            let st = s.status();
            assert_eq!(st.replay_size, replay, "case {i}");
            assert_eq!(st.transitions_received, replay, "case {i}");
        }
        let st = s.status();
        assert_eq!(st.rejected_by_reason, by_reason);
        assert_eq!(st.transitions_rejected, rejected);
        assert_eq!(st.actors[0].transitions_rejected, rejected);
        assert!(st.actors[0].last_error.as_deref().unwrap().contains("malformed"));
        assert_eq!(by_reason.len(), 9, "every reason was exercised: {by_reason:?}");
        let text = crate::metrics::render_prometheus(&crate::metrics::Sample {
            elapsed_s: 0.0,
            status: st,
            rooms: vec![],
            memory: Default::default(),
        });
        assert!(text.contains("dvnav_requests_rejected_total{reason=\"rewards\"} "), "{text}");
    }

    /// Random and truncated bytes through the prost decoder and into ingestion: nothing
    /// panics, and the replay buffer grows by exactly what was acknowledged as accepted.
    #[tokio::test]
    async fn random_bytes_through_the_decoder_and_ingestion_never_panic() {
        use prost::Message;
        use rand::{Rng, SeedableRng};
        let mut cfg = small_config();
        cfg.run.steps = 1 << 40;
        cfg.replay.capacity = 1 << 14;
        cfg.sac.learning_starts = 1 << 40;
        let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
        let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        let valid = batch(&cfg, 2, id, 0).encode_to_vec();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        let (mut decoded, mut accepted_total) = (0, 0u64);
        for i in 0..6_000 {
            let bytes: Vec<u8> = match i % 3 {
                0 => (0..rng.random_range(0..300)).map(|_| rng.random()).collect(),
                1 => valid[..rng.random_range(0..valid.len())].to_vec(),
                _ => {
                    let mut v = valid.clone();
                    for _ in 0..rng.random_range(1..4) {
                        let j = rng.random_range(0..v.len());
                        v[j] = rng.random();
                    }
                    v
                }
            };
            let Ok(mut msg) = pb::TransitionBatch::decode(bytes.as_slice()) else { continue };
            decoded += 1;
            // Mostly the registered actor at its next sequence number, so that validation (not
            // the unknown-actor or duplicate check) sees the damage.
            if rng.random_range(0..4) > 0 {
                msg.actor_id = id;
                msg.sequence = s.status().actors[0].next_sequence;
            }
            let before = s.status().replay_size;
            let accepted = match s.ingest(msg).await {
                Ok(ack) => ack.accepted as u64,
                Err(e) => {
                    let _ = tonic::Status::from(e);
                    0
                }
            };
            accepted_total += accepted;
            assert_eq!(s.status().replay_size, before + accepted, "case {i}");
        }
        assert!(decoded > 1_000, "{decoded} decoded");
        let st = s.status();
        assert_eq!(st.transitions_received, accepted_total);
        assert!(st.rejected_by_reason.values().sum::<u64>() > 10, "{:?}", st.rejected_by_reason);
    }

    #[test]
    fn refuses_other_protocol_versions_and_wrong_tokens() {
        let s = LearnerState::new(small_config(), "r".into(), Some("t0k".into()), vec![]);
        assert!(matches!(s.register("a", 999), Err(LearnerError::ProtocolMismatch { .. })));
        assert!(matches!(s.authorize(None), Err(LearnerError::Unauthenticated)));
        assert!(matches!(s.authorize(Some("x")), Err(LearnerError::Unauthenticated)));
        assert!(s.authorize(Some("t0k")).is_ok());
        // Same name, same id.
        let a = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        let b = s.register("b", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        assert_ne!(a, b);
        assert_eq!(s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id, a);
    }
}
