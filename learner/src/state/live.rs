//! The live recorder: what ingestion records that counters alone do not keep, the policy lag
//! of every transition (current weight version minus the version that acted; PID transitions,
//! version 0, have no lag) and per-stage episode outcomes; and what the metrics sampler leaves
//! for readers between samples (rates, the lag of the latest interval, the rendered text).

use dvnav_link::core::TransitionBatch;
use dvnav_sim::Outcome;
use serde::Serialize;
use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};

/// Episodes per stage in the per-stage success rate (the curriculum's default window).
pub const STAGE_WINDOW: usize = 50;

/// Policy lag (weight versions) of a set of transitions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct LagStats {
    /// Sum of lags.
    pub sum: u64,
    /// Transitions counted (those that a policy chose, not the PID controller).
    pub count: u64,
    /// Largest lag.
    pub max: u64,
}

impl LagStats {
    fn add(&mut self, lag: u64) {
        self.sum += lag;
        self.count += 1;
        self.max = self.max.max(lag);
    }

    /// Mean lag; NaN when no policy-chosen transition was counted.
    pub fn mean(&self) -> f64 {
        if self.count == 0 { f64::NAN } else { self.sum as f64 / self.count as f64 }
    }
}

/// Lags kept exactly up to this; a larger one counts as this plus one (the percentiles then
/// read "more than 256").
const LAG_BUCKETS: usize = 257;

/// The distribution of the policy lag over a run, one count per lag in weight versions, for
/// percentiles (a mean hides the tail that stale data is).
#[derive(Clone, Debug, PartialEq)]
pub struct LagHistogram {
    counts: Vec<u64>,
}

impl Default for LagHistogram {
    fn default() -> Self {
        Self { counts: vec![0; LAG_BUCKETS + 1] }
    }
}

impl LagHistogram {
    /// Counts one transition of lag `lag`.
    pub fn add(&mut self, lag: u64) {
        let i = (lag as usize).min(LAG_BUCKETS);
        self.counts[i] += 1;
    }

    /// The nearest-rank `q`-quantile (0 < q ≤ 1); `None` before any transition.
    pub fn quantile(&self, q: f64) -> Option<u64> {
        let n: u64 = self.counts.iter().sum();
        if n == 0 {
            return None;
        }
        let rank = ((q * n as f64).ceil() as u64).clamp(1, n);
        let mut seen = 0;
        self.counts
            .iter()
            .position(|&c| {
                seen += c;
                seen >= rank
            })
            .map(|i| i as u64)
    }

    /// p50, p95, p99 and the count.
    pub fn percentiles(&self) -> LagPercentiles {
        LagPercentiles {
            p50: self.quantile(0.5),
            p95: self.quantile(0.95),
            p99: self.quantile(0.99),
            count: self.counts.iter().sum(),
        }
    }
}

/// Percentiles of the policy lag (weight versions) over the run's policy-chosen transitions;
/// `None` while only the PID controller has acted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct LagPercentiles {
    /// Median.
    pub p50: Option<u64>,
    /// 95th percentile.
    pub p95: Option<u64>,
    /// 99th percentile.
    pub p99: Option<u64>,
    /// Transitions counted.
    pub count: u64,
}

/// Episode outcomes of one curriculum stage.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct StageStats {
    /// Stage index.
    pub stage: u32,
    /// Episodes reported in this stage, all of the run.
    pub episodes: u64,
    /// Of which successes.
    pub successes: u64,
    /// Success rate over the stage's last [`STAGE_WINDOW`] episodes (NaN before any).
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub recent_success_rate: f64,
}

#[derive(Debug, Default)]
struct StageAcc {
    episodes: u64,
    successes: u64,
    recent: VecDeque<bool>,
}

#[derive(Debug, Default)]
struct LiveInner {
    lag: LagStats,
    lag_histogram: LagHistogram,
    window_lag: LagStats,
    stages: BTreeMap<u32, StageAcc>,
    env_steps_per_s: f64,
    updates_per_s: f64,
    recent_lag: LagStats,
    text: Arc<String>,
}

