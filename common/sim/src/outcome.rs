//! How an episode ends, and the paper's score of it.

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Outcome {
    /// The robot's centre came within the goal tolerance.
    Success,
    /// The footprint touched an obstacle.
    Collision,
    /// T_max steps passed (a truncation: the value still bootstraps).
    Timeout,
}

impl Outcome {
    /// True when the episode terminated in the MDP sense (success, collision).
    pub fn is_terminal(self) -> bool {
        matches!(self, Outcome::Success | Outcome::Collision)
    }
    /// Lower-case name, as in JSON and tables.
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Success => "success",
            Outcome::Collision => "collision",
            Outcome::Timeout => "timeout",
        }
    }
}

/// The paper's score of an episode: 1 − 2·T_s/T_max on success, −1 otherwise.
pub fn score(outcome: Outcome, steps: u32, max_steps: u32) -> f64 {
    match outcome {
        Outcome::Success => 1.0 - 2.0 * steps as f64 / max_steps as f64,
        Outcome::Collision | Outcome::Timeout => -1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_score_rewards_fast_success_and_punishes_failure() {
        // S = 1 − 2·T_s/T_max on success, −1 on collision or timeout (design §4).
        assert_eq!(score(Outcome::Success, 0, 400), 1.0);
        assert_eq!(score(Outcome::Success, 100, 400), 0.5);
        assert_eq!(score(Outcome::Success, 400, 400), -1.0);
        assert_eq!(score(Outcome::Collision, 10, 400), -1.0);
        assert_eq!(score(Outcome::Timeout, 400, 400), -1.0);
    }
}
