//! [`Sampler`]: takes a [`Sample`] of the state, with rates over the last [`RATE_WINDOW`] and
//! the lag of the transitions since the previous sample, and leaves the rates and the rendered
//! Prometheus text in the state's live recorder.

use super::prometheus::render_prometheus;
use super::sample::Sample;
use crate::process_memory::ProcessMemory;
use crate::state::LearnerState;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Rates (steps/s, updates/s) are taken over about this much wall time, to smooth out the
/// batch-sized steps in which transitions arrive.
pub const RATE_WINDOW: Duration = Duration::from_secs(10);

/// Takes [`Sample`]s; keeps the short history that rates are computed over.
#[derive(Debug)]
pub struct Sampler {
    started: Instant,
    /// (seconds since start, env steps, updates), oldest first.
    pub(super) history: VecDeque<(f64, u64, u64)>,
}

impl Default for Sampler {
    fn default() -> Self {
        Self::new()
    }
}

impl Sampler {
    /// A sampler whose clock starts now.
    pub fn new() -> Self {
        Self { started: Instant::now(), history: VecDeque::new() }
    }

    /// Samples `state`: rates over the last [`RATE_WINDOW`] (0 at the first sample), the lag
    /// of the transitions since the previous sample; stores both and the rendered text in the
    /// state's live recorder ([`LiveMetrics`](crate::state::LiveMetrics)).
    pub fn sample(&mut self, state: &LearnerState) -> Sample {
        let t = self.started.elapsed().as_secs_f64();
        let before = state.status();
        let now = (t, before.transitions_received, before.updates);
        while self.history.len() > 1
            && self.history.get(1).is_some_and(|h| t - h.0 >= RATE_WINDOW.as_secs_f64())
        {
            self.history.pop_front();
        }
        let (steps_per_s, updates_per_s) = match self.history.front() {
            Some(&(t0, s0, u0)) if t > t0 => (
                now.1.saturating_sub(s0) as f64 / (t - t0),
                now.2.saturating_sub(u0) as f64 / (t - t0),
            ),
            _ => (0.0, 0.0),
        };
        self.history.push_back(now);
        state.live().close_interval(steps_per_s, updates_per_s);
        let sample = Sample {
            elapsed_s: t,
            status: state.status(),
            rooms: state.config().curriculum.rooms.clone(),
            memory: ProcessMemory::read(),
        };
        state.live().set_text(render_prometheus(&sample));
        sample
    }
}
