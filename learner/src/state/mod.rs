//! The learner's domain state, independent of gRPC: registration, ingestion into the replay
//! buffer, counters per actor, the curriculum, the warm-up phase, the step budget and the end
//! of the run. The gRPC service only translates to and from these calls.
//!
//! # Layout
//! - this module: [`LearnerState`], with its own [`save`](LearnerState::save) and
//!   [`restore`](LearnerState::restore) (the checkpoint module assembles a checkpoint from
//!   this part, the SAC learner's and the trainer's generator).
//! - [`status`]: what it reports: [`StatusSnapshot`], [`ActorCounters`], [`Readiness`],
//!   [`Stall`], and [`Progress`], the counters the watchdog reads.
//! - [`live`]: [`LiveMetrics`], the live recorder (policy lag, per-stage outcomes, the
//!   sampler's rates and text).
//! - [`error`]: [`LearnerError`], why a request is refused.
//! - [`saved`]: [`SavedState`], the state's part of a checkpoint.
//! - [`sessions`]: [`Sessions`], the credential that binds a transition stream to its actor.
//!
//! The submodules are plain data and import nothing from this one; this one imports them.
//!
//! The end of the run is two [`CancellationToken`]s: `done` (the step budget is reached, or
//! Ctrl-C: actors are told to stop) and `shutdown` (streams end, registration is refused,
//! waiters are released). Holders get child tokens, so only the state cancels them.

pub mod error;
pub mod live;
pub mod saved;
pub mod sessions;
pub mod status;

pub use error::LearnerError;
pub use live::{LagHistogram, LagPercentiles, LagStats, LiveMetrics, LiveSnapshot, StageStats};
pub use saved::SavedState;
pub use sessions::Sessions;
pub use status::{Ack, ActorCounters, Progress, Readiness, Registration, Stall, StatusSnapshot};

use crate::actor_tokens::ActorTokens;
use crate::curriculum::{Curriculum, CurriculumState};
use crate::rate_limiter::RateLimiter;
use crate::replay::{Batch, ObsCodec, ReplayBuffer, Returns};
use crate::sac::UpdateMetrics;
use crate::variable_source::VariableSource;
use dvnav_config::Config;
use dvnav_link::consistency::{self, EpisodeBounds};
use dvnav_link::core::Variables;
use dvnav_link::wire;
use dvnav_proto as pb;
use dvnav_sim::Outcome;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use tokio_util::sync::CancellationToken;

#[derive(Debug)]
struct Counters {
    next_actor_id: u32,
    actors: BTreeMap<u32, ActorCounters>,
    received: u64,
    rejected: u64,
    episodes: u64,
    curriculum: Curriculum,
    metrics: UpdateMetrics,
    losses_finite: bool,
    done: bool,
    rejected_by_reason: BTreeMap<String, u64>,
    sessions: Sessions,
    write_failures: BTreeMap<String, u64>,
    last_write_error: Option<String>,
    trainer_last_error: Option<String>,
    /// Actors with a `Variables` stream open (at most one each).
    variables_streams: std::collections::BTreeSet<u32>,
}

