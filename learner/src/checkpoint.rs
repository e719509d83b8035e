//! Checkpoints: everything the next update depends on, written atomically.
//!
//! Layout: `OUT/checkpoints/ckpt-<updates, 10 digits>/` with `state.safetensors` (networks,
//! targets, log α, optimizer moments), `policy.safetensors` (the policy alone, what `dvnav eval`
//! and actors load), `meta.json` (counters, curriculum, the learner's two random generators),
//! `config.toml`, and `replay.safetensors` when `replay.save_in_checkpoint` is on. A
//! checkpoint is written into a `.tmp` directory and renamed into place, so a crash mid-write
//! never leaves a directory with the final name; readers only consider directories with a
//! `meta.json`.
//!
//! Exact resume: the next update depends on the networks, targets, Adam moments and step
//! counts, log α, the update counter (policy delay), the policy-noise generator and the batch
//! the sampling generator draws from the replay buffer. All of them are here; with the replay
//! buffer saved too, a resumed learner's next update is bit-for-bit the one it would have done
//! (`learner/tests/sac/resume.rs`).

use crate::curriculum::CurriculumState;
use crate::replay::{ObsCodec, ReplayBuffer};
use crate::sac::SacLearner;
use crate::state::LearnerState;
use candle_core::Tensor;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Counters stored beside the tensors.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct CheckpointMeta {
    /// Learner updates done.
    pub updates: u64,
    /// Transitions received.
    pub env_steps: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Weight version published last.
    pub weight_version: u64,
    /// Optimizer step counts (critic, actor, alpha).
    pub optimizer_steps: [u64; 3],
    /// Curriculum stage.
    pub stage: u32,
    /// Run id.
    pub run_id: String,
    /// Curriculum stage, success window and stage history (absent in older checkpoints).
    #[serde(default)]
    pub curriculum: Option<CurriculumState>,
    /// The learner's policy-noise generator ([`SacLearner::noise_rng`]).
    #[serde(default)]
    pub noise_rng: Option<rand_pcg::Pcg64>,
    /// The trainer's batch-sampling generator.
    #[serde(default)]
    pub sample_rng: Option<rand_pcg::Pcg64>,
}

/// The replay buffer's file inside a checkpoint directory, when it was saved.
pub const REPLAY_FILE: &str = "replay.safetensors";

/// A checkpoint read back: its directory, counters and state tensors.
pub struct Checkpoint {
    /// The checkpoint's directory.
    pub dir: PathBuf,
    /// Counters, curriculum and generators.
    pub meta: CheckpointMeta,
    /// Networks, targets, log α and optimizer moments by name.
    pub tensors: HashMap<String, Tensor>,
}

impl Checkpoint {
    /// Reads the newest complete checkpoint under `out_dir`, for `--resume`.
    pub fn latest(out_dir: &Path) -> anyhow::Result<Self> {
        let dir = latest(out_dir)?.ok_or_else(|| {
            anyhow::anyhow!(
                "no complete checkpoint under {}",
                out_dir.join("checkpoints").display()
            )
        })?;
        let (meta, tensors) = read(&dir)?;
        Ok(Self { dir, meta, tensors })
    }

    /// Puts the networks, targets, log α, optimizer state, update counter and noise generator
    /// into `learner`.
    pub fn restore_learner(&self, learner: &mut SacLearner) -> anyhow::Result<()> {
        learner.load_state(&self.tensors, self.meta.updates, self.meta.optimizer_steps)?;
        if let Some(rng) = &self.meta.noise_rng {
            learner.set_noise_rng(rng.clone());
        }
        Ok(())
    }

    /// Continues a run from this checkpoint (`--resume`): restores `learner` (see
    /// [`Self::restore_learner`]) and `state` (counters, curriculum, weight version, and the
    /// replay buffer when it was saved and fits this run's config), and returns the trainer's
    /// batch-sampling generator when the checkpoint holds one.
    pub fn resume(
        &self,
        learner: &mut SacLearner,
        state: &LearnerState,
    ) -> anyhow::Result<Option<rand_pcg::Pcg64>> {
        self.restore_learner(learner)?;
        let cfg = state.config();
        let replay = match self.replay(ObsCodec::for_config(cfg), cfg.replay.capacity) {
            Some(Ok(r)) => Some(r),
            Some(Err(e)) => {
                tracing::warn!(error = %e, "the checkpoint's replay buffer cannot be used; refilling it");
                None
            }
            None => None,
        };
        state.restore(&self.meta, replay, learner.policy_safetensors()?);
        Ok(self.meta.sample_rng.clone())
    }

    /// The saved replay buffer, if this checkpoint holds one.
    pub fn replay(&self, codec: ObsCodec, capacity: usize) -> Option<anyhow::Result<ReplayBuffer>> {
        let path = self.dir.join(REPLAY_FILE);
        path.exists().then(|| ReplayBuffer::load(&path, codec, capacity))
    }
}

