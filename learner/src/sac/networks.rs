//! The SAC networks: policy, twin critics and their target copies, each with its own `VarMap`
//! (so nothing filters variables by name prefix), plus the temperature log α.
//!
//! The SAC learner (`sac::learning`, which imports this module) needs only two things of a
//! network, written as two small traits: a [`GaussianPolicy`] gives the mean and log std of the
//! pre-squash Gaussian, a [`QFunction`] gives Q(s, a). The navigation CNNs of
//! [`dvnav_nav::nets`] are the default instantiation (`SacNetworks` alone means
//! `SacNetworks<Actor, Critic>`); the pendulum test plugs in plain MLPs.

use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use dvnav_config::Config;
use dvnav_nav::nets::{Actor, Critic, PolicySample, init_seeded, squashed_gaussian};
use dvnav_sim::obs::ACTION_DIM;

/// π_θ(a|s) as a tanh-squashed diagonal Gaussian: the network gives μ and log σ, the sample
/// is a = tanh(μ + σ·ε).
pub trait GaussianPolicy: Sync {
    /// Length of an action.
    fn action_dim(&self) -> usize;
    /// `(mean, log_std)` of the pre-squash Gaussian, each `(batch, action_dim)`.
    fn mean_log_std(&self, obs: &Tensor) -> Result<(Tensor, Tensor)>;
    /// a = tanh(μ + σ·ε) for standard-normal noise `eps` `(batch, action_dim)`, with log π(a|s).
    fn sample_with_noise(&self, obs: &Tensor, eps: &Tensor) -> Result<PolicySample> {
        let (mean, log_std) = self.mean_log_std(obs)?;
        squashed_gaussian(&mean, &log_std, eps)
    }
}

/// A soft Q-function Q_φ(s, a) → `(batch,)`.
pub trait QFunction: Sync {
    /// Q(s, a) for a batch of observations and actions.
    fn q(&self, obs: &Tensor, action: &Tensor) -> Result<Tensor>;
    /// Q(s, a) as the policy loss uses it: the same value, and the same gradient with respect
    /// to the action; a network may skip gradients the policy loss throws away.
    fn q_for_policy(&self, obs: &Tensor, action: &Tensor) -> Result<Tensor> {
        self.q(obs, action)
    }
}

impl GaussianPolicy for Actor {
    fn action_dim(&self) -> usize {
        ACTION_DIM
    }
    fn mean_log_std(&self, obs: &Tensor) -> Result<(Tensor, Tensor)> {
        self.forward(obs)
    }
}

impl QFunction for Critic {
    fn q(&self, obs: &Tensor, action: &Tensor) -> Result<Tensor> {
        self.forward(obs, action)
    }
    fn q_for_policy(&self, obs: &Tensor, action: &Tensor) -> Result<Tensor> {
        self.forward_for_policy(obs, action)
    }
}

/// A network and the variables behind it.
pub struct Owned<N> {
    /// The module.
    pub net: N,
    /// Its variables.
    pub vars: VarMap,
}

impl<N> Owned<N> {
    /// Builds a network into a fresh `VarMap` and initialises it from `seed` with
    /// [`init_seeded`].
    pub fn build(dev: &Device, seed: u64, f: impl FnOnce(VarBuilder) -> Result<N>) -> Result<Self> {
        let vars = VarMap::new();
        let net = f(VarBuilder::from_varmap(&vars, DType::F32, dev))?;
        init_seeded(&vars, seed)?;
        Ok(Owned { net, vars })
    }

    /// Variables with their names, sorted by name (stable order for optimizers and checkpoints).
    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let data = self.vars.data().lock().expect("varmap lock");
        let mut v: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }
}

/// Everything SAC learns.
pub struct SacNetworks<P = Actor, Q = Critic> {
    /// π_θ.
    pub actor: Owned<P>,
    /// Q_φ1.
    pub critic1: Owned<Q>,
    /// Q_φ2.
    pub critic2: Owned<Q>,
    /// Q_φ̂1, Polyak-averaged copy of Q_φ1.
    pub target1: Owned<Q>,
    /// Q_φ̂2.
    pub target2: Owned<Q>,
    /// log α (a scalar), learned when the temperature is tuned.
    pub log_alpha: Var,
}

impl SacNetworks {
    /// Fresh navigation networks, deterministically initialised from `seed`; targets start as
    /// copies. Their matrix products run in `learner.precision` (`auto` in fp32: the learner
    /// resolves it by measuring first, [`crate::bench::precision`]).
    pub fn new(cfg: &Config, seed: u64, dev: &Device) -> Result<Self> {
        let layout = cfg.obs_layout();
        let (n, p) = (&cfg.network, cfg.learner.precision);
        Self::build(
            dev,
            seed,
            cfg.sac.initial_alpha,
            |vb| Ok(Actor::new(vb, n, layout)?.with_precision(p)),
            |vb| Ok(Critic::new(vb, n, layout)?.with_precision(p)),
        )
    }
}

impl<P, Q> SacNetworks<P, Q> {
    /// Fresh networks of any kind: the policy from `seed`, critic j and its target from
    /// `seed + j` (so each target starts as a copy of its critic), log α = ln `initial_alpha`.
    pub fn build(
        dev: &Device,
        seed: u64,
        initial_alpha: f64,
        actor: impl FnOnce(VarBuilder) -> Result<P>,
        critic: impl Fn(VarBuilder) -> Result<Q>,
    ) -> Result<Self> {
        let actor = Owned::build(dev, seed, actor)?;
        let critic1 = Owned::build(dev, seed.wrapping_add(1), &critic)?;
        let critic2 = Owned::build(dev, seed.wrapping_add(2), &critic)?;
        let target1 = Owned::build(dev, seed.wrapping_add(1), &critic)?;
        let target2 = Owned::build(dev, seed.wrapping_add(2), &critic)?;
        let log_alpha = Var::from_tensor(&Tensor::new(&[initial_alpha.ln() as f32], dev)?)?;
        Ok(Self { actor, critic1, critic2, target1, target2, log_alpha })
    }

    /// α = exp(log α) as a plain number.
    pub fn alpha(&self) -> f64 {
        self.log_alpha
            .as_tensor()
            .exp()
            .and_then(|t| t.to_vec1::<f32>())
            .map(|v| v[0] as f64)
            .unwrap_or(f64::NAN)
    }
}
