//! Learner benchmarks behind `dvnav bench learner`: SAC updates per second on random data of
//! the real observation shape, their GFLOP/s against the CPU's measured matrix-product peak,
//! and policy inference latency.

pub mod flops;
pub mod peak;
pub mod precision;

use crate::replay::{Batch, ObsCodec, ReplayBuffer, Returns};
use crate::sac::{SacLearner, SacNetworks};
use candle_core::{Device, Tensor};
use dvnav_config::Config;
use dvnav_link::core::TransitionBatch;
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
    /// Learner threads the update was spread over.
    pub threads: usize,
    /// Device name.
    pub device: String,
    /// Network description.
    pub network: String,
    /// Updates timed.
    pub updates: usize,
    /// FLOPs of one update (GFLOP), counted from the network's shapes ([`flops`]).
    pub update_gflop: f64,
    /// The update's arithmetic rate (GFLOP/s): `update_gflop` × updates per second.
    pub gflops: f64,
    /// The CPU's measured fp32 matrix-product peak at the same threads (GFLOP/s; [`peak`]);
    /// `None` on a GPU.
    pub gemm_peak_gflops_fp32: Option<f64>,
    /// `gflops` / `gemm_peak_gflops_fp32`.
    pub fraction_of_peak_fp32: Option<f64>,
    /// The CPU's bf16 matrix-product peak at the same threads (GFLOP/s, dvnav's AVX512-BF16
    /// kernel; [`peak`]); `None` without AVX512-BF16 or on a GPU.
    pub gemm_peak_gflops_bf16: Option<f64>,
    /// Whether the CPU has bf16 dot products in hardware (AVX512-BF16).
    pub cpu_bf16: bool,
    /// The update's matrix-product precision (`learner.precision`): `fp32` or `bf16`.
    pub precision: String,
    /// How `auto` chose `precision`, when it was asked to (`dvnav bench learner --precision
    /// auto`, or the config's `auto`); `None` for a precision given outright.
    pub precision_choice: Option<precision::PrecisionChoice>,
    /// The kernel bf16 products run on here: `avx512-bf16`, or `rounded-fp32` (fp32 speed).
    pub bf16_kernel: String,
    /// Policy inference latency at batch 1 (ms, mean).
    pub inference_ms_batch1: f64,
    /// Policy inference latency at batch 64 (ms, mean).
    pub inference_ms_batch64: f64,
    /// Whether the timed updates were replayed from a captured CUDA graph (CUDA with
    /// `learner.cuda_graph` / `--cuda-graph` only).
    pub cuda_graph: bool,
}

impl LearnerBench {
    /// Sets the update rate (a median over rounds, say) and the figures that follow from it.
    pub fn set_rate(&mut self, sac_updates_per_s: f64) {
        self.sac_updates_per_s = sac_updates_per_s;
        self.ms_per_update = 1e3 / sac_updates_per_s;
        self.gflops = self.update_gflop * sac_updates_per_s;
        self.fraction_of_peak_fp32 = self.gemm_peak_gflops_fp32.map(|p| self.gflops / p);
    }
}

