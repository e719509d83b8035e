//! The SAC update on an NVIDIA GPU, captured once as a CUDA graph and replayed.
//!
//! An update is about a thousand small kernels (five networks forward, three backward, Adam on
//! every variable), and an eager executor launches them one by one from the host: on an H200
//! that held the update to 14-18 ms whatever the batch (docs/results.md, "On an NVIDIA H200"),
//! where its arithmetic takes well under one. Captured once, the whole update is one launch.
//!
//! What a replay needs is what [`SacLearner::step_networks`] already is: it counts nothing on
//! the host and reads nothing back. Everything that changes from one update to the next lives
//! in device memory the graph reads: the batch and the policy noise ([`Inputs`], written before
//! each replay), α (exp(log α) on the device, not a number baked into a kernel's arguments),
//! and the Adam bias corrections (6 values written with the batch). Every tensor the graph
//! outlives (weights, targets, moments, log α, the metrics) is written in place, so its
//! address is the one captured. The two kinds of update (critics only, and critics with the
//! policy and α every `policy_delay`-th) are two graphs.
//!
//! Each kind runs once eagerly first, with candle's CUDA-graph cache on, so that the small
//! host-to-device uploads of kernel parameters (shapes and strides) are made then and reused
//! while capturing, where an upload from host memory is not allowed (uploads above 4 kB are
//! not cached at all: the convolutions' gather positions are made once per layer for this,
//! `dvnav_nav::fused::unfold_index`). cuBLAS gets a workspace of its own first, so that it
//! allocates nothing inside a capture. A capture that fails
//! (a candle operation the driver will not capture) is logged, and the learner goes on
//! eagerly: slower, never wrong.
//!
//! The losses and mean Q come back to the host every [`METRICS_EVERY`] updates (each read
//! waits for the GPU); between reads [`SacLearner::last_metrics`] is the last read.

use super::{SacLearner, StepLosses, UpdateMetrics, UpdateNoise, shards};
use crate::replay::Batch;
use candle_core::cuda::WrapErr;
use candle_core::cuda::cudarc::cublas::{CudaBlas, sys as cublas_sys};
use candle_core::cuda::cudarc::driver::{CudaGraph, CudaSlice, DevicePtr, sys};
use candle_core::{DType, Device, Result, Tensor, Var};
use std::sync::Arc;

/// Updates between two reads of the losses from the device.
pub const METRICS_EVERY: u64 = 16;

/// cuBLAS's workspace while updates are captured and replayed (PyTorch's CUDA graphs set one
/// too): with a workspace of its own, cuBLAS allocates nothing inside a capture.
const CUBLAS_WORKSPACE_BYTES: usize = 32 << 20;

/// The captured updates of one learner, and whether to use them.
pub struct CudaGraphs {
    /// Replay captured updates on a CUDA device (`learner.cuda_graph`).
    pub enabled: bool,
    captured: Option<Captured>,
    /// Set once, before the first capture; dropped (and cuBLAS back on its default) with the
    /// learner.
    workspace: Option<CublasWorkspace>,
}

impl CudaGraphs {
    /// On or off; nothing is captured before the first update on a CUDA device.
    pub fn new(enabled: bool) -> Self {
        Self { enabled, captured: None, workspace: None }
    }

    /// Whether updates are being replayed from a capture now.
    pub fn replaying(&self) -> bool {
        self.captured.as_ref().is_some_and(|c| c.graphs.iter().any(Option::is_some))
    }
}

/// A device buffer given to the device's cuBLAS handle as its workspace, taken back on drop
/// (the handle is the device's, and outlives the learner).
struct CublasWorkspace {
    blas: Arc<CudaBlas>,
    _buffer: CudaSlice<u8>,
}

impl CublasWorkspace {
    fn set(cuda: &candle_core::CudaDevice) -> Result<Self> {
        let blas = cuda.cublas_handle();
        let stream = cuda.cuda_stream();
        let buffer = stream.alloc_zeros::<u8>(CUBLAS_WORKSPACE_BYTES).w()?;
        let status = {
            let (ptr, _sync) = buffer.device_ptr(&stream);
            // SAFETY: the buffer lives as long as this value, whose drop takes it back from
            // the handle before freeing it.
            unsafe {
                cublas_sys::cublasSetWorkspace_v2(
                    *blas.handle(),
                    ptr as *mut std::ffi::c_void,
                    CUBLAS_WORKSPACE_BYTES,
                )
            }
        };
        if status != cublas_sys::cublasStatus_t::CUBLAS_STATUS_SUCCESS {
            candle_core::bail!("cublasSetWorkspace: {status:?}");
        }
        Ok(Self { blas, _buffer: buffer })
    }
}

