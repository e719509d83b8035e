//! Acme-style seams between acting and learning.
//!
//! An environment loop hands each step to an [`Adder`], which turns steps into
//! [`TransitionBatch`]es for the learner; it reads the newest policy from a [`VariableSource`].
//! The actor implements both over gRPC; tests implement them in process, so the same loop runs
//! with or without a network.
//!
//! # Each observation once
//!
//! As in Acme, the loop hands an [`Adder`] each observation once: the first of an episode with
//! [`Adder::add_first`], every later one as the `next_obs` of [`Adder::add`]. A
//! [`TransitionBatch`] keeps it once too and pairs by position: row `i` of `observations` is
//! what transition `i` acts from, and [`TransitionBatch::next`] says where its next
//! observation is, in a later row (the same environment's next step) or in
//! `next_observations` (where an episode ended, or the environment's newest when the batch was
//! handed over). [`BatchWriter`] does that pairing for an adder.
//!
//! Why rows per transition and an index, not per-environment segments: transitions keep the
//! order the loop produced them in (environments interleaved), which is the order the replay
//! buffer ages them in, and the only pairing data is one index per transition.
//!
//! A batch is self-contained, so it can be inserted on its own (a resend after a reconnect, a
//! learner restarted with an empty buffer): an environment still running when a batch is handed
//! over has its current observation at the end of that batch (in `next_observations`) and again
//! as the first row it acts from in the next batch. That is the only repetition: at most one
//! observation per environment per batch, `actor.envs / actor.batch_transitions` per
//! transition.

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
    /// A varied robot driven through DVST (`env.dvst`): its success is not the meta robot's,
    /// so the curriculum does not count it.
    pub varied: bool,
}

/// Where a transition's next observation is in its [`TransitionBatch`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NextObs {
    /// Row `j` of `observations`: what transition `j`, the same environment's next step
    /// (`j` after this transition), acts from.
    Step(u32),
    /// Row `k` of `next_observations`.
    Last(u32),
}

/// How far back [`TransitionBatch::push`] looks for the step it continues: well beyond the
/// environments of one actor, whose steps interleave.
const PUSH_LOOKBACK: usize = 256;

