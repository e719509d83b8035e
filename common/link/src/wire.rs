//! Conversions between the wire types of `dvnav-proto` and the domain types of [`crate::core`].
//!
//! Decoding is where untrusted input enters the learner, so [`batch_from_proto`] checks every
//! length and value and never panics: a batch that fails any check is refused whole and never
//! reaches the replay buffer.
//!
//! [`EncodedBatch`] is a batch encoded once, when the actor's adder hands it over: the stream to
//! the learner sends those bytes, and sends them again unchanged after a reconnect.

use crate::core::{EpisodeStats, NextObs, TransitionBatch, Variables};
use bytes::{BufMut, Bytes};
use dvnav_proto as pb;
use dvnav_sim::Outcome;
use dvnav_sim::obs::ACTION_DIM;
use prost::Message;
use std::fmt;
use std::sync::Arc;

/// Largest |reward| accepted; the task's rewards are bounded by r_s, r_c and the progress term.
pub const MAX_ABS_REWARD: f32 = 1.0e3;
/// Largest transition count in one batch.
pub const MAX_BATCH_TRANSITIONS: usize = 65_536;
/// Request metadata key of the `Transitions` stream that carries the session credential
/// `Register` returned: the stream speaks for that actor only.
pub const SESSION_METADATA: &str = "x-dvnav-session";

/// Why a batch was refused; the message names the field.
#[derive(Debug, Clone, PartialEq)]
pub struct WireError {
    /// The offending field, e.g. `observations`.
    pub field: &'static str,
    /// What is wrong with it.
    pub reason: String,
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "field `{}`: {}", self.field, self.reason)
    }
}

impl std::error::Error for WireError {}

fn err(field: &'static str, reason: impl Into<String>) -> WireError {
    WireError { field, reason: reason.into() }
}

fn check_len<T>(field: &'static str, v: &[T], expect: usize) -> Result<(), WireError> {
    if v.len() == expect {
        Ok(())
    } else {
        Err(err(field, format!("has {} values, expected {expect}", v.len())))
    }
}

fn check_finite(field: &'static str, v: &[f32]) -> Result<(), WireError> {
    // Chunks are checked without an early exit, which vectorizes; the offending value is
    // looked for only in a batch that has one.
    if v.chunks(1024).all(|c| c.iter().fold(true, |ok, x| ok & x.is_finite())) {
        return Ok(());
    }
    let i = v.iter().position(|x| !x.is_finite()).unwrap_or_default();
    Err(err(field, format!("value {i} is {} (NaN/Inf refused)", v[i])))
}

/// Rows of `next_observations`: whole rows, no more than transitions (each is one's next).
fn last_rows(v: &[f32], obs_dim: usize, n: usize) -> Result<usize, WireError> {
    let field = "next_observations";
    if obs_dim == 0 {
        return if v.is_empty() { Ok(0) } else { Err(err(field, "values for empty observations")) };
    }
    if !v.len().is_multiple_of(obs_dim) {
        return Err(err(field, format!("has {} values, not whole rows of {obs_dim}", v.len())));
    }
    let rows = v.len() / obs_dim;
    if rows > n {
        return Err(err(field, format!("has {rows} rows for {n} transitions")));
    }
    Ok(rows)
}

/// The pairing of `n` transitions with `last` rows of `next_observations`.
fn pairing(index: &[u32], n: usize, last: usize) -> Result<Vec<NextObs>, WireError> {
    let field = "next_obs_index";
    let mut named = vec![false; n + last];
    let mut next = Vec::with_capacity(n);
    for (i, &v) in index.iter().enumerate() {
        let r = v as usize;
        if r >= n + last {
            return Err(err(field, format!("transition {i} names row {r} of {}", n + last)));
        }
        if r <= i {
            return Err(err(field, format!("transition {i} continues into row {r}, not later")));
        }
        if std::mem::replace(&mut named[r], true) {
            return Err(err(field, format!("row {r} is the next observation of two transitions")));
        }
        next.push(if r < n { NextObs::Step(v) } else { NextObs::Last((r - n) as u32) });
    }
    if let Some(k) = named[n..].iter().position(|&x| !x) {
        return Err(err("next_observations", format!("row {k} is no transition's next")));
    }
    Ok(next)
}