impl Drop for CublasWorkspace {
    fn drop(&mut self) {
        // SAFETY: a null workspace of size 0 puts the handle back on cuBLAS's own.
        unsafe {
            cublas_sys::cublasSetWorkspace_v2(*self.blas.handle(), std::ptr::null_mut(), 0);
        }
    }
}

/// The device buffers a captured update reads, written before each replay.
struct Inputs {
    obs: Var,
    next_obs: Var,
    actions: Var,
    rewards: Var,
    discounts: Var,
    terminated: Var,
    demonstrated: Var,
    eps_next: Var,
    eps_pi: Var,
    /// Adam's 1/(1 − β₁ᵗ), 1/(1 − β₂ᵗ) for the critics, the policy and α, in that order.
    corrections: Var,
}

impl Inputs {
    fn new(batch: usize, obs_dim: usize, action_dim: usize, dev: &Device) -> Result<Self> {
        let zeros = |shape: &[usize]| Var::zeros(shape, DType::F32, dev);
        Ok(Self {
            obs: zeros(&[batch, obs_dim])?,
            next_obs: zeros(&[batch, obs_dim])?,
            actions: zeros(&[batch, action_dim])?,
            rewards: zeros(&[batch])?,
            discounts: zeros(&[batch])?,
            terminated: zeros(&[batch])?,
            demonstrated: zeros(&[batch])?,
            eps_next: zeros(&[batch, action_dim])?,
            eps_pi: zeros(&[batch, action_dim])?,
            corrections: zeros(&[6])?,
        })
    }

    fn write(&self, batch: &Batch, noise: &UpdateNoise, corrections: &[f32; 6]) -> Result<()> {
        let put = |v: &Var, data: &[f32]| v.set(&Tensor::from_slice(data, v.shape(), v.device())?);
        put(&self.obs, &batch.obs)?;
        put(&self.next_obs, &batch.next_obs)?;
        put(&self.actions, &batch.actions)?;
        put(&self.rewards, &batch.rewards)?;
        put(&self.discounts, &batch.discounts)?;
        put(&self.terminated, &batch.terminated)?;
        put(&self.demonstrated, &batch.demonstrated)?;
        put(&self.eps_next, &noise.next)?;
        put(&self.eps_pi, &noise.current)?;
        put(&self.corrections, corrections)
    }

    /// The whole batch as the one shard a GPU update takes.
    fn shard(&self) -> shards::Shard {
        let t = |v: &Var| v.as_tensor().clone();
        shards::Shard {
            obs: t(&self.obs),
            next_obs: t(&self.next_obs),
            actions: t(&self.actions),
            rewards: t(&self.rewards),
            discounts: t(&self.discounts),
            terminated: t(&self.terminated),
            demonstrated: t(&self.demonstrated),
            eps_next: t(&self.eps_next),
            eps_pi: t(&self.eps_pi),
            share: 1.0,
            first: true,
        }
    }
}

/// A graph moves with the learner to the thread that trains; it is only ever used by the one
/// thread that owns the learner (CUDA graphs are not internally synchronized, so not `Sync`).
struct Graph(CudaGraph);

// SAFETY: the graph and its executable are driver handles with no thread affinity; only the
// learner that owns this value launches it, from one thread at a time (`&mut self`).
unsafe impl Send for Graph {}

/// The buffers and graphs for one batch size.
struct Captured {
    inputs: Inputs,
    /// [L(φ1) + L(φ2), mean Q1] of the last update.
    critic_metrics: Var,
    /// [L(θ), −mean log π] of the last policy update.
    policy_metrics: Var,
    /// By whether the update steps the policy: the graph, once captured.
    graphs: [Option<Graph>; 2],
    /// By kind: whether it ran once eagerly (which makes the parameter uploads capture needs).
    warmed: [bool; 2],
}

impl Captured {
    /// The batch size its buffers and graphs are for.
    fn batch(&self) -> Result<usize> {
        self.inputs.rewards.dim(0)
    }
}

