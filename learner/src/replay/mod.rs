//! The replay buffer: a ring of transitions sampled uniformly, each observation stored once and
//! compactly ([`ObsCodec`]), each sample's return summed over up to n steps of its episode
//! ([`Returns`]); `file.rs` saves and restores it with a checkpoint.

mod codec;
mod file;

pub use codec::ObsCodec;
use dvnav_link::core::{NextObs, TransitionBatch};
use dvnav_sim::obs::ACTION_DIM;
use rand::Rng;

/// Makes room in `v` for one more observation of `per_obs` values, growing (by doubling, as
/// `Vec` does) but never past `obs_capacity` observations: doubling past the store's size
/// would hold up to twice the memory the buffer can ever use.
fn grow_within<T>(v: &mut Vec<T>, per_obs: usize, obs_capacity: usize) {
    if v.len() + per_obs > v.capacity() {
        let limit = obs_capacity * per_obs;
        let more = v.len().max(per_obs).min(limit.saturating_sub(v.len())).max(per_obs);
        v.reserve_exact(more);
    }
}

/// A sampled minibatch, laid out for tensors. Named fields rather than a tuple, and
/// `terminated` kept apart from truncation: only termination masks the bootstrap.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Batch {
    /// Transitions in the batch.
    pub size: usize,
    /// Length of one observation.
    pub obs_dim: usize,
    /// `size × obs_dim`.
    pub obs: Vec<f32>,
    /// `size × 2`, normalized actions in [-1, 1].
    pub actions: Vec<f32>,
    /// `size`: the return r_t + γ r_t+1 + … + γ^(k−1) r_t+k−1 of the k steps summed
    /// ([`Returns`]); the reward itself for one-step returns.
    pub rewards: Vec<f32>,
    /// `size`: γ^k, the discount of the bootstrap from `next_obs`, which is s_t+k.
    pub discounts: Vec<f32>,
    /// `size × obs_dim`.
    pub next_obs: Vec<f32>,
    /// `size`, 1.0 where the episode terminated (success or collision), else 0.0. A timeout is
    /// not a termination: its target bootstraps from `next_obs`.
    pub terminated: Vec<f32>,
    /// `size`, 1.0 where a controller chose the action (the PID warm-up, the planner expert:
    /// weight version 0), else 0.0: what `sac.bc_weight` clones.
    pub demonstrated: Vec<f32>,
}

/// How [`ReplayBuffer::sample_into`] forms each sample's return: the rewards of up to `n`
/// consecutive steps of one episode, discounted by `gamma`, and the bootstrap from the
/// observation after the last of them (`sac.n_step`, `sac.gamma`).
///
/// A sample sums fewer than `n` steps where its episode terminates or times out first, or
/// where the stored steps of its environment end: steps are linked only inside the batch an
/// actor sent them in (the next batch starts its own chain), so a chain is cut there and
/// bootstraps early, which is still a correct k-step target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Returns {
    /// Most steps summed; 1 is the one-step target.
    pub n: usize,
    /// Discount per step.
    pub gamma: f32,
}

impl Returns {
    /// What a run's `[sac]` asks for.
    pub fn for_config(sac: &dvnav_config::SacConfig) -> Self {
        Self { n: sac.n_step, gamma: sac.gamma as f32 }
    }
}

/// What a stored transition did, beside the observations it refers to.
#[derive(Clone, Copy, Debug)]
struct Step {
    action: [f32; ACTION_DIM],
    reward: f32,
    terminated: bool,
    /// A controller chose the action, not the policy.
    demonstrated: bool,
}

