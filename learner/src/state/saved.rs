//! The state's own part of a checkpoint ([`SavedState`]); the checkpoint module stores it
//! beside the SAC learner's part and the trainer's generator.

use crate::curriculum::CurriculumState;

/// What the learner state saves of itself and restores from (besides the replay buffer, which
/// it hands out under its lock, and the policy, which is the SAC learner's).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SavedState {
    /// Run id.
    pub run_id: String,
    /// Transitions received.
    pub env_steps: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Weight version published last.
    pub weight_version: u64,
    /// Curriculum stage.
    pub stage: u32,
    /// Curriculum stage, success window and stage history (absent in older checkpoints, which
    /// keep only the stage).
    pub curriculum: Option<CurriculumState>,
}