/// The learner's shared state (see the module docs).
pub struct LearnerState {
    cfg: Config,
    config_toml: String,
    run_id: String,
    token: Option<String>,
    actor_tokens: Option<ActorTokens>,
    episode_bounds: EpisodeBounds,
    replay: Mutex<ReplayBuffer>,
    limiter: RateLimiter,
    counters: Mutex<Counters>,
    variables: VariableSource,
    done: CancellationToken,
    shutdown: CancellationToken,
    live: LiveMetrics,
    /// What the watchdog found stuck at its last sample; apart from the counters it reads.
    stalled: Mutex<Vec<Stall>>,
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
                cfg.curriculum.replay_ratio(0, cfg.sac.updates_per_env_step),
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
                sessions: Sessions::default(),
                write_failures: BTreeMap::new(),
                last_write_error: None,
                trainer_last_error: None,
                variables_streams: Default::default(),
            }),
            config_toml: cfg.to_toml_string(),
            episode_bounds: EpisodeBounds::new(&cfg.env, cfg.curriculum.rooms.len()),
            cfg,
            run_id,
            token,
            actor_tokens: None,
            variables,
            done: CancellationToken::new(),
            shutdown: CancellationToken::new(),
            live: Default::default(),
            stalled: Mutex::new(Vec::new()),
            serving: AtomicBool::new(false),
        }
    }

    /// Per-actor tokens (`--actor-tokens`): a listed name registers only with its own token
    /// (see [`ActorTokens`]).
    pub fn with_actor_tokens(mut self, tokens: Option<ActorTokens>) -> Self {
        self.actor_tokens = tokens;
        self
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
    pub fn live(&self) -> &LiveMetrics {
        &self.live
    }

    /// Checks the shared token, when one is configured; a refusal is counted under
    /// `unauthenticated`.
    pub fn authorize(&self, presented: Option<&str>) -> Result<(), LearnerError> {
        let accepted = match &self.actor_tokens {
            None => dvnav_tls::auth::token_accepted(self.token.as_deref(), presented),
            // With per-actor tokens nothing is open: the shared token or a listed one.
            Some(t) => {
                let shared = self.token.is_some()
                    && dvnav_tls::auth::token_accepted(self.token.as_deref(), presented);
                shared | t.accepts_any(presented)
            }
        };
        if accepted {
            Ok(())
        } else {
            let e = LearnerError::Unauthenticated;
            self.count_rejection(None, e.reason(), &e.to_string());
            Err(e)
        }
    }

    /// Binds a transition stream to the actor whose session `credential` it presents, and
    /// marks that actor connected (undo with [`Self::set_connected`]). A missing or unknown
    /// credential is refused and counted.
    pub fn open_stream(&self, credential: Option<&str>) -> Result<u32, LearnerError> {
        let found = {
            let c = self.counters.lock().expect("counters lock");
            match credential {
                None => Err(LearnerError::NoSession),
                Some(k) => c.sessions.actor(k).ok_or(LearnerError::UnknownSession),
            }
        };
        match found {
            Ok(id) => {
                self.set_connected(id, true);
                Ok(id)
            }
            Err(e) => {
                self.count_rejection(None, e.reason(), &e.to_string());
                tracing::warn!(error = %e, "refused a transition stream");
                Err(e)
            }
        }
    }

    /// Registers an actor that presented no token of its own (in process; see
    /// [`Self::register_presenting`]).
    pub fn register(
        &self,
        name: &str,
        protocol_version: u32,
    ) -> Result<Registration, LearnerError> {
        self.register_presenting(name, protocol_version, None)
    }

    /// Registers an actor that presented the bearer token `presented`: with per-actor tokens a
    /// listed name must have presented its own, a name not listed the shared one.
    pub fn register_presenting(
        &self,
        name: &str,
        protocol_version: u32,
        presented: Option<&str>,
    ) -> Result<Registration, LearnerError> {
        self.register_checked(name, protocol_version, presented).inspect_err(|e| {
            self.count_rejection(None, e.reason(), &e.to_string());
            tracing::warn!(name, error = %e, "refused a registration");
        })
    }

    fn register_checked(
        &self,
        name: &str,
        protocol_version: u32,
        presented: Option<&str>,
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
        if let Some(t) = &self.actor_tokens {
            let own = match t.token_of(name) {
                Some(expected) => dvnav_tls::auth::token_accepted(Some(expected), presented),
                None => {
                    self.token.is_some()
                        && dvnav_tls::auth::token_accepted(self.token.as_deref(), presented)
                }
            };
            if !own {
                return Err(LearnerError::ActorToken(name.to_string()));
            }
        }
        if self.shutdown.is_cancelled() {
            return Err(LearnerError::ShuttingDown);
        }
        let mut c = self.counters.lock().expect("counters lock");
        // An actor that comes back under the same name keeps its id and counters.
        let existing = c.actors.values().find(|a| a.name == name).map(|a| a.actor_id);
        let limit = self.cfg.learner.max_actor_names;
        if existing.is_none() && c.actors.len() >= limit {
            return Err(LearnerError::TooManyActors(limit));
        }
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
        let session = c.sessions.issue(actor_id);
        let actor_seed =
            self.cfg.run.seed.wrapping_mul(1_000_003).wrapping_add(actor_id as u64 + 1);
        Ok(Registration { actor_id, actor_seed, next_sequence, session })
    }

    /// Opens registered actor `actor_id`'s `Variables` stream. An actor has at most one open:
    /// a weight message a reader has not taken stays buffered in its HTTP/2 stream (about
    /// twice the policy's size) until the reader reads or goes away, so one stream per
    /// registered name (`learner.max_actor_names` of them) bounds what idle readers can pin,
    /// however many streams a client opens. An unknown id, and a second stream while the
    /// first is open, are refused and counted; an actor that reconnects gets its stream once
    /// the server has seen the old one go (at once for a closed connection, within the
    /// keepalive timeout for a vanished one). Call [`Self::close_variables_stream`] when it ends.
    pub fn open_variables_stream(&self, actor_id: u32) -> Result<(), LearnerError> {
        let refused = {
            let mut c = self.counters.lock().expect("counters lock");
            if !c.actors.contains_key(&actor_id) {
                LearnerError::UnknownActor(actor_id)
            } else if !c.variables_streams.insert(actor_id) {
                LearnerError::VariablesStreamOpen(actor_id)
            } else {
                return Ok(());
            }
        };
        self.count_rejection(Some(actor_id), refused.reason(), &refused.to_string());
        tracing::warn!(actor_id, error = %refused, "refused a variables stream");
        Err(refused)
    }

    /// Actor `actor_id`'s `Variables` stream ended: it may open another.
    pub fn close_variables_stream(&self, actor_id: u32) {
        self.counters.lock().expect("counters lock").variables_streams.remove(&actor_id);
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

    /// Sets what the watchdog found stuck at its last heartbeat (kept apart from the counters
    /// it reads through [`LearnerState::progress`]).
    pub fn set_stalled(&self, stalled: Vec<Stall>) {
        *self.stalled.lock().expect("stalls lock") = stalled;
    }

    /// What the watchdog found stuck at its last sample.
    pub fn stalled(&self) -> Vec<Stall> {
        self.stalled.lock().expect("stalls lock").clone()
    }

    /// Whether the learner is live (`GET /healthz`): not when the trainer or the rate limiter,
    /// the parts only a restart can unstick, has been stalled for `learner.liveness_stall_s`.
    /// A stalled ingest or actor is the actors' side; restarting the learner would not help.
    pub fn liveness(&self) -> Result<(), String> {
        let limit = self.cfg.learner.liveness_stall_s;
        if limit <= 0.0 {
            return Ok(());
        }
        let stalled = self.stalled();
        let wedged = stalled.iter().find(|s| {
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

    /// The most transitions an actor's next batches should hold: its share of
    /// `learner.transitions_in_flight` among the connected actors (`joining`: counting one more,
    /// an actor registering before its stream opens). See [`share_of_in_flight`].
    pub fn batch_transitions_advice(&self, joining: bool) -> u32 {
        let connected = {
            let c = self.counters.lock().expect("counters lock");
            c.actors.values().filter(|a| a.connected).count()
        };
        let budget = self.config().learner.transitions_in_flight;
        share_of_in_flight(budget, connected + usize::from(joining)) as u32
    }

    /// Records that a gRPC service serves this state (see [`LearnerState::readiness`]).
    pub fn set_serving(&self) {
        self.serving.store(true, Ordering::SeqCst);
    }

    /// Whether the learner takes actors now: ready from the moment its gRPC service exists
    /// until the step budget is reached or shutdown begins.
    pub fn readiness(&self) -> Readiness {
        if self.shutdown.is_cancelled() || self.done.is_cancelled() {
            Readiness::Finished
        } else if self.serving.load(Ordering::SeqCst) {
            Readiness::Ready
        } else {
            Readiness::Starting
        }
    }

    /// Validates a batch that arrived on a stream bound to `stream_actor`
    /// ([`Self::open_stream`]) and inserts it into the replay buffer, waiting first while
    /// ingestion is ahead of training (backpressure). Refused, and counted by reason: a batch
    /// that claims another actor, one whose sequence number skips ahead of the next expected,
    /// a malformed one, and one whose episode reports its transitions do not back
    /// ([`consistency`]). A batch whose sequence number was already inserted (a resend after a
    /// reconnect) is acknowledged as a duplicate and not inserted again.
    pub async fn ingest(
        &self,
        stream_actor: u32,
        msg: pb::TransitionBatch,
    ) -> Result<Ack, LearnerError> {
        let actor_id = stream_actor;
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
            let refusal = if msg.actor_id != actor_id {
                Some(LearnerError::WrongActor { stream: actor_id, claimed: msg.actor_id })
            } else if sequence > a.next_sequence {
                Some(LearnerError::SequenceGap { got: sequence, expected: a.next_sequence })
            } else {
                None
            };
            if let Some(e) = refusal {
                refuse_batch(&mut c, actor_id, claimed, &e);
                return Err(e);
            }
            if sequence < a.next_sequence {
                a.duplicate_batches += 1;
                tracing::debug!(actor_id, sequence, "duplicate batch acknowledged, not inserted");
                return Ok(Ack { accepted: 0, duplicate: true });
            }
        }
        let checked = wire::batch_from_proto(msg, self.cfg.obs_dim()).and_then(|b| {
            consistency::check_episodes(&b, &self.episode_bounds)?;
            Ok(b)
        });
        let batch = match checked {
            Ok(b) => b,
            Err(e) => {
                let e = LearnerError::from(e);
                refuse_batch(
                    &mut self.counters.lock().expect("counters lock"),
                    actor_id,
                    claimed,
                    &e,
                );
                return Err(e);
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
            // A varied robot's episode (env.dvst) says nothing of the meta robot's stage bar.
            let uncounted = e.warmup || e.varied;
            if let Some(change) =
                c.curriculum.record(e.stage, success, uncounted, received, updates)
            {
                let ratio = self.replay_ratio(change.stage as usize);
                tracing::info!(stage = change.stage, room = %change.room, env_steps = received, replay_ratio = ratio, "curriculum: next stage");
                self.limiter.set_ratio(ratio);
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
            self.done.cancel();
            // Ingestion ends with the budget: what actors still have in flight is accepted
            // without waiting, so they can flush and leave. Training goes on until it has
            // done the updates the ratio owes for what came in (see `run`).
            self.limiter.stop_ingest();
        }
        let warmup = c.episodes < self.cfg.warmup.pid_episodes;
        let (stage, room, done) = (c.curriculum.stage(), c.curriculum.room().to_string(), c.done);
        drop(c);
        self.variables.set_run_state(stage, &room, warmup, done);
        Ok(Ack { accepted: n as u32, duplicate: false })
    }

    /// The replay ratio of curriculum stage `stage`.
    fn replay_ratio(&self, stage: usize) -> f64 {
        self.cfg.curriculum.replay_ratio(stage, self.cfg.sac.updates_per_env_step)
    }

    /// Samples a training batch.
    pub fn sample(&self, size: usize, rng: &mut impl rand::Rng, out: &mut Batch) {
        let returns = Returns::for_config(&self.cfg.sac);
        self.replay.lock().expect("replay lock").sample_into(size, returns, rng, out);
    }

    /// The curriculum's stage, window and history.
    pub fn curriculum_state(&self) -> CurriculumState {
        self.counters.lock().expect("counters lock").curriculum.snapshot()
    }

    /// Saves the state's own part of a checkpoint: `write` gets it and, when
    /// `replay.save_in_checkpoint` is on, the replay buffer, under its lock (ingestion waits
    /// meanwhile; the buffer is not copied).
    pub fn save<R>(&self, write: impl FnOnce(&SavedState, Option<&ReplayBuffer>) -> R) -> R {
        let saved = {
            let c = self.counters.lock().expect("counters lock");
            SavedState {
                run_id: self.run_id.clone(),
                env_steps: c.received,
                episodes: c.episodes,
                weight_version: self.variables.current().version,
                stage: c.curriculum.stage(),
                curriculum: Some(c.curriculum.snapshot()),
            }
        };
        if self.cfg.replay.save_in_checkpoint {
            write(&saved, Some(&self.replay.lock().expect("replay lock")))
        } else {
            write(&saved, None)
        }
    }

    /// Continues a run from a checkpoint (`--resume`), before any actor connects: counters,
    /// curriculum, weight version (`policy` is the restored policy), the rate limiter from the
    /// SAC learner's `updates` and, when the checkpoint holds one, the replay buffer. Without a
    /// saved buffer ingestion refills it, and the rate limiter holds training back until
    /// `sac.learning_starts` new transitions are in, then keeps the replay ratio from there.
    pub fn restore(
        &self,
        saved: &SavedState,
        updates: u64,
        replay: Option<ReplayBuffer>,
        policy: Vec<u8>,
    ) {
        let mut c = self.counters.lock().expect("counters lock");
        c.received = saved.env_steps;
        c.episodes = saved.episodes;
        let curriculum = saved
            .curriculum
            .clone()
            .unwrap_or(CurriculumState { stage: saved.stage, ..Default::default() });
        c.curriculum = Curriculum::restore(self.cfg.curriculum.clone(), curriculum);
        let replay_restored = replay.is_some();
        let inserted = match replay {
            Some(r) => {
                *self.replay.lock().expect("replay lock") = r;
                saved.env_steps
            }
            // The count at which the updates done so far are exactly what the ratio allows
            // once `learning_starts` more transitions arrive (see `RateLimiter::updates_allowed`).
            None => ((updates as f64 / self.cfg.sac.updates_per_env_step).ceil() as u64)
                .saturating_sub(1),
        };
        self.limiter.restore(inserted, updates);
        if !self.cfg.curriculum.replay_ratios.is_empty() {
            // The ratio changed with the stages, so the count above (one ratio all along) is
            // not what was allowed: go on from the updates done, at this stage's ratio, once
            // `learning_starts` transitions refill an emptied buffer.
            let refill = if replay_restored { 1 } else { self.cfg.sac.learning_starts };
            self.limiter
                .continue_at(self.replay_ratio(c.curriculum.stage() as usize), inserted + refill);
        }
        let warmup = c.episodes < self.cfg.warmup.pid_episodes;
        let (stage, room) = (c.curriculum.stage(), c.curriculum.room().to_string());
        drop(c);
        self.variables.restore(saved.weight_version, policy);
        self.variables.set_run_state(stage, &room, warmup, false);
    }

    /// Records the metrics of a finished update.
    pub fn record_update(&self, m: UpdateMetrics) {
        let mut c = self.counters.lock().expect("counters lock");
        if !(m.critic_loss.is_finite() && m.actor_loss.is_finite() && m.alpha.is_finite()) {
            c.losses_finite = false;
        }
        c.metrics = m;
    }

    /// Cancelled when the step budget is reached or the run is ended early ([`Self::finish`]).
    pub fn done_signal(&self) -> CancellationToken {
        self.done.child_token()
    }

    /// Ends the run early (Ctrl-C): actors are told to stop.
    pub fn finish(&self) {
        self.limiter.close();
        let mut c = self.counters.lock().expect("counters lock");
        c.done = true;
        let (stage, room) = (c.curriculum.stage(), c.curriculum.room().to_string());
        drop(c);
        self.done.cancel();
        let warmup = self.variables.current().warmup;
        self.variables.set_run_state(stage, &room, warmup, true);
    }

    /// Starts shutdown: streams end, registration is refused, waiters are released.
    pub fn begin_shutdown(&self) {
        self.finish();
        self.limiter.close();
        self.shutdown.cancel();
    }

    /// Cancelled when shutdown begins (stream handlers, the metrics, the watchdog and the
    /// servers stop on it).
    pub fn shutdown_signal(&self) -> CancellationToken {
        self.shutdown.child_token()
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
            policy_entropy: c.metrics.entropy,
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
            stalled: self.stalled(),
        }
    }

    /// The progress counters alone, for the watchdog: what moves when the learner works.
    pub fn progress(&self) -> Progress {
        let (_, updates) = self.limiter.counters();
        let c = self.counters.lock().expect("counters lock");
        Progress {
            transitions_received: c.received,
            updates,
            done: c.done,
            trainer_last_error: c.trainer_last_error.clone(),
            actors: c.actors.values().cloned().collect(),
        }
    }
}

/// The fewest transitions the learner asks an actor to batch: below this, per-batch costs
/// (a message, an acknowledgement, each environment's first observation) outweigh freshness.
pub const MIN_ADVISED_BATCH: usize = 8;

/// Each of `actors` actors' share of `budget` transitions in flight, at least
/// [`MIN_ADVISED_BATCH`]: with one batch in flight per actor, all of them together hold about
/// `budget`, so what the learner inserts was acted at most about `budget` steps of training
/// ago, whether two actors run or twenty.
pub fn share_of_in_flight(budget: usize, actors: usize) -> usize {
    budget.div_ceil(actors.max(1)).max(MIN_ADVISED_BATCH)
}

/// Counts a refused batch of `actor_id` that claimed `claimed` transitions under its reason,
/// and logs it.
fn refuse_batch(c: &mut Counters, actor_id: u32, claimed: u64, e: &LearnerError) {
    // The claimed count is untrusted: count at most the largest batch there can be.
    let claimed = claimed.min(wire::MAX_BATCH_TRANSITIONS as u64);
    c.rejected += claimed;
    *c.rejected_by_reason.entry(e.reason().to_string()).or_default() += 1;
    if let Some(a) = c.actors.get_mut(&actor_id) {
        a.transitions_rejected += claimed;
        a.last_error = Some(e.to_string());
    }
    tracing::warn!(actor_id, error = %e, "refused a batch");
}

#[cfg(test)]
mod tests;
