//! [`NavPolicy`]: the seam between "something that drives" and everything that runs it
//! (evaluation, DVST, the controller service). An observation in the flat layout of
//! [`dvnav_sim::obs`] (physical units: metres, radians, m/s) goes in; a velocity command (v, ω) in
//! m/s and rad/s comes out. DVST wraps any `NavPolicy`, not only our network (design §5).
//!
//! A policy says how long its observations are ([`NavPolicy::obs_dim`]): the standard layout,
//! or one longer for a [`MetaAgent`] trained with `env.radius_input` (the SAC_RI baseline).
//! Environments of the same `EnvConfig` write that layout with their own robot's radius, so
//! the radius a policy sees is always the size of the robot being simulated.

use crate::control::{action_to_velocity, pid_velocity};
use crate::nets::Actor;
use anyhow::Context;
use candle_core::{Device, Tensor};
use dvnav_config::{Config, EnvConfig, WarmupConfig};
use dvnav_sim::obs::{ObsLayout, ObsView, obs_dim};
use std::path::{Path, PathBuf};

/// A navigation controller: observation in, velocity command out.
pub trait NavPolicy {
    /// Scan length this policy expects.
    fn beams(&self) -> usize;
    /// Length of one observation: the standard layout's `obs_dim(beams)` unless the policy
    /// takes more (the robot's radius, [`ObsLayout::radius_input`]).
    fn obs_dim(&self) -> usize {
        obs_dim(self.beams())
    }
    /// The command (v in m/s, ω in rad/s) for one observation of [`obs_dim`](Self::obs_dim)
    /// values.
    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)>;
    /// Linear and angular speed bounds (v_max, ω_max) the policy was made for.
    fn velocity_bounds(&self) -> (f64, f64);
    /// Commands for several observations laid out back to back (`n · obs_dim` values), in
    /// order. By default one [`act`](Self::act) each; a network overrides it with one
    /// forward pass for all, which is how evaluation steps many environments in lockstep
    /// (`dvnav-eval`).
    fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        let d = self.obs_dim();
        anyhow::ensure!(
            obs.len().is_multiple_of(d),
            "observation batch is not a multiple of {d} values"
        );
        obs.chunks_exact(d).map(|o| self.act(o)).collect()
    }
    /// As [`act_batch`](Self::act_batch), with the rows that have noise ε (standard normal,
    /// one value per action dimension) sampled from the policy's own distribution instead of
    /// acted deterministically: the stall escape ([`crate::escape`]). A policy that has no
    /// distribution (the PID controller) ignores the noise, which is this default.
    fn act_batch_noisy(
        &mut self,
        obs: &[f32],
        noise: &[Option<[f32; 2]>],
    ) -> anyhow::Result<Vec<(f64, f64)>> {
        let _ = noise;
        self.act_batch(obs)
    }
}

/// A policy as stored: its weights file and the configuration beside it.
#[derive(Clone, Debug)]
pub struct PolicyFile {
    /// The `policy.safetensors` read.
    pub path: PathBuf,
    /// Its bytes.
    pub weights: Vec<u8>,
    /// `config.toml` beside it, else the defaults.
    pub config: Config,
}

/// Reads a policy from a checkpoint directory, a model directory or a `policy.safetensors`
/// file, with the `config.toml` beside it (else the defaults). One read of the weights serves
/// building the network and anything else that needs the bytes (a version hash).
pub fn read_policy(path: &Path) -> anyhow::Result<PolicyFile> {
    anyhow::ensure!(path.exists(), "checkpoint {}: no such file or directory", path.display());
    let file = if path.is_dir() { path.join("policy.safetensors") } else { path.to_path_buf() };
    let dir = file.parent().unwrap_or(Path::new("."));
    let cfg_file = dir.join("config.toml");
    let config = if cfg_file.exists() { Config::load(&cfg_file)? } else { Config::default() };
    let weights = std::fs::read(&file)
        .with_context(|| format!("{}: cannot read the policy weights", file.display()))?;
    Ok(PolicyFile { path: file, weights, config })
}

/// The trained meta agent acting deterministically: a = tanh(μ(s)), mapped to velocities within
/// the meta robot's bounds (design §3). Its observations are in the layout of its run's config
/// ([`Config::obs_layout`]): with `env.radius_input` the robot's radius follows ω.
#[derive(Debug)]
pub struct MetaAgent {
    actor: Actor,
    env: EnvConfig,
    layout: ObsLayout,
}

