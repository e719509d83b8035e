//! [`check_file`]: decode every message of a log file against its schema and say whether the
//! file is finished (`dvnav inspect --check`, the crash test, disk-cost figures).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result};
use foxglove::messages::{FrameTransform, LaserScan, SceneUpdate};
use prost::Message as _;
use serde::Serialize;

use super::{METADATA_NAME, TOPIC_EPISODE, TOPIC_STEP};

/// At most this many errors are kept per file; one is usually enough to act on.
const MAX_ERRORS: usize = 20;

/// What [`check_file`] found in one file.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FileCheck {
    /// The file.
    pub file: PathBuf,
    /// Its size (bytes).
    pub bytes: u64,
    /// It has a summary section and footer: it was finished by rotation or a clean shutdown.
    /// An unfinished file is still being written, or its writer was killed.
    pub finished: bool,
    /// The `dvnav` metadata record (run id, actor, config hash, version, …), if present.
    pub metadata: BTreeMap<String, String>,
    /// Messages read and decoded.
    pub messages: u64,
    /// Messages per topic.
    pub topics: BTreeMap<String, u64>,
    /// Episodes whose summary and every step record (steps + 1) are in the file.
    pub complete_episodes: u64,
    /// Step records (`/dvnav/step`) in the file.
    pub steps: u64,
    /// For an unfinished file: why reading stopped (the damaged or missing tail).
    pub truncated: Option<String>,
    /// Everything wrong: undecodable messages, unknown schemas, an episode summary without all
    /// its steps, damage inside a finished file, a missing metadata record.
    pub errors: Vec<String>,
}

impl FileCheck {
    /// No errors; an unfinished tail is not an error (a killed writer leaves one).
    pub fn is_ok(&self) -> bool {
        self.errors.is_empty()
    }

    fn error(&mut self, e: String) {
        if self.errors.len() < MAX_ERRORS {
            self.errors.push(e);
        }
    }
}

/// Decodes `data` as the protobuf message `schema` names; the five schemas dvnav writes.
fn decode(schema: &str, data: &[u8]) -> Result<(), String> {
    let r = match schema {
        "foxglove.LaserScan" => LaserScan::decode(data).map(drop),
        "foxglove.FrameTransform" => FrameTransform::decode(data).map(drop),
        "foxglove.SceneUpdate" => SceneUpdate::decode(data).map(drop),
        "dvnav.v1.StepRecord" => dvnav_proto::StepRecord::decode(data).map(drop),
        "dvnav.v1.EpisodeSummary" => dvnav_proto::EpisodeSummary::decode(data).map(drop),
        other => return Err(format!("unknown schema {other:?}")),
    };
    r.map_err(|e| e.to_string())
}

/// Checks that a channel's schema is protobuf and that its descriptor set defines the message.
fn check_schema(channel: &mcap::Channel<'_>) -> Result<String, String> {
    let schema = channel.schema.as_ref().ok_or_else(|| format!("{}: no schema", channel.topic))?;
    if schema.encoding != "protobuf" || channel.message_encoding != "protobuf" {
        return Err(format!(
            "{}: schema encoding {:?}, message encoding {:?}; expected protobuf",
            channel.topic, schema.encoding, channel.message_encoding
        ));
    }
    let fds = prost_types::FileDescriptorSet::decode(schema.data.as_ref())
        .map_err(|e| format!("{}: schema is not a FileDescriptorSet: {e}", channel.topic))?;
    let (package, message) = schema.name.rsplit_once('.').unwrap_or(("", &schema.name));
    let defined = fds
        .file
        .iter()
        .any(|f| f.package() == package && f.message_type.iter().any(|d| d.name() == message));
    if !defined {
        return Err(format!(
            "{}: {} is not in its schema's descriptors",
            channel.topic, schema.name
        ));
    }
    Ok(schema.name.clone())
}

/// Decodes every message of `path` against its channel's schema, counts episodes whose steps
/// are all present, and reads the metadata. Errors are for a file that cannot be read at all;
/// what is wrong inside it goes into [`FileCheck::errors`].
pub fn check_file(path: &Path) -> Result<FileCheck> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut check =
        FileCheck { file: path.to_path_buf(), bytes: bytes.len() as u64, ..Default::default() };
    check.finished = matches!(mcap::Summary::read(&bytes), Ok(Some(_)));

    // Metadata: the linear records up to the first damage.
    match mcap::read::LinearReader::new(&bytes) {
        Ok(records) => {
            for record in records {
                match record {
                    Ok(mcap::records::Record::Metadata(m)) if m.name == METADATA_NAME => {
                        check.metadata = m.metadata;
                    }
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
        }
        Err(e) => {
            check.error(format!("not an MCAP file: {e}"));
            return Ok(check);
        }
    }
    if check.metadata.is_empty() {
        check.error(format!("no `{METADATA_NAME}` metadata record"));
    }

    // Chunk CRCs are checked before a chunk is parsed (see `reader::messages`): a flipped bit
    // inside a compressed chunk can otherwise decode into plausible protobuf, or worse.
    let (readable, damage) = super::reader::sane_prefix(&bytes);
    if let Some(d) = damage {
        check.error(d);
    }
    let stream = super::reader::messages(readable);
    let mut schemas: HashMap<u16, Result<String, String>> = HashMap::new();
    let mut steps_of: HashMap<u64, u64> = HashMap::new();
    for message in stream {
        let m = match message {
            Ok(m) => m,
            Err(e) => {
                if check.finished {
                    check.error(format!("damaged: {e}"));
                } else {
                    check.truncated = Some(e.to_string());
                }
                break;
            }
        };
        let schema = schemas.entry(m.channel.id).or_insert_with(|| check_schema(&m.channel));
        let name = match schema {
            Ok(name) => name.clone(),
            Err(e) => {
                let e = e.clone();
                check.error(e);
                continue;
            }
        };
        if let Err(e) = decode(&name, &m.data) {
            check.error(format!("{} message {}: {e}", m.channel.topic, m.sequence));
            continue;
        }
        check.messages += 1;
        *check.topics.entry(m.channel.topic.clone()).or_default() += 1;
        match m.channel.topic.as_str() {
            TOPIC_STEP => {
                check.steps += 1;
                let rec = dvnav_proto::StepRecord::decode(m.data.as_ref()).expect("decoded above");
                *steps_of.entry(rec.episode_id).or_default() += 1;
            }
            TOPIC_EPISODE => {
                let s =
                    dvnav_proto::EpisodeSummary::decode(m.data.as_ref()).expect("decoded above");
                let logged = steps_of.get(&s.episode_id).copied().unwrap_or(0);
                if logged == u64::from(s.steps) + 1 {
                    check.complete_episodes += 1;
                } else {
                    check.error(format!(
                        "episode {}: summary says {} steps, the file has {logged} step records",
                        s.episode_id,
                        u64::from(s.steps) + 1
                    ));
                }
            }
            _ => {}
        }
    }
    Ok(check)
}

/// [`check_file`] for `path` itself or every `.mcap` file under it.
pub fn check_files(path: &Path) -> Result<Vec<FileCheck>> {
    super::reader::files_under(path)?.iter().map(|f| check_file(f)).collect()
}