/// Encodes a batch for the wire.
pub fn batch_to_proto(
    batch: &TransitionBatch,
    actor_id: u32,
    sequence: u64,
) -> pb::TransitionBatch {
    let n = batch.len() as u32;
    pb::TransitionBatch {
        actor_id,
        sequence,
        count: n,
        observations: batch.observations.clone(),
        actions: batch.actions.clone(),
        rewards: batch.rewards.clone(),
        terminated: batch.terminated.clone(),
        truncated: batch.truncated.clone(),
        policy_versions: batch.policy_versions.clone(),
        episodes: batch.episodes.iter().map(episode_to_proto).collect(),
        next_observations: batch.next_observations.clone(),
        next_obs_index: batch
            .next
            .iter()
            .map(|&x| match x {
                NextObs::Step(j) => j,
                NextObs::Last(k) => n.saturating_add(k),
            })
            .collect(),
    }
}

/// A batch encoded for the wire once, when the adder hands it over; a resend after a reconnect
/// sends the same bytes. It holds every field but `actor_id` and `sequence`, which
/// [`EncodedBatch::write`] puts in front at each send (the actor id may change with a
/// reconnect): protobuf merges concatenated encodings into one message, so the learner decodes
/// the whole as any `TransitionBatch`.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedBatch {
    count: u32,
    body: Bytes,
}

impl EncodedBatch {
    /// Encodes `batch`.
    pub fn new(batch: &TransitionBatch) -> Self {
        let body = batch_to_proto(batch, 0, 0).encode_to_vec();
        Self { count: batch.len() as u32, body: Bytes::from(body) }
    }

    /// Transitions in the batch.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// True when the batch has no transitions (it may still report episodes).
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Bytes of the encoded fields (all but `actor_id` and `sequence`).
    pub fn body_len(&self) -> usize {
        self.body.len()
    }

    /// Writes the whole message, as sent by `actor_id` under `sequence`, into `buf`, a buffer
    /// that grows (`Vec<u8>`, `BytesMut`, tonic's `EncodeBuf`); panics if it cannot.
    pub fn write(&self, actor_id: u32, sequence: u64, buf: &mut impl BufMut) {
        let head = pb::TransitionBatch { actor_id, sequence, ..Default::default() };
        head.encode(buf).expect("a growable buffer");
        buf.put_slice(&self.body);
    }
}

/// Wire form of the variables an actor receives; the weights are shared, not copied.
pub fn variables_to_proto(v: &Variables) -> pb::VariablesUpdate {
    pb::VariablesUpdate {
        version: v.version,
        safetensors: policy_bytes(&v.policy),
        assignment: Some(pb::StageAssignment { stage: v.stage, room: v.room.clone() }),
        warmup: v.warmup,
        stop: v.stop,
    }
}

/// Domain form of a wire update (a missing assignment reads as stage 0 with no room).
pub fn variables_from_proto(u: pb::VariablesUpdate) -> Variables {
    let (stage, room) = u.assignment.map(|a| (a.stage, a.room)).unwrap_or_default();
    Variables {
        version: u.version,
        policy: Arc::new(u.safetensors.into()),
        stage,
        room,
        warmup: u.warmup,
        stop: u.stop,
    }
}

/// A version's policy weights as the wire's `Bytes`, sharing their buffer: every actor's
/// `Variables` stream sends the one serialization of a version, none copies it.
pub fn policy_bytes(policy: &Arc<Vec<u8>>) -> Bytes {
    Bytes::from_owner(SharedWeights(policy.clone()))
}

/// Keeps a version's weights alive while some stream still sends them.
struct SharedWeights(Arc<Vec<u8>>);