/// What [`LiveMetrics`] adds to a status snapshot.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct LiveSnapshot {
    /// Environment steps per second over the sampler's rate window (about 10 s).
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub env_steps_per_s: f64,
    /// Learner updates per second over the sampler's rate window.
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub updates_per_s: f64,
    /// Policy lag of the whole run.
    pub policy_lag: LagStats,
    /// Policy lag of the transitions of the latest sample interval.
    pub recent_policy_lag: LagStats,
    /// Percentiles of the policy lag over the whole run.
    #[serde(default)]
    pub policy_lag_percentiles: LagPercentiles,
    /// Per stage, in stage order.
    pub stages: Vec<StageStats>,
}

/// Metrics that ingestion records and the sampler reads; one per learner state.
#[derive(Debug, Default)]
pub struct LiveMetrics {
    inner: Mutex<LiveInner>,
}

impl LiveMetrics {
    fn lock(&self) -> std::sync::MutexGuard<'_, LiveInner> {
        self.inner.lock().expect("live metrics lock")
    }

    /// Records an accepted batch: the lag of every policy-chosen transition against
    /// `current_version`, and the outcome of every finished episode.
    pub fn record_batch(&self, batch: &TransitionBatch, current_version: u64) {
        let mut m = self.lock();
        for &v in &batch.policy_versions {
            if v > 0 {
                let lag = current_version.saturating_sub(v);
                m.lag.add(lag);
                m.lag_histogram.add(lag);
                m.window_lag.add(lag);
            }
        }
        for e in &batch.episodes {
            let s = m.stages.entry(e.stage).or_default();
            let success = e.outcome == Outcome::Success;
            s.episodes += 1;
            s.successes += u64::from(success);
            if s.recent.len() == STAGE_WINDOW {
                s.recent.pop_front();
            }
            s.recent.push_back(success);
        }
    }

    /// The snapshot that goes into the state's status snapshot.
    pub fn snapshot(&self) -> LiveSnapshot {
        let m = self.lock();
        LiveSnapshot {
            env_steps_per_s: m.env_steps_per_s,
            updates_per_s: m.updates_per_s,
            policy_lag: m.lag,
            recent_policy_lag: m.recent_lag,
            policy_lag_percentiles: m.lag_histogram.percentiles(),
            stages: m
                .stages
                .iter()
                .map(|(&stage, s)| StageStats {
                    stage,
                    episodes: s.episodes,
                    successes: s.successes,
                    recent_success_rate: if s.recent.is_empty() {
                        f64::NAN
                    } else {
                        s.recent.iter().filter(|&&x| x).count() as f64 / s.recent.len() as f64
                    },
                })
                .collect(),
        }
    }

    /// The Prometheus text of the latest sample (empty before the first).
    pub fn text(&self) -> Arc<String> {
        self.lock().text.clone()
    }

    /// Ends a sample interval (the metrics sampler calls it): stores the rates, and returns the
    /// lag of the interval's transitions.
    pub fn close_interval(&self, env_steps_per_s: f64, updates_per_s: f64) -> LagStats {
        let mut m = self.lock();
        m.env_steps_per_s = env_steps_per_s;
        m.updates_per_s = updates_per_s;
        m.recent_lag = std::mem::take(&mut m.window_lag);
        m.recent_lag
    }

    /// Stores the Prometheus text of the latest sample, for `GET /metrics`.
    pub fn set_text(&self, text: String) {
        self.lock().text = Arc::new(text);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lag_percentiles_are_nearest_rank_and_the_tail_is_capped() {
        let mut h = LagHistogram::default();
        assert_eq!(h.percentiles(), LagPercentiles::default());
        for lag in 1..=100 {
            h.add(lag);
        }
        assert_eq!(
            h.percentiles(),
            LagPercentiles { p50: Some(50), p95: Some(95), p99: Some(99), count: 100 }
        );
        let mut tail = LagHistogram::default();
        tail.add(0);
        tail.add(10_000);
        assert_eq!((tail.quantile(0.5), tail.quantile(1.0)), (Some(0), Some(257)));
    }
}