fn random_replay(cfg: &Config, n: usize, rng: &mut impl Rng) -> ReplayBuffer {
    let d = cfg.obs_dim();
    let mut replay = ReplayBuffer::new(ObsCodec::for_config(cfg), n);
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

/// What [`sac_updates`] times.
#[derive(Clone, Debug)]
pub struct UpdateBench {
    /// Minibatch size.
    pub batch: usize,
    /// Learner threads (0: one per core; see [`SacLearner::with_threads`]).
    pub threads: usize,
    /// Untimed updates first.
    pub warmup: usize,
    /// Updates timed.
    pub updates: usize,
    /// Start from the newest checkpoint of this run directory (trained weights and Adam
    /// moments, whose small values a fresh network lacks) instead of fresh networks.
    pub checkpoint: Option<std::path::PathBuf>,
    /// Flush subnormals to zero on the timing thread, as the trainer does ([`crate::denormals`]).
    pub flush_denormals: bool,
    /// Also measure the CPU's matrix-product peak (about 0.5 s; CPU only).
    pub measure_peak: bool,
}

/// Times `run.updates` SAC updates after `run.warmup` untimed ones.
pub fn sac_updates(cfg: &Config, run: &UpdateBench, dev: &Device) -> anyhow::Result<LearnerBench> {
    let (batch, threads, mut warmup, updates) = (run.batch, run.threads, run.warmup, run.updates);
    if dev.is_cuda() && cfg.learner.cuda_graph {
        // Each kind of update (critics only, critics and policy) runs once op by op and is
        // then captured as a CUDA graph: neither belongs in the timed updates.
        warmup = warmup.max(2 * cfg.sac.policy_delay as usize + 2);
    }
    let dev = dev.clone();
    if run.flush_denormals {
        crate::denormals::flush_denormals_to_zero();
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let replay = random_replay(cfg, 4 * batch, &mut rng);
    let returns = Returns::for_config(&cfg.sac);
    let nets = SacNetworks::new(cfg, 0, &dev)?;
    let mut learner = SacLearner::new(nets, cfg.sac.clone(), dev.clone(), 0)?
        .with_threads(threads)?
        .with_cuda_graphs(cfg.learner.cuda_graph);
    if let Some(dir) = &run.checkpoint {
        crate::checkpoint::Checkpoint::latest(dir)?.restore_learner(&mut learner)?;
    }
    let mut b = Batch::default();
    for _ in 0..warmup {
        replay.sample_into(batch, returns, &mut rng, &mut b);
        learner.update(&b)?;
    }
    dev.synchronize()?;
    let t = Instant::now();
    for _ in 0..updates {
        replay.sample_into(batch, returns, &mut rng, &mut b);
        learner.update(&b)?;
    }
    // A GPU runs asynchronously: the time counts only once its queue is done.
    dev.synchronize()?;
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
    let rate = updates as f64 / secs;
    let update_gflop = flops::update_flops(cfg, batch) / 1e9;
    let (peak, peak_bf16) = match dev {
        Device::Cpu if run.measure_peak => {
            let per_thread = std::time::Duration::from_millis(500);
            (
                Some(peak::gemm_fp32_gflops(learner.threads(), per_thread)?),
                peak::gemm_bf16_gflops(learner.threads(), per_thread)?,
            )
        }
        _ => (None, None),
    };
    Ok(LearnerBench {
        sac_updates_per_s: rate,
        ms_per_update: secs * 1e3 / updates as f64,
        batch,
        threads: learner.threads(),
        device: crate::device::name(&dev),
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
        update_gflop,
        gflops: update_gflop * rate,
        gemm_peak_gflops_fp32: peak,
        fraction_of_peak_fp32: peak.map(|p| update_gflop * rate / p),
        gemm_peak_gflops_bf16: peak_bf16,
        cpu_bf16: dvnav_nav::bf16::Kernel::Avx512Bf16.available(),
        precision: cfg.learner.precision.to_string(),
        precision_choice: None,
        bf16_kernel: dvnav_nav::bf16::Kernel::detect().name().to_string(),
        inference_ms_batch1: latency(1)?,
        inference_ms_batch64: latency(64)?,
        cuda_graph: learner.replays_cuda_graphs(),
    })
}

/// How far apart two learners end after the same `updates` updates from the same networks,
/// batches and noise, one replaying captured CUDA graphs and one launching each operation:
/// the largest absolute difference over every weight, target, moment and log α. The same
/// arithmetic in another order of launches gives the
/// same numbers up to float rounding (cuBLAS may pick other kernels for the same product).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct GraphCheck {
    /// Updates run on each side (the first of each kind run eagerly, the second captured).
    pub updates: usize,
    /// Largest |graph − eager| over all state tensors.
    pub max_abs_diff: f64,
    /// Largest |value| over the same tensors, for scale.
    pub max_abs_value: f64,
    /// Whether the graph side really replayed graphs.
    pub replayed: bool,
}

/// [`GraphCheck`] at `batch` on `dev` (a CUDA device; on the CPU both sides are eager).
pub fn cuda_graph_check(
    cfg: &Config,
    batch: usize,
    updates: usize,
    dev: &Device,
) -> anyhow::Result<GraphCheck> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let replay = random_replay(cfg, 4 * batch, &mut rng);
    let returns = Returns::for_config(&cfg.sac);
    let mut batches = Vec::with_capacity(updates);
    for _ in 0..updates {
        let mut b = Batch::default();
        replay.sample_into(batch, returns, &mut rng, &mut b);
        batches.push(b);
    }
    let run = |graphs: bool| -> anyhow::Result<(Vec<(String, Tensor)>, bool)> {
        let nets = SacNetworks::new(cfg, 0, dev)?;
        let mut learner =
            SacLearner::new(nets, cfg.sac.clone(), dev.clone(), 0)?.with_cuda_graphs(graphs);
        for b in &batches {
            learner.update(b)?;
        }
        Ok((learner.state_tensors()?, learner.replays_cuda_graphs()))
    };
    let (graph, replayed) = run(true)?;
    let (eager, _) = run(false)?;
    let (mut max_abs_diff, mut max_abs_value) = (0f64, 0f64);
    for ((name, a), (other, b)) in graph.iter().zip(&eager) {
        anyhow::ensure!(name == other, "state tensors in another order: {name} / {other}");
        let a = a.flatten_all()?.to_dtype(candle_core::DType::F64)?.to_vec1::<f64>()?;
        let b = b.flatten_all()?.to_dtype(candle_core::DType::F64)?.to_vec1::<f64>()?;
        for (x, y) in a.iter().zip(&b) {
            max_abs_diff = max_abs_diff.max((x - y).abs());
            max_abs_value = max_abs_value.max(y.abs());
        }
    }
    Ok(GraphCheck { updates, max_abs_diff, max_abs_value, replayed })
}

