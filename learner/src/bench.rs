//! Learner benchmarks behind `dvnav bench learner`: SAC updates per second on random data of
//! the real observation shape, and policy inference latency.

use crate::replay::{Batch, ReplayBuffer};
use crate::sac::{SacLearner, SacNetworks};
use candle_core::{Device, Tensor};
use dvnav_common::config::Config;
use dvnav_common::core::TransitionBatch;
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::time::Instant;

/// Result of [`sac_updates`].
#[derive(Clone, Debug, Serialize)]
pub struct LearnerBench {
    /// SAC updates per second (critics every update, policy every `policy_delay`).
    pub sac_updates_per_s: f64,
    /// Mean milliseconds per update.
    pub ms_per_update: f64,
    /// Minibatch size.
    pub batch: usize,
    /// Threads candle may use.
    pub threads: usize,
    /// Device name.
    pub device: String,
    /// Network description.
    pub network: String,
    /// Updates timed.
    pub updates: usize,
    /// Policy inference latency at batch 1 (ms, mean).
    pub inference_ms_batch1: f64,
    /// Policy inference latency at batch 64 (ms, mean).
    pub inference_ms_batch64: f64,
}

fn random_replay(cfg: &Config, n: usize, rng: &mut impl Rng) -> ReplayBuffer {
    let d = cfg.obs_dim();
    let mut replay = ReplayBuffer::new(d, n);
    let mut b = TransitionBatch::with_capacity(d, n);
    let mut o = vec![0f32; d];
    let mut o2 = vec![0f32; d];
    for _ in 0..n {
        for x in o.iter_mut().chain(o2.iter_mut()) {
            *x = rng.random_range(0.1..10.0);
        }
        let a = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
        b.push(&o, a, rng.random_range(-1.0..1.0), &o2, rng.random_bool(0.05), false, 1);
    }
    replay.insert(&b);
    replay
}

/// Times `updates` SAC updates at `batch` after `warmup` untimed ones.
pub fn sac_updates(
    cfg: &Config,
    batch: usize,
    warmup: usize,
    updates: usize,
) -> anyhow::Result<LearnerBench> {
    let dev = Device::Cpu;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let replay = random_replay(cfg, 4 * batch, &mut rng);
    let nets = SacNetworks::new(cfg, 0, &dev)?;
    let mut learner = SacLearner::new(nets, cfg.sac.clone(), dev.clone(), 0)?;
    let mut b = Batch::default();
    for _ in 0..warmup {
        replay.sample_into(batch, &mut rng, &mut b);
        learner.update(&b)?;
    }
    let t = Instant::now();
    for _ in 0..updates {
        replay.sample_into(batch, &mut rng, &mut b);
        learner.update(&b)?;
    }
    let secs = t.elapsed().as_secs_f64();

    let latency = |n: usize| -> anyhow::Result<f64> {
        let obs = Tensor::rand(0.1f32, 10.0, (n, cfg.obs_dim()), &dev)?;
        let actor = &learner.nets.actor.net;
        actor.deterministic(&obs)?;
        let reps = 50;
        let t = Instant::now();
        for _ in 0..reps {
            actor.sample(&obs)?;
        }
        Ok(t.elapsed().as_secs_f64() * 1e3 / reps as f64)
    };
    let n = &cfg.network;
    Ok(LearnerBench {
        sac_updates_per_s: updates as f64 / secs,
        ms_per_update: secs * 1e3 / updates as f64,
        batch,
        threads: std::env::var("CANDLE_NUM_THREADS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(candle_core::utils::get_num_threads),
        device: "cpu".into(),
        network: format!(
            "conv({}x{}/{})-conv({}x{}/{})-fc{}-fc{}x2",
            n.conv1_channels,
            n.conv1_kernel,
            n.conv1_stride,
            n.conv2_channels,
            n.conv2_kernel,
            n.conv2_stride,
            n.scan_features,
            n.hidden
        ),
        updates,
        inference_ms_batch1: latency(1)?,
        inference_ms_batch64: latency(64)?,
    })
}
