//! The replay buffer in a checkpoint (`replay.safetensors`, written when
//! `replay.save_in_checkpoint` is on): the stored observations oldest first, and the
//! transitions oldest first with the observations they refer to (which also says which step
//! continues which, for n-step returns). A restored buffer samples the
//! same transitions with the same generator and stores and evicts the next arrivals as the saved
//! one would have.
//!
//! The format is unchanged since the buffer paired observations by hash: its `pending` array
//! (the unclaimed `next_obs` awaiting their successor) is now written empty, and read (and
//! checked) but not used, since batches pair their own observations by position. Files of
//! either kind load. The `demonstrated` flags (which actions a controller chose) came later
//! and are optional: a file without them loads with every action the policy's.

use super::{ObsCodec, ReplayBuffer};
use dvnav_sim::obs::ACTION_DIM;
use safetensors::Dtype;
use std::collections::HashMap;
use std::path::Path;

/// Written into the file's metadata; a file of another layout is refused.
const FORMAT: &str = "dvnav-replay-2";

impl ReplayBuffer {
    /// Writes the buffer to `path`.
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let n_obs = self.stored_observations();
        let (s, e) = (self.codec.scan_len, self.codec.extra_len());
        let (mut scans, mut extras) =
            (Vec::with_capacity(n_obs * s), Vec::with_capacity(n_obs * e));
        for id in self.oldest_obs..self.next_obs_id {
            let (sc, ex) = self.stored(id);
            scans.extend_from_slice(sc);
            extras.extend_from_slice(ex);
        }
        let rel = |id: u64| id - self.oldest_obs;
        let order: Vec<usize> = (0..self.len).map(|i| self.position(i)).collect();
        let obs_id: Vec<u64> = order.iter().map(|&j| rel(self.obs_id[j])).collect();
        let next_id: Vec<u64> = order.iter().map(|&j| rel(self.next_id[j])).collect();
        let actions: Vec<f32> = order
            .iter()
            .flat_map(|&j| self.actions[j * ACTION_DIM..(j + 1) * ACTION_DIM].iter().copied())
            .collect();
        let rewards: Vec<f32> = order.iter().map(|&j| self.rewards[j]).collect();
        let terminated: Vec<u8> = order.iter().map(|&j| self.terminated[j] as u8).collect();
        let demonstrated: Vec<u8> = order.iter().map(|&j| self.demonstrated[j] as u8).collect();
        // Kept for the format (see the module docs).
        let pending: Vec<u64> = Vec::new();
        let n = self.len;
        let tensors = [
            ("actions", Slot::new(Dtype::F32, vec![n, ACTION_DIM], le(&actions))),
            ("demonstrated", Slot::new(Dtype::U8, vec![n], demonstrated)),
            ("extras", Slot::new(Dtype::F32, vec![n_obs, e], le(&extras))),
            ("next_id", Slot::new(Dtype::U64, vec![n], le(&next_id))),
            ("obs_id", Slot::new(Dtype::U64, vec![n], le(&obs_id))),
            ("pending", Slot::new(Dtype::U64, vec![pending.len()], le(&pending))),
            ("rewards", Slot::new(Dtype::F32, vec![n], le(&rewards))),
            ("scans", Slot::new(Dtype::U16, vec![n_obs, s], le(&scans))),
            ("terminated", Slot::new(Dtype::U8, vec![n], terminated)),
        ];
        let meta = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("capacity".to_string(), self.capacity.to_string()),
            ("codec".to_string(), codec_tag(&self.codec)),
        ]);
        safetensors::tensor::serialize_to_file(tensors, Some(meta), path)?;
        Ok(())
    }

    /// Reads a buffer written by [`Self::save`]; its capacity and observation layout must equal
    /// this run's (`capacity`, `codec`).
    pub fn load(path: &Path, codec: ObsCodec, capacity: usize) -> anyhow::Result<Self> {
        let at = path.display();
        let bytes = std::fs::read(path)?;
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)?;
        let meta = header.metadata().clone().unwrap_or_default();
        let get = |k: &str| meta.get(k).map(String::as_str).unwrap_or("");
        anyhow::ensure!(get("format") == FORMAT, "{at}: not a `{FORMAT}` replay file");
        anyhow::ensure!(
            get("capacity") == capacity.to_string(),
            "{at}: saved with capacity {}, this run has {capacity}",
            get("capacity")
        );
        anyhow::ensure!(
            get("codec") == codec_tag(&codec),
            "{at}: saved for observations `{}`, this run has `{}`",
            get("codec"),
            codec_tag(&codec)
        );
        let st = safetensors::SafeTensors::deserialize(&bytes)?;
        let read = |name: &str, dtype: Dtype| -> anyhow::Result<Vec<u8>> {
            let t = st.tensor(name)?;
            anyhow::ensure!(t.dtype() == dtype, "{at}: `{name}` is not {dtype:?}");
            Ok(t.data().to_vec())
        };
        let scans: Vec<u16> = from_le(&read("scans", Dtype::U16)?);
        let extras: Vec<f32> = from_le(&read("extras", Dtype::F32)?);
        let obs_id: Vec<u64> = from_le(&read("obs_id", Dtype::U64)?);
        let next_id: Vec<u64> = from_le(&read("next_id", Dtype::U64)?);
        let pending: Vec<u64> = from_le(&read("pending", Dtype::U64)?);
        let actions: Vec<f32> = from_le(&read("actions", Dtype::F32)?);
        let rewards: Vec<f32> = from_le(&read("rewards", Dtype::F32)?);
        let terminated = read("terminated", Dtype::U8)?;
        let demonstrated = match st.names().contains(&"demonstrated") {
            true => read("demonstrated", Dtype::U8)?,
            false => vec![0; rewards.len()],
        };

        let (s, e, n) = (codec.scan_len, codec.extra_len(), rewards.len());
        let n_obs = scans.len().checked_div(s).unwrap_or(extras.len() / e.max(1));
        let mut buffer = Self::new(codec, capacity);
        anyhow::ensure!(
            scans.len() == n_obs * s
                && extras.len() == n_obs * e
                && n_obs <= buffer.obs_capacity
                && n <= capacity
                && obs_id.len() == n
                && next_id.len() == n
                && actions.len() == n * ACTION_DIM
                && terminated.len() == n
                && demonstrated.len() == n
                && obs_id.iter().chain(&next_id).chain(&pending).all(|&id| (id as usize) < n_obs),
            "{at}: inconsistent replay arrays"
        );
        for k in 0..n_obs {
            buffer.store_encoded(&scans[k * s..(k + 1) * s], &extras[k * e..(k + 1) * e]);
        }
        // The links between an episode's steps are not in the file: a transition's successor
        // is the later one whose observation is its next observation (ids are unique).
        let acting_from: HashMap<u64, usize> =
            obs_id.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        for i in 0..n {
            let successor = match acting_from.get(&next_id[i]) {
                Some(&j) if j > i => (j - i) as u32,
                _ => 0,
            };
            let step = super::Step {
                action: [actions[2 * i], actions[2 * i + 1]],
                reward: rewards[i],
                terminated: terminated[i] != 0,
                demonstrated: demonstrated[i] != 0,
            };
            buffer.push(obs_id[i], next_id[i], successor, step);
        }
        Ok(buffer)
    }
}