/// Fixed-capacity FIFO of transitions, each observation stored once.
///
/// Layout: an *observation store* (a ring of compactly encoded observations, see
/// [`ObsCodec`]) and a *transition ring* that refers to observations by id. A batch holds each
/// of its observations once and pairs its transitions by position
/// ([`dvnav_link::core::TransitionBatch`]); [`ReplayBuffer::insert`] stores each of them once and
/// maps the batch's positions to stored ids: about one stored observation per transition
/// instead of two, plus one per episode end and one per environment and batch (the batch
/// boundary), and ranges in `u16`.
///
/// Ids are handed out in transition order (each transition's observation, then its next one
/// unless that is a later transition's), so observation ids increase along the ring and each
/// transition's next id is above its own: the oldest stored observation is always the oldest
/// transition's, and eviction only ever drops transitions from the oldest end.
///
/// The observation store holds `obs_capacity` observations (a quarter more than one per
/// transition, to absorb episode ends and batch boundaries: an actor of 16 environments and
/// batches of 128 repeats an eighth; the store only grows as far as a stream needs it). If a stream pairs observations
/// worse than that, the oldest transitions are dropped earlier to free theirs: the buffer then
/// holds fewer than `capacity` transitions, never a transition with a missing observation.
#[derive(Debug)]
pub struct ReplayBuffer {
    codec: ObsCodec,
    capacity: usize,
    /// Observation store: `obs_capacity` slots; observation `id` lives in slot
    /// `id % obs_capacity`; ids below `oldest_obs` are gone.
    obs_capacity: usize,
    scans: Vec<u16>,
    extras: Vec<f32>,
    next_obs_id: u64,
    oldest_obs: u64,
    /// Transition ring: logical index `i` (0 = oldest) is at `(head + i) % capacity`.
    obs_id: Vec<u64>,
    next_id: Vec<u64>,
    /// Ring distance to the transition that continues this one's episode from its next
    /// observation, 0 where none is stored (the episode ended, or the batch did).
    successor: Vec<u32>,
    actions: Vec<f32>,
    rewards: Vec<f32>,
    terminated: Vec<bool>,
    /// A controller chose the action (weight version 0).
    demonstrated: Vec<bool>,
    head: usize,
    len: usize,
    /// Encoding scratch, kept to avoid two allocations per observation.
    scratch: (Vec<u16>, Vec<f32>),
    /// Insertion scratch: the id each row of a batch's `observations` gets.
    row_ids: Vec<u64>,
}

