//! Reading episode summaries back (`dvnav inspect`), from finished and from damaged files.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result};
use prost::Message as _;
use serde::Serialize;

use super::{TOPIC_EPISODE, TOPIC_STEP};

/// One episode summary read from a log file.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeRecord {
    /// The file it came from.
    pub file: PathBuf,
    /// The summary as logged on `/dvnav/episode`.
    pub summary: dvnav_proto::EpisodeSummary,
}

/// Outcome statistics of the episodes of one actor in one curriculum stage.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GroupSummary {
    /// Actor name.
    pub actor: String,
    /// Curriculum stage.
    pub stage: u32,
    /// Episodes in the group.
    pub episodes: u64,
    /// Share of episodes that reached the goal, in [0, 1].
    pub success_rate: f64,
    /// Share of episodes that ended in a collision, in [0, 1].
    pub collision_rate: f64,
    /// Share of episodes that timed out, in [0, 1].
    pub timeout_rate: f64,
    /// Mean episode length (control steps).
    pub mean_steps: f64,
    /// Mean undiscounted return.
    pub mean_return: f64,
}

/// Every `.mcap` file under `dir`, recursively, in path order. Symbolic links to directories
/// are not followed (no cycles).
pub(crate) fn mcap_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    let mut entries = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .collect::<std::io::Result<Vec<_>>>()
        .with_context(|| format!("listing {}", dir.display()))?;
    entries.sort_by_key(|e| e.path());
    for entry in entries {
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            mcap_files(&path, out)?;
        } else if path.extension().is_some_and(|e| e == "mcap") {
            out.push(path);
        }
    }
    Ok(())
}

/// The episode summaries of one file, reading up to the first damage (an actor killed while
/// writing leaves a file without a summary section, cut inside a chunk).
fn read_file(path: &Path, out: &mut Vec<EpisodeRecord>) -> Result<()> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let (readable, damage) = sane_prefix(&bytes);
    if let Some(d) = damage {
        tracing::warn!(file = %path.display(), "{d}; read up to it");
    }
    let stream = messages(readable);
    let before = out.len();
    for message in stream {
        let message = match message {
            Ok(m) => m,
            Err(e) => {
                tracing::warn!(
                    file = %path.display(),
                    error = %e,
                    episodes = out.len() - before,
                    "episode log is unfinished (still being written, or its writer was killed) or damaged; read up to that point"
                );
                break;
            }
        };
        if message.channel.topic != TOPIC_EPISODE {
            continue;
        }
        match dvnav_proto::EpisodeSummary::decode(message.data.as_ref()) {
            Ok(summary) => out.push(EpisodeRecord { file: path.to_path_buf(), summary }),
            Err(e) => tracing::warn!(
                file = %path.display(),
                sequence = message.sequence,
                error = %e,
                "undecodable episode summary; skipped"
            ),
        }
    }
    Ok(())
}

/// `path` itself when it is a file, else every `.mcap` file under it, in path order.
pub(crate) fn files_under(path: &Path) -> Result<Vec<PathBuf>> {
    let meta = std::fs::metadata(path).with_context(|| format!("reading {}", path.display()))?;
    if meta.is_dir() {
        let mut files = Vec::new();
        mcap_files(path, &mut files)?;
        Ok(files)
    } else {
        Ok(vec![path.to_path_buf()])
    }
}

/// Reads the episode summaries (`/dvnav/episode`) of one `.mcap` file, or of every `.mcap`
/// file under a directory (recursively), sorted by (actor id, episode id).
///
/// Unfinished or damaged files (an actor killed with SIGKILL) do not fail the call: every
/// complete message before the damage is read and a warning is logged. Errors are for a path
/// that cannot be read at all.
pub fn read_episodes(path: &Path) -> Result<Vec<EpisodeRecord>> {
    let files = files_under(path)?;
    let mut out = Vec::new();
    for file in &files {
        read_file(file, &mut out)?;
    }
    // Stable: equal keys (e.g. an actor restarted with the same ids) keep file order.
    out.sort_by_key(|r| (r.summary.actor_id, r.summary.episode_id));
    Ok(out)
}

