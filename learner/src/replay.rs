//! The replay buffer: a ring of transitions in structure-of-arrays layout, sampled uniformly.

use dvnav_common::core::TransitionBatch;
use dvnav_common::obs::ACTION_DIM;
use rand::Rng;

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
    /// `size`.
    pub rewards: Vec<f32>,
    /// `size × obs_dim`.
    pub next_obs: Vec<f32>,
    /// `size`, 1.0 where the episode terminated (success or collision), else 0.0. A timeout is
    /// not a termination: its target bootstraps from `next_obs`.
    pub terminated: Vec<f32>,
}

/// Fixed-capacity FIFO of transitions.
#[derive(Debug)]
pub struct ReplayBuffer {
    obs_dim: usize,
    capacity: usize,
    obs: Vec<f32>,
    next_obs: Vec<f32>,
    actions: Vec<f32>,
    rewards: Vec<f32>,
    terminated: Vec<bool>,
    len: usize,
    next: usize,
}

impl ReplayBuffer {
    /// An empty buffer for `capacity` transitions of `obs_dim`-long observations. Memory grows
    /// with use, up to the capacity.
    pub fn new(obs_dim: usize, capacity: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self {
            obs_dim,
            capacity,
            obs: Vec::new(),
            next_obs: Vec::new(),
            actions: Vec::new(),
            rewards: Vec::new(),
            terminated: Vec::new(),
            len: 0,
            next: 0,
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

    /// Appends every transition of a validated batch, overwriting the oldest when full.
    pub fn insert(&mut self, batch: &TransitionBatch) {
        assert_eq!(batch.obs_dim, self.obs_dim, "batch observation size");
        let d = self.obs_dim;
        for i in 0..batch.len() {
            let o = &batch.observations[i * d..(i + 1) * d];
            let no = &batch.next_observations[i * d..(i + 1) * d];
            let a = &batch.actions[i * ACTION_DIM..(i + 1) * ACTION_DIM];
            if self.len < self.capacity && self.next == self.len {
                self.obs.extend_from_slice(o);
                self.next_obs.extend_from_slice(no);
                self.actions.extend_from_slice(a);
                self.rewards.push(batch.rewards[i]);
                self.terminated.push(batch.terminated[i]);
                self.len += 1;
            } else {
                let j = self.next;
                self.obs[j * d..(j + 1) * d].copy_from_slice(o);
                self.next_obs[j * d..(j + 1) * d].copy_from_slice(no);
                self.actions[j * ACTION_DIM..(j + 1) * ACTION_DIM].copy_from_slice(a);
                self.rewards[j] = batch.rewards[i];
                self.terminated[j] = batch.terminated[i];
            }
            self.next = (self.next + 1) % self.capacity;
        }
    }

    /// Samples `size` transitions uniformly with replacement into `out` (reusing its memory).
    pub fn sample_into(&self, size: usize, rng: &mut impl Rng, out: &mut Batch) {
        assert!(!self.is_empty(), "sampling an empty replay buffer");
        let d = self.obs_dim;
        out.size = size;
        out.obs_dim = d;
        out.obs.clear();
        out.next_obs.clear();
        out.actions.clear();
        out.rewards.clear();
        out.terminated.clear();
        for _ in 0..size {
            let j = rng.random_range(0..self.len);
            out.obs.extend_from_slice(&self.obs[j * d..(j + 1) * d]);
            out.next_obs.extend_from_slice(&self.next_obs[j * d..(j + 1) * d]);
            out.actions.extend_from_slice(&self.actions[j * ACTION_DIM..(j + 1) * ACTION_DIM]);
            out.rewards.push(self.rewards[j]);
            out.terminated.push(if self.terminated[j] { 1.0 } else { 0.0 });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn batch(start: usize, n: usize) -> TransitionBatch {
        let mut b = TransitionBatch::with_capacity(3, n);
        for i in start..start + n {
            let x = i as f32;
            b.push(&[x; 3], [0.1, -0.1], x, &[x + 0.5; 3], i % 2 == 0, false, 1);
        }
        b
    }

    #[test]
    fn keeps_the_newest_transitions_when_full() {
        let mut r = ReplayBuffer::new(3, 4);
        r.insert(&batch(0, 3));
        r.insert(&batch(3, 3));
        assert_eq!(r.len(), 4);
        let mut rewards = r.rewards.clone();
        rewards.sort_by(f32::total_cmp);
        assert_eq!(rewards, vec![2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn samples_are_whole_transitions() {
        let mut r = ReplayBuffer::new(3, 10);
        r.insert(&batch(0, 10));
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        let mut b = Batch::default();
        r.sample_into(32, &mut rng, &mut b);
        assert_eq!(b.obs.len(), 96);
        for i in 0..32 {
            let x = b.rewards[i];
            assert_eq!(b.obs[i * 3], x);
            assert_eq!(b.next_obs[i * 3 + 2], x + 0.5);
            assert_eq!(b.terminated[i], if (x as usize).is_multiple_of(2) { 1.0 } else { 0.0 });
        }
    }
}
