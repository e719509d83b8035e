//! The SAC update (Haarnoja et al. 2018, 2019) as the paper writes it, one small function per
//! equation, read top to bottom like CleanRL's `sac_continuous_action.py`.
//!
//! | function | equation |
//! |---|---|
//! | [`soft_bellman_target`] | Q̂(s,a) = r + γ(1 − d)(min_j Q_φ̂j(s′, ã′) − α log π_θ(ã′|s′)) |
//! | (n-step, `sac.n_step`) | r and γ become Σ_i<k γ^i r_t+i and γ^k, s′ becomes s_t+k |
//! | [`critic_loss`] | L(φ_j) = 1/|M| Σ (Q_φj(s,a) − Q̂(s,a))², summed over j = 1, 2 |
//! | [`actor_loss`] | L(θ) = 1/|M| Σ (α log π_θ(ã|s) − min_j Q_φj(s,ã)) + λ‖θ‖² |
//! | [`behaviour_cloning_loss`] (`sac.bc_weight` > 0) | + λ_BC/|M| Σ m ‖tanh μ_θ(s) − a‖², m = [a demonstrated ∧ min_j Q_φj(s,a) > min_j Q_φj(s,ã)] |
//! | [`temperature_loss`] | J(α) = 1/|M| Σ −α (log π_θ(ã|s) + H̄) (Haarnoja 2019, eq. 18) |
//! | [`soft_update`] | φ̂ ← τ φ + (1 − τ) φ̂ |
//! | [`PolicyAverage::update`] (`sac.policy_average_tau` > 0) | θ̄ ← τ_π θ + (1 − τ_π) θ̄ after each policy update; θ̄ is the agent saved and evaluated |
//!
//! `d` is *termination* (success or collision) only: a timeout is a truncation and still
//! bootstraps.

#[cfg(feature = "cuda")]
mod captured;

use super::average::PolicyAverage;
use super::networks::{GaussianPolicy, Owned, QFunction, SacNetworks};
use super::optim::{Adam, polyak_in_place};
use super::shards::{self, Workers};
use crate::replay::Batch;
use candle_core::backprop::GradStore;
use candle_core::{Device, Result, Tensor, Var};
use dvnav_config::SacConfig;
use dvnav_nav::nets::{Actor, Critic};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// α as the losses take it: a number read from the device, or exp(log α) left on the device as
/// a one-element tensor (what a captured CUDA update needs: a number would be baked into its
/// kernels' arguments at capture).
pub trait Temperature: Sync {
    /// α · `x`.
    fn times(&self, x: &Tensor) -> Result<Tensor>;
}

impl Temperature for f64 {
    fn times(&self, x: &Tensor) -> Result<Tensor> {
        x * *self
    }
}

impl Temperature for Tensor {
    fn times(&self, x: &Tensor) -> Result<Tensor> {
        x.broadcast_mul(self)
    }
}

/// Q̂(s,a) = r + γ(1 − d)(min(Q̂1, Q̂2)(s′, ã′) − α log π(ã′|s′)), detached from the graph.
/// `discount` is γ per row: γ^k for a k-step return in `reward` (the replay's
/// [`Batch::discounts`]).
pub fn soft_bellman_target(
    reward: &Tensor,
    terminated: &Tensor,
    discount: &Tensor,
    next_q1: &Tensor,
    next_q2: &Tensor,
    next_log_prob: &Tensor,
    alpha: &impl Temperature,
) -> Result<Tensor> {
    let soft_v = (next_q1.minimum(next_q2)? - alpha.times(next_log_prob)?)?;
    let not_done = (terminated.neg()? + 1.0)?;
    (reward + ((not_done * soft_v)? * discount)?)?.detach().contiguous()
}

/// Sum of the two critics' mean squared errors against the target.
pub fn critic_loss(q1: &Tensor, q2: &Tensor, target: &Tensor) -> Result<Tensor> {
    td_loss(q1, target)? + td_loss(q2, target)?
}

/// L(φi) = mean((Q_φi(s, a) − y)²), one critic's part of [`critic_loss`].
pub fn td_loss(q: &Tensor, target: &Tensor) -> Result<Tensor> {
    (q - target)?.sqr()?.mean_all()
}

/// mean(α log π(ã|s) − min(Q1, Q2)(s, ã)) + λ Σ‖W‖² over the policy's weights.
pub fn actor_loss(
    log_prob: &Tensor,
    q1: &Tensor,
    q2: &Tensor,
    alpha: &impl Temperature,
    l2_coef: f64,
    policy_weights: &[Tensor],
) -> Result<Tensor> {
    let sac = (alpha.times(log_prob)? - q1.minimum(q2)?)?.mean_all()?;
    match l2_penalty(policy_weights, l2_coef)? {
        Some(l2) => sac + l2,
        None => Ok(sac),
    }
}

/// 1/|M| Σ m ‖tanh μ(s) − a‖² with m = demonstrated · [q_demo > q_pi]: the policy's
/// deterministic action pulled towards a controller's action `a` where the critics rate that
/// action above the policy's own (the Q-filter of Nair et al. 2018, "Overcoming exploration in
/// reinforcement learning with demonstrations"), so a demonstration that is worse than what
/// the policy does is not imitated. `q_demo` = min_j Q_j(s, a) and `q_pi` = min_j Q_j(s, ã)
/// are detached: the filter is a mask, not a path for gradients. Also returns the mask.
pub fn behaviour_cloning_loss(
    mean_action: &Tensor,
    action: &Tensor,
    demonstrated: &Tensor,
    q_demo: &Tensor,
    q_pi: &Tensor,
) -> Result<(Tensor, Tensor)> {
    let better = q_demo.detach().gt(&q_pi.detach())?.to_dtype(demonstrated.dtype())?;
    let mask = (demonstrated * better)?;
    let sq = (mean_action - action)?.sqr()?.sum(1)?;
    Ok(((sq * &mask)?.mean_all()?, mask))
}

/// λ Σ‖W‖² over the policy's weight matrices; `None` when λ = 0 or there are none.
pub fn l2_penalty(policy_weights: &[Tensor], l2_coef: f64) -> Result<Option<Tensor>> {
    if l2_coef == 0.0 || policy_weights.is_empty() {
        return Ok(None);
    }
    let mut l2 = policy_weights[0].sqr()?.sum_all()?;
    for w in &policy_weights[1..] {
        l2 = (l2 + w.sqr()?.sum_all()?)?;
    }
    Ok(Some((l2 * l2_coef)?))
}