/// Outcome rates, mean length and mean return per (actor, stage), ordered by actor then stage.
/// Episodes with an unspecified outcome count in `episodes` but in none of the rates.
pub fn summarize(records: &[EpisodeRecord]) -> Vec<GroupSummary> {
    #[derive(Default)]
    struct Acc {
        n: u64,
        success: u64,
        collision: u64,
        timeout: u64,
        steps: f64,
        ret: f64,
    }
    let mut groups: BTreeMap<(&str, u32), Acc> = BTreeMap::new();
    for r in records {
        let s = &r.summary;
        let acc = groups.entry((s.actor.as_str(), s.stage)).or_default();
        acc.n += 1;
        match dvnav_link::wire::outcome_from_proto(s.outcome) {
            Some(dvnav_sim::Outcome::Success) => acc.success += 1,
            Some(dvnav_sim::Outcome::Collision) => acc.collision += 1,
            Some(dvnav_sim::Outcome::Timeout) => acc.timeout += 1,
            None => {}
        }
        acc.steps += f64::from(s.steps);
        acc.ret += s.episode_return;
    }
    groups
        .into_iter()
        .map(|((actor, stage), a)| {
            let n = a.n as f64;
            GroupSummary {
                actor: actor.to_string(),
                stage,
                episodes: a.n,
                success_rate: a.success as f64 / n,
                collision_rate: a.collision as f64 / n,
                timeout_rate: a.timeout as f64 / n,
                mean_steps: a.steps / n,
                mean_return: a.ret / n,
            }
        })
        .collect()
}

/// The step records (`/dvnav/step`) of the episodes `ids` in one file, in step order, read up to
/// the first damage like [`read_episodes`]. An episode's ids are unique within its actor, and
/// each file belongs to one actor, so (file, id) names one episode.
pub fn read_steps(
    file: &Path,
    ids: &BTreeSet<u64>,
) -> Result<BTreeMap<u64, Vec<dvnav_proto::StepRecord>>> {
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let mut out: BTreeMap<u64, Vec<dvnav_proto::StepRecord>> = BTreeMap::new();
    for message in messages(sane_prefix(&bytes).0) {
        let Ok(message) = message else { break };
        if message.channel.topic != TOPIC_STEP {
            continue;
        }
        if let Ok(rec) = dvnav_proto::StepRecord::decode(message.data.as_ref())
            && ids.contains(&rec.episode_id)
        {
            out.entry(rec.episode_id).or_default().push(rec);
        }
    }
    for steps in out.values_mut() {
        steps.sort_by_key(|r| r.step);
    }
    Ok(out)
}

/// One episode in detail: its summary plus figures computed from its step records
/// (`dvnav inspect --episode`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EpisodeDetail {
    /// Episode id (unique within its actor).
    pub episode_id: u64,
    /// Actor name and id.
    pub actor: String,
    /// Actor id given by the learner.
    pub actor_id: u32,
    /// Environment index within the actor.
    pub env_index: u32,
    /// Curriculum stage and room.
    pub stage: u32,
    /// Room name (`Room::builtin` name).
    pub room: String,
    /// The actor's base seed.
    pub seed: u64,
    /// Footprint description and DVST scale factor μ.
    pub footprint: String,
    /// DVST scale factor (1 without DVST).
    pub mu: f64,
    /// `success`, `collision`, `timeout` or `unspecified`.
    pub outcome: String,
    /// Control steps (after the reset step).
    pub steps: u32,
    /// Undiscounted return.
    pub episode_return: f64,
    /// Evaluation score S (design §4).
    pub score: f64,
    /// Weight version that acted last (0: PID).
    pub policy_version: u64,
    /// Driven by the PID warm-up controller.
    pub warmup: bool,
    /// Start and goal positions (m, world frame).
    pub start: [f64; 2],
    /// Goal position (m, world frame).
    pub goal: [f64; 2],
    /// Straight-line distance from start to goal (m).
    pub start_goal_distance_m: f64,
    /// Step records found in the file (steps + 1 for a complete episode).
    pub logged_steps: usize,
    /// Length of the driven path (m).
    pub path_length_m: f64,
    /// Goal distance at the last step and the closest approach (m).
    pub final_goal_distance_m: f64,
    /// Closest approach to the goal (m).
    pub min_goal_distance_m: f64,
    /// Mean and largest commanded linear velocity (m/s).
    pub mean_v: f64,
    /// Largest commanded linear velocity (m/s).
    pub max_v: f64,
    /// Mean |ω| (rad/s).
    pub mean_abs_omega: f64,
    /// Simulation time of the first and last step on the file's clock (s).
    pub start_time_s: f64,
    /// Simulation time of the last step (s).
    pub end_time_s: f64,
    /// The file it is in.
    pub file: PathBuf,
}

/// Outcome name of a logged summary.
pub(crate) fn outcome_name(v: i32) -> &'static str {
    dvnav_link::wire::outcome_from_proto(v).map_or("unspecified", |o| o.as_str())
}

