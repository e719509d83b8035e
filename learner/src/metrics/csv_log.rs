//! `metrics.csv`: one [`MetricsRow`] per sample, appended by [`CsvLog`] and read back by
//! [`read`] (`dvnav plot curves --metric success`, `dvnav train --seeds`).
//!
//! The columns are fixed ([`COLUMNS`]) but for a tail of one `success_rate_stage<i>` per
//! curriculum room: rows are written by position (the csv crate writes a trailing `Vec` as the
//! rest of the record) under a header written from [`header`], and read by column name, so a
//! reader takes older or hand-made files with fewer columns: only `env_steps` is required, a
//! missing number reads as NaN (a missing count as 0).

use super::sample::Sample;
use crate::csv_format::{ser_2_decimals, ser_3_decimals, ser_number, ser_numbers};
use crate::state::LearnerState;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The fixed columns of `metrics.csv`, in [`MetricsRow`]'s field order.
pub const COLUMNS: [&str; 19] = [
    "time_s",
    "env_steps",
    "env_steps_per_s",
    "updates",
    "updates_per_s",
    "episodes",
    "replay_size",
    "connected_actors",
    "weight_version",
    "policy_lag_mean",
    "policy_lag_max",
    "stage",
    "curriculum_success_rate",
    "critic_loss",
    "actor_loss",
    "alpha",
    "policy_entropy",
    "transitions_received",
    "transitions_rejected",
];

/// Prefix of the per-stage columns: `success_rate_stage0`, `success_rate_stage1`, ….
pub const STAGE_COLUMN: &str = "success_rate_stage";

/// One row of `metrics.csv`; NaN where there is no value yet. Read it with [`read`], which
/// also collects the per-stage columns (deserialized alone, a row has none).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    /// Seconds since the learner started sampling.
    #[serde(serialize_with = "ser_3_decimals", default = "crate::json_f64::nan")]
    pub time_s: f64,
    /// Environment steps (transitions) accepted.
    pub env_steps: u64,
    /// Environment steps per second over the sampler's rate window.
    #[serde(serialize_with = "ser_2_decimals", default = "crate::json_f64::nan")]
    pub env_steps_per_s: f64,
    /// SAC updates done.
    #[serde(default)]
    pub updates: u64,
    /// Updates per second over the rate window.
    #[serde(serialize_with = "ser_3_decimals", default = "crate::json_f64::nan")]
    pub updates_per_s: f64,
    /// Episodes reported.
    #[serde(default)]
    pub episodes: u64,
    /// Transitions in the replay buffer.
    #[serde(default)]
    pub replay_size: u64,
    /// Actors with an open transition stream.
    #[serde(default)]
    pub connected_actors: u64,
    /// Newest published weight version.
    #[serde(default)]
    pub weight_version: u64,
    /// Mean policy lag of the transitions since the previous sample (NaN: none policy-driven).
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub policy_lag_mean: f64,
    /// Largest policy lag of those transitions.
    #[serde(default)]
    pub policy_lag_max: u64,
    /// Curriculum stage.
    #[serde(default)]
    pub stage: u32,
    /// Success rate over the curriculum window of the current stage.
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub curriculum_success_rate: f64,
    /// Latest critic loss.
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub critic_loss: f64,
    /// Latest actor loss.
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub actor_loss: f64,
    /// Entropy temperature α.
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub alpha: f64,
    /// The policy's entropy estimate, −mean log π, of the last policy update.
    #[serde(serialize_with = "ser_number", default = "crate::json_f64::nan")]
    pub policy_entropy: f64,
    /// Transitions accepted.
    #[serde(default)]
    pub transitions_received: u64,
    /// Transitions refused as malformed.
    #[serde(default)]
    pub transitions_rejected: u64,
    /// Success rate over the last episodes of each stage, in stage order (one column per room).
    #[serde(serialize_with = "ser_numbers", skip_deserializing)]
    pub success_rate_stage: Vec<f64>,
}

impl MetricsRow {
    /// The row of `sample`.
    pub fn of(sample: &Sample) -> Self {
        let s = &sample.status;
        let l = &s.live;
        Self {
            time_s: sample.elapsed_s,
            env_steps: s.transitions_received,
            env_steps_per_s: l.env_steps_per_s,
            updates: s.updates,
            updates_per_s: l.updates_per_s,
            episodes: s.episodes,
            replay_size: s.replay_size,
            connected_actors: s.actors.iter().filter(|a| a.connected).count() as u64,
            weight_version: s.weight_version,
            policy_lag_mean: l.recent_policy_lag.mean(),
            policy_lag_max: l.recent_policy_lag.max,
            stage: s.stage,
            curriculum_success_rate: s.success_rate,
            critic_loss: s.critic_loss,
            actor_loss: s.actor_loss,
            alpha: s.alpha,
            policy_entropy: s.policy_entropy,
            transitions_received: s.transitions_received,
            transitions_rejected: s.transitions_rejected,
            success_rate_stage: (0..sample.rooms.len() as u32)
                .map(|i| {
                    l.stages
                        .iter()
                        .find(|st| st.stage == i)
                        .map_or(f64::NAN, |st| st.recent_success_rate)
                })
                .collect(),
        }
    }

