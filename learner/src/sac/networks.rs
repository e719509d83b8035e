//! The SAC networks: policy, twin critics and their target copies, each with its own `VarMap`
//! (so nothing filters variables by name prefix), plus the temperature log α.

use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use dvnav_common::config::Config;
use dvnav_common::nets::{Actor, Critic, init_seeded};

/// A network and the variables behind it.
pub struct Owned<N> {
    /// The module.
    pub net: N,
    /// Its variables.
    pub vars: VarMap,
}

impl<N> Owned<N> {
    /// Variables with their names, sorted by name (stable order for optimizers and checkpoints).
    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let data = self.vars.data().lock().expect("varmap lock");
        let mut v: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }
}

fn build<N>(dev: &Device, seed: u64, f: impl FnOnce(VarBuilder) -> Result<N>) -> Result<Owned<N>> {
    let vars = VarMap::new();
    let net = f(VarBuilder::from_varmap(&vars, DType::F32, dev))?;
    init_seeded(&vars, seed)?;
    Ok(Owned { net, vars })
}

/// Everything SAC learns.
pub struct SacNetworks {
    /// π_θ.
    pub actor: Owned<Actor>,
    /// Q_φ1.
    pub critic1: Owned<Critic>,
    /// Q_φ2.
    pub critic2: Owned<Critic>,
    /// Q_φ̂1, Polyak-averaged copy of Q_φ1.
    pub target1: Owned<Critic>,
    /// Q_φ̂2.
    pub target2: Owned<Critic>,
    /// log α (a scalar), learned when the temperature is tuned.
    pub log_alpha: Var,
}

impl SacNetworks {
    /// Fresh networks, deterministically initialised from `seed`; targets start as copies.
    pub fn new(cfg: &Config, seed: u64, dev: &Device) -> Result<Self> {
        let beams = cfg.env.lidar.beams;
        let n = &cfg.network;
        let actor = build(dev, seed, |vb| Actor::new(vb, n, beams))?;
        let critic1 = build(dev, seed.wrapping_add(1), |vb| Critic::new(vb, n, beams))?;
        let critic2 = build(dev, seed.wrapping_add(2), |vb| Critic::new(vb, n, beams))?;
        let target1 = build(dev, seed.wrapping_add(1), |vb| Critic::new(vb, n, beams))?;
        let target2 = build(dev, seed.wrapping_add(2), |vb| Critic::new(vb, n, beams))?;
        let log_alpha = Var::from_tensor(&Tensor::new(&[cfg.sac.initial_alpha.ln() as f32], dev)?)?;
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