/// Figures of `dvnav bench replay`.
#[derive(Debug, serde::Serialize)]
pub struct ReplayBench {
    /// Transitions held after filling.
    pub transitions: usize,
    /// Capacity asked for.
    pub capacity: usize,
    /// Observations stored for them (ideal: one per transition plus one per episode).
    pub stored_observations: usize,
    /// Stored observations per transition.
    pub observations_per_transition: f64,
    /// Heap memory of the buffer (MiB).
    pub memory_mib: f64,
    /// Bytes per transition held.
    pub bytes_per_transition: f64,
    /// What two `f32` copies of each observation would take (MiB), for comparison.
    pub naive_memory_mib: f64,
    /// Transitions inserted per second (insertion alone, no simulation).
    pub insert_per_s: f64,
    /// Time to sample one minibatch of `batch` (µs).
    pub sample_us: f64,
    /// Minibatch size sampled.
    pub batch: usize,
}

/// Fills a buffer of `capacity` with transitions of real episodes (env0, 16 environments
/// driven by the PID controller with noise, batched as an actor batches them) and times
/// insertion and sampling.
pub fn replay(cfg: &Config, capacity: usize, batch: usize) -> anyhow::Result<ReplayBench> {
    use dvnav_nav::control::{pid_velocity, velocity_to_action};
    use dvnav_sim::{Room, VecEnv};
    let n_envs = 16;
    let room = Room::builtin("env0")?;
    let seeds: Vec<u64> = (0..n_envs as u64).collect();
    let mut envs = VecEnv::new(vec![room; n_envs], &cfg.env, &seeds);
    let d = cfg.obs_dim();
    let (mut obs, mut next) = (vec![0f32; n_envs * d], vec![0f32; n_envs * d]);
    envs.write_obs(&mut obs);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let mut replay = ReplayBuffer::new(ObsCodec::for_config(cfg), capacity);
    let returns = Returns::for_config(&cfg.sac);
    let mut tb = TransitionBatch::with_capacity(d, 128);
    let mut insert_s = 0.0;
    let mut made = 0;
    while made < capacity {
        let commands: Vec<(f64, f64)> = (0..n_envs)
            .map(|i| {
                let o = dvnav_sim::obs::ObsView::with_layout(
                    &obs[i * d..(i + 1) * d],
                    cfg.obs_layout(),
                );
                let (v, w) = pid_velocity(
                    o.goal_distance() as f64,
                    o.goal_angle() as f64,
                    &cfg.warmup,
                    &cfg.env,
                );
                (v * rng.random_range(0.5..1.0), w + rng.random_range(-0.5..0.5))
            })
            .collect();
        let outcomes = envs.step(&commands);
        envs.write_obs(&mut next);
        for (i, out) in outcomes.iter().enumerate() {
            let (v, w) = commands[i];
            let a = velocity_to_action(v, w, &cfg.env);
            let done = out.done;
            let terminated = done.is_some_and(|o| o.is_terminal());
            let truncated = done.is_some() && !terminated;
            tb.push(
                &obs[i * d..(i + 1) * d],
                a,
                out.reward,
                &next[i * d..(i + 1) * d],
                terminated,
                truncated,
                0,
            );
            if done.is_some() {
                envs.reset(i);
                envs.envs()[i].write_obs(&mut next[i * d..(i + 1) * d]);
            }
            made += 1;
            if tb.len() == 128 {
                let t = Instant::now();
                replay.insert(&tb);
                insert_s += t.elapsed().as_secs_f64();
                tb.clear();
            }
        }
        std::mem::swap(&mut obs, &mut next);
    }
    let t = Instant::now();
    replay.insert(&tb);
    insert_s += t.elapsed().as_secs_f64();
    let mut b = Batch::default();
    replay.sample_into(batch, returns, &mut rng, &mut b);
    let reps = 200;
    let t = Instant::now();
    for _ in 0..reps {
        replay.sample_into(batch, returns, &mut rng, &mut b);
    }
    let sample_us = t.elapsed().as_secs_f64() * 1e6 / reps as f64;
    let mib = |b: usize| b as f64 / (1 << 20) as f64;
    let naive = replay.len() * (2 * d * 4 + 2 * 4 + 4 + 1);
    Ok(ReplayBench {
        transitions: replay.len(),
        capacity,
        stored_observations: replay.stored_observations(),
        observations_per_transition: replay.stored_observations() as f64 / replay.len() as f64,
        memory_mib: mib(replay.memory_bytes()),
        bytes_per_transition: replay.memory_bytes() as f64 / replay.len() as f64,
        naive_memory_mib: mib(naive),
        insert_per_s: made as f64 / insert_s,
        sample_us,
        batch,
    })
}