impl MetaAgent {
    /// Builds the agent from policy weights (safetensors bytes) and the run's configuration.
    pub fn from_safetensors(bytes: &[u8], cfg: &Config) -> anyhow::Result<Self> {
        let layout = cfg.obs_layout();
        let actor = Actor::from_safetensors(bytes, &cfg.network, layout, &Device::Cpu)
            .context("policy weights do not match the configured network")?;
        Ok(Self { actor, env: cfg.env.clone(), layout })
    }

    /// Loads `policy.safetensors` from `path`: a checkpoint directory, a model directory, or
    /// the file itself. The configuration is `config.toml` beside the weights if there is
    /// one, else the defaults.
    pub fn load(path: &Path) -> anyhow::Result<(Self, Config)> {
        let file = read_policy(path)?;
        Ok((Self::from_policy_file(&file)?, file.config))
    }

    /// Builds the agent from weights read by [`read_policy`].
    pub fn from_policy_file(file: &PolicyFile) -> anyhow::Result<Self> {
        Self::from_safetensors(&file.weights, &file.config).with_context(|| {
            format!("{}: not a policy of the network in its config", file.path.display())
        })
    }

    /// The underlying network.
    pub fn actor(&self) -> &Actor {
        &self.actor
    }

    /// The observation layout the agent takes.
    pub fn layout(&self) -> ObsLayout {
        self.layout
    }

    /// Deterministic commands for a batch of observations laid out back to back.
    pub fn act_batch(&self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        let d = self.layout.dim();
        anyhow::ensure!(
            obs.len().is_multiple_of(d),
            "observation batch is not a multiple of {d} values"
        );
        let n = obs.len() / d;
        let t = Tensor::from_slice(obs, (n, d), &Device::Cpu)?;
        let a = self.actor.deterministic(&t)?.to_vec2::<f32>()?;
        Ok(a.into_iter().map(|a| action_to_velocity([a[0], a[1]], &self.env)).collect())
    }

    /// [`act_batch`](Self::act_batch) with the rows that have noise ε sampled: a =
    /// tanh(μ + σ·ε), the squashed Gaussian SAC trained; the other rows as `act_batch` gives
    /// them, to the bit.
    pub fn act_batch_noisy(
        &self,
        obs: &[f32],
        noise: &[Option<[f32; 2]>],
    ) -> anyhow::Result<Vec<(f64, f64)>> {
        let d = self.layout.dim();
        let n = obs.len() / d;
        anyhow::ensure!(
            obs.len() == n * d && noise.len() == n,
            "{} observation values and {} noise rows: expected {d} values per row",
            obs.len(),
            noise.len()
        );
        if noise.iter().all(Option::is_none) {
            return self.act_batch(obs);
        }
        let t = Tensor::from_slice(obs, (n, d), &Device::Cpu)?;
        let (mean, log_std) = self.actor.forward(&t)?;
        let deterministic = mean.tanh()?.to_vec2::<f32>()?;
        let (mean, log_std) = (mean.to_vec2::<f32>()?, log_std.to_vec2::<f32>()?);
        Ok((0..n)
            .map(|i| {
                let a = match noise[i] {
                    Some(eps) => {
                        let u = |j: usize| (mean[i][j] + log_std[i][j].exp() * eps[j]).tanh();
                        [u(0), u(1)]
                    }
                    None => [deterministic[i][0], deterministic[i][1]],
                };
                action_to_velocity(a, &self.env)
            })
            .collect())
    }
}

impl NavPolicy for MetaAgent {
    fn beams(&self) -> usize {
        self.layout.beams
    }

