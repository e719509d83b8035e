//! A recorded ROS 2 bag's scans, odometry, planned paths and goals: an MCAP file or a rosbag2
//! SQLite file (`.db3`), or a rosbag2 directory of either, the topics decoded from CDR, in the
//! order they were logged.

use super::ros::{self, LaserScan, Odometry};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Records larger than this (bytes) are refused rather than allocated: no LaserScan or
/// Odometry comes near it, a corrupt length does.
const MAX_RECORD_BYTES: usize = 256 << 20;

/// What a bag holds on the topics, each message with its log time (ns).
#[derive(Debug, Default)]
pub struct Recording {
    pub scans: Vec<(u64, LaserScan)>,
    pub odometry: Vec<(u64, Odometry)>,
    /// The robot's planner's paths (`nav_msgs/msg/Path`), each replacing the one before.
    pub plans: Vec<(u64, ros::Path)>,
    /// Goals sent to the robot (`geometry_msgs/msg/PoseStamped`, Nav2's `/goal_pose`), each
    /// replacing the one before.
    pub goals: Vec<(u64, ros::PoseStamped)>,
    /// Every transform on `/tf_static`, in log order (a later one for the same child frame
    /// replaces an earlier one).
    pub tf_static: Vec<ros::TransformStamped>,
}

/// One file of a bag, by its storage.
enum BagFile {
    /// An MCAP file (`ros2 bag record -s mcap`, the default since ROS 2 Iron).
    Mcap(PathBuf),
    /// A rosbag2 SQLite file (`.db3`, the default before Iron).
    Sqlite(PathBuf),
}

impl BagFile {
    fn of(path: PathBuf) -> BagFile {
        if path.extension().is_some_and(|x| x == "db3") {
            BagFile::Sqlite(path)
        } else {
            BagFile::Mcap(path)
        }
    }
}

/// One message of a bag, whatever its storage.
struct Message<'a> {
    file: &'a Path,
    topic: &'a str,
    /// The message type (`sensor_msgs/msg/LaserScan`).
    schema: &'a str,
    /// The serialization (`cdr`).
    encoding: &'a str,
    log_time: u64,
    data: &'a [u8],
}

/// The files of `path`: the file itself, or those of a rosbag2 directory in name order (its
/// `.mcap` files, or else its `.db3` files).
fn bag_files(path: &Path) -> anyhow::Result<Vec<BagFile>> {
    if !path.is_dir() {
        anyhow::ensure!(path.exists(), "{}: no such bag file or directory", path.display());
        return Ok(vec![BagFile::of(path.to_path_buf())]);
    }
    let entries: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the bag directory: {e}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    for ext in ["mcap", "db3"] {
        let mut files: Vec<PathBuf> =
            entries.iter().filter(|p| p.extension().is_some_and(|x| x == ext)).cloned().collect();
        if !files.is_empty() {
            files.sort();
            return Ok(files.into_iter().map(BagFile::of).collect());
        }
    }
    anyhow::bail!(
        "{}: a directory without .mcap or .db3 files; give a rosbag2 directory, or one of its \
         files",
        path.display()
    )
}

/// Calls `each` with every message of `file`, in the file's order (MCAP) or by log time (SQLite).
fn for_each_message(
    file: &BagFile,
    each: &mut dyn FnMut(Message<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    match file {
        BagFile::Mcap(file) => {
            let bytes = std::fs::read(file)
                .map_err(|e| anyhow::anyhow!("{}: cannot read: {e}", file.display()))?;
            let options = mcap::sans_io::LinearReaderOptions::default()
                .with_prevalidate_chunk_crcs(true)
                .with_record_length_limit(MAX_RECORD_BYTES);
            let reader =
                mcap::io::MessageReader::new_with_options(std::io::Cursor::new(&bytes), options);
            for m in reader {
                let m = m.map_err(|e| {
                    anyhow::anyhow!("{}: not a readable MCAP file: {e}", file.display())
                })?;
                let schema = m.channel.schema.as_ref().map_or("", |s| s.name.as_str());
                each(Message {
                    file,
                    topic: &m.channel.topic,
                    schema,
                    encoding: &m.channel.message_encoding,
                    log_time: m.log_time,
                    data: &m.data,
                })?;
            }
            Ok(())
        }
        BagFile::Sqlite(file) => {
            use rusqlite::{Connection, OpenFlags};
            let bad = |e: rusqlite::Error| {
                anyhow::anyhow!("{}: not a readable rosbag2 SQLite file: {e}", file.display())
            };
            // Read-only: a bag being inspected is never written, not even its journal.
            let db = Connection::open_with_flags(
                file,
                OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
            )
            .map_err(bad)?;
            // rosbag2's schema: topics(id, name, type, serialization_format, …) and
            // messages(id, topic_id, timestamp, data), the timestamp being the log time (ns).
            let mut query = db
                .prepare(
                    "SELECT t.name, t.type, t.serialization_format, m.timestamp, m.data \
                     FROM messages m JOIN topics t ON m.topic_id = t.id \
                     ORDER BY m.timestamp, m.id",
                )
                .map_err(bad)?;
            let mut rows = query.query([]).map_err(bad)?;
            while let Some(row) = rows.next().map_err(bad)? {
                let topic: String = row.get(0).map_err(bad)?;
                let schema: String = row.get(1).map_err(bad)?;
                let encoding: String = row.get(2).map_err(bad)?;
                let stamp: i64 = row.get(3).map_err(bad)?;
                let data = row.get_ref(4).map_err(bad)?.as_blob().map_err(|e| {
                    anyhow::anyhow!("{}: {topic}: a message's data: {e}", file.display())
                })?;
                let log_time = u64::try_from(stamp).map_err(|_| {
                    anyhow::anyhow!("{}: {topic}: a negative log time {stamp} ns", file.display())
                })?;
                each(Message {
                    file,
                    topic: &topic,
                    schema: &schema,
                    encoding: &encoding,
                    log_time,
                    data,
                })?;
            }
            Ok(())
        }
    }
}

/// The topics a replay reads; a name matches with or without its leading slash (`scan` is
/// `/scan`).
#[derive(Clone, Copy, Debug)]
pub struct Topics<'a> {
    /// `sensor_msgs/msg/LaserScan`.
    pub scan: &'a str,
    /// `nav_msgs/msg/Odometry`.
    pub odom: &'a str,
    /// `nav_msgs/msg/Path`.
    pub plan: &'a str,
    /// `geometry_msgs/msg/PoseStamped`.
    pub goal: &'a str,
    /// `tf2_msgs/msg/TFMessage`.
    pub tf_static: &'a str,
}

