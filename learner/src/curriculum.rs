//! The room curriculum (design §4): start in the first room; when the success rate over the
//! last `window` episodes of the current stage reaches `threshold`, move to the next room.
//! Warm-up (PID) episodes and episodes reported from another stage do not count: the rule
//! measures the learned policy in the current room.

use dvnav_config::CurriculumConfig;
use std::collections::VecDeque;

/// A stage change, for logs and the run summary.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StageChange {
    /// The new stage index.
    pub stage: u32,
    /// Its room.
    pub room: String,
    /// Environment steps received when it happened.
    pub env_steps: u64,
    /// Learner updates done when it happened.
    pub updates: u64,
}

/// What a checkpoint keeps of the curriculum: the stage, the success window and the history.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CurriculumState {
    /// Current stage.
    pub stage: u32,
    /// Outcomes (true: success) of the current stage's latest episodes, oldest first.
    pub recent: Vec<bool>,
    /// Stage changes so far.
    pub changes: Vec<StageChange>,
    /// When the last room first reached the threshold over a full window ("time to skill").
    #[serde(default)]
    pub skilled: Option<StageChange>,
}

/// Curriculum state owned by the learner.
#[derive(Clone, Debug)]
pub struct Curriculum {
    cfg: CurriculumConfig,
    stage: u32,
    recent: VecDeque<bool>,
    changes: Vec<StageChange>,
    skilled: Option<StageChange>,
}

impl Curriculum {
    /// Starts at stage 0.
    pub fn new(cfg: CurriculumConfig) -> Self {
        Self { cfg, stage: 0, recent: VecDeque::new(), changes: Vec::new(), skilled: None }
    }

    /// Continues from a checkpoint's state; the stage is clamped to the configured rooms.
    pub fn restore(cfg: CurriculumConfig, state: CurriculumState) -> Self {
        let stage = state.stage.min(cfg.rooms.len() as u32 - 1);
        let mut recent: VecDeque<bool> = state.recent.into();
        while recent.len() > cfg.window {
            recent.pop_front();
        }
        Self { cfg, stage, recent, changes: state.changes, skilled: state.skilled }
    }

    /// The state a checkpoint keeps.
    pub fn snapshot(&self) -> CurriculumState {
        CurriculumState {
            stage: self.stage,
            recent: self.recent.iter().copied().collect(),
            changes: self.changes.clone(),
            skilled: self.skilled.clone(),
        }
    }

    /// Current stage.
    pub fn stage(&self) -> u32 {
        self.stage
    }

    /// Room of the current stage.
    pub fn room(&self) -> &str {
        &self.cfg.rooms[self.stage as usize]
    }

    /// Success rate over the current window (0 when empty).
    pub fn success_rate(&self) -> f64 {
        if self.recent.is_empty() {
            0.0
        } else {
            self.recent.iter().filter(|s| **s).count() as f64 / self.recent.len() as f64
        }
    }

    /// Stage changes so far.
    pub fn changes(&self) -> &[StageChange] {
        &self.changes
    }

    /// When the last room first reached the threshold over a full window, if it has.
    pub fn skilled(&self) -> Option<&StageChange> {
        self.skilled.as_ref()
    }

    /// Records a finished episode; returns the stage change it caused, if any. An `uncounted`
    /// one (the PID warm-up's, a varied robot's) changes nothing.
    pub fn record(
        &mut self,
        stage: u32,
        success: bool,
        uncounted: bool,
        env_steps: u64,
        updates: u64,
    ) -> Option<StageChange> {
        if uncounted || stage != self.stage {
            return None;
        }
        self.recent.push_back(success);
        while self.recent.len() > self.cfg.window {
            self.recent.pop_front();
        }
        let last = self.cfg.rooms.len() as u32 - 1;
        let passed =
            self.recent.len() == self.cfg.window && self.success_rate() >= self.cfg.threshold;
        if passed && self.stage == last && self.skilled.is_none() {
            self.skilled = Some(StageChange {
                stage: self.stage,
                room: self.room().to_string(),
                env_steps,
                updates,
            });
        }
        if self.stage < last && passed {
            self.stage += 1;
            self.recent.clear();
            let change = StageChange {
                stage: self.stage,
                room: self.room().to_string(),
                env_steps,
                updates,
            };
            self.changes.push(change.clone());
            return Some(change);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> CurriculumConfig {
        CurriculumConfig {
            rooms: vec!["a".into(), "b".into()],
            window: 4,
            threshold: 0.75,
            ..Default::default()
        }
    }

    #[test]
    fn advances_when_the_window_reaches_the_threshold() {
        let mut c = Curriculum::new(cfg());
        for s in [true, false, true] {
            assert_eq!(c.record(0, s, false, 0, 0), None);
        }
        // Window full with 3/4 = 0.75.
        let ch = c.record(0, true, false, 100, 7).unwrap();
        assert_eq!((ch.stage, ch.room.as_str(), ch.env_steps), (1, "b", 100));
        assert_eq!(c.stage(), 1);
        // The last stage stays; the first full window at the threshold there is the skill.
        for k in 0..8 {
            assert_eq!(c.record(1, true, false, 200 + k, 0), None);
        }
        assert_eq!(c.skilled().map(|s| (s.stage, s.env_steps)), Some((1, 203)));
        assert_eq!(c.snapshot().skilled, c.skilled().cloned());
    }

    #[test]
    fn warmup_and_other_stages_do_not_count() {
        let mut c = Curriculum::new(cfg());
        for _ in 0..10 {
            assert_eq!(c.record(0, true, true, 0, 0), None);
            assert_eq!(c.record(1, true, false, 0, 0), None);
        }
        assert_eq!(c.stage(), 0);
        assert_eq!(c.success_rate(), 0.0);
    }

    #[test]
    fn a_restored_curriculum_continues_where_it_stopped() {
        let mut a = Curriculum::new(cfg());
        for s in [true, false, true] {
            a.record(0, s, false, 0, 0);
        }
        let mut b = Curriculum::restore(cfg(), a.snapshot());
        assert_eq!(b.snapshot(), a.snapshot());
        // One more success fills the window at 3/4 in both.
        assert_eq!(a.record(0, true, false, 5, 1), b.record(0, true, false, 5, 1));
        assert_eq!((b.stage(), b.changes().len()), (1, 1));
    }

    #[test]
    fn a_failure_in_the_window_holds_the_stage() {
        let mut c = Curriculum::new(CurriculumConfig { threshold: 1.0, ..cfg() });
        for s in [true, true, false, true, true, true] {
            c.record(0, s, false, 0, 0);
        }
        // Last four: false, true, true, true → 0.75 < 1.0 until the failure leaves the window.
        assert_eq!(c.stage(), 0);
        assert!(c.record(0, true, false, 0, 0).is_some());
    }
}