/// J(α) = mean(−α (log π + H̄)), with α = exp(log α) and log π treated as a constant.
pub fn temperature_loss(
    log_alpha: &Tensor,
    log_prob: &Tensor,
    target_entropy: f64,
) -> Result<Tensor> {
    let alpha = log_alpha.exp()?;
    let gap = (log_prob.detach() + target_entropy)?;
    gap.broadcast_mul(&alpha)?.neg()?.mean_all()
}

/// Polyak averaging of a target critic towards its online critic: φ̂ ← τ φ + (1 − τ) φ̂.
pub fn soft_update<Q>(target: &Owned<Q>, online: &Owned<Q>, tau: f64) -> Result<()> {
    for (t, o) in target_pairs(target, online) {
        polyak_in_place(&t, o.as_tensor(), tau)?;
    }
    Ok(())
}

/// A target network's variables beside its online network's, name by name.
fn target_pairs<Q>(target: &Owned<Q>, online: &Owned<Q>) -> Vec<(Var, Var)> {
    target
        .named_vars()
        .into_iter()
        .zip(online.named_vars())
        .map(|((tn, t), (on, o))| {
            debug_assert_eq!(tn, on);
            (t, o)
        })
        .collect()
}

/// What one update reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateMetrics {
    /// L(φ1) + L(φ2).
    pub critic_loss: f64,
    /// L(θ) of the last policy update.
    pub actor_loss: f64,
    /// α after the update.
    pub alpha: f64,
    /// Mean of Q1 on the batch.
    pub q_mean: f64,
    /// −mean log π of the last policy update (an entropy estimate).
    pub entropy: f64,
}

/// The standard-normal noise ε one update consumes: `next` for ã′ ~ π(·|s′) in the target,
/// `current` for ã ~ π(·|s) in the policy and temperature losses; each `(batch, action_dim)`.
/// [`SacLearner::update`] draws it from the learner's seeded generator; tests pass their own
/// to [`SacLearner::update_with_noise`].
#[derive(Clone, Debug)]
pub struct UpdateNoise {
    /// ε for the next observations, row-major `(batch, action_dim)`.
    pub next: Vec<f32>,
    /// ε for the current observations, row-major `(batch, action_dim)`.
    pub current: Vec<f32>,
}

impl UpdateNoise {
    /// The noise as [`shards::split`] takes it.
    pub fn view(&self) -> shards::Noise<'_> {
        shards::Noise { next: &self.next, current: &self.current }
    }
}

/// The SAC learner: networks, optimizers, and the update counter. Generic over the policy and
/// critic networks; the default is the navigation CNN pair.
pub struct SacLearner<P = Actor, Q = Critic> {
    /// The networks.
    pub nets: SacNetworks<P, Q>,
    cfg: SacConfig,
    critic_opt: Adam,
    actor_opt: Adam,
    alpha_opt: Adam,
    /// Policy weight matrices (not biases) for the L2 term.
    policy_weights: Vec<Var>,
    target_entropy: f64,
    action_dim: usize,
    updates: u64,
    last: UpdateMetrics,
    device: Device,
    /// Worker threads an update's minibatch is shared out over ([`super::shards`]).
    workers: Workers,
    /// Source of the policy's sampling noise, seeded, so an update depends only on the seed,
    /// the networks and the batch (candle's own CPU generator cannot be seeded).
    noise: rand_pcg::Pcg64,
    /// θ̄, when `sac.policy_average_tau` > 0.
    average: Option<PolicyAverage>,
    /// The update captured as CUDA graphs, on a CUDA device ([`captured`]).
    #[cfg(feature = "cuda")]
    graphs: captured::CudaGraphs,
}

impl<P: GaussianPolicy, Q: QFunction> SacLearner<P, Q> {
    /// A learner over fresh or loaded networks.
    pub fn new(nets: SacNetworks<P, Q>, cfg: SacConfig, device: Device, seed: u64) -> Result<Self> {
        let prefixed = |p: &str, vars: Vec<(String, Var)>| {
            vars.into_iter().map(|(n, v)| (format!("{p}.{n}"), v)).collect::<Vec<_>>()
        };
        let mut critic_vars = prefixed("critic1", nets.critic1.named_vars());
        critic_vars.extend(prefixed("critic2", nets.critic2.named_vars()));
        let actor_vars = nets.actor.named_vars();
        let policy_weights = actor_vars
            .iter()
            .filter(|(n, _)| n.ends_with(".weight"))
            .map(|(_, v)| v.clone())
            .collect();
        let critic_opt = Adam::new(critic_vars, cfg.critic_lr)?;
        let actor_opt = Adam::new(actor_vars, cfg.actor_lr)?;
        let alpha_opt =
            Adam::new(vec![("log_alpha".into(), nets.log_alpha.clone())], cfg.alpha_lr)?;
        let action_dim = nets.actor.net.action_dim();
        let target_entropy = cfg.target_entropy.unwrap_or(-(action_dim as f64));
        let average = (cfg.policy_average_tau > 0.0)
            .then(|| PolicyAverage::start(&nets.actor.named_vars(), cfg.policy_average_tau))
            .transpose()?;
        Ok(Self {
            nets,
            cfg,
            critic_opt,
            actor_opt,
            alpha_opt,
            policy_weights,
            target_entropy,
            action_dim,
            updates: 0,
            last: UpdateMetrics::default(),
            device,
            workers: Workers::new(1)?,
            noise: rand_pcg::Pcg64::seed_from_u64(seed),
            average,
            #[cfg(feature = "cuda")]
            graphs: captured::CudaGraphs::new(false),
        })
    }

    /// Spreads each update over `threads` worker threads (0: one per core) by cutting its
    /// minibatch into shards ([`super::shards`]): the same update up to float rounding, and
    /// deterministic for a given thread count. Candle's own CPU threads should stay at one.
    pub fn with_threads(mut self, threads: usize) -> Result<Self> {
        self.workers = Workers::new(threads)?;
        Ok(self)
    }