/// Number of checkpoints kept; older ones are removed after a new one is in place.
pub const KEEP: usize = 3;

/// Writes a checkpoint under `out_dir/checkpoints` (with the replay buffer when one is given)
/// and returns its directory.
pub fn write(
    out_dir: &Path,
    learner: &SacLearner,
    meta: &CheckpointMeta,
    config_toml: &str,
    replay: Option<&ReplayBuffer>,
) -> anyhow::Result<PathBuf> {
    let root = out_dir.join("checkpoints");
    std::fs::create_dir_all(&root)?;
    let name = format!("ckpt-{:010}", meta.updates);
    let tmp = root.join(format!("{name}.tmp"));
    let dest = root.join(&name);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir_all(&tmp)?;
    let state = safetensors::tensor::serialize(learner.state_tensors(), None)?;
    std::fs::write(tmp.join("state.safetensors"), state)?;
    std::fs::write(tmp.join("policy.safetensors"), learner.policy_safetensors()?)?;
    std::fs::write(tmp.join("config.toml"), config_toml)?;
    if let Some(replay) = replay {
        replay.save(&tmp.join(REPLAY_FILE))?;
        std::fs::File::open(tmp.join(REPLAY_FILE))?.sync_all()?;
    }
    // meta.json last: readers take a directory with one as complete.
    std::fs::write(tmp.join("meta.json"), serde_json::to_vec_pretty(meta)?)?;
    for f in ["state.safetensors", "policy.safetensors", "config.toml", "meta.json"] {
        std::fs::File::open(tmp.join(f))?.sync_all()?;
    }
    if dest.exists() {
        std::fs::remove_dir_all(&dest)?;
    }
    std::fs::rename(&tmp, &dest)?;
    prune(&root)?;
    Ok(dest)
}

/// Complete checkpoints under `out_dir/checkpoints`, oldest first.
pub fn list(out_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let root = out_dir.join("checkpoints");
    if !root.exists() {
        return Ok(Vec::new());
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(&root)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("ckpt-") && !n.ends_with(".tmp"))
                && p.join("meta.json").exists()
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The newest complete checkpoint.
pub fn latest(out_dir: &Path) -> anyhow::Result<Option<PathBuf>> {
    Ok(list(out_dir)?.pop())
}

/// Reads a checkpoint's counters and tensors.
pub fn read(
    dir: &Path,
) -> anyhow::Result<(CheckpointMeta, std::collections::HashMap<String, candle_core::Tensor>)> {
    let meta: CheckpointMeta = serde_json::from_slice(&std::fs::read(dir.join("meta.json"))?)?;
    let tensors =
        candle_core::safetensors::load(dir.join("state.safetensors"), &candle_core::Device::Cpu)?;
    Ok((meta, tensors))
}

fn prune(root: &Path) -> anyhow::Result<()> {
    let out = root.parent().expect("checkpoints has a parent");
    let all = list(out)?;
    if all.len() > KEEP {
        for old in &all[..all.len() - KEEP] {
            std::fs::remove_dir_all(old)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sac::SacNetworks;
    use candle_core::Device;
    use dvnav_common::config::Config;

    fn learner(seed: u64) -> SacLearner {
        let cfg = Config::default();
        let nets = SacNetworks::new(&cfg, seed, &Device::Cpu).unwrap();
        SacLearner::new(nets, cfg.sac.clone(), Device::Cpu, seed).unwrap()
    }

    #[test]
    fn written_checkpoints_restore_and_half_written_ones_are_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let a = learner(1);
        let meta =
            CheckpointMeta { updates: 0, env_steps: 77, run_id: "r".into(), ..Default::default() };
        let path = write(dir.path(), &a, &meta, "[run]\n", None).unwrap();
        // A crash mid-write leaves only a .tmp directory, which readers skip.
        std::fs::create_dir_all(dir.path().join("checkpoints/ckpt-0000000099.tmp")).unwrap();
        assert_eq!(latest(dir.path()).unwrap(), Some(path.clone()));
        let (m, tensors) = read(&path).unwrap();
        assert_eq!(m, meta);
        let mut b = learner(2);
        assert_ne!(b.policy_safetensors().unwrap(), a.policy_safetensors().unwrap());
        b.load_state(&tensors, m.updates, m.optimizer_steps).unwrap();
        assert_eq!(b.policy_safetensors().unwrap(), a.policy_safetensors().unwrap());
        assert_eq!(
            std::fs::read(path.join("policy.safetensors")).unwrap(),
            a.policy_safetensors().unwrap()
        );
    }

    #[test]
    fn keeps_the_newest_three() {
        let dir = tempfile::tempdir().unwrap();
        let a = learner(1);
        for u in 1..=5 {
            let meta = CheckpointMeta { updates: u, ..Default::default() };
            write(dir.path(), &a, &meta, "", None).unwrap();
        }
        let names: Vec<String> = list(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["ckpt-0000000003", "ckpt-0000000004", "ckpt-0000000005"]);
    }
}