/// Transitions in structure-of-arrays layout, as they travel and as the replay buffer takes them,
/// each observation held once (see the [module docs](self)).
///
/// Invariants (kept by [`TransitionBatch::push`] and [`BatchWriter`], checked by
/// `wire::batch_from_proto`): every `next` entry points inside the batch, a [`NextObs::Step`]
/// to a later transition; no row is the next observation of two transitions, and each row of
/// `next_observations` is that of exactly one.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TransitionBatch {
    /// Length of one observation.
    pub obs_dim: usize,
    /// `len() * obs_dim` floats: row `i` is the observation transition `i` acts from.
    pub observations: Vec<f32>,
    /// Rows of `obs_dim` floats: the next observations no transition of this batch acts from
    /// (where an episode ended, and each running environment's newest at the batch's end).
    pub next_observations: Vec<f32>,
    /// Per transition, where its next observation is.
    pub next: Vec<NextObs>,
    /// `len() * ACTION_DIM` floats in [-1, 1].
    pub actions: Vec<f32>,
    /// One reward per transition.
    pub rewards: Vec<f32>,
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
            next_observations: Vec::new(),
            next: Vec::with_capacity(capacity),
            actions: Vec::with_capacity(capacity * ACTION_DIM),
            rewards: Vec::with_capacity(capacity),
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

    /// Rows of `next_observations`.
    pub fn last_rows(&self) -> usize {
        self.next_observations.len().checked_div(self.obs_dim).unwrap_or(0)
    }

    /// Observations held: one per transition and one per row of `next_observations`.
    pub fn stored_observations(&self) -> usize {
        self.len() + self.last_rows()
    }

    /// The observation transition `i` acts from.
    pub fn obs(&self, i: usize) -> &[f32] {
        row(&self.observations, self.obs_dim, i)
    }

    /// Row `k` of `next_observations`.
    pub fn last_obs(&self, k: usize) -> &[f32] {
        row(&self.next_observations, self.obs_dim, k)
    }

    /// The next observation of transition `i`.
    pub fn next_obs(&self, i: usize) -> &[f32] {
        match self.next[i] {
            NextObs::Step(j) => self.obs(j as usize),
            NextObs::Last(k) => self.last_obs(k as usize),
        }
    }

    /// Appends one transition, given both its observations. When `obs` is, bit for bit, the
    /// next observation of a recent transition of this batch whose episode did not end, that
    /// transition now continues into this one and the observation is held once: a stream of
    /// steps pushed in order pairs like one written through [`BatchWriter`].
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
        let i = self.len() as u32;
        if let Some(t) = self.continued_by(obs) {
            let NextObs::Last(k) = self.next[t] else { unreachable!("an open transition") };
            self.next[t] = NextObs::Step(i);
            self.remove_last_row(k as usize);
        }
        self.observations.extend_from_slice(obs);
        let k = self.push_last(next_obs);
        self.push_fields(NextObs::Last(k), action, reward, terminated, truncated, policy_version);
    }

    /// Empties the batch, keeping its allocations.
    pub fn clear(&mut self) {
        self.observations.clear();
        self.next_observations.clear();
        self.next.clear();
        self.actions.clear();
        self.rewards.clear();
        self.terminated.clear();
        self.truncated.clear();
        self.policy_versions.clear();
        self.episodes.clear();
    }

    /// The recent transition whose next observation (a row of `next_observations`, its episode
    /// still running) equals `obs` bit for bit.
    fn continued_by(&self, obs: &[f32]) -> Option<usize> {
        let n = self.len();
        (n.saturating_sub(PUSH_LOOKBACK)..n).rev().find(|&t| match self.next[t] {
            NextObs::Last(k) if !(self.terminated[t] || self.truncated[t]) => {
                same_bits(self.last_obs(k as usize), obs)
            }
            _ => false,
        })
    }

    /// Removes row `k` of `next_observations`, moving the last row into its place.
    fn remove_last_row(&mut self, k: usize) {
        let d = self.obs_dim;
        let last = self.last_rows() - 1;
        if k != last {
            self.next_observations.copy_within(last * d..(last + 1) * d, k * d);
            let owner = self.next.iter().rposition(|&n| n == NextObs::Last(last as u32));
            if let Some(u) = owner {
                self.next[u] = NextObs::Last(k as u32);
            }
        }
        self.next_observations.truncate(last * d);
    }

    /// Appends a row to `next_observations`; returns its index.
    fn push_last(&mut self, obs: &[f32]) -> u32 {
        let k = self.last_rows() as u32;
        self.next_observations.extend_from_slice(obs);
        k
    }

    /// Appends everything of a transition but its observation row.
    fn push_fields(
        &mut self,
        next: NextObs,
        action: [f32; ACTION_DIM],
        reward: f32,
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) {
        self.next.push(next);
        self.actions.extend_from_slice(&action);
        self.rewards.push(reward);
        self.terminated.push(terminated);
        self.truncated.push(truncated);
        self.policy_versions.push(policy_version);
    }
}

