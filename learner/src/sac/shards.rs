//! Data-parallel SAC updates on a CPU: the minibatch is cut into row shards, each shard's losses
//! are its share of the whole batch's losses, and the shards run side by side on the learner's
//! own worker threads. Every loss is a mean over the batch, so with shard `s` of `n_s` rows
//! weighted by `n_s / n`, the shards' gradients add up to the whole batch's gradient (the same
//! update up to float rounding); terms of the batch as a whole (the policy's L2) go to the first
//! shard only.
//!
//! The critics' update cuts finer: the twin critics are independent networks, so each critic on
//! each row group ([`twin_groups`]: pairs of shards, up to [`MAX_GROUP_ROWS`] rows) is a job of
//! its own, and on two workers each runs one whole critic over the batch instead of both
//! critics over half of it.
//!
//! Why not candle's own threads: they split each tensor operation, and an update is thousands of
//! small ones, so they synchronize thousands of times per update (with spin barriers in candle
//! 0.11), and more threads made an update slower (docs/results.md, "Learner threads"). A shard is
//! one whole forward and backward pass: a few synchronizations per update (the passes, then the
//! optimizers' per-variable steps, [`Workers::for_each`]), and workers that block rather than
//! spin between updates, so they leave a busy machine's cores to its actors.

use crate::replay::Batch;
use candle_core::backprop::GradStore;
use candle_core::{Device, Result, Tensor, Var};
use rayon::prelude::*;

/// Fewest rows a shard gets: below this a pass is all per-operation overhead.
pub const MIN_SHARD_ROWS: usize = 16;

/// One shard's rows of a minibatch and of its policy noise, as tensors.
pub struct Shard {
    /// `(rows, obs_dim)`.
    pub obs: Tensor,
    /// `(rows, obs_dim)`.
    pub next_obs: Tensor,
    /// `(rows, action_dim)`.
    pub actions: Tensor,
    /// `(rows,)`.
    pub rewards: Tensor,
    /// `(rows,)`: γ^k of each row's bootstrap.
    pub discounts: Tensor,
    /// `(rows,)`.
    pub terminated: Tensor,
    /// `(rows,)`: 1 where a controller chose the action ([`Batch::demonstrated`]).
    pub demonstrated: Tensor,
    /// ε for the next observations, `(rows, action_dim)`.
    pub eps_next: Tensor,
    /// ε for the current observations, `(rows, action_dim)`.
    pub eps_pi: Tensor,
    /// rows / batch rows: the weight of this shard's means in the batch's.
    pub share: f64,
    /// The first shard carries the terms of the batch as a whole.
    pub first: bool,
}

/// The policy's sampling noise ε of one update, `(batch, action_dim)` each, row-major.
#[derive(Clone, Copy, Debug)]
pub struct Noise<'a> {
    /// ε for the next observations.
    pub next: &'a [f32],
    /// ε for the current observations.
    pub current: &'a [f32],
}

/// Cuts `batch` and `noise` into `shards` shards of consecutive rows, sizes differing by at most
/// one (fewer shards when the batch is too small for [`MIN_SHARD_ROWS`] each).
pub fn split(
    batch: &Batch,
    noise: Noise,
    action_dim: usize,
    shards: usize,
    dev: &Device,
) -> Result<Vec<Shard>> {
    let b = batch.size;
    let d = batch.obs_dim;
    let n = shards.min(b / MIN_SHARD_ROWS).max(1);
    let bounds = |s: usize| (s * b / n, (s + 1) * b / n);
    (0..n)
        .map(|s| {
            let (lo, hi) = bounds(s);
            let r = hi - lo;
            let rows = |v: &[f32], width: usize| {
                Tensor::from_slice(&v[lo * width..hi * width], (r, width), dev)
            };
            let column = |v: &[f32]| Tensor::from_slice(&v[lo..hi], r, dev);
            Ok(Shard {
                obs: rows(&batch.obs, d)?,
                next_obs: rows(&batch.next_obs, d)?,
                actions: rows(&batch.actions, action_dim)?,
                rewards: column(&batch.rewards)?,
                discounts: column(&batch.discounts)?,
                terminated: column(&batch.terminated)?,
                demonstrated: column(&batch.demonstrated)?,
                eps_next: rows(noise.next, action_dim)?,
                eps_pi: rows(noise.current, action_dim)?,
                share: r as f64 / b as f64,
                first: s == 0,
            })
        })
        .collect()
}

