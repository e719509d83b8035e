//! What the learner reports about itself: the [`StatusSnapshot`] that `Status`, `/metrics`,
//! `metrics.csv` and the run summary are built from, the counters of each actor, readiness,
//! the stalls the watchdog names, and [`Progress`], the few counters the watchdog reads.
//! Plain data: nothing here reads or writes the state.

use super::live::LiveSnapshot;
use crate::curriculum::StageChange;
use crate::json_f64::f64_or_nan;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Counters of one actor.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
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
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
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
    #[serde(deserialize_with = "f64_or_nan")]
    pub success_rate: f64,
    /// Last critic loss.
    #[serde(deserialize_with = "f64_or_nan")]
    pub critic_loss: f64,
    /// Last actor loss.
    #[serde(deserialize_with = "f64_or_nan")]
    pub actor_loss: f64,
    /// Temperature α.
    #[serde(deserialize_with = "f64_or_nan")]
    pub alpha: f64,
    /// −mean log π(ã|s) of the last policy update: the policy's entropy, to read α against
    /// (α → 0 with the entropy at its target is the constraint no longer binding, not a bug).
    #[serde(default = "crate::json_f64::nan", deserialize_with = "f64_or_nan")]
    pub policy_entropy: f64,
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
    /// Rates, policy lag and per-stage outcomes ([`LiveSnapshot`]).
    pub live: LiveSnapshot,
    /// Refused requests and batches by reason
    /// ([`LearnerError::reason`](super::error::LearnerError::reason); `stream_oversized` for a
    /// message over the size limit, `stream_broken` for a stream that broke).
    pub rejected_by_reason: BTreeMap<String, u64>,
    /// Failed writes by output (`checkpoint`, `metrics_csv`, `eval_csv`); training goes on.
    pub write_failures: BTreeMap<String, u64>,
    /// The last failed write: output, path and OS error.
    pub last_write_error: Option<String>,
    /// The trainer's last error (a failed checkpoint, for one).
    pub trainer_last_error: Option<String>,
    /// Components the watchdog finds stuck now.
    pub stalled: Vec<Stall>,
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
    /// The session credential its transition streams present.
    pub session: String,
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

/// A component stuck for `for_s` seconds (named by the watchdog).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stall {
    /// `ingest`, `trainer`, `rate_limiter` or `actor:<name>`.
    pub component: String,
    /// Seconds since it last made progress (as seen at heartbeats).
    #[serde(deserialize_with = "f64_or_nan")]
    pub for_s: f64,
    /// What it is not doing.
    pub what: String,
    /// Its last error, when one is known.
    pub last_error: Option<String>,
}

/// The progress counters the watchdog reads: no rates, no stalls (it reports those, it does not
/// read them back).
#[derive(Clone, Debug, Default)]
pub struct Progress {
    /// Transitions accepted.
    pub transitions_received: u64,
    /// Updates done.
    pub updates: u64,
    /// The step budget is reached (or shutdown began).
    pub done: bool,
    /// The trainer's last error.
    pub trainer_last_error: Option<String>,
    /// Per actor.
    pub actors: Vec<ActorCounters>,
}