    /// The row as one CSV line, with its line end.
    fn to_line(&self) -> Result<Vec<u8>, csv::Error> {
        let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        w.serialize(self)?;
        w.into_inner().map_err(|e| e.into_error().into())
    }
}

/// Column names of `metrics.csv`; one `success_rate_stage<i>` per curriculum room.
pub fn header(stages: usize) -> Vec<String> {
    let stage = (0..stages).map(|i| format!("{STAGE_COLUMN}{i}"));
    COLUMNS.iter().map(|c| c.to_string()).chain(stage).collect()
}

/// [`header`] as the file's first line (without its line end).
pub fn csv_header(stages: usize) -> String {
    header(stages).join(",")
}

/// One `metrics.csv` line of `sample` (same columns as [`csv_header`], without its line end).
pub fn csv_row(sample: &Sample) -> String {
    let line = MetricsRow::of(sample).to_line().expect("a row of numbers serializes");
    String::from_utf8(line).expect("CSV of numbers is UTF-8").trim_end().to_string()
}

/// Appends rows to `metrics.csv`; writes the header when the file is new or empty.
pub struct CsvLog {
    path: PathBuf,
    file: std::fs::File,
}

impl CsvLog {
    /// Opens (or creates) `path` for a run with `stages` curriculum rooms.
    pub fn open(path: &Path, stages: usize) -> anyhow::Result<Self> {
        let fail = |e: std::io::Error| anyhow::anyhow!("cannot write {}: {e}", path.display());
        let mut file =
            std::fs::OpenOptions::new().create(true).append(true).open(path).map_err(fail)?;
        if file.metadata().map_err(fail)?.len() == 0 {
            let mut w = csv::Writer::from_writer(Vec::new());
            w.write_record(header(stages))
                .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
            let head = w.into_inner().map_err(|e| fail(e.into_error()))?;
            file.write_all(&head).map_err(fail)?;
        }
        Ok(Self { path: path.to_path_buf(), file })
    }

    /// Appends the row of `sample`. A failed row (disk full) is logged and counted in `state`;
    /// the next sample tries again.
    pub fn append(&mut self, sample: &Sample, state: &LearnerState) {
        let written = MetricsRow::of(sample)
            .to_line()
            .map_err(std::io::Error::other)
            .and_then(|line| self.file.write_all(&line));
        if let Err(e) = written {
            state.record_write_failure("metrics_csv", &self.path, &e);
        }
    }
}

/// The columns a `metrics.csv` must have to be read.
pub const REQUIRED: [&str; 1] = ["env_steps"];

/// A row as read: the named columns, and the rest (the per-stage columns among them).
#[derive(Deserialize)]
struct Record {
    #[serde(flatten)]
    row: MetricsRow,
    #[serde(flatten)]
    rest: BTreeMap<String, Cell>,
}

/// A cell of a column [`MetricsRow`] does not name: a number, or anything else.
#[derive(Deserialize)]
#[serde(untagged)]
enum Cell {
    Number(f64),
    Other(serde::de::IgnoredAny),
}

/// Reads the rows of the `metrics.csv` at `path`, by column name. A row that does not parse (a
/// run killed mid-write leaves at most a partial last line) is skipped with a warning.
pub fn read(path: &Path) -> anyhow::Result<Vec<MetricsRow>> {
    let mut r = csv::Reader::from_path(path)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let names = r.headers().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if let Some(c) = REQUIRED.iter().find(|c| !names.iter().any(|n| n == **c)) {
        anyhow::bail!("{}: no `{c}` column", path.display());
    }
    let mut rows = Vec::new();
    for (n, record) in r.deserialize::<Record>().enumerate() {
        let Record { mut row, rest } = match record {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!(file = %path.display(), line = n + 2, error = %e, "skipping a malformed row");
                continue;
            }
        };
        for (name, cell) in rest {
            let Some(k) = name.strip_prefix(STAGE_COLUMN).and_then(|k| k.parse::<usize>().ok())
            else {
                continue;
            };
            if row.success_rate_stage.len() <= k {
                row.success_rate_stage.resize(k + 1, f64::NAN);
            }
            row.success_rate_stage[k] = match cell {
                Cell::Number(v) => v,
                Cell::Other(_) => f64::NAN,
            };
        }
        rows.push(row);
    }
    Ok(rows)
}