/// Row groups the critics' update is cut into for `shards` row shards ([`split`] with this
/// count gives groups of whole consecutive shards): each critic of the twin pair is a job of
/// its own on every group, so half as many groups as shards keep an even number of workers
/// busy with whole networks; an odd number keeps a group per shard.
pub fn twin_groups(shards: usize, rows: usize) -> usize {
    let halved = shards.is_multiple_of(2) && rows / (shards / 2) <= MAX_GROUP_ROWS;
    if halved { shards / 2 } else { shards }
}

/// Most rows a twin group gets when it joins two shards.
pub const MAX_GROUP_ROWS: usize = 128;

/// The shards' rows of `(actions, log_probs)`-like pairs joined into `groups` groups of
/// consecutive shards, as [`twin_groups`] cuts them.
pub fn join_rows(parts: Vec<(Tensor, Tensor)>, groups: usize) -> Result<Vec<(Tensor, Tensor)>> {
    if groups == 0 || !parts.len().is_multiple_of(groups) {
        candle_core::bail!("{} row shards do not make {groups} equal groups", parts.len());
    }
    if groups == parts.len() {
        return Ok(parts);
    }
    parts
        .chunks(parts.len() / groups)
        .map(|chunk| {
            let (a, b): (Vec<Tensor>, Vec<Tensor>) = chunk.iter().cloned().unzip();
            Ok((Tensor::cat(&a, 0)?, Tensor::cat(&b, 0)?))
        })
        .collect()
}

/// The learner's worker threads: one blocking rayon pool of its own, or none for one thread.
pub struct Workers {
    pool: Option<rayon::ThreadPool>,
    threads: usize,
}

impl Workers {
    /// `threads` workers; 0 means one per available core.
    pub fn new(threads: usize) -> Result<Self> {
        let threads = match threads {
            0 => std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            n => n,
        };
        let pool = if threads > 1 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(|i| format!("dvnav-learner-{i}"))
                .start_handler(|_| {
                    crate::denormals::flush_denormals_to_zero();
                })
                .build()
                .map_err(|e| candle_core::Error::Msg(format!("learner worker threads: {e}")))?;
            Some(pool)
        } else {
            None
        };
        Ok(Self { pool, threads })
    }

    /// No worker threads: everything on the calling thread.
    pub fn sequential() -> Self {
        Self { pool: None, threads: 1 }
    }

    /// Threads an update is spread over.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// `f` on every shard, side by side on the workers; results in shard order.
    pub fn map<T: Send>(
        &self,
        shards: &[Shard],
        f: impl Fn(&Shard) -> Result<T> + Sync,
    ) -> Result<Vec<T>> {
        match &self.pool {
            Some(pool) if shards.len() > 1 => pool.install(|| shards.par_iter().map(&f).collect()),
            _ => shards.iter().map(f).collect(),
        }
    }
}

impl Workers {
    /// `f(i)` for every `i` in `0..n`, side by side on the workers, each index a job of its
    /// own; results in index order.
    pub fn run<T: Send>(&self, n: usize, f: impl Fn(usize) -> Result<T> + Sync) -> Result<Vec<T>> {
        match &self.pool {
            Some(pool) if n > 1 => {
                pool.install(|| (0..n).into_par_iter().with_max_len(1).map(&f).collect())
            }
            _ => (0..n).map(f).collect(),
        }
    }

