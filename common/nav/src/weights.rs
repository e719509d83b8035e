//! Policy weights as they travel from learner to actors: safetensors bytes with a version.
//!
//! The learner serializes the policy's `VarMap` ([`crate::nets::varmap_to_safetensors`]); an
//! actor turns the bytes back into an [`crate::nets::Actor`]. [`PolicyHandle`] caches the built
//! network per version so an actor rebuilds it only when a new version arrives.

use crate::nets::Actor;
use candle_core::Device;
use dvnav_config::NetConfig;
use dvnav_sim::obs::ObsLayout;

/// The actor's current policy network and the version it was built from.
#[derive(Debug, Default)]
pub struct PolicyHandle {
    current: Option<(u64, Actor)>,
}

impl PolicyHandle {
    /// Version of the loaded policy, 0 when none is loaded.
    pub fn version(&self) -> u64 {
        self.current.as_ref().map_or(0, |(v, _)| *v)
    }

    /// The loaded policy, if any.
    pub fn actor(&self) -> Option<&Actor> {
        self.current.as_ref().map(|(_, a)| a)
    }

    /// Rebuilds the policy for observations of `layout` when `version` is newer than the
    /// loaded one.
    pub fn update(
        &mut self,
        version: u64,
        bytes: &[u8],
        cfg: &NetConfig,
        layout: ObsLayout,
    ) -> anyhow::Result<bool> {
        if version <= self.version() {
            return Ok(false);
        }
        let actor = Actor::from_safetensors(bytes, cfg, layout, &Device::Cpu)?;
        self.current = Some((version, actor));
        Ok(true)
    }
}