fn codec_tag(c: &ObsCodec) -> String {
    format!("obs_dim={} scan_len={} scale={:e}", c.obs_dim, c.scan_len, c.scale())
}

/// Little-endian bytes of plain numbers.
trait Le: Copy {
    const SIZE: usize;
    fn put(self, out: &mut Vec<u8>);
    fn get(b: &[u8]) -> Self;
}

macro_rules! le_impl {
    ($($t:ty),*) => {$(
        impl Le for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            fn put(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn get(b: &[u8]) -> Self {
                <$t>::from_le_bytes(b.try_into().expect("chunk of the type's size"))
            }
        }
    )*};
}
le_impl!(u16, u64, f32);

fn le<T: Le>(v: &[T]) -> Vec<u8> {
    let mut out = Vec::with_capacity(v.len() * T::SIZE);
    v.iter().for_each(|x| x.put(&mut out));
    out
}

fn from_le<T: Le>(b: &[u8]) -> Vec<T> {
    b.chunks_exact(T::SIZE).map(T::get).collect()
}

/// One array of [`ReplayBuffer::save`], as safetensors wants it.
struct Slot {
    dtype: Dtype,
    shape: Vec<usize>,
    bytes: Vec<u8>,
}

impl Slot {
    fn new(dtype: Dtype, shape: Vec<usize>, bytes: Vec<u8>) -> Self {
        Self { dtype, shape, bytes }
    }
}

impl safetensors::View for Slot {
    fn dtype(&self) -> Dtype {
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