fn row(v: &[f32], d: usize, i: usize) -> &[f32] {
    &v[i * d..(i + 1) * d]
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// One environment as a [`BatchWriter`] follows it.
#[derive(Clone, Debug, Default)]
struct EnvCursor {
    /// Its current observation: what its next step acts from.
    obs: Vec<f32>,
    /// An episode is running (`add_first` came, and no end since).
    running: bool,
    /// The transition of the batch being written whose next observation is `obs`, to be
    /// pointed at the row of the next step or, at the batch's end, at a row of
    /// `next_observations`.
    open: Option<u32>,
}

/// Writes the [`Adder`] contract's calls into self-contained [`TransitionBatch`]es, pairing by
/// position: each step's observation is copied once into the batch, and again only at a batch
/// boundary (see the [module docs](self)).
#[derive(Clone, Debug)]
pub struct BatchWriter {
    batch: TransitionBatch,
    capacity: usize,
    envs: Vec<EnvCursor>,
}

/// Placeholder for a next observation not yet written (the environment's next step, or the
/// batch's end, decides which row it is).
const OPEN: NextObs = NextObs::Last(u32::MAX);

impl BatchWriter {
    /// A writer of batches of `obs_dim`-long observations, each with room for `capacity`
    /// transitions.
    pub fn new(obs_dim: usize, capacity: usize) -> Self {
        Self {
            batch: TransitionBatch::with_capacity(obs_dim, capacity),
            capacity,
            envs: Vec::new(),
        }
    }

    /// Length of one observation.
    pub fn obs_dim(&self) -> usize {
        self.batch.obs_dim
    }

    /// Transitions in the batch being written.
    pub fn len(&self) -> usize {
        self.batch.len()
    }

    /// True when the batch being written has neither transitions nor episode reports.
    pub fn is_empty(&self) -> bool {
        self.batch.is_empty() && self.batch.episodes.is_empty()
    }

    /// Environment `env` starts an episode at `obs`.
    pub fn add_first(&mut self, env: usize, obs: &[f32]) -> anyhow::Result<()> {
        self.check_len("first observation", obs)?;
        if env >= self.envs.len() {
            self.envs.resize_with(env + 1, EnvCursor::default);
        }
        // An episode left without an end: its last step's next observation stays in the batch.
        self.close(env);
        let c = &mut self.envs[env];
        c.obs.clear();
        c.obs.extend_from_slice(obs);
        c.running = true;
        Ok(())
    }

    /// Environment `env` took `action` from its current observation and reached `next_obs`.
    #[allow(clippy::too_many_arguments)]
    pub fn add(
        &mut self,
        env: usize,
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) -> anyhow::Result<()> {
        self.check_len("next observation", next_obs)?;
        let Some(c) = self.envs.get_mut(env).filter(|c| c.running) else {
            anyhow::bail!("environment {env} stepped outside an episode (no add_first)");
        };
        let b = &mut self.batch;
        let i = b.len() as u32;
        if let Some(t) = c.open.take() {
            b.next[t as usize] = NextObs::Step(i);
        }
        b.observations.extend_from_slice(&c.obs);
        let next = if terminated || truncated {
            c.running = false;
            NextObs::Last(b.push_last(next_obs))
        } else {
            c.obs.copy_from_slice(next_obs);
            c.open = Some(i);
            OPEN
        };
        b.push_fields(next, action, reward, terminated, truncated, policy_version);
        Ok(())
    }

    /// Reports a finished episode with the batch being written.
    pub fn add_episode(&mut self, stats: EpisodeStats) {
        self.batch.episodes.push(stats);
    }

    /// Hands over the batch written so far and starts the next one. Each running
    /// environment's current observation ends this batch and is repeated in the next.
    pub fn take(&mut self) -> TransitionBatch {
        for env in 0..self.envs.len() {
            self.close(env);
        }
        let fresh = TransitionBatch::with_capacity(self.batch.obs_dim, self.capacity);
        std::mem::replace(&mut self.batch, fresh)
    }

    /// Points the open transition of `env`, if any, at a new last row holding its current
    /// observation.
    fn close(&mut self, env: usize) {
        let c = &mut self.envs[env];
        if let Some(t) = c.open.take() {
            let k = self.batch.push_last(&c.obs);
            self.batch.next[t as usize] = NextObs::Last(k);
        }
    }

    fn check_len(&self, what: &str, obs: &[f32]) -> anyhow::Result<()> {
        anyhow::ensure!(
            obs.len() == self.batch.obs_dim,
            "{what} has {} values, expected {}",
            obs.len(),
            self.batch.obs_dim
        );
        Ok(())
    }
}

/// Turns environment steps into transitions for the learner (Acme's Adder). Each observation
/// is handed over once: an episode's first with [`Adder::add_first`], every later one as the
/// `next_obs` of the step that reached it.
pub trait Adder {
    /// Environment `env` starts an episode at `obs`.
    fn add_first(&mut self, env: usize, obs: &[f32]) -> anyhow::Result<()>;
    /// Environment `env` took `action` from its current observation (the last one handed over
    /// for it) and reached `next_obs`. After a terminated or truncated step, the next episode
    /// begins with [`Adder::add_first`].
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        env: usize,
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
    /// Waits until the adder can take the next step's transitions, so that the loop chooses
    /// the step's actions only then, with the newest weights it has: a loop that chose them and
    /// then waited would hand over actions of a policy as old as the wait. An adder with
    /// nothing to wait for is ready at once.
    fn ready(&mut self) -> anyhow::Result<()> {
        Ok(())
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn o(x: f32) -> [f32; 2] {
        [x, -x]
    }

    /// Every transition as (obs, next_obs, reward), read through the pairing.
    fn transitions(b: &TransitionBatch) -> Vec<(Vec<f32>, Vec<f32>, f32)> {
        (0..b.len()).map(|i| (b.obs(i).to_vec(), b.next_obs(i).to_vec(), b.rewards[i])).collect()
    }

    #[test]
    fn the_writer_holds_each_observation_once_and_repeats_it_only_at_the_boundary() {
        let mut w = BatchWriter::new(2, 8);
        // Two environments, interleaved; env 1's episode ends at its second step.
        w.add_first(0, &o(0.0)).unwrap();
        w.add_first(1, &o(10.0)).unwrap();
        w.add(0, [0.0; 2], 1.0, &o(1.0), false, false, 1).unwrap();
        w.add(1, [0.0; 2], 11.0, &o(11.0), false, false, 1).unwrap();
        w.add(0, [0.0; 2], 2.0, &o(2.0), false, false, 1).unwrap();
        w.add(1, [0.0; 2], 12.0, &o(12.0), true, false, 1).unwrap();
        w.add_first(1, &o(20.0)).unwrap();
        w.add(1, [0.0; 2], 21.0, &o(21.0), false, false, 1).unwrap();
        let a = w.take();
        assert_eq!(
            transitions(&a),
            vec![
                (o(0.0).to_vec(), o(1.0).to_vec(), 1.0),
                (o(10.0).to_vec(), o(11.0).to_vec(), 11.0),
                (o(1.0).to_vec(), o(2.0).to_vec(), 2.0),
                (o(11.0).to_vec(), o(12.0).to_vec(), 12.0),
                (o(20.0).to_vec(), o(21.0).to_vec(), 21.0),
            ]
        );
        // 5 rows acted from, and the ends: env 1's episode, env 0's and env 1's newest.
        assert_eq!((a.len(), a.last_rows()), (5, 3));
        assert_eq!(a.next[0], NextObs::Step(2));
        assert_eq!(a.next[1], NextObs::Step(3));
        // The next batch starts from each environment's newest observation, repeated once.
        w.add(0, [0.0; 2], 3.0, &o(3.0), false, false, 1).unwrap();
        w.add(1, [0.0; 2], 22.0, &o(22.0), false, true, 1).unwrap();
        let b = w.take();
        assert_eq!(b.obs(0), o(2.0));
        assert_eq!(b.obs(1), o(21.0));
        assert_eq!(b.next_obs(1), o(22.0));
        assert_eq!((b.len(), b.last_rows()), (2, 2));
        assert!(w.add(1, [0.0; 2], 0.0, &o(0.0), false, false, 1).is_err(), "no add_first");
        assert!(w.add_first(0, &[1.0]).is_err(), "wrong length");
    }

    #[test]
    fn push_pairs_a_stream_pushed_in_order_like_the_writer() {
        // Two interleaved environments, pushed transition by transition.
        let mut p = TransitionBatch::with_capacity(2, 8);
        let mut w = BatchWriter::new(2, 8);
        w.add_first(0, &o(0.0)).unwrap();
        w.add_first(1, &o(10.0)).unwrap();
        let steps = [(0, 0.0, 1.0, false), (1, 10.0, 11.0, false), (0, 1.0, 2.0, true)];
        for (env, x, y, end) in steps {
            p.push(&o(x), [0.5, 0.5], y, &o(y), end, false, 1);
            w.add(env, [0.5, 0.5], y, &o(y), end, false, 1).unwrap();
        }
        let w = w.take();
        assert_eq!(transitions(&p), transitions(&w));
        assert_eq!((p.len(), p.last_rows()), (3, 2));
        assert_eq!(p.stored_observations(), w.stored_observations());
        // Unrelated steps share nothing, and an ended episode is not continued.
        let mut b = TransitionBatch::with_capacity(2, 3);
        b.push(&o(0.0), [0.0; 2], 0.0, &o(1.0), true, false, 1);
        b.push(&o(1.0), [0.0; 2], 0.0, &o(5.0), false, false, 1);
        b.push(&o(7.0), [0.0; 2], 0.0, &o(8.0), false, false, 1);
        assert_eq!((b.len(), b.last_rows()), (3, 3));
        assert_eq!(b.next_obs(0), o(1.0));
        assert_eq!(b.next_obs(2), o(8.0));
    }
}
