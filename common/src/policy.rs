//! [`NavPolicy`]: the seam between "something that drives" and everything that runs it
//! (evaluation, DVST, the controller service). An observation in the flat layout of
//! [`crate::obs`] (physical units: metres, radians, m/s) goes in; a velocity command (v, ω) in
//! m/s and rad/s comes out. DVST wraps any `NavPolicy`, not only our network (design §5).

use crate::config::{Config, EnvConfig, WarmupConfig};
use crate::control::{action_to_velocity, pid_velocity};
use crate::nets::Actor;
use crate::obs::{ObsView, obs_dim};
use anyhow::Context;
use candle_core::{Device, Tensor};
use std::path::Path;

/// A navigation controller: observation in, velocity command out.
pub trait NavPolicy {
    /// Scan length this policy expects.
    fn beams(&self) -> usize;
    /// The command (v in m/s, ω in rad/s) for one observation of `obs_dim(beams)` values.
    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)>;
    /// Linear and angular speed bounds (v_max, ω_max) the policy was made for.
    fn velocity_bounds(&self) -> (f64, f64);
    /// Commands for several observations laid out back to back (`n · obs_dim(beams)` values),
    /// in order. By default one [`act`](Self::act) each; a network overrides it with one
    /// forward pass for all, which is how evaluation steps many environments in lockstep
    /// ([`crate::eval`]).
    fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        let d = obs_dim(self.beams());
        anyhow::ensure!(
            obs.len().is_multiple_of(d),
            "observation batch is not a multiple of {d} values"
        );
        obs.chunks_exact(d).map(|o| self.act(o)).collect()
    }
}

/// The trained meta agent acting deterministically: a = tanh(μ(s)), mapped to velocities within
/// the meta robot's bounds (design §3).
#[derive(Debug)]
pub struct MetaAgent {
    actor: Actor,
    env: EnvConfig,
    beams: usize,
}

impl MetaAgent {
    /// Builds the agent from policy weights (safetensors bytes) and the run's configuration.
    pub fn from_safetensors(bytes: &[u8], cfg: &Config) -> anyhow::Result<Self> {
        let beams = cfg.env.lidar.beams;
        let actor = Actor::from_safetensors(bytes, &cfg.network, beams, &Device::Cpu)
            .context("policy weights do not match the configured network")?;
        Ok(Self { actor, env: cfg.env.clone(), beams })
    }

    /// Loads `policy.safetensors` from `path`: a checkpoint directory, a model directory, or
    /// the file itself. The configuration is `config.toml` beside the weights if there is
    /// one, else the defaults.
    pub fn load(path: &Path) -> anyhow::Result<(Self, Config)> {
        let file = if path.is_dir() { path.join("policy.safetensors") } else { path.to_path_buf() };
        let dir = file.parent().unwrap_or(Path::new("."));
        let cfg_file = dir.join("config.toml");
        let cfg = if cfg_file.exists() { Config::load(&cfg_file)? } else { Config::default() };
        let bytes = std::fs::read(&file)
            .with_context(|| format!("{}: cannot read the policy weights", file.display()))?;
        let agent = Self::from_safetensors(&bytes, &cfg)
            .with_context(|| format!("{}: not a policy of this network", file.display()))?;
        Ok((agent, cfg))
    }

    /// The underlying network.
    pub fn actor(&self) -> &Actor {
        &self.actor
    }

    /// Deterministic commands for a batch of observations laid out back to back.
    pub fn act_batch(&self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        let d = obs_dim(self.beams);
        anyhow::ensure!(
            obs.len().is_multiple_of(d),
            "observation batch is not a multiple of {d} values"
        );
        let n = obs.len() / d;
        let t = Tensor::from_slice(obs, (n, d), &Device::Cpu)?;
        let a = self.actor.deterministic(&t)?.to_vec2::<f32>()?;
        Ok(a.into_iter().map(|a| action_to_velocity([a[0], a[1]], &self.env)).collect())
    }
}

impl NavPolicy for MetaAgent {
    fn beams(&self) -> usize {
        self.beams
    }

    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        let d = obs_dim(self.beams);
        anyhow::ensure!(obs.len() == d, "observation has {} values, expected {d}", obs.len());
        Ok(self.act_batch(obs)?[0])
    }

    fn velocity_bounds(&self) -> (f64, f64) {
        (self.env.v_max, self.env.omega_max)
    }

    fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        MetaAgent::act_batch(self, obs)
    }
}

/// The PID warm-up controller as a policy (a baseline that ignores the scan).
#[derive(Clone, Debug)]
pub struct PidPolicy {
    /// Gains.
    pub warmup: WarmupConfig,
    /// Bounds and geometry.
    pub env: EnvConfig,
}

impl NavPolicy for PidPolicy {
    fn beams(&self) -> usize {
        self.env.lidar.beams
    }

    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        let o = ObsView::new(obs, self.env.lidar.beams);
        Ok(pid_velocity(o.goal_distance() as f64, o.goal_angle() as f64, &self.warmup, &self.env))
    }

    fn velocity_bounds(&self) -> (f64, f64) {
        (self.env.v_max, self.env.omega_max)
    }
}
