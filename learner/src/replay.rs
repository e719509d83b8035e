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

/// The replay buffer in a checkpoint (`replay.safetensors`, written when
/// `replay.save_in_checkpoint` is on): every slot in slot order, so that sampling after a
/// restore with the restored generator picks the same transitions; the slot written next and
/// the capacity are in the file's metadata.
impl ReplayBuffer {
    /// Writes the buffer to `path` (safetensors: `obs`, `next_obs`, `actions`, `rewards` as
    /// F32, `terminated` as U8), one array at a time.
    pub fn save(&self, path: &std::path::Path) -> anyhow::Result<()> {
        let n = self.len;
        let f32s = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let tensors = [
            (
                "actions",
                Slot::new(safetensors::Dtype::F32, vec![n, ACTION_DIM], f32s(&self.actions)),
            ),
            (
                "next_obs",
                Slot::new(safetensors::Dtype::F32, vec![n, self.obs_dim], f32s(&self.next_obs)),
            ),
            ("obs", Slot::new(safetensors::Dtype::F32, vec![n, self.obs_dim], f32s(&self.obs))),
            ("rewards", Slot::new(safetensors::Dtype::F32, vec![n], f32s(&self.rewards))),
            (
                "terminated",
                Slot::new(
                    safetensors::Dtype::U8,
                    vec![n],
                    self.terminated.iter().map(|&t| t as u8).collect(),
                ),
            ),
        ];
        let meta = std::collections::HashMap::from([
            ("next".to_string(), self.next.to_string()),
            ("capacity".to_string(), self.capacity.to_string()),
        ]);
        safetensors::tensor::serialize_to_file(tensors, Some(meta), path)?;
        Ok(())
    }

    /// Reads a buffer written by [`Self::save`]; its capacity and observation size must equal
    /// `capacity` and `obs_dim` (otherwise the slots would not line up).
    pub fn load(path: &std::path::Path, obs_dim: usize, capacity: usize) -> anyhow::Result<Self> {
        let bytes = std::fs::read(path)?;
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)?;
        let meta = header.metadata().clone().unwrap_or_default();
        let number = |k: &str| -> anyhow::Result<usize> {
            meta.get(k)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| anyhow::anyhow!("{}: no `{k}` in the metadata", path.display()))
        };
        let (next, saved_capacity) = (number("next")?, number("capacity")?);
        anyhow::ensure!(
            saved_capacity == capacity,
            "{}: saved with capacity {saved_capacity}, this run has {capacity}",
            path.display()
        );
        let st = safetensors::SafeTensors::deserialize(&bytes)?;
        let f32s = |name: &str, width: usize| -> anyhow::Result<Vec<f32>> {
            let t = st.tensor(name)?;
            anyhow::ensure!(t.dtype() == safetensors::Dtype::F32, "`{name}` is not F32");
            anyhow::ensure!(t.shape().iter().skip(1).product::<usize>() == width, "`{name}` width");
            Ok(t.data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        };
        let rewards = f32s("rewards", 1)?;
        let len = rewards.len();
        let buffer = Self {
            obs_dim,
            capacity,
            obs: f32s("obs", obs_dim)?,
            next_obs: f32s("next_obs", obs_dim)?,
            actions: f32s("actions", ACTION_DIM)?,
            rewards,
            terminated: st.tensor("terminated")?.data().iter().map(|&b| b != 0).collect(),
            len,
            next,
        };
        anyhow::ensure!(
            len <= capacity
                && next < capacity
                && buffer.obs.len() == len * obs_dim
                && buffer.next_obs.len() == len * obs_dim
                && buffer.actions.len() == len * ACTION_DIM
                && buffer.terminated.len() == len,
            "{}: inconsistent replay arrays",
            path.display()
        );
        Ok(buffer)
    }
}

/// One array of [`ReplayBuffer::save`], as safetensors wants it.
struct Slot {
    dtype: safetensors::Dtype,
    shape: Vec<usize>,
    bytes: Vec<u8>,
}

impl Slot {
    fn new(dtype: safetensors::Dtype, shape: Vec<usize>, bytes: Vec<u8>) -> Self {
        Self { dtype, shape, bytes }
    }
}

impl safetensors::View for Slot {
    fn dtype(&self) -> safetensors::Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> std::borrow::Cow<'_, [u8]> {
        std::borrow::Cow::Borrowed(&self.bytes)
    }
    fn data_len(&self) -> usize {
        self.bytes.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn a_saved_buffer_samples_the_same_batches_after_loading() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("replay.safetensors");
        let mut r = ReplayBuffer::new(3, 4);
        r.insert(&batch(0, 6)); // full, wrapped: the next write goes to slot 2
        r.save(&path).unwrap();
        let mut loaded = ReplayBuffer::load(&path, 3, 4).unwrap();
        assert!(ReplayBuffer::load(&path, 3, 5).is_err(), "another capacity is refused");
        let (mut a, mut b) = (Batch::default(), Batch::default());
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        r.sample_into(8, &mut rng.clone(), &mut a);
        loaded.sample_into(8, &mut rng, &mut b);
        assert_eq!(a, b);
        // And the next insert overwrites the same (oldest) slot.
        r.insert(&batch(6, 1));
        loaded.insert(&batch(6, 1));
        assert_eq!((r.rewards.clone(), r.next), (loaded.rewards.clone(), loaded.next));
    }

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
