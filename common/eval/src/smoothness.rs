//! How smooth a policy's commands are, as a real motor feels them: the ω-reversal rate (the
//! share of control cycles where the angular command changes sign by more than ω_max at once,
//! the chatter that wears gearboxes and shakes a robot in place) and the mean |Δω| per cycle.
//!
//! Counted over consecutive commands within one episode: an episode of n steps has n − 1
//! transitions (the first command follows a reset, not a command). Aggregates pool the
//! transitions of all episodes, so long episodes weigh what they drove.

use serde::Serialize;

/// Command transitions of one episode, or of many pooled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CommandStats {
    /// Pairs of consecutive commands.
    pub transitions: u32,
    /// Transitions where ω changed sign with |Δω| > ω_max.
    pub reversals: u32,
    /// Σ |Δω| over the transitions (rad/s).
    pub sum_abs_domega: f64,
}

impl CommandStats {
    /// Share of transitions that are reversals (NaN with none).
    pub fn reversal_rate(&self) -> f64 {
        self.reversals as f64 / self.transitions as f64
    }

    /// Mean |Δω| per transition (rad/s; NaN with none).
    pub fn mean_abs_domega(&self) -> f64 {
        self.sum_abs_domega / self.transitions as f64
    }

    /// The pooled transitions of `self` and `other`.
    pub fn pooled(self, other: CommandStats) -> CommandStats {
        CommandStats {
            transitions: self.transitions + other.transitions,
            reversals: self.reversals + other.reversals,
            sum_abs_domega: self.sum_abs_domega + other.sum_abs_domega,
        }
    }
}

/// Counts [`CommandStats`] command by command.
#[derive(Clone, Debug)]
pub struct CommandCounter {
    omega_max: f64,
    last: Option<f64>,
    stats: CommandStats,
}

impl CommandCounter {
    /// A counter for a robot whose angular bound is `omega_max` (rad/s).
    pub fn new(omega_max: f64) -> CommandCounter {
        CommandCounter { omega_max, last: None, stats: CommandStats::default() }
    }

    /// The next angular command (rad/s, as executed).
    pub fn push(&mut self, omega: f64) {
        if let Some(prev) = self.last {
            let d = omega - prev;
            self.stats.transitions += 1;
            self.stats.sum_abs_domega += d.abs();
            if prev * omega < 0.0 && d.abs() > self.omega_max {
                self.stats.reversals += 1;
            }
        }
        self.last = Some(omega);
    }

    /// What was counted.
    pub fn stats(&self) -> CommandStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reversals_are_sign_changes_larger_than_omega_max() {
        let w = 1.5;
        let mut c = CommandCounter::new(w);
        // Transitions: +1.0 → −1.0 (Δ 2.0, reversal), −1.0 → −0.2 (same sign),
        // −0.2 → +0.5 (sign change, Δ 0.7 ≤ ω_max: not a reversal), +0.5 → 0.0 (not a sign
        // change), 0.0 → −1.5 (from zero: not a sign change), −1.5 → 1.5 (reversal, Δ 3.0).
        for o in [1.0, -1.0, -0.2, 0.5, 0.0, -1.5, 1.5] {
            c.push(o);
        }
        let s = c.stats();
        assert_eq!((s.transitions, s.reversals), (6, 2));
        assert!((s.sum_abs_domega - (2.0 + 0.8 + 0.7 + 0.5 + 1.5 + 3.0)).abs() < 1e-12);
        assert!((s.reversal_rate() - 2.0 / 6.0).abs() < 1e-12);
        assert!((s.mean_abs_domega() - 8.5 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn one_command_has_no_transition_and_pooling_adds_counts() {
        let mut c = CommandCounter::new(1.0);
        c.push(1.0);
        assert_eq!(c.stats(), CommandStats::default());
        assert!(c.stats().reversal_rate().is_nan());
        let a = CommandStats { transitions: 3, reversals: 1, sum_abs_domega: 2.0 };
        let b = CommandStats { transitions: 1, reversals: 0, sum_abs_domega: 0.5 };
        assert_eq!(a.pooled(b), CommandStats { transitions: 4, reversals: 1, sum_abs_domega: 2.5 });
    }
}