/// The detail of `record`, with `steps` its step records in step order.
pub fn episode_detail(record: &EpisodeRecord, steps: &[dvnav_proto::StepRecord]) -> EpisodeDetail {
    let s = &record.summary;
    let path_length_m = steps.windows(2).map(|w| (w[1].x - w[0].x).hypot(w[1].y - w[0].y)).sum();
    // Step 0 is the pose after reset, before any command.
    let moving = steps.get(1..).unwrap_or(&[]);
    let n = moving.len().max(1) as f64;
    EpisodeDetail {
        episode_id: s.episode_id,
        actor: s.actor.clone(),
        actor_id: s.actor_id,
        env_index: s.env_index,
        stage: s.stage,
        room: s.room.clone(),
        seed: s.seed,
        footprint: s.footprint.clone(),
        mu: s.mu,
        outcome: outcome_name(s.outcome).to_string(),
        steps: s.steps,
        episode_return: s.episode_return,
        score: s.score,
        policy_version: s.policy_version,
        warmup: s.warmup,
        start: [s.start_x, s.start_y],
        goal: [s.goal_x, s.goal_y],
        start_goal_distance_m: (s.goal_x - s.start_x).hypot(s.goal_y - s.start_y),
        logged_steps: steps.len(),
        path_length_m,
        final_goal_distance_m: steps.last().map_or(f64::NAN, |r| r.goal_distance),
        min_goal_distance_m: steps.iter().map(|r| r.goal_distance).fold(f64::NAN, f64::min),
        mean_v: moving.iter().map(|r| r.v).sum::<f64>() / n,
        max_v: moving.iter().map(|r| r.v).fold(0.0, f64::max),
        mean_abs_omega: moving.iter().map(|r| r.omega.abs()).sum::<f64>() / n,
        start_time_s: s.start_time_ns as f64 * 1e-9,
        end_time_s: s.end_time_ns as f64 * 1e-9,
        file: record.file.clone(),
    }
}

/// Largest uncompressed chunk a reader accepts (bytes). The logger's chunks are ~2 MiB; the
/// `mcap` crate's streaming reader reserves a chunk's claimed uncompressed size up front, so a
/// damaged size field (a flipped bit) would abort the process on allocation failure.
const MAX_CHUNK_BYTES: u64 = 256 * 1024 * 1024;

/// The prefix of an MCAP file up to its first chunk that claims an implausible uncompressed
/// size (or up to the chunk being written, whose sizes are placeholders), and why it stops
/// there when that is damage. Walks the record framing only (opcode, length); stops quietly
/// at a truncated record, which the readers report themselves.
pub(crate) fn sane_prefix(bytes: &[u8]) -> (&[u8], Option<String>) {
    const MAGIC: usize = 8;
    const CHUNK: u8 = 0x06;
    let u64_at = |at: usize| -> Option<u64> {
        Some(u64::from_le_bytes(bytes.get(at..at + 8)?.try_into().ok()?))
    };
    let mut at = MAGIC;
    while let (Some(&op), Some(len)) = (bytes.get(at), u64_at(at + 1)) {
        let body = at + 9;
        // Chunk body: start time, end time, uncompressed size, …
        if op == CHUNK
            && let Some(size) = u64_at(body + 16)
            && size > MAX_CHUNK_BYTES
        {
            // The chunk still being written (the writer streams it with placeholder sizes and
            // fills them in when it closes): the unfinished tail a killed writer leaves.
            if size == u64::MAX {
                return (&bytes[..at], None);
            }
            let why = format!("chunk at byte {at} claims {size} bytes uncompressed (damaged)");
            return (&bytes[..at], Some(why));
        }
        match usize::try_from(len).ok().and_then(|l| body.checked_add(l)) {
            Some(next) if next <= bytes.len() => at = next,
            _ => break,
        }
    }
    (bytes, None)
}

/// The messages of an MCAP file in file order, read defensively: a chunk's CRC is checked
/// before its records are parsed, and no record or chunk may claim more than
/// [`MAX_CHUNK_BYTES`]. `mcap::MessageStream` checks CRCs only after it has parsed a chunk's
/// records, so a flipped bit in compressed data could make it reserve a record length read from
/// garbage and abort the process.
pub(crate) fn messages(
    bytes: &[u8],
) -> impl Iterator<Item = mcap::McapResult<mcap::Message<'static>>> + '_ {
    let options = mcap::sans_io::LinearReaderOptions::default()
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(MAX_CHUNK_BYTES as usize);
    mcap::io::MessageReader::new_with_options(std::io::Cursor::new(bytes), options)
}
