//! Reading episode summaries back (`dvnav inspect`), from finished and from damaged files.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result};
use prost::Message as _;
use serde::Serialize;

use super::TOPIC_EPISODE;

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
fn mcap_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
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
    let stream = match mcap::MessageStream::new(&bytes) {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!(file = %path.display(), error = %e, "not a readable MCAP file; skipped");
            return Ok(());
        }
    };
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

/// Reads the episode summaries (`/dvnav/episode`) of one `.mcap` file, or of every `.mcap`
/// file under a directory (recursively), sorted by (actor id, episode id).
///
/// Unfinished or damaged files (an actor killed with SIGKILL) do not fail the call: every
/// complete message before the damage is read and a warning is logged. Errors are for a path
/// that cannot be read at all.
pub fn read_episodes(path: &Path) -> Result<Vec<EpisodeRecord>> {
    let meta = std::fs::metadata(path).with_context(|| format!("reading {}", path.display()))?;
    let files = if meta.is_dir() {
        let mut files = Vec::new();
        mcap_files(path, &mut files)?;
        files
    } else {
        vec![path.to_path_buf()]
    };
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
        match crate::core::Outcome::from_proto(s.outcome) {
            Some(crate::core::Outcome::Success) => acc.success += 1,
            Some(crate::core::Outcome::Collision) => acc.collision += 1,
            Some(crate::core::Outcome::Timeout) => acc.timeout += 1,
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
