//! A recorded ROS 2 bag's scans, odometry and planned paths: the MCAP file (or the `.mcap`
//! files of a rosbag2 directory), the topics decoded from CDR, in the order they were logged.

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
}

/// The `.mcap` files of `path`: the file itself, or those of a rosbag2 directory in name order.
fn mcap_files(path: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if !path.is_dir() {
        anyhow::ensure!(path.exists(), "{}: no such bag file or directory", path.display());
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the bag directory: {e}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "{}: a directory without .mcap files; record with `ros2 bag record -s mcap` (or convert \
         with `rosbags-convert`)",
        path.display()
    );
    Ok(files)
}

/// Reads `scan_topic` (sensor_msgs/msg/LaserScan), `odom_topic` (nav_msgs/msg/Odometry) and
/// `plan_topic` (nav_msgs/msg/Path) from the bag at `path`; a topic name matches with or
/// without its leading slash (`scan` is `/scan`). No scan, or a topic of another type or not
/// CDR, is an error naming the topics the bag has; no odometry and no plan are not (a fixed
/// sensor, a robot without a planner: the caller decides).
pub fn read(
    path: &Path,
    scan_topic: &str,
    odom_topic: &str,
    plan_topic: &str,
) -> anyhow::Result<Recording> {
    let same = |a: &str, b: &str| a.trim_start_matches('/') == b.trim_start_matches('/');
    let mut rec = Recording::default();
    // topic -> (schema name, message encoding, count)
    let mut seen: BTreeMap<String, (String, String, usize)> = BTreeMap::new();
    for file in mcap_files(path)? {
        let bytes = std::fs::read(&file)
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
            let topic = &m.channel.topic;
            let schema = m.channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default();
            let entry = seen
                .entry(topic.clone())
                .or_insert_with(|| (schema.clone(), m.channel.message_encoding.clone(), 0));
            entry.2 += 1;
            let want = if same(topic, scan_topic) {
                "sensor_msgs/msg/LaserScan"
            } else if same(topic, odom_topic) {
                "nav_msgs/msg/Odometry"
            } else if same(topic, plan_topic) {
                "nav_msgs/msg/Path"
            } else {
                continue;
            };
            anyhow::ensure!(
                schema == want && m.channel.message_encoding == "cdr",
                "{}: topic {topic} carries {schema:?} encoded as {:?}; dvnav replay reads {want} \
                 in CDR",
                file.display(),
                m.channel.message_encoding
            );
            let context = |e: anyhow::Error| {
                anyhow::anyhow!("{}: {topic} at log time {} ns: {e}", file.display(), m.log_time)
            };
            if same(topic, scan_topic) {
                rec.scans.push((m.log_time, ros::decode(&m.data).map_err(context)?));
            } else if same(topic, odom_topic) {
                rec.odometry.push((m.log_time, ros::decode(&m.data).map_err(context)?));
            } else {
                rec.plans.push((m.log_time, ros::decode(&m.data).map_err(context)?));
            }
        }
    }
    let topics = || {
        if seen.is_empty() {
            return "no messages at all".to_string();
        }
        let list: Vec<String> =
            seen.iter().map(|(t, (s, _, n))| format!("{t} ({s}, {n} messages)")).collect();
        format!("it has {}", list.join(", "))
    };
    anyhow::ensure!(
        !rec.scans.is_empty(),
        "{}: no {scan_topic} messages; {}",
        path.display(),
        topics()
    );
    if rec.odometry.is_empty() {
        eprintln!(
            "replay: {}: no {odom_topic} messages ({}); replaying as a fixed sensor at the origin \
             of the odometry frame, standing still",
            path.display(),
            topics()
        );
    }
    // Several files, or a recorder that wrote out of order: by log time, stable.
    rec.scans.sort_by_key(|(t, _)| *t);
    rec.odometry.sort_by_key(|(t, _)| *t);
    rec.plans.sort_by_key(|(t, _)| *t);
    Ok(rec)
}