    fn obs_dim(&self) -> usize {
        self.layout.dim()
    }

    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        let d = self.layout.dim();
        anyhow::ensure!(obs.len() == d, "observation has {} values, expected {d}", obs.len());
        Ok(self.act_batch(obs)?[0])
    }

    fn velocity_bounds(&self) -> (f64, f64) {
        (self.env.v_max, self.env.omega_max)
    }

    fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
        MetaAgent::act_batch(self, obs)
    }

    fn act_batch_noisy(
        &mut self,
        obs: &[f32],
        noise: &[Option<[f32; 2]>],
    ) -> anyhow::Result<Vec<(f64, f64)>> {
        MetaAgent::act_batch_noisy(self, obs, noise)
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

    fn obs_dim(&self) -> usize {
        self.env.obs_layout().dim()
    }

    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        let o = ObsView::with_layout(obs, self.env.obs_layout());
        Ok(pid_velocity(o.goal_distance() as f64, o.goal_angle() as f64, &self.warmup, &self.env))
    }

    fn velocity_bounds(&self) -> (f64, f64) {
        (self.env.v_max, self.env.omega_max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dvst::{Dvst, VariedRobot};
    use candle_core::DType;
    use candle_nn::{VarBuilder, VarMap};
    use dvnav_sim::Footprint;

    /// A radius-input config with a small network, and a seeded policy for it.
    fn radius_input_agent() -> (Config, MetaAgent) {
        let mut cfg = Config::default();
        cfg.env.radius_input = true;
        (cfg.network.conv1_channels, cfg.network.conv2_channels) = (4, 4);
        (cfg.network.scan_features, cfg.network.hidden) = (8, 16);
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        Actor::new(vb, &cfg.network, cfg.obs_layout()).unwrap();
        crate::nets::init_seeded(&vm, 3).unwrap();
        let bytes = crate::nets::varmap_to_safetensors(&vm).unwrap();
        let agent = MetaAgent::from_safetensors(&bytes, &cfg).unwrap();
        (cfg, agent)
    }

    #[test]
    fn a_radius_input_agent_takes_the_longer_observation_and_reads_the_radius() {
        let (cfg, mut agent) = radius_input_agent();
        assert_eq!((agent.beams(), NavPolicy::obs_dim(&agent)), (540, 545));
        let mut o = vec![3.0f32; 545];
        o[540..].copy_from_slice(&[2.0, 0.3, 0.1, 0.0, 0.2]);
        let small = agent.act(&o).unwrap();
        o[544] = 0.5;
        let large = agent.act(&o).unwrap();
        assert_ne!(small, large, "the radius is an input");
        let batch: Vec<f32> = o.iter().chain(&o).copied().collect();
        assert_eq!(agent.act_batch(&batch).unwrap(), vec![large, large]);
        assert!(agent.act(&o[..544]).is_err(), "the standard observation is one short");
        // The PID controller reads the same layout.
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        assert_eq!(pid.obs_dim(), 545);
        assert!(pid.act(&o).unwrap().0 > 0.0);
        // DVST transfers the standard observation only.
        let e = Dvst::new(agent, VariedRobot::new(Footprint::circle(0.4))).unwrap_err();
        assert!(e.to_string().contains("own radius"), "{e}");
    }

    #[test]
    fn noisy_rows_sample_the_squashed_gaussian_and_the_others_stay_deterministic() {
        let (cfg, agent) = radius_input_agent();
        let d = NavPolicy::obs_dim(&agent);
        let mut obs = vec![2.0f32; 3 * d];
        for (k, row) in obs.chunks_exact_mut(d).enumerate() {
            row[540..].copy_from_slice(&[1.5 + k as f32, 0.4, 0.2, 0.1, 0.2]);
        }
        let plain = agent.act_batch(&obs).unwrap();
        let eps = [0.7f32, -1.3];
        let noisy = agent.act_batch_noisy(&obs, &[None, Some(eps), None]).unwrap();
        assert_eq!((noisy[0], noisy[2]), (plain[0], plain[2]), "rows without noise, to the bit");
        assert_ne!(noisy[1], plain[1]);
        // Row 1 is tanh(μ + σ·ε), computed here from the network's own outputs.
        let t = Tensor::from_slice(&obs[d..2 * d], (1, d), &Device::Cpu).unwrap();
        let (mean, log_std) = agent.actor().forward(&t).unwrap();
        let (m, ls) = (mean.to_vec2::<f32>().unwrap(), log_std.to_vec2::<f32>().unwrap());
        let a = [0, 1].map(|j| (m[0][j] + ls[0][j].exp() * eps[j]).tanh());
        let want = action_to_velocity(a, &cfg.env);
        assert!((noisy[1].0 - want.0).abs() < 1e-6 && (noisy[1].1 - want.1).abs() < 1e-6);
        // No noise at all: act_batch itself; a wrong number of rows is refused.
        assert_eq!(agent.act_batch_noisy(&obs, &[None; 3]).unwrap(), plain);
        assert!(agent.act_batch_noisy(&obs, &[None; 2]).is_err());
        // The PID controller has no distribution: it ignores the noise.
        let mut pid = PidPolicy { warmup: cfg.warmup.clone(), env: cfg.env.clone() };
        assert_eq!(
            pid.act_batch_noisy(&obs, &[Some(eps); 3]).unwrap(),
            pid.act_batch(&obs).unwrap()
        );
    }
}