impl ReplayBuffer {
    /// An empty buffer for `capacity` transitions of observations laid out as `codec` says.
    /// Memory grows with use, up to the capacity.
    pub fn new(codec: ObsCodec, capacity: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self {
            codec,
            capacity,
            obs_capacity: capacity + capacity / 4 + 1024,
            scans: Vec::new(),
            extras: Vec::new(),
            next_obs_id: 0,
            oldest_obs: 0,
            obs_id: Vec::new(),
            next_id: Vec::new(),
            successor: Vec::new(),
            actions: Vec::new(),
            rewards: Vec::new(),
            terminated: Vec::new(),
            demonstrated: Vec::new(),
            head: 0,
            len: 0,
            scratch: (Vec::new(), Vec::new()),
            row_ids: Vec::new(),
        }
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Capacity in transitions.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Observations stored (at most `capacity` plus an eighth).
    pub fn stored_observations(&self) -> usize {
        (self.next_obs_id - self.oldest_obs) as usize
    }

    /// Heap bytes held by the stored data (observations and transitions).
    pub fn memory_bytes(&self) -> usize {
        self.scans.capacity() * 2
            + self.extras.capacity() * 4
            + (self.obs_id.capacity() + self.next_id.capacity()) * 8
            + self.successor.capacity() * 4
            + self.actions.capacity() * 4
            + self.rewards.capacity() * 4
            + self.terminated.capacity()
            + self.demonstrated.capacity()
    }

    /// Appends every transition of a validated batch, dropping the oldest when full. Each
    /// observation of the batch is stored once, and its positions in the batch become ids.
    pub fn insert(&mut self, batch: &TransitionBatch) {
        assert_eq!(batch.obs_dim, self.codec.obs_dim, "batch observation size");
        let n = batch.len();
        // A later row is the next observation of a continuing step; anything else (a row of
        // `next_observations`, or a pairing the wire would refuse) is stored with its
        // transition.
        let later = |i: usize| match batch.next[i] {
            NextObs::Step(j) => (i + 1..n).contains(&(j as usize)),
            NextObs::Last(_) => false,
        };
        // The ids the rows get when stored in transition order: transition i stores its row,
        // then its next observation unless that is a later row.
        let mut row_ids = std::mem::take(&mut self.row_ids);
        row_ids.clear();
        let mut id = self.next_obs_id;
        for i in 0..n {
            row_ids.push(id);
            id += if later(i) { 1 } else { 2 };
        }
        for i in 0..n {
            let obs = self.store(batch.obs(i));
            debug_assert_eq!(obs, row_ids[i]);
            // A later row's id is handed out before it is stored, further on in this loop.
            // Transitions are pushed in batch order, so that row's step (the successor) is as
            // many places further along the ring as it is rows further down the batch.
            let (next, successor) = match batch.next[i] {
                NextObs::Step(j) if later(i) => (row_ids[j as usize], j - i as u32),
                NextObs::Step(j) => (self.store(batch.obs(j as usize)), 0),
                NextObs::Last(k) => (self.store(batch.last_obs(k as usize)), 0),
            };
            let a = [batch.actions[i * ACTION_DIM], batch.actions[i * ACTION_DIM + 1]];
            let step = Step {
                action: a,
                reward: batch.rewards[i],
                terminated: batch.terminated[i],
                demonstrated: batch.policy_versions[i] == 0,
            };
            self.push(obs, next, successor, step);
        }
        self.row_ids = row_ids;
    }

    fn store(&mut self, obs: &[f32]) -> u64 {
        let (mut scan, mut extra) = std::mem::take(&mut self.scratch);
        scan.clear();
        extra.clear();
        self.codec.encode(obs, &mut scan, &mut extra);
        let id = self.store_encoded(&scan, &extra);
        self.scratch = (scan, extra);
        id
    }

    fn store_encoded(&mut self, scan: &[u16], extra: &[f32]) -> u64 {
        if self.stored_observations() == self.obs_capacity {
            self.evict_oldest_observation();
        }
        let id = self.next_obs_id;
        let slot = (id % self.obs_capacity as u64) as usize;
        let (s, e) = (self.codec.scan_len, self.codec.extra_len());
        if slot * s == self.scans.len() && slot * e == self.extras.len() {
            grow_within(&mut self.scans, s, self.obs_capacity);
            grow_within(&mut self.extras, e, self.obs_capacity);
            self.scans.extend_from_slice(scan);
            self.extras.extend_from_slice(extra);
        } else {
            self.scans[slot * s..(slot + 1) * s].copy_from_slice(scan);
            self.extras[slot * e..(slot + 1) * e].copy_from_slice(extra);
        }
        self.next_obs_id += 1;
        id
    }

    fn stored(&self, id: u64) -> (&[u16], &[f32]) {
        let slot = (id % self.obs_capacity as u64) as usize;
        let (s, e) = (self.codec.scan_len, self.codec.extra_len());
        (&self.scans[slot * s..(slot + 1) * s], &self.extras[slot * e..(slot + 1) * e])
    }

    /// Frees the oldest observation, dropping the transitions that still refer to it.
    fn evict_oldest_observation(&mut self) {
        self.oldest_obs += 1;
        while self.len > 0 && self.obs_id[self.head] < self.oldest_obs {
            self.pop_oldest();
        }
    }

    /// Appends one transition. `successor` is the ring distance to the transition that
    /// continues its episode, pushed later (0: none); evicting oldest first never removes a
    /// successor before its predecessor.
    fn push(&mut self, obs: u64, next: u64, successor: u32, step: Step) {
        let Step { action, reward, terminated: term, demonstrated } = step;
        if self.len == self.capacity {
            self.pop_oldest();
        }
        let j = (self.head + self.len) % self.capacity;
        if j == self.obs_id.len() {
            self.obs_id.push(obs);
            self.next_id.push(next);
            self.successor.push(successor);
            self.actions.extend_from_slice(&action);
            self.rewards.push(reward);
            self.terminated.push(term);
            self.demonstrated.push(demonstrated);
        } else {
            self.obs_id[j] = obs;
            self.next_id[j] = next;
            self.successor[j] = successor;
            self.actions[j * ACTION_DIM..(j + 1) * ACTION_DIM].copy_from_slice(&action);
            self.rewards[j] = reward;
            self.terminated[j] = term;
            self.demonstrated[j] = demonstrated;
        }
        self.len += 1;
    }

    fn pop_oldest(&mut self) {
        self.head = (self.head + 1) % self.capacity;
        self.len -= 1;
    }

    /// Position in the ring of the `i`-th oldest transition.
    fn position(&self, i: usize) -> usize {
        (self.head + i) % self.capacity
    }

    /// Samples `size` transitions uniformly with replacement into `out` (reusing its memory),
    /// each with its return over up to `returns.n` steps.
    pub fn sample_into(&self, size: usize, returns: Returns, rng: &mut impl Rng, out: &mut Batch) {
        assert!(!self.is_empty(), "sampling an empty replay buffer");
        assert!(returns.n >= 1, "an n-step return sums at least one step");
        out.size = size;
        out.obs_dim = self.codec.obs_dim;
        out.obs.clear();
        out.next_obs.clear();
        out.actions.clear();
        out.rewards.clear();
        out.discounts.clear();
        out.terminated.clear();
        out.demonstrated.clear();
        for _ in 0..size {
            let first = self.position(rng.random_range(0..self.len));
            let (s, e) = self.stored(self.obs_id[first]);
            self.codec.decode(s, e, &mut out.obs);
            let a = &self.actions[first * ACTION_DIM..(first + 1) * ACTION_DIM];
            out.actions.extend_from_slice(a);
            let (last, ret, discount) = self.n_step_return(first, returns);
            let (s, e) = self.stored(self.next_id[last]);
            self.codec.decode(s, e, &mut out.next_obs);
            out.rewards.push(ret);
            out.discounts.push(discount);
            out.terminated.push(if self.terminated[last] { 1.0 } else { 0.0 });
            out.demonstrated.push(if self.demonstrated[first] { 1.0 } else { 0.0 });
        }
    }

    /// From the transition at ring position `first`: the position of the last step summed,
    /// Σ γ^i r_t+i over the steps summed, and γ^k for the k steps summed. The sum stops at
    /// `returns.n` steps, at a termination, or where no continuing step is stored.
    fn n_step_return(&self, first: usize, returns: Returns) -> (usize, f32, f32) {
        let (mut j, mut ret, mut discount) = (first, 0.0f32, 1.0f32);
        for k in 1..=returns.n {
            ret += discount * self.rewards[j];
            discount *= returns.gamma;
            let successor = self.successor[j] as usize;
            if k == returns.n || self.terminated[j] || successor == 0 {
                break;
            }
            j = (j + successor) % self.capacity;
        }
        (j, ret, discount)
    }

    /// The `i`-th oldest transition as (obs, action, reward, next_obs, terminated), decoded.
    pub fn get(&self, i: usize) -> (Vec<f32>, [f32; ACTION_DIM], f32, Vec<f32>, bool) {
        assert!(i < self.len, "transition {i} of {}", self.len);
        let j = self.position(i);
        let (mut o, mut no) = (Vec::new(), Vec::new());
        let (s, e) = self.stored(self.obs_id[j]);
        self.codec.decode(s, e, &mut o);
        let (s, e) = self.stored(self.next_id[j]);
        self.codec.decode(s, e, &mut no);
        let a = [self.actions[j * ACTION_DIM], self.actions[j * ACTION_DIM + 1]];
        (o, a, self.rewards[j], no, self.terminated[j])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Transitions `start..start + n` of one stream of 5-step episodes: `obs` of a step is the
    /// previous step's `next_obs` inside an episode. Observation `[x; 3]` for step x; rewards
    /// are x; every third step's action is a controller's (weight version 0).
    fn stream(start: usize, n: usize) -> TransitionBatch {
        let mut b = TransitionBatch::with_capacity(3, n);
        for i in start..start + n {
            let x = i as f32;
            let last = i % 5 == 4;
            let next = if last { [x + 0.5; 3] } else { [x + 1.0; 3] };
            let version = if i % 3 == 0 { 0 } else { 1 };
            b.push(&[x; 3], [0.1, -0.1], x, &next, last && i % 2 == 0, last && i % 2 == 1, version);
        }
        b
    }

    fn rewards(r: &ReplayBuffer) -> Vec<f32> {
        (0..r.len()).map(|i| r.get(i).2).collect()
    }

    #[test]
    fn a_saved_buffer_samples_the_same_batches_and_continues_alike_after_loading() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("replay.safetensors");
        let codec = ObsCodec::new(3, 2, 100.0);
        let mut r = ReplayBuffer::new(codec, 8);
        r.insert(&stream(0, 11)); // wrapped
        r.save(&path).unwrap();
        let mut loaded = ReplayBuffer::load(&path, codec, 8).unwrap();
        assert!(ReplayBuffer::load(&path, codec, 9).is_err(), "another capacity is refused");
        assert!(ReplayBuffer::load(&path, ObsCodec::plain(3), 8).is_err(), "another layout");
        let (mut a, mut b) = (Batch::default(), Batch::default());
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for n in [1, 3] {
            let returns = Returns { n, gamma: 0.9 };
            r.sample_into(16, returns, &mut rng.clone(), &mut a);
            loaded.sample_into(16, returns, &mut rng, &mut b);
            assert_eq!(a, b, "{n}-step samples");
        }
        r.insert(&stream(11, 7));
        loaded.insert(&stream(11, 7));
        assert_eq!(rewards(&r), rewards(&loaded));
        assert_eq!(r.stored_observations(), loaded.stored_observations(), "pairing continued");
        for i in 0..r.len() {
            assert_eq!(r.get(i), loaded.get(i));
        }
    }

    /// A file saved before the `demonstrated` flags loads with every action the policy's.
    #[test]
    fn a_file_without_demonstration_flags_loads_as_the_policys_actions() {
        let dir = tempfile::tempdir().unwrap();
        let (path, old) = (dir.path().join("new.safetensors"), dir.path().join("old.safetensors"));
        let codec = ObsCodec::plain(3);
        let mut r = ReplayBuffer::new(codec, 8);
        r.insert(&stream(0, 6));
        r.save(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let kept: Vec<_> =
            st.tensors().into_iter().filter(|(name, _)| name != "demonstrated").collect();
        assert_eq!(kept.len() + 1, st.len());
        safetensors::tensor::serialize_to_file(kept, header.metadata().clone(), &old).unwrap();
        let loaded = ReplayBuffer::load(&old, codec, 8).unwrap();
        let mut b = Batch::default();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        loaded.sample_into(32, Returns { n: 1, gamma: 0.9 }, &mut rng, &mut b);
        assert_eq!(b.demonstrated, vec![0.0; 32]);
        ReplayBuffer::load(&path, codec, 8).unwrap().sample_into(
            32,
            Returns { n: 1, gamma: 0.9 },
            &mut rng,
            &mut b,
        );
        assert!(b.demonstrated.contains(&1.0), "the new file keeps them");
    }

    #[test]
    fn keeps_the_newest_transitions_when_full() {
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 4);
        r.insert(&stream(0, 3));
        r.insert(&stream(3, 3));
        assert_eq!(r.len(), 4);
        assert_eq!(rewards(&r), vec![2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn samples_are_whole_transitions() {
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 10);
        r.insert(&stream(0, 10));
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        let mut b = Batch::default();
        r.sample_into(64, Returns { n: 1, gamma: 0.9 }, &mut rng, &mut b);
        assert_eq!(b.obs.len(), 192);
        assert_eq!(b.discounts, vec![0.9; 64]);
        for i in 0..64 {
            let x = b.rewards[i];
            let ends = (x as usize) % 5 == 4;
            assert_eq!(b.obs[i * 3], x);
            assert_eq!(b.next_obs[i * 3 + 2], if ends { x + 0.5 } else { x + 1.0 });
            let term = ends && (x as usize).is_multiple_of(2);
            assert_eq!(b.terminated[i], if term { 1.0 } else { 0.0 });
            let demonstrated = (x as usize).is_multiple_of(3);
            assert_eq!(b.demonstrated[i], if demonstrated { 1.0 } else { 0.0 });
        }
    }

    /// The k-step return of step `x` of [`stream`] at γ = 0.5: k, Σ 0.5^i (x + i), and the
    /// next observation's first value.
    fn expected_return(x: usize, n: usize, batch_end: usize) -> (usize, f32, f32) {
        let episode_left = 5 - x % 5;
        let k = n.min(episode_left).min(batch_end - x);
        let ret = (0..k).map(|i| 0.5f32.powi(i as i32) * (x + i) as f32).sum();
        let last = x + k - 1;
        let next = if last % 5 == 4 { last as f32 + 0.5 } else { last as f32 + 1.0 };
        (k, ret, next)
    }

    #[test]
    fn n_step_samples_sum_their_episodes_rewards_up_to_its_end_or_the_batchs() {
        // Episodes of 5 steps; the first batch ends inside the third episode (step 12).
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 100);
        r.insert(&stream(0, 13));
        r.insert(&stream(13, 12));
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let mut b = Batch::default();
        let mut seen = std::collections::BTreeSet::new();
        r.sample_into(400, Returns { n: 3, gamma: 0.5 }, &mut rng, &mut b);
        for i in 0..b.size {
            let x = b.obs[i * 3] as usize;
            let (k, ret, next) = expected_return(x, 3, if x < 13 { 13 } else { 25 });
            assert!((b.rewards[i] - ret).abs() < 1e-5, "step {x}: {} vs {ret}", b.rewards[i]);
            assert_eq!(b.discounts[i], 0.5f32.powi(k as i32), "step {x}");
            assert_eq!(b.next_obs[i * 3], next, "step {x}");
            let last = x + k - 1;
            let terminated = last % 5 == 4 && last.is_multiple_of(2);
            assert_eq!(b.terminated[i], if terminated { 1.0 } else { 0.0 }, "step {x}");
            assert_eq!(b.actions[2 * i..2 * i + 2], [0.1, -0.1]);
            seen.insert(x);
        }
        assert_eq!(seen.len(), 25, "every step sampled");
        // Spot checks of the rule: a whole 3-step return, one cut by a termination (step 4
        // is the episode's last), one cut by the batch's end (12 is the first batch's last).
        assert_eq!(expected_return(0, 3, 13), (3, 0.0 + 0.5 + 0.5, 3.0));
        assert_eq!(expected_return(3, 3, 13).0, 2);
        assert_eq!(expected_return(12, 3, 13).0, 1);
    }

    #[test]
    fn a_continuing_step_reuses_the_stored_observation() {
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 1000);
        r.insert(&stream(0, 100));
        // 100 transitions in 20 episodes: one observation per step plus one per episode end.
        assert_eq!(r.stored_observations(), 120);
        // Two interleaved streams (two environments of one actor) pair as well.
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 1000);
        let (a, b) = (stream(0, 50), stream(1000, 50));
        let mut both = TransitionBatch::with_capacity(3, 100);
        for i in 0..50 {
            for s in [&a, &b] {
                let o = &s.observations[i * 3..i * 3 + 3];
                let no = s.next_obs(i);
                let act = [s.actions[2 * i], s.actions[2 * i + 1]];
                both.push(o, act, s.rewards[i], no, s.terminated[i], s.truncated[i], 1);
            }
        }
        r.insert(&both);
        assert_eq!(r.stored_observations(), 120);
        for i in 0..r.len() {
            let (o, _, x, no, _) = r.get(i);
            assert_eq!(o[0], x);
            assert!(no[0] == x + 1.0 || no[0] == x + 0.5);
        }
    }