/// What a topic of [`Topics`] holds.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Scan,
    Odometry,
    Plan,
    Goal,
    TfStatic,
}

impl Kind {
    fn of(topic: &str, t: &Topics<'_>) -> Option<Kind> {
        let same = |b: &str| topic.trim_start_matches('/') == b.trim_start_matches('/');
        [
            (t.scan, Kind::Scan),
            (t.odom, Kind::Odometry),
            (t.plan, Kind::Plan),
            (t.goal, Kind::Goal),
            (t.tf_static, Kind::TfStatic),
        ]
        .into_iter()
        .find(|(name, _)| same(name))
        .map(|(_, k)| k)
    }

    fn schema(self) -> &'static str {
        match self {
            Kind::Scan => "sensor_msgs/msg/LaserScan",
            Kind::Odometry => "nav_msgs/msg/Odometry",
            Kind::Plan => "nav_msgs/msg/Path",
            Kind::Goal => "geometry_msgs/msg/PoseStamped",
            Kind::TfStatic => "tf2_msgs/msg/TFMessage",
        }
    }
}

/// Reads the topics of `topics` from the bag at `path` (MCAP or rosbag2 SQLite). No scan, or
/// a topic of another type or not CDR, is an error naming the topics the bag has; no
/// odometry, no plan and no goal are not (a fixed sensor, a robot without a planner, a goal
/// given on the command line: the caller decides).
pub fn read(path: &Path, topics: &Topics<'_>) -> anyhow::Result<Recording> {
    let mut rec = Recording::default();
    // topic -> (schema name, message encoding, count)
    let mut seen: BTreeMap<String, (String, String, usize)> = BTreeMap::new();
    for file in bag_files(path)? {
        for_each_message(&file, &mut |m: Message<'_>| {
            let entry = seen
                .entry(m.topic.to_string())
                .or_insert_with(|| (m.schema.to_string(), m.encoding.to_string(), 0));
            entry.2 += 1;
            let Some(kind) = Kind::of(m.topic, topics) else { return Ok(()) };
            let want = kind.schema();
            anyhow::ensure!(
                m.schema == want && m.encoding == "cdr",
                "{}: topic {} carries {:?} encoded as {:?}; dvnav replay reads {want} in CDR",
                m.file.display(),
                m.topic,
                m.schema,
                m.encoding
            );
            let context = |e: anyhow::Error| {
                anyhow::anyhow!(
                    "{}: {} at log time {} ns: {e}",
                    m.file.display(),
                    m.topic,
                    m.log_time
                )
            };
            let t = m.log_time;
            match kind {
                Kind::Scan => rec.scans.push((t, ros::decode(m.data).map_err(context)?)),
                Kind::Odometry => rec.odometry.push((t, ros::decode(m.data).map_err(context)?)),
                Kind::Plan => rec.plans.push((t, ros::decode(m.data).map_err(context)?)),
                Kind::Goal => rec.goals.push((t, ros::decode(m.data).map_err(context)?)),
                Kind::TfStatic => {
                    let tf: ros::TfMessage = ros::decode(m.data).map_err(context)?;
                    rec.tf_static.extend(tf.transforms);
                }
            }
            Ok(())
        })?;
    }
    let list = || {
        if seen.is_empty() {
            return "no messages at all".to_string();
        }
        let list: Vec<String> =
            seen.iter().map(|(t, (s, _, n))| format!("{t} ({s}, {n} messages)")).collect();
        format!("it has {}", list.join(", "))
    };
    anyhow::ensure!(
        !rec.scans.is_empty(),
        "{}: no {} messages; {}",
        path.display(),
        topics.scan,
        list()
    );
    if rec.odometry.is_empty() {
        eprintln!(
            "replay: {}: no {} messages ({}); replaying as a fixed sensor at the origin of the \
             odometry frame, standing still",
            path.display(),
            topics.odom,
            list()
        );
    }
    // Several files, or a recorder that wrote out of order: by log time, stable.
    rec.scans.sort_by_key(|(t, _)| *t);
    rec.odometry.sort_by_key(|(t, _)| *t);
    rec.plans.sort_by_key(|(t, _)| *t);
    rec.goals.sort_by_key(|(t, _)| *t);
    Ok(rec)
}