    /// On a CUDA device, replay each update from a CUDA graph captured at the first updates
    /// (`learner.cuda_graph`; off by default) instead of launching its kernels one by one.
    /// Same arithmetic; the losses reach [`Self::last_metrics`] every 16th update. Without the
    /// `cuda` feature, and on the CPU, it changes nothing.
    #[allow(unused_mut, unused_variables)]
    pub fn with_cuda_graphs(mut self, on: bool) -> Self {
        #[cfg(feature = "cuda")]
        {
            self.graphs.enabled = on;
        }
        self
    }

    /// Whether updates are replayed from a captured CUDA graph now.
    pub fn replays_cuda_graphs(&self) -> bool {
        #[cfg(feature = "cuda")]
        return self.graphs.replaying();
        #[cfg(not(feature = "cuda"))]
        false
    }

    /// Worker threads an update is spread over.
    pub fn threads(&self) -> usize {
        self.workers.threads()
    }

    /// Updates done.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The device the networks live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// One SAC update on a minibatch with noise from the learner's seeded generator: both
    /// critics every call; the policy and α every `policy_delay`-th call; the targets by
    /// Polyak averaging every call.
    pub fn update(&mut self, batch: &Batch) -> Result<UpdateMetrics> {
        let noise = UpdateNoise {
            next: self.standard_normal(batch.size),
            current: self.standard_normal(batch.size),
        };
        self.update_with_noise(batch, &noise)
    }

    /// [`Self::update`] with the given policy noise.
    pub fn update_with_noise(
        &mut self,
        batch: &Batch,
        noise: &UpdateNoise,
    ) -> Result<UpdateMetrics> {
        #[cfg(feature = "cuda")]
        if let Some(metrics) = self.captured_update(batch, noise)? {
            return Ok(metrics);
        }
        let split = |n| shards::split(batch, noise.view(), self.action_dim, n, &self.device);
        let shards = split(self.shard_count())?;
        let groups = match shards::twin_groups(shards.len(), batch.size) {
            n if n == shards.len() => None,
            n => Some(split(n)?),
        };
        let groups = groups.as_deref().unwrap_or(&shards);
        let policy = self.policy_due();
        let losses = self.step_networks(&shards, groups, &self.nets.alpha(), policy, None)?;
        self.last.critic_loss = sum_of(&losses.critic)?;
        self.last.q_mean = sum_of(&losses.q_mean)?;
        if let Some((actor, entropy)) = &losses.policy {
            self.last.actor_loss = sum_of(actor)?;
            self.last.entropy = scalar(entropy)?;
        }
        self.updates += 1;
        self.last.alpha = self.nets.alpha();
        Ok(self.last)
    }

    /// Whether the next update steps the policy and α too (every `policy_delay`-th).
    fn policy_due(&self) -> bool {
        self.updates.is_multiple_of(self.cfg.policy_delay)
    }

    /// The Adam bias corrections of the next update, as [`Self::step_networks`] takes them
    /// on the device: the critics', the policy's and α's 1/(1 − β₁ᵗ), 1/(1 − β₂ᵗ).
    #[cfg_attr(not(feature = "cuda"), allow(dead_code))] // the CPU runs it in tests only
    fn next_corrections(&self) -> [f32; 6] {
        let mut c = [0f32; 6];
        c[..2].copy_from_slice(&self.critic_opt.next_corrections());
        c[2..4].copy_from_slice(&self.actor_opt.next_corrections());
        c[4..].copy_from_slice(&self.alpha_opt.next_corrections());
        c
    }

    /// Counts an update that [`Self::step_networks`] ran with device-side corrections, which
    /// counts nothing itself.
    #[cfg_attr(not(feature = "cuda"), allow(dead_code))] // the CPU runs it in tests only
    fn count_replayed(&mut self, policy: bool) {
        self.critic_opt.count_step();
        if policy {
            self.actor_opt.count_step();
            if self.cfg.autotune_alpha {
                self.alpha_opt.count_step();
            }
        }
        self.updates += 1;
    }

