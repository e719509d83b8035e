//! [`Sample`]: what one look at the learner holds; the Prometheus text and the CSV row are both
//! rendered from it.

use crate::process_memory::ProcessMemory;
use crate::state::StatusSnapshot;

/// One sample of the metrics.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Seconds since the sampler started.
    pub elapsed_s: f64,
    /// Counters, including the live snapshot with the rates of this sample.
    pub status: StatusSnapshot,
    /// Room name of each curriculum stage, for labels.
    pub rooms: Vec<String>,
    /// The learner process's memory.
    pub memory: ProcessMemory,
}