    /// `f(i)` for every `i` in `0..n`, side by side on the workers, each index a job of its
    /// own (the jobs are per-variable optimizer steps of very different sizes); stops at the
    /// first error.
    pub fn for_each(&self, n: usize, f: impl Fn(usize) -> Result<()> + Sync) -> Result<()> {
        match &self.pool {
            Some(pool) if n > 1 => {
                pool.install(|| (0..n).into_par_iter().with_max_len(1).try_for_each(&f))
            }
            _ => (0..n).try_for_each(f),
        }
    }
}

/// The shards' gradients of `vars` added up, in shard order (deterministic for a given number of
/// shards), in the first shard's store.
pub fn sum_grads<'a>(
    mut stores: Vec<GradStore>,
    vars: impl Iterator<Item = &'a Var> + Clone,
) -> Result<GradStore> {
    if stores.is_empty() {
        candle_core::bail!("no gradients to add up");
    }
    let sums = vars
        .map(|var| Ok((var, grad_sum(&stores, var.as_tensor())?)))
        .collect::<Result<Vec<_>>>()?;
    let mut total = stores.swap_remove(0);
    for (var, sum) in sums {
        if let Some(sum) = sum {
            total.insert(var.as_tensor(), sum);
        }
    }
    Ok(total)
}

/// The shards' gradients of one variable added up in shard order (the same sum, bit for bit,
/// whichever thread computes it); `None` when no shard reached the variable.
pub fn grad_sum(stores: &[GradStore], var: &Tensor) -> Result<Option<Tensor>> {
    let mut parts = stores.iter().filter_map(|store| store.get(var));
    let Some(first) = parts.next() else { return Ok(None) };
    let mut sum = first.clone();
    for part in parts {
        sum = (sum + part)?;
    }
    Ok(Some(sum))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct UpdateNoise {
        next: Vec<f32>,
        current: Vec<f32>,
    }

    impl UpdateNoise {
        fn view(&self) -> Noise<'_> {
            Noise { next: &self.next, current: &self.current }
        }
    }

    fn batch(n: usize, d: usize) -> (Batch, UpdateNoise) {
        let b = Batch {
            size: n,
            obs_dim: d,
            obs: (0..n * d).map(|i| i as f32).collect(),
            actions: (0..n * 2).map(|i| -(i as f32)).collect(),
            rewards: (0..n).map(|i| i as f32 * 0.5).collect(),
            next_obs: (0..n * d).map(|i| 1000.0 + i as f32).collect(),
            discounts: (0..n).map(|i| 0.9 + i as f32 * 0.001).collect(),
            terminated: (0..n).map(|i| (i % 2) as f32).collect(),
            demonstrated: vec![0.0; n],
        };
        let noise = UpdateNoise {
            next: (0..n * 2).map(|i| i as f32 * 0.1).collect(),
            current: (0..n * 2).map(|i| i as f32 * -0.1).collect(),
        };
        (b, noise)
    }

    #[test]
    fn shards_cover_every_row_once_in_order_with_their_shares() {
        let (b, noise) = batch(50, 3);
        let shards = split(&b, noise.view(), 2, 3, &Device::Cpu).unwrap();
        assert_eq!(shards.len(), 3);
        let rows: Vec<usize> = shards.iter().map(|s| s.rewards.dim(0).unwrap()).collect();
        assert_eq!(rows, vec![16, 17, 17]);
        let shares: f64 = shards.iter().map(|s| s.share).sum();
        assert!((shares - 1.0).abs() < 1e-12);
        assert_eq!(shards.iter().filter(|s| s.first).count(), 1);
        let cat = |f: fn(&Shard) -> &Tensor| {
            let parts: Vec<Tensor> = shards.iter().map(|s| f(s).clone()).collect();
            Tensor::cat(&parts, 0).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()
        };
        assert_eq!(cat(|s| &s.obs), b.obs);
        assert_eq!(cat(|s| &s.next_obs), b.next_obs);
        assert_eq!(cat(|s| &s.actions), b.actions);
        assert_eq!(cat(|s| &s.rewards), b.rewards);
        assert_eq!(cat(|s| &s.terminated), b.terminated);
        assert_eq!(cat(|s| &s.discounts), b.discounts);
        assert_eq!(cat(|s| &s.eps_next), noise.next);
        assert_eq!(cat(|s| &s.eps_pi), noise.current);
    }

    #[test]
    fn a_small_batch_gets_fewer_shards() {
        let (b, noise) = batch(40, 3);
        assert_eq!(split(&b, noise.view(), 2, 8, &Device::Cpu).unwrap().len(), 2);
        let (b, noise) = batch(10, 3);
        assert_eq!(split(&b, noise.view(), 2, 8, &Device::Cpu).unwrap().len(), 1);
    }

    #[test]
    fn twin_groups_join_pairs_of_shards_up_to_the_row_cap() {
        assert_eq!(twin_groups(1, 128), 1);
        assert_eq!(twin_groups(2, 128), 1);
        assert_eq!(twin_groups(3, 128), 3);
        assert_eq!(twin_groups(4, 128), 2);
        // Two shards of 128 rows stay two groups: a whole batch of 256 per job ran slower.
        assert_eq!(twin_groups(2, 256), 2);
        assert_eq!(twin_groups(4, 256), 2);
    }

    #[test]
    fn joined_rows_are_the_groups_rows_in_order() {
        let (b, noise) = batch(64, 3);
        let shards = split(&b, noise.view(), 2, 4, &Device::Cpu).unwrap();
        let groups = split(&b, noise.view(), 2, twin_groups(4, 64), &Device::Cpu).unwrap();
        assert_eq!(groups.len(), 2);
        let parts = shards.iter().map(|s| (s.actions.clone(), s.rewards.clone())).collect();
        let joined = join_rows(parts, groups.len()).unwrap();
        for ((actions, rewards), g) in joined.iter().zip(&groups) {
            let v = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert_eq!(v(actions), v(&g.actions));
            assert_eq!(v(rewards), v(&g.rewards));
        }
        let parts: Vec<_> = shards.iter().map(|s| (s.actions.clone(), s.rewards.clone())).collect();
        assert!(join_rows(parts, 3).unwrap_err().to_string().contains("4 row shards"));
    }

    #[test]
    fn gradients_add_up_per_variable() {
        let w = Var::new(&[1f32, 2.0], &Device::Cpu).unwrap();
        let grads = |k: f64| (w.as_tensor() * k).unwrap().sum_all().unwrap().backward().unwrap();
        let total = sum_grads(vec![grads(1.0), grads(2.0), grads(0.5)], [&w].into_iter()).unwrap();
        let g = total.get(w.as_tensor()).unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(g, vec![3.5, 3.5]);
    }

    #[test]
    fn workers_return_results_in_shard_order() {
        let (b, noise) = batch(64, 3);
        let shards = split(&b, noise.view(), 2, 4, &Device::Cpu).unwrap();
        let workers = Workers::new(2).unwrap();
        assert_eq!(workers.threads(), 2);
        let first: Vec<f32> = workers.map(&shards, |s| Ok(s.rewards.to_vec1::<f32>()?[0])).unwrap();
        assert_eq!(first, vec![0.0, 8.0, 16.0, 24.0]);
        let squares = workers.run(9, |i| Ok(i * i)).unwrap();
        assert_eq!(squares, (0..9).map(|i| i * i).collect::<Vec<_>>());
        assert!(Workers::new(0).unwrap().threads() >= 1);
        let hits: Vec<std::sync::atomic::AtomicUsize> =
            (0..37).map(|_| Default::default()).collect();
        for w in [workers, Workers::sequential()] {
            w.for_each(hits.len(), |i| {
                hits[i].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                Ok(())
            })
            .unwrap();
        }
        assert!(hits.iter().all(|h| h.load(std::sync::atomic::Ordering::Relaxed) == 2));
        let err = Workers::new(2)
            .unwrap()
            .for_each(8, |i| if i == 5 { candle_core::bail!("job {i}") } else { Ok(()) });
        assert!(err.unwrap_err().to_string().contains("job 5"));
    }
}