impl<P: super::GaussianPolicy, Q: super::QFunction> SacLearner<P, Q> {
    /// Replays the captured update when the learner is on a CUDA device with CUDA graphs on
    /// (capturing it first when needed); `None` where the eager update is to run instead.
    pub(super) fn captured_update(
        &mut self,
        batch: &Batch,
        noise: &UpdateNoise,
    ) -> Result<Option<UpdateMetrics>> {
        let Device::Cuda(cuda) = self.device.clone() else { return Ok(None) };
        // θ̄ is replaced, not written in place, at each update: not replayable.
        if !self.graphs.enabled || self.average.is_some() {
            return Ok(None);
        }
        let mut c = match self.graphs.captured.take() {
            Some(c) if c.batch()? == batch.size => c,
            _ => Captured {
                inputs: Inputs::new(batch.size, batch.obs_dim, self.action_dim, &self.device)?,
                critic_metrics: Var::zeros(2, DType::F32, &self.device)?,
                policy_metrics: Var::zeros(2, DType::F32, &self.device)?,
                graphs: [None, None],
                warmed: [false; 2],
            },
        };
        let policy = self.policy_due();
        let kind = usize::from(policy);
        c.inputs.write(batch, noise, &self.next_corrections())?;

        if c.graphs[kind].is_none() {
            if self.graphs.workspace.is_none() {
                // Before the first update that runs with the upload cache, so that the
                // warm-up already uses the workspace the captures will.
                self.graphs.workspace = Some(CublasWorkspace::set(&cuda)?);
            }
            if !c.warmed[kind] {
                let _cache = cuda.enable_cuda_graph_htod_cache();
                self.replayable_step(&c, policy)?;
                c.warmed[kind] = true;
                return self.finish_replayed(c, policy).map(Some);
            }
            match self.capture(&cuda, &c, policy) {
                Ok(graph) => {
                    tracing::info!(
                        policy,
                        batch = batch.size,
                        "captured the SAC update as a CUDA graph"
                    );
                    c.graphs[kind] = Some(Graph(graph));
                }
                Err(e) => {
                    tracing::warn!(
                        "could not capture the SAC update as a CUDA graph ({e}); updating op by op from here on (learner.cuda_graph = false skips the attempt)"
                    );
                    self.graphs.enabled = false;
                    return Ok(None);
                }
            }
        }
        let graph = c.graphs[kind].as_ref().expect("captured above");
        graph.0.launch().w()?;
        self.finish_replayed(c, policy).map(Some)
    }

    /// [`SacLearner::step_networks`] on the fixed inputs with α and the bias corrections on
    /// the device, the losses written into the metrics buffers.
    fn replayable_step(&mut self, c: &Captured, policy: bool) -> Result<()> {
        let alpha = self.nets.log_alpha.as_tensor().exp()?.detach();
        let shard = c.inputs.shard();
        let corrections = c.inputs.corrections.as_tensor().clone();
        let losses: StepLosses = self.step_networks(
            std::slice::from_ref(&shard),
            std::slice::from_ref(&shard),
            &alpha,
            policy,
            Some(&corrections),
        )?;
        c.critic_metrics.set(&Tensor::stack(&[&losses.critic[0], &losses.q_mean[0]], 0)?)?;
        if let Some((actor, entropy)) = &losses.policy {
            c.policy_metrics.set(&Tensor::stack(&[&actor[0], entropy], 0)?)?;
        }
        Ok(())
    }

    /// Captures one kind of update; every tensor the capture allocates is freed inside it.
    fn capture(
        &mut self,
        cuda: &candle_core::CudaDevice,
        c: &Captured,
        policy: bool,
    ) -> Result<CudaGraph> {
        let stream = cuda.cuda_stream();
        // Whatever was queued before (the inputs just written) must not become part of it.
        stream.synchronize().w()?;
        stream.begin_capture(sys::CUstreamCaptureMode::CU_STREAM_CAPTURE_MODE_THREAD_LOCAL).w()?;
        let body = {
            let _cache = cuda.enable_cuda_graph_htod_cache();
            self.replayable_step(c, policy)
        };
        // Always ended, so that a failed capture leaves the stream usable.
        let graph = stream.end_capture(sys::CUgraphInstantiate_flags(0));
        if body.is_err() || graph.is_err() {
            // A failed capture also leaves its error in the context's deferred error state.
            let _ = stream.context().check_err();
        }
        body?;
        let graph = graph.w()?;
        graph.ok_or_else(|| candle_core::Error::Msg("the capture recorded nothing".into()))
    }

    /// Counts an update that ran from the fixed inputs, and reads its losses back every
    /// [`METRICS_EVERY`] updates (and the first few, so a run's first report is real).
    fn finish_replayed(&mut self, c: Captured, policy: bool) -> Result<UpdateMetrics> {
        self.count_replayed(policy);
        if self.updates <= 2 * self.cfg.policy_delay || self.updates.is_multiple_of(METRICS_EVERY) {
            let critic = c.critic_metrics.as_tensor().to_vec1::<f32>()?;
            let actor = c.policy_metrics.as_tensor().to_vec1::<f32>()?;
            self.last.critic_loss = f64::from(critic[0]);
            self.last.q_mean = f64::from(critic[1]);
            self.last.actor_loss = f64::from(actor[0]);
            self.last.entropy = f64::from(actor[1]);
            self.last.alpha = self.nets.alpha();
        }
        self.graphs.captured = Some(c);
        Ok(self.last)
    }
}
