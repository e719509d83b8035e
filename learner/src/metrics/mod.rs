//! Live metrics of a learner, by job: sampling, Prometheus text, `metrics.csv` and the HTTP
//! endpoints. The Prometheus text and the CSV row are rendered from the same [`Sample`] of the
//! [`LearnerState`].
//!
//! - [`sampler`]: [`Sampler`] takes a [`Sample`] every [`SAMPLE_EVERY`]: counters, rates over
//!   the last [`RATE_WINDOW`], the lag of the transitions since the previous sample (recorded at
//!   ingestion by the state's live recorder, [`crate::state::LiveMetrics`]).
//! - [`prometheus`]: [`render_prometheus`], a plain function unit-tested on its own.
//! - [`csv_log`]: [`MetricsRow`], one row of `metrics.csv`, written by [`CsvLog`] and read back
//!   by [`csv_log::read`].
//! - [`http`]: the axum [`router`] for `/metrics`, `/healthz` and `/readyz`, and [`serve`].
//! - this module: [`record`], the task that samples, appends a CSV row per sample and leaves
//!   the rendered text for the HTTP layer.

pub mod csv_log;
pub mod http;
pub mod prometheus;
pub mod sample;
pub mod sampler;

pub use csv_log::{CsvLog, MetricsRow, csv_header, csv_row};
pub use http::{HTTP_PATHS, router, serve};
pub use prometheus::render_prometheus;
pub use sample::Sample;
pub use sampler::{RATE_WINDOW, Sampler};

use crate::process_memory;
use crate::state::LearnerState;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// How often the learner samples its metrics (and appends to `metrics.csv`).
pub const SAMPLE_EVERY: Duration = Duration::from_secs(2);

/// Samples `state` every [`SAMPLE_EVERY`] until `stop` is cancelled, appending each sample to
/// the CSV at `csv` (if given), then takes a last sample.
pub async fn record(
    state: Arc<LearnerState>,
    csv: Option<PathBuf>,
    stop: CancellationToken,
) -> anyhow::Result<()> {
    let mut csv =
        csv.map(|p| CsvLog::open(&p, state.config().curriculum.rooms.len())).transpose()?;
    let mut sampler = Sampler::new();
    let mut ticks = tokio::time::interval(SAMPLE_EVERY);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut released = tokio::time::Instant::now();
    loop {
        tokio::select! {
            _ = ticks.tick() => {
                let sample = sampler.sample(&state);
                if let Some(c) = csv.as_mut() {
                    c.append(&sample, &state);
                }
                if released.elapsed() >= process_memory::RELEASE_EVERY {
                    released = tokio::time::Instant::now();
                    // Off the runtime's threads: it walks every arena.
                    tokio::task::spawn_blocking(process_memory::release_free_memory);
                }
            }
            () = stop.cancelled() => break,
        }
    }
    let sample = sampler.sample(&state);
    if let Some(c) = csv.as_mut() {
        c.append(&sample, &state);
    }
    Ok(())
}

#[cfg(test)]
mod tests;