impl AsRef<[u8]> for SharedWeights {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

/// The wire and log enum value of an outcome.
pub fn outcome_to_proto(o: Outcome) -> pb::Outcome {
    match o {
        Outcome::Success => pb::Outcome::Success,
        Outcome::Collision => pb::Outcome::Collision,
        Outcome::Timeout => pb::Outcome::Timeout,
    }
}

/// An outcome from its wire and log enum value; `None` for unspecified or unknown values.
pub fn outcome_from_proto(v: i32) -> Option<Outcome> {
    match pb::Outcome::try_from(v).ok()? {
        pb::Outcome::Success => Some(Outcome::Success),
        pb::Outcome::Collision => Some(Outcome::Collision),
        pb::Outcome::Timeout => Some(Outcome::Timeout),
        pb::Outcome::Unspecified => None,
    }
}

/// Encodes episode statistics.
pub fn episode_to_proto(e: &EpisodeStats) -> pb::EpisodeStats {
    pb::EpisodeStats {
        env_index: e.env_index,
        stage: e.stage,
        room: e.room.clone(),
        outcome: outcome_to_proto(e.outcome) as i32,
        steps: e.steps,
        episode_return: e.episode_return,
        policy_version: e.policy_version,
        warmup: e.warmup,
        varied: e.varied,
    }
}

/// Decodes and validates a batch of `obs_dim`-long observations. Checks: count within bounds,
/// every array of the right length (`next_observations` whole rows), all floats finite, actions
/// in [−1, 1], |reward| ≤ [`MAX_ABS_REWARD`], no transition both terminated and truncated, the
/// pairing sound (every `next_obs_index` inside the batch, a row of `observations` only for a
/// later transition, no row named twice, every row of `next_observations` named), episode
/// outcomes known.
pub fn batch_from_proto(
    msg: pb::TransitionBatch,
    obs_dim: usize,
) -> Result<TransitionBatch, WireError> {
    let n = msg.count as usize;
    if n > MAX_BATCH_TRANSITIONS {
        return Err(err("count", format!("{n} exceeds the limit of {MAX_BATCH_TRANSITIONS}")));
    }
    check_len("observations", &msg.observations, n * obs_dim)?;
    let last = last_rows(&msg.next_observations, obs_dim, n)?;
    check_len("next_obs_index", &msg.next_obs_index, n)?;
    check_len("actions", &msg.actions, n * ACTION_DIM)?;
    check_len("rewards", &msg.rewards, n)?;
    check_len("terminated", &msg.terminated, n)?;
    check_len("truncated", &msg.truncated, n)?;
    check_len("policy_versions", &msg.policy_versions, n)?;
    check_finite("observations", &msg.observations)?;
    check_finite("next_observations", &msg.next_observations)?;
    check_finite("actions", &msg.actions)?;
    check_finite("rewards", &msg.rewards)?;
    if let Some(i) = msg.actions.iter().position(|a| a.abs() > 1.0) {
        return Err(err("actions", format!("value {i} = {} is outside [-1, 1]", msg.actions[i])));
    }
    if let Some(i) = msg.rewards.iter().position(|r| r.abs() > MAX_ABS_REWARD) {
        return Err(err(
            "rewards",
            format!("value {i} = {} exceeds ±{MAX_ABS_REWARD}", msg.rewards[i]),
        ));
    }
    if let Some(i) = (0..n).find(|&i| msg.terminated[i] && msg.truncated[i]) {
        return Err(err("truncated", format!("transition {i} is both terminated and truncated")));
    }
    let next = pairing(&msg.next_obs_index, n, last)?;
    let mut episodes = Vec::with_capacity(msg.episodes.len());
    for (i, e) in msg.episodes.into_iter().enumerate() {
        let outcome = outcome_from_proto(e.outcome).ok_or_else(|| {
            err("episodes", format!("episode {i} has unknown outcome {}", e.outcome))
        })?;
        if !e.episode_return.is_finite() {
            return Err(err("episodes", format!("episode {i} has a non-finite return")));
        }
        episodes.push(EpisodeStats {
            env_index: e.env_index,
            stage: e.stage,
            room: e.room,
            outcome,
            steps: e.steps,
            episode_return: e.episode_return,
            policy_version: e.policy_version,
            warmup: e.warmup,
            varied: e.varied,
        });
    }
    Ok(TransitionBatch {
        obs_dim,
        observations: msg.observations,
        next_observations: msg.next_observations,
        next,
        actions: msg.actions,
        rewards: msg.rewards,
        terminated: msg.terminated,
        truncated: msg.truncated,
        policy_versions: msg.policy_versions,
        episodes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> TransitionBatch {
        let mut b = TransitionBatch::with_capacity(3, 2);
        b.push(&[1.0, 2.0, 3.0], [0.5, -0.5], 0.1, &[1.5, 2.5, 3.5], false, false, 4);
        b.push(&[1.5, 2.5, 3.5], [1.0, -1.0], -10.0, &[0.0, 0.0, 0.0], true, false, 4);
        b.episodes.push(EpisodeStats {
            env_index: 0,
            stage: 0,
            room: "env0".into(),
            outcome: Outcome::Collision,
            steps: 2,
            episode_return: -9.9,
            policy_version: 4,
            warmup: false,
            varied: false,
        });
        b
    }

    /// Two environments interleaved through a [`BatchWriter`]: steps continued in the batch,
    /// an episode end, and both environments' newest observations at the end.
    fn interleaved() -> TransitionBatch {
        let mut w = crate::core::BatchWriter::new(3, 8);
        w.add_first(0, &[0.0; 3]).unwrap();
        w.add_first(1, &[5.0; 3]).unwrap();
        for t in 1..=4 {
            let x = t as f32;
            w.add(0, [0.1, 0.2], x, &[x; 3], false, false, 2).unwrap();
            w.add(1, [0.3, 0.4], -x, &[5.0 + x; 3], t == 2, false, 2).unwrap();
            if t == 2 {
                w.add_first(1, &[9.0; 3]).unwrap();
            }
        }
        w.take()
    }

    /// Whatever passes validation is internally consistent: every transition's observations
    /// are there, whole.
    fn assert_consistent(b: &TransitionBatch) {
        assert_eq!(b.observations.len(), b.len() * 3);
        assert_eq!(b.next.len(), b.len());
        for i in 0..b.len() {
            assert_eq!((b.obs(i).len(), b.next_obs(i).len()), (3, 3));
        }
        assert_eq!(b.actions.len(), b.len() * ACTION_DIM);
        assert!(b.rewards.iter().all(|r| r.is_finite()));
    }

    /// Untrusted bytes never panic the decoder: random buffers, truncations and byte flips of
    /// a valid message either fail to decode or are refused by validation (or are valid).
    #[test]
    fn random_and_damaged_messages_never_panic() {
        use prost::Message;
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(99);
        let valid = batch_to_proto(&sample(), 1, 0).encode_to_vec();
        let mut decoded = 0;
        let mut accepted = 0;
        for i in 0..20_000 {
            let bytes: Vec<u8> = match i % 3 {
                0 => (0..rng.random_range(0..200)).map(|_| rng.random()).collect(),
                1 => valid[..rng.random_range(0..valid.len())].to_vec(),
                _ => {
                    let mut v = valid.clone();
                    for _ in 0..rng.random_range(1..6) {
                        let j = rng.random_range(0..v.len());
                        v[j] = rng.random();
                    }
                    v
                }
            };
            if let Ok(msg) = pb::TransitionBatch::decode(bytes.as_slice()) {
                decoded += 1;
                if let Ok(b) = batch_from_proto(msg, 3) {
                    accepted += 1;
                    // Whatever passes is internally consistent.
                    assert_consistent(&b);
                }
            }
        }
        assert!(decoded > 1_000, "the damaged inputs exercised validation ({decoded} decoded)");
        assert!(accepted < decoded, "validation refused some ({accepted} of {decoded})");
    }

    /// The pairing fields damaged on purpose (indices anywhere, repeated or dropped rows,
    /// counts off by one): refused or consistent, never a panic.
    #[test]
    fn damaged_pairings_never_panic() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let valid = batch_to_proto(&interleaved(), 1, 0);
        let (n, rows) = (valid.count, (valid.next_observations.len() / 3) as u32);
        let mut accepted = 0;
        for _ in 0..20_000 {
            let mut m = valid.clone();
            for _ in 0..rng.random_range(1..4) {
                // At most 3 pops of 8: never empty.
                let len = m.next_obs_index.len();
                let i = rng.random_range(0..len);
                match rng.random_range(0..7) {
                    0 => m.next_obs_index[i] = rng.random(),
                    1 => m.next_obs_index[i] = rng.random_range(0..n + rows + 2),
                    2 => m.next_obs_index.swap(i, rng.random_range(0..len)),
                    3 => {
                        m.next_obs_index.pop();
                    }
                    4 => m.next_obs_index.push(rng.random_range(0..2 * n)),
                    5 => m
                        .next_observations
                        .truncate(rng.random_range(0..=valid.next_observations.len())),
                    _ => m.next_observations.extend([1.0; 3]),
                }
            }
            if let Ok(b) = batch_from_proto(m, 3) {
                accepted += 1;
                assert_consistent(&b);
            }
        }
        assert!((1..20_000).contains(&accepted), "{accepted} accepted");
    }

    #[test]
    fn round_trips() {
        let mut b = sample();
        assert_eq!(batch_from_proto(batch_to_proto(&b, 1, 0), 3).unwrap(), b);
        // A varied robot's episode stays one on the wire: the curriculum must not count it.
        b.episodes[0].varied = true;
        assert_eq!(batch_from_proto(batch_to_proto(&b, 1, 0), 3).unwrap(), b);
        let b = interleaved();
        assert_eq!((b.len(), b.last_rows()), (8, 3));
        assert_eq!(batch_from_proto(batch_to_proto(&b, 1, 0), 3).unwrap(), b);
    }

    #[test]
    fn the_weights_are_shared_not_copied() {
        let w = Arc::new(vec![7u8; 1000]);
        let (a, b) = (policy_bytes(&w), policy_bytes(&w));
        assert_eq!(&a[..], &w[..]);
        assert_eq!((a.as_ptr(), b.as_ptr()), (w.as_ptr(), w.as_ptr()));
        assert_eq!(Arc::strong_count(&w), 3);
        drop((a, b));
        assert_eq!(Arc::strong_count(&w), 1);
    }

    /// The bytes encoded once decode, under any actor id and sequence number, as the message
    /// converted for them.
    #[test]
    fn an_encoded_batch_is_the_message_under_any_id_and_sequence() {
        let b = interleaved();
        let e = EncodedBatch::new(&b);
        assert_eq!(e.len(), 8);
        for (id, seq) in [(0, 0), (3, 9), (u32::MAX, u64::MAX)] {
            let mut buf = Vec::new();
            e.write(id, seq, &mut buf);
            let m = pb::TransitionBatch::decode(buf.as_slice()).unwrap();
            assert_eq!(m, batch_to_proto(&b, id, seq));
        }
    }

    #[test]
    fn refuses_bad_batches_naming_the_field() {
        let good = batch_to_proto(&sample(), 1, 0);
        let mut m = good.clone();
        m.observations.pop();
        assert_eq!(batch_from_proto(m, 3).unwrap_err().field, "observations");
        let mut m = good.clone();
        m.rewards[0] = f32::NAN;
        assert_eq!(batch_from_proto(m, 3).unwrap_err().field, "rewards");
        let mut m = good.clone();
        m.actions[1] = 1.5;
        assert_eq!(batch_from_proto(m, 3).unwrap_err().field, "actions");
        let mut m = good.clone();
        m.count = 3;
        assert!(batch_from_proto(m, 3).is_err());
        let mut m = good.clone();
        m.episodes[0].outcome = 17;
        assert_eq!(batch_from_proto(m, 3).unwrap_err().field, "episodes");
        let mut m = good;
        m.count = u32::MAX;
        assert_eq!(batch_from_proto(m, 3).unwrap_err().field, "count");
        // The pairing: `interleaved` has 8 transitions and 3 rows of `next_observations`.
        let good = batch_to_proto(&interleaved(), 1, 0);
        let field = |f: &dyn Fn(&mut pb::TransitionBatch)| {
            let mut m = good.clone();
            f(&mut m);
            batch_from_proto(m, 3).unwrap_err().field
        };
        assert_eq!(field(&|m| m.next_obs_index[0] = 11), "next_obs_index", "beyond the rows");
        assert_eq!(field(&|m| m.next_obs_index[3] = 2), "next_obs_index", "an earlier step");
        assert_eq!(field(&|m| m.next_obs_index[3] = 3), "next_obs_index", "itself");
        let twice = |m: &mut pb::TransitionBatch| m.next_obs_index[1] = m.next_obs_index[0];
        assert_eq!(field(&twice), "next_obs_index", "a row named twice");
        assert_eq!(
            field(&|m| {
                m.next_obs_index.pop();
            }),
            "next_obs_index"
        );
        assert_eq!(
            field(&|m| {
                m.next_observations.pop();
            }),
            "next_observations"
        );
        let unnamed = |m: &mut pb::TransitionBatch| m.next_observations.extend([0.0; 3]);
        assert_eq!(field(&unnamed), "next_observations", "a row nobody continues into");
        assert_eq!(field(&|m| m.next_observations[4] = f32::INFINITY), "next_observations");
    }

    #[test]
    fn variables_cross_the_wire_unchanged_and_share_their_weights() {
        let v = Variables {
            version: 4,
            policy: Arc::new(vec![1, 2, 3]),
            stage: 2,
            room: "env2".into(),
            warmup: false,
            stop: true,
        };
        let msg = variables_to_proto(&v);
        assert_eq!(msg.safetensors.as_ptr(), v.policy.as_ptr(), "no copy per stream");
        assert_eq!(variables_from_proto(msg), v);
    }
}