    /// The update's arithmetic on `shards`, the minibatch's row shards, and `groups`, the
    /// same rows in [`shards::twin_groups`] groups, each a whole number of consecutive shards:
    /// both critics, then (when `policy`) the policy, α and θ̄, then the targets. Counts
    /// nothing on the host and reads nothing back, so that it can be captured as a CUDA graph:
    /// `corrections` (the critics', policy's and α's Adam bias corrections, 6 values on the
    /// device) replace the optimizers' own step counts when given. Returns the losses as
    /// tensors.
    fn step_networks(
        &mut self,
        shards: &[shards::Shard],
        groups: &[shards::Shard],
        alpha: &impl Temperature,
        policy: bool,
        corrections: Option<&Tensor>,
    ) -> Result<StepLosses> {
        let nets = &self.nets;
        let adam = |opt: &mut Adam, grads: &GradStore, k: usize| match corrections {
            Some(c) => opt.step_corrected(grads, &c.narrow(0, 2 * k, 2)?),
            None => opt.step(grads),
        };
        // The optimizer steps and the targets' Polyak pass are per-variable jobs, spread over
        // the worker threads on a CPU; a GPU (and its captured graph) gets them from this
        // thread alone.
        let one = Workers::sequential();
        let workers = if self.device.is_cpu() { &self.workers } else { &one };
        let step_shards = |opt: &mut Adam, stores: Vec<GradStore>, k: usize| match corrections {
            Some(_) => adam(opt, &shards::sum_grads(stores, opt.vars())?, k),
            None => opt.step_shards(&stores, workers),
        };

        // Critics, in three steps over the workers: (1) the policy's next actions ã′ ~ π(·|s′)
        // on the row shards; (2) each target critic on each row group, a job of its own, then
        // y per group; (3) each critic's loss, its group's share of L(φi), and its backward
        // pass, again a job per critic and group. The twins are independent networks, so a
        // job runs one whole network over its rows: cut into row shards instead, every worker
        // repeats each weight's work (packing it for the products, copying its gradient), and
        // two half-batch shards took 1.2x the time of the whole batch on one worker
        // (docs/results.md, "Twin critics").
        let next = workers.map(shards, |s| {
            let next = nets.actor.net.sample_with_noise(&s.next_obs, &s.eps_next)?;
            Ok((next.action.detach(), next.log_prob.detach()))
        })?;
        let next = shards::join_rows(next, groups.len())?;
        let targets = [&nets.target1.net, &nets.target2.net];
        let target_q = workers.run(2 * groups.len(), |job| {
            let (k, i) = (job / 2, job % 2);
            Ok(targets[i].q(&groups[k].next_obs, &next[k].0)?.detach())
        })?;
        let y = groups
            .iter()
            .enumerate()
            .map(|(k, g)| {
                let (q1, q2) = (&target_q[2 * k], &target_q[2 * k + 1]);
                soft_bellman_target(
                    &g.rewards,
                    &g.terminated,
                    &g.discounts,
                    q1,
                    q2,
                    &next[k].1,
                    alpha,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let critics = [&nets.critic1.net, &nets.critic2.net];
        let parts = workers.run(2 * groups.len(), |job| {
            let (k, i) = (job / 2, job % 2);
            let g = &groups[k];
            let q = critics[i].q(&g.obs, &g.actions)?;
            let loss = share_of(td_loss(&q, &y[k])?, g.share)?;
            Ok((loss.backward()?, loss.detach(), share_of(q.mean_all()?, g.share)?.detach()))
        })?;
        let (stores, twin_losses, twin_q) = unzip3(parts);
        step_shards(&mut self.critic_opt, stores, 0)?;
        // Per group: L(φ1) + L(φ2), and the mean of Q1.
        let critic = twin_losses.chunks(2).map(|l| &l[0] + &l[1]).collect::<Result<Vec<_>>>()?;
        let q_mean = twin_q.into_iter().step_by(2).collect();
        let mut losses = StepLosses { critic, q_mean, policy: None };

        // Policy and temperature, delayed.
        if policy {
            let weights: Vec<Tensor> =
                self.policy_weights.iter().map(|v| v.as_tensor().clone()).collect();
            let (nets, cfg) = (&self.nets, &self.cfg);
            let parts = self.workers.map(shards, |s| {
                let pi = nets.actor.net.sample_with_noise(&s.obs, &s.eps_pi)?;
                let q1_pi = nets.critic1.net.q_for_policy(&s.obs, &pi.action)?;
                let q2_pi = nets.critic2.net.q_for_policy(&s.obs, &pi.action)?;
                // The L2 term belongs to the batch, not to a shard: the first shard adds it.
                let mut sac = actor_loss(&pi.log_prob, &q1_pi, &q2_pi, alpha, 0.0, &[])?;
                if cfg.bc_weight > 0.0 {
                    let q_demo = nets
                        .critic1
                        .net
                        .q(&s.obs, &s.actions)?
                        .minimum(&nets.critic2.net.q(&s.obs, &s.actions)?)?;
                    let (bc, _) = behaviour_cloning_loss(
                        &pi.mean_action,
                        &s.actions,
                        &s.demonstrated,
                        &q_demo,
                        &q1_pi.minimum(&q2_pi)?,
                    )?;
                    sac = (sac + (bc * cfg.bc_weight)?)?;
                }
                let mut loss = share_of(sac, s.share)?;
                if s.first
                    && let Some(l2) = l2_penalty(&weights, cfg.policy_l2)?
                {
                    loss = (loss + l2)?;
                }
                // The backward pass also reaches the critics' heads through Q(s, ã); only the
                // policy's optimizer steps, so their gradients are dropped.
                Ok((loss.backward()?, loss.detach(), pi.log_prob.detach()))
            })?;
            let (stores, actor, log_probs) = unzip3(parts);
            step_shards(&mut self.actor_opt, stores, 1)?;
            let log_prob = Tensor::cat(&log_probs, 0)?;
            if self.cfg.autotune_alpha {
                let loss_a = temperature_loss(
                    self.nets.log_alpha.as_tensor(),
                    &log_prob,
                    self.target_entropy,
                )?;
                adam(&mut self.alpha_opt, &loss_a.backward()?, 2)?;
            }
            if let Some(avg) = &mut self.average {
                avg.update(&self.nets.actor.named_vars())?;
            }
            losses.policy = Some((actor, log_prob.mean_all()?.neg()?));
        }

        let pairs: Vec<(Var, Var)> =
            [(&self.nets.target1, &self.nets.critic1), (&self.nets.target2, &self.nets.critic2)]
                .into_iter()
                .flat_map(|(target, online)| target_pairs(target, online))
                .collect();
        let tau = self.cfg.tau;
        workers
            .for_each(pairs.len(), |i| polyak_in_place(&pairs[i].0, pairs[i].1.as_tensor(), tau))?;
        Ok(losses)
    }

    /// Shards an update is cut into: one per worker thread on a CPU, one on a GPU (a GPU
    /// parallelizes inside each operation).
    fn shard_count(&self) -> usize {
        if self.device.is_cpu() { self.workers.threads() } else { 1 }
    }

    /// `(batch, action_dim)` standard-normal noise from the learner's seeded generator.
    fn standard_normal(&mut self, batch: usize) -> Vec<f32> {
        (0..batch * self.action_dim).map(|_| StandardNormal.sample(&mut self.noise)).collect()
    }

    /// The state of the noise generator, for a checkpoint.
    pub fn noise_rng(&self) -> &rand_pcg::Pcg64 {
        &self.noise
    }

    /// Restores the noise generator from a checkpoint.
    pub fn set_noise_rng(&mut self, rng: rand_pcg::Pcg64) {
        self.noise = rng;
    }

    /// Every network's variables under its checkpoint prefix.
    fn network_vars(&self) -> [(&'static str, Vec<(String, Var)>); 5] {
        [
            ("actor", self.nets.actor.named_vars()),
            ("critic1", self.nets.critic1.named_vars()),
            ("critic2", self.nets.critic2.named_vars()),
            ("target1", self.nets.target1.named_vars()),
            ("target2", self.nets.target2.named_vars()),
        ]
    }

    /// Named tensors of everything an exact resume needs besides the counters: networks,
    /// targets, log α and every optimizer's moments.
    pub fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let mut out = Vec::new();
        for (prefix, vars) in self.network_vars() {
            out.extend(
                vars.into_iter().map(|(n, v)| (format!("{prefix}.{n}"), v.as_tensor().clone())),
            );
        }
        out.push(("log_alpha".into(), self.nets.log_alpha.as_tensor().clone()));
        if let Some(avg) = &self.average {
            out.extend(
                avg.tensors().iter().map(|(n, t)| (format!("{AVERAGE_PREFIX}.{n}"), t.clone())),
            );
        }
        out.extend(self.critic_opt.state_tensors("opt.critic")?);
        out.extend(self.actor_opt.state_tensors("opt.actor")?);
        out.extend(self.alpha_opt.state_tensors("opt.alpha")?);
        Ok(out)
    }

    /// Optimizer step counts (critic, actor, alpha), stored beside [`Self::state_tensors`].
    pub fn optimizer_steps(&self) -> [u64; 3] {
        [self.critic_opt.steps(), self.actor_opt.steps(), self.alpha_opt.steps()]
    }

    /// Restores what [`Self::state_tensors`] saved, and the counters.
    pub fn load_state(
        &mut self,
        tensors: &std::collections::HashMap<String, Tensor>,
        updates: u64,
        optimizer_steps: [u64; 3],
    ) -> anyhow::Result<()> {
        for (prefix, vars) in self.network_vars() {
            for (n, v) in vars {
                let key = format!("{prefix}.{n}");
                let t = tensors
                    .get(&key)
                    .ok_or_else(|| anyhow::anyhow!("checkpoint lacks tensor `{key}`"))?;
                if t.dims() != v.dims() {
                    anyhow::bail!(
                        "checkpoint tensor `{key}` has shape {:?}, expected {:?}",
                        t.dims(),
                        v.dims()
                    );
                }
                v.set(t)?;
            }
        }
        let la = tensors
            .get("log_alpha")
            .ok_or_else(|| anyhow::anyhow!("checkpoint lacks `log_alpha`"))?;
        self.nets.log_alpha.set(la)?;
        if let Some(avg) = &mut self.average {
            let prefixed = |n: &str| tensors.get(&format!("{AVERAGE_PREFIX}.{n}")).cloned();
            if tensors.keys().any(|k| k.starts_with(&format!("{AVERAGE_PREFIX}."))) {
                avg.load(prefixed)
                    .map_err(|e| anyhow::anyhow!("checkpoint's policy average {e}"))?;
            } else {
                // A run saved without the average (turned on at a resume): it starts here.
                tracing::warn!(
                    "the checkpoint has no policy average (sac.policy_average_tau was 0); it starts at the checkpoint's policy"
                );
                *avg = PolicyAverage::start(
                    &self.nets.actor.named_vars(),
                    self.cfg.policy_average_tau,
                )?;
            }
        }
        self.critic_opt.load_state("opt.critic", tensors, optimizer_steps[0])?;
        self.actor_opt.load_state("opt.actor", tensors, optimizer_steps[1])?;
        self.alpha_opt.load_state("opt.alpha", tensors, optimizer_steps[2])?;
        self.updates = updates;
        self.last.alpha = self.nets.alpha();
        Ok(())
    }

    /// The online policy's weights as safetensors bytes: what the actors act with.
    pub fn policy_safetensors(&self) -> anyhow::Result<Vec<u8>> {
        dvnav_nav::nets::varmap_to_safetensors(&self.nets.actor.vars)
    }

    /// The run's agent as safetensors bytes, for checkpoints (`dvnav eval`, `dvnav serve`) and
    /// the training-time evaluation: the policy average θ̄ when `sac.policy_average_tau` > 0,
    /// else the online policy.
    pub fn agent_safetensors(&self) -> anyhow::Result<Vec<u8>> {
        match &self.average {
            Some(avg) => avg.safetensors(),
            None => self.policy_safetensors(),
        }
    }

    /// Whether the agent is a policy average rather than the online policy.
    pub fn averages_policy(&self) -> bool {
        self.average.is_some()
    }

    /// Metrics of the most recent update.
    pub fn last_metrics(&self) -> UpdateMetrics {
        self.last
    }
}

/// Prefix of θ̄'s tensors in a checkpoint's state.
const AVERAGE_PREFIX: &str = "actor_average";

/// What [`SacLearner::step_networks`] leaves on the device: each shard's share of the critics'
/// loss and of mean Q1, and with a policy step each shard's share of the policy's loss and the
/// entropy estimate −mean log π.
struct StepLosses {
    critic: Vec<Tensor>,
    q_mean: Vec<Tensor>,
    policy: Option<(Vec<Tensor>, Tensor)>,
}

/// The sum of the shards' parts, as a number.
fn sum_of(parts: &[Tensor]) -> Result<f64> {
    parts.iter().map(scalar).sum()
}

/// A shard's part of a batch mean: the shard's own mean times its share of the rows.
fn share_of(mean: Tensor, share: f64) -> Result<Tensor> {
    if share == 1.0 { Ok(mean) } else { mean * share }
}

fn unzip3<A, B, C>(v: Vec<(A, B, C)>) -> (Vec<A>, Vec<B>, Vec<C>) {
    let mut out =
        (Vec::with_capacity(v.len()), Vec::with_capacity(v.len()), Vec::with_capacity(v.len()));
    for (a, b, c) in v {
        out.0.push(a);
        out.1.push(b);
        out.2.push(c);
    }
    out
}

fn scalar(t: &Tensor) -> Result<f64> {
    Ok(t.to_dtype(candle_core::DType::F64)?.flatten_all()?.to_vec1::<f64>()?[0])
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn t(v: &[f32]) -> Tensor {
        Tensor::new(v, &Device::Cpu).unwrap()
    }

    fn tiny_batch(cfg: &dvnav_config::Config) -> Batch {
        let d = cfg.obs_dim();
        let n = 4;
        Batch {
            size: n,
            obs_dim: d,
            obs: (0..n * d).map(|i| 0.3 + (i % 13) as f32 * 0.2).collect(),
            actions: (0..n * 2).map(|i| (i as f32 * 0.37).sin()).collect(),
            rewards: vec![0.1, -0.2, 10.0, -10.0],
            next_obs: (0..n * d).map(|i| 0.4 + (i % 11) as f32 * 0.2).collect(),
            discounts: vec![0.99; n],
            terminated: vec![0.0, 0.0, 1.0, 1.0],
            demonstrated: vec![0.0; n],
        }
    }

    /// `n` rows that differ from one another, every fifth terminated, none demonstrated.
    fn varied_batch(cfg: &dvnav_config::Config, n: usize) -> Batch {
        let d = cfg.obs_dim();
        Batch {
            size: n,
            obs_dim: d,
            obs: (0..n * d).map(|i| 0.3 + ((i * 7) % 23) as f32 * 0.2).collect(),
            actions: (0..n * 2).map(|i| (i as f32 * 0.37).sin()).collect(),
            rewards: (0..n).map(|i| (i as f32 * 0.9).cos()).collect(),
            next_obs: (0..n * d).map(|i| 0.4 + ((i * 5) % 19) as f32 * 0.2).collect(),
            discounts: vec![0.99; n],
            terminated: (0..n).map(|i| (i % 5 == 0) as u8 as f32).collect(),
            demonstrated: vec![0.0; n],
        }
    }

    fn learner(seed: u64) -> SacLearner {
        let cfg = dvnav_config::Config::default();
        let nets = SacNetworks::new(&cfg, 3, &Device::Cpu).unwrap();
        SacLearner::new(nets, cfg.sac.clone(), Device::Cpu, seed).unwrap()
    }

    #[test]
    fn updates_are_deterministic_given_the_seed_and_move_the_weights() {
        let cfg = dvnav_config::Config::default();
        let batch = tiny_batch(&cfg);
        let (mut a, mut b, mut c) = (learner(1), learner(1), learner(2));
        let before = a.policy_safetensors().unwrap();
        for _ in 0..3 {
            let ma = a.update(&batch).unwrap();
            let mb = b.update(&batch).unwrap();
            c.update(&batch).unwrap();
            assert_eq!(ma, mb);
            assert!(ma.critic_loss.is_finite() && ma.actor_loss.is_finite());
        }
        assert_eq!(a.updates(), 3);
        let after = a.policy_safetensors().unwrap();
        assert_ne!(before, after, "the policy was updated");
        assert_eq!(after, b.policy_safetensors().unwrap());
        assert_ne!(after, c.policy_safetensors().unwrap(), "other noise, other result");
    }

    #[test]
    fn the_replayable_step_is_the_eager_step() {
        // What a captured CUDA update runs (α and Adam's bias corrections as tensors on the
        // device, nothing counted or read back on the host; `captured`), run op by op here on
        // the CPU: the same updates as the eager path, policy steps included.
        let cfg = dvnav_config::Config::default();
        let batch = varied_batch(&cfg, 32);
        let (mut eager, mut replay) = (learner(5), learner(5));
        for _ in 0..5 {
            let noise = UpdateNoise {
                next: replay.standard_normal(batch.size),
                current: replay.standard_normal(batch.size),
            };
            eager.update_with_noise(&batch, &noise).unwrap();
            let shards =
                shards::split(&batch, noise.view(), replay.action_dim, 1, &Device::Cpu).unwrap();
            let corrections = Tensor::new(&replay.next_corrections()[..], &Device::Cpu).unwrap();
            let alpha = replay.nets.log_alpha.as_tensor().exp().unwrap();
            let policy = replay.policy_due();
            replay.step_networks(&shards, &shards, &alpha, policy, Some(&corrections)).unwrap();
            replay.count_replayed(policy);
        }
        assert_eq!(replay.updates(), eager.updates());
        assert_eq!(replay.optimizer_steps(), eager.optimizer_steps());
        let (a, b) = (eager.state_tensors().unwrap(), replay.state_tensors().unwrap());
        let mut worst = 0f32;
        for ((name, x), (_, y)) in a.iter().zip(&b) {
            let x = x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let y = y.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (x, y) in x.iter().zip(&y) {
                assert!((x - y).abs() <= 1e-6 * (1.0 + x.abs()), "{name}: {x} vs {y}");
                worst = worst.max((x - y).abs());
            }
        }
        let fresh = learner(5).state_tensors().unwrap();
        let moved =
            |t: &[(String, Tensor)]| t[0].1.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_ne!(moved(&b), moved(&fresh), "the replayable step moved the policy");
    }

    #[test]
    fn an_update_shared_out_over_threads_is_the_same_update() {
        // 64 rows in 1, 2, 3 or 4 shards (the critics' twin jobs on 1, 1, 3 and 2 row groups):
        // the same metrics and weights up to float rounding.
        let cfg = dvnav_config::Config::default();
        let batch = varied_batch(&cfg, 64);
        let weights = |l: &SacLearner| -> Vec<f32> {
            let mut all = Vec::new();
            for (_, t) in l.state_tensors().unwrap() {
                all.extend(t.flatten_all().unwrap().to_vec1::<f32>().unwrap());
            }
            all
        };
        // A large L2 coefficient, so that a shard adding it twice or not at all shows.
        let mut sac = cfg.sac.clone();
        sac.policy_l2 = 0.5;
        let run = |threads: usize| {
            let nets = SacNetworks::new(&cfg, 3, &Device::Cpu).unwrap();
            let l = SacLearner::new(nets, sac.clone(), Device::Cpu, 1).unwrap();
            let mut l = l.with_threads(threads).unwrap();
            let metrics: Vec<UpdateMetrics> = (0..4).map(|_| l.update(&batch).unwrap()).collect();
            (metrics, weights(&l))
        };
        let (m1, w1) = run(1);
        for threads in [2, 3, 4] {
            let (m, w) = run(threads);
            for (a, b) in m1.iter().zip(&m) {
                for (x, y) in [
                    (a.critic_loss, b.critic_loss),
                    (a.actor_loss, b.actor_loss),
                    (a.alpha, b.alpha),
                    (a.q_mean, b.q_mean),
                    (a.entropy, b.entropy),
                ] {
                    assert!(
                        (x - y).abs() <= 1e-4 * (1.0 + x.abs()),
                        "{threads} threads: {a:?} vs {b:?}"
                    );
                }
            }
            assert_eq!(w.len(), w1.len());
            let worst = w1.iter().zip(&w).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
            assert!(worst < 1e-4, "{threads} threads: weights differ by up to {worst}");
            assert!(
                w != w1 || threads == 1,
                "float rounding differs; an identical result means one shard ran"
            );
        }
    }

    #[test]
    fn behaviour_cloning_pulls_only_demonstrations_the_critics_rate_higher() {
        // Row 0: demonstrated, Q(s,a) 2 > Q(s,ã) 1: cloned, ‖(0.5, 0) − (0, 0)‖² = 0.25.
        // Row 1: demonstrated, but Q(s,a) 0 < Q(s,ã) 1: filtered out. Row 2: the policy's own.
        let mean = t(&[0.5, 0.0, 0.0, 0.0, 1.0, 1.0]).reshape((3, 2)).unwrap();
        let action = t(&[0.0, 0.0, 0.0, 0.5, 0.0, 0.0]).reshape((3, 2)).unwrap();
        let (loss, mask) = behaviour_cloning_loss(
            &mean,
            &action,
            &t(&[1.0, 1.0, 0.0]),
            &t(&[2.0, 0.0, 5.0]),
            &t(&[1.0, 1.0, 0.0]),
        )
        .unwrap();
        assert!((scalar(&loss).unwrap() - 0.25 / 3.0).abs() < 1e-7);
        assert_eq!(mask.to_vec1::<f32>().unwrap(), vec![1.0, 0.0, 0.0]);
    }

    /// `sac.bc_weight`: nothing changes without demonstrated rows; with them the policy's
    /// update differs, the same over 1 and 2 threads, and its mean action moves towards them.
    #[test]
    fn the_cloning_term_acts_on_demonstrated_rows_only() {
        let cfg = dvnav_config::Config::default();
        let (d, n) = (cfg.obs_dim(), 32);
        let mut batch = varied_batch(&cfg, n);
        let run = |bc_weight: f64, threads: usize, batch: &Batch| {
            let sac = dvnav_config::SacConfig { bc_weight, policy_delay: 1, ..cfg.sac.clone() };
            let nets = SacNetworks::new(&cfg, 3, &Device::Cpu).unwrap();
            let mut l = SacLearner::new(nets, sac, Device::Cpu, 1).unwrap();
            l = l.with_threads(threads).unwrap();
            for _ in 0..3 {
                l.update(batch).unwrap();
            }
            l
        };
        let policy = |l: &SacLearner| l.policy_safetensors().unwrap();
        assert_eq!(policy(&run(0.0, 1, &batch)), policy(&run(5.0, 1, &batch)));
        batch.demonstrated = vec![1.0; n];
        let (plain, cloned) = (run(0.0, 1, &batch), run(5.0, 1, &batch));
        assert_ne!(policy(&plain), policy(&cloned));
        // Closer to the demonstrated actions, over the rows, than without the term.
        let gap = |l: &SacLearner| {
            let obs = Tensor::from_slice(&batch.obs, (n, d), &Device::Cpu).unwrap();
            let eps = Tensor::zeros((n, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
            let mean = l.nets.actor.net.sample_with_noise(&obs, &eps).unwrap().mean_action;
            let a = Tensor::from_slice(&batch.actions, (n, 2), &Device::Cpu).unwrap();
            scalar(&(mean - a).unwrap().sqr().unwrap().mean_all().unwrap()).unwrap()
        };
        assert!(gap(&cloned) < gap(&plain), "{} vs {}", gap(&cloned), gap(&plain));
        let two = run(5.0, 2, &batch);
        let (a, b) = (two.last_metrics(), cloned.last_metrics());
        assert!((a.actor_loss - b.actor_loss).abs() <= 1e-4 * (1.0 + b.actor_loss.abs()));
    }

    #[test]
    fn radius_input_batches_pass_the_wire_and_the_replay_buffer_into_an_update() {
        use crate::replay::{ObsCodec, ReplayBuffer, Returns};
        use dvnav_link::core::TransitionBatch;
        use dvnav_link::wire;
        let cfg = dvnav_config::Config::from_toml_str(include_str!("../../../configs/sac_ri.toml"))
            .unwrap();
        let d = cfg.obs_dim();
        assert_eq!(d, 545);
        // Two episodes' worth of steps, each observation ending in its robot's radius.
        let radii = [0.23f32, 0.47];
        let obs = |k: usize, r: f32| -> Vec<f32> {
            let mut o: Vec<f32> = (0..540).map(|i| 0.5 + ((i + k) % 17) as f32 * 0.5).collect();
            o.extend([3.0 - 0.1 * k as f32, 0.2, 0.3, -0.1, r]);
            o
        };
        let mut tb = TransitionBatch::with_capacity(d, 12);
        for k in 0..12 {
            let (r, end) = (radii[k / 6], k % 6 == 5);
            tb.push(&obs(k, r), [0.2, -0.3], 0.1, &obs(k + 1, r), end, false, 1);
        }
        let tb = wire::batch_from_proto(wire::batch_to_proto(&tb, 0, 0), d).unwrap();
        let mut replay = ReplayBuffer::new(ObsCodec::for_config(&cfg), 64);
        replay.insert(&tb);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        let mut batch = Batch::default();
        replay.sample_into(16, Returns::for_config(&cfg.sac), &mut rng, &mut batch);
        assert_eq!((batch.size, batch.obs_dim), (16, 545));
        for o in batch.obs.chunks_exact(d) {
            assert!(radii.contains(&o[544]), "the radius is stored exactly: {}", o[544]);
        }
        let nets = SacNetworks::new(&cfg, 3, &Device::Cpu).unwrap();
        let mut sac = SacLearner::new(nets, cfg.sac.clone(), Device::Cpu, 1).unwrap();
        let before = sac.policy_safetensors().unwrap();
        for _ in 0..2 {
            let m = sac.update(&batch).unwrap();
            assert!(m.critic_loss.is_finite() && m.actor_loss.is_finite());
        }
        assert_ne!(sac.policy_safetensors().unwrap(), before);
        // A batch of the standard layout does not fit these networks.
        let short = tiny_batch(&dvnav_config::Config::default());
        assert!(sac.update(&short).is_err());
    }

    #[test]
    fn state_round_trips_into_a_fresh_learner() {
        let cfg = dvnav_config::Config::default();
        let batch = tiny_batch(&cfg);
        let mut a = learner(1);
        for _ in 0..2 {
            a.update(&batch).unwrap();
        }
        let saved: std::collections::HashMap<String, Tensor> =
            a.state_tensors().unwrap().into_iter().collect();
        let mut fresh = learner(9);
        fresh.load_state(&saved, a.updates(), a.optimizer_steps()).unwrap();
        assert_eq!(fresh.policy_safetensors().unwrap(), a.policy_safetensors().unwrap());
        assert_eq!(fresh.updates(), 2);
        assert_eq!(fresh.optimizer_steps(), a.optimizer_steps());
    }

    /// `sac.policy_average_tau`: off, the agent is the online policy; on, the agent is θ̄,
    /// which moves at the policy updates only (every `policy_delay`-th), stays between the
    /// start and the online weights, and survives a checkpoint's state into a fresh learner.
    #[test]
    fn the_policy_average_is_the_agent_and_round_trips() {
        let cfg = dvnav_config::Config::default();
        let batch = tiny_batch(&cfg);
        let off = learner(1);
        assert!(!off.averages_policy());
        assert_eq!(off.agent_safetensors().unwrap(), off.policy_safetensors().unwrap());
        let avg_learner = |seed: u64| {
            let sac = dvnav_config::SacConfig { policy_average_tau: 0.3, ..cfg.sac.clone() };
            let nets = SacNetworks::new(&cfg, 3, &Device::Cpu).unwrap();
            SacLearner::new(nets, sac, Device::Cpu, seed).unwrap()
        };
        let mut a = avg_learner(1);
        let start = a.agent_safetensors().unwrap();
        assert_eq!(start, a.policy_safetensors().unwrap(), "θ̄ starts at θ");
        let flat = |bytes: &[u8]| -> Vec<f32> {
            let mut m: Vec<_> = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)
                .unwrap()
                .into_iter()
                .collect();
            m.sort_by(|x, y| x.0.cmp(&y.0));
            m.iter().flat_map(|(_, t)| t.flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
        };
        // Update 0 updates the policy (policy_delay 2), update 1 does not.
        a.update(&batch).unwrap();
        let after_first = a.agent_safetensors().unwrap();
        assert_ne!(after_first, start);
        assert_ne!(after_first, a.policy_safetensors().unwrap(), "θ̄ lags θ");
        let (s0, a1, p1) =
            (flat(&start), flat(&after_first), flat(&a.policy_safetensors().unwrap()));
        let worst = s0
            .iter()
            .zip(&a1)
            .zip(&p1)
            .map(|((s, m), p)| (m - (0.7 * s + 0.3 * p)).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-6, "θ̄ = 0.3 θ + 0.7 θ̄₀ up to rounding: {worst}");
        a.update(&batch).unwrap();
        assert_eq!(a.agent_safetensors().unwrap(), after_first, "no policy update, no move");
        a.update(&batch).unwrap();
        assert_ne!(a.agent_safetensors().unwrap(), after_first);
        // Into a fresh learner through the checkpoint's tensors.
        let saved: std::collections::HashMap<String, Tensor> =
            a.state_tensors().unwrap().into_iter().collect();
        assert!(saved.keys().any(|k| k.starts_with("actor_average.")));
        let mut fresh = avg_learner(9);
        fresh.load_state(&saved, a.updates(), a.optimizer_steps()).unwrap();
        assert_eq!(fresh.agent_safetensors().unwrap(), a.agent_safetensors().unwrap());
        // A state saved without an average starts θ̄ at its policy.
        let mut no_avg = learner(1);
        no_avg.update(&batch).unwrap();
        let plain: std::collections::HashMap<String, Tensor> =
            no_avg.state_tensors().unwrap().into_iter().collect();
        let mut turned_on = avg_learner(9);
        turned_on.load_state(&plain, 1, no_avg.optimizer_steps()).unwrap();
        assert_eq!(turned_on.agent_safetensors().unwrap(), no_avg.policy_safetensors().unwrap());
    }

    #[test]
    fn target_bootstraps_only_without_termination() {
        // r = 1, γ = 0.5, min Q' = 2, α log π' = 0.1·(−1): soft V' = 2.1.
        let y = soft_bellman_target(
            &t(&[1.0, 1.0]),
            &t(&[0.0, 1.0]),
            &t(&[0.5, 0.5]),
            &t(&[2.0, 2.0]),
            &t(&[3.0, 3.0]),
            &t(&[-1.0, -1.0]),
            &0.1,
        )
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
        assert!((y[0] - 2.05).abs() < 1e-6 && (y[1] - 1.0).abs() < 1e-6, "{y:?}");
    }

    #[test]
    fn an_n_step_target_discounts_the_bootstrap_by_its_own_gamma_power() {
        // Rows with k = 1, 2 and 3 steps summed at γ = 0.5: the bootstrap soft V' = 2.1 is
        // weighed by 0.5, 0.25 and 0.125.
        let y = soft_bellman_target(
            &t(&[1.0, 1.5, 1.75]),
            &t(&[0.0, 0.0, 0.0]),
            &t(&[0.5, 0.25, 0.125]),
            &t(&[2.0, 2.0, 2.0]),
            &t(&[3.0, 3.0, 3.0]),
            &t(&[-1.0, -1.0, -1.0]),
            &0.1,
        )
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
        let want = [1.0 + 0.5 * 2.1, 1.5 + 0.25 * 2.1, 1.75 + 0.125 * 2.1];
        for (got, want) in y.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{y:?}");
        }
    }

    #[test]
    fn losses_match_hand_computed_values() {
        let q1 = t(&[1.0, 2.0]);
        let q2 = t(&[0.0, 4.0]);
        let y = t(&[1.0, 3.0]);
        // ((0 + 1)/2) + ((1 + 1)/2) = 1.5
        let l = critic_loss(&q1, &q2, &y).unwrap().to_scalar::<f32>().unwrap();
        assert!((l - 1.5).abs() < 1e-6);
        // mean(0.5·[−1, −2] − [0, 2]) = mean([−0.5, −3]) = −1.75; L2: 1e-2·(1 + 4) = 0.05
        let w = [t(&[1.0, 2.0])];
        let a = actor_loss(&t(&[-1.0, -2.0]), &q1, &q2, &0.5, 1e-2, &w)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!((a + 1.7).abs() < 1e-6, "{a}");
        // −α·mean(log π + H̄) with α = 2, log π = [−1, −3], H̄ = −2: −2·mean([−3, −5]) = 8
        let la = t(&[2f32.ln()]);
        let j = temperature_loss(&la, &t(&[-1.0, -3.0]), -2.0).unwrap().to_scalar::<f32>().unwrap();
        assert!((j - 8.0).abs() < 1e-5, "{j}");
    }
}