    #[test]
    fn an_unpaired_stream_drops_old_transitions_but_never_an_observation_in_use() {
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 4000);
        let mut b = TransitionBatch::with_capacity(3, 10_000);
        for i in 0..10_000 {
            let x = i as f32;
            b.push(&[x; 3], [0.0, 0.0], x, &[-x; 3], false, false, 1);
        }
        r.insert(&b);
        assert!(r.stored_observations() <= r.obs_capacity);
        assert!(r.len() >= r.obs_capacity / 2 - 1 && r.len() < 4000, "{}", r.len());
        for i in 0..r.len() {
            let (o, _, x, no, _) = r.get(i);
            assert_eq!((o[0], no[0]), (x, -x));
        }
        assert_eq!(r.get(r.len() - 1).2, 9999.0);
    }

    /// Many environments interleaved (a step's next observation is 300 rows later), episode
    /// ends, batch boundaries, and more observations per batch than the store holds: every
    /// transition kept is whole, and the newest `capacity` are kept.
    #[test]
    fn interleaved_batches_pair_by_position_and_keep_every_transition_whole() {
        use dvnav_link::core::BatchWriter;
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 100);
        let mut w = BatchWriter::new(3, 3000);
        // Environment e at time t observes [e, t, 0]; its episodes end every 4 steps.
        let envs = 300;
        for e in 0..envs {
            w.add_first(e, &[e as f32, 0.0, 0.0]).unwrap();
        }
        for round in 0..2 {
            for t in 0..10 {
                for e in 0..envs {
                    let t = (round * 10 + t) as f32;
                    let end = t as usize % 4 == 3;
                    w.add(e, [0.0, 0.0], t, &[e as f32, t + 1.0, 0.0], end, false, 1).unwrap();
                    if end {
                        w.add_first(e, &[e as f32, t + 1.0, 0.0]).unwrap();
                    }
                }
            }
            let b = w.take();
            assert!(b.stored_observations() > r.obs_capacity, "{}", b.stored_observations());
            r.insert(&b);
        }
        assert_eq!(r.len(), 100);
        assert!(r.stored_observations() <= r.obs_capacity);
        for i in 0..r.len() {
            let (o, _, t, no, _) = r.get(i);
            assert_eq!((o[0], o[1]), (no[0], t), "transition {i}");
            assert_eq!(no[1], t + 1.0, "transition {i}");
        }
        assert_eq!(r.get(99).2, 19.0);
    }

    #[test]
    fn the_papers_buffer_fits_well_under_two_gib() {
        let cfg = dvnav_config::Config::default();
        let codec = ObsCodec::for_config(&cfg);
        let r = ReplayBuffer::new(codec, 500_000);
        // Observation ids, successor, action, reward, terminated.
        let per_transition = 2 * 8 + 4 + ACTION_DIM * 4 + 4 + 1;
        let bytes = r.obs_capacity * codec.bytes_per_obs() + 500_000 * per_transition;
        assert!(bytes < 700 << 20, "{} MiB", bytes >> 20);
    }

    /// `Vec`'s doubling would take the store to twice the observations it can ever hold; it
    /// stops at `obs_capacity`.
    #[test]
    fn the_observation_store_never_grows_past_its_capacity() {
        let mut r = ReplayBuffer::new(ObsCodec::plain(3), 3000);
        let mut b = TransitionBatch::with_capacity(3, 10_000);
        for i in 0..10_000 {
            let x = i as f32;
            b.push(&[x; 3], [0.0, 0.0], x, &[-x; 3], false, false, 1);
        }
        r.insert(&b);
        assert_eq!(r.stored_observations(), r.obs_capacity);
        let held = r.scans.capacity() + r.extras.capacity();
        assert!(held <= r.obs_capacity * 3, "{held} values for {} observations", r.obs_capacity);
    }
}
