//! Checkpoints: everything the next update depends on, written atomically.
//!
//! Layout: `OUT/checkpoints/ckpt-<updates, 10 digits>/` with `state.safetensors` (networks,
//! targets, log α, optimizer moments), `policy.safetensors` (the policy alone, what `dvnav eval`
//! and actors load), `meta.json` (counters) and `config.toml`. A checkpoint is written into a
//! `.tmp` directory and renamed into place, so a crash mid-write never leaves a directory with
//! the final name; readers only consider directories with a `meta.json`.

use crate::sac::SacLearner;
use serde::{Deserialize, Serialize};
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
}

/// Number of checkpoints kept; older ones are removed after a new one is in place.
pub const KEEP: usize = 3;

/// Writes a checkpoint under `out_dir/checkpoints` and returns its directory.
pub fn write(
    out_dir: &Path,
    learner: &SacLearner,
    meta: &CheckpointMeta,
    config_toml: &str,
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
        let path = write(dir.path(), &a, &meta, "[run]\n").unwrap();
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
            write(dir.path(), &a, &meta, "").unwrap();
        }
        let names: Vec<String> = list(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["ckpt-0000000003", "ckpt-0000000004", "ckpt-0000000005"]);
    }
}
