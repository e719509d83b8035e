//! Round trips through real files in a temp dir, read back with `mcap::MessageStream`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use foxglove::messages::{FrameTransform, LaserScan, SceneUpdate};
use prost::Message as _;

use super::*;
use dvnav_config::LidarConfig;
use dvnav_sim::{ObstacleSpec, RoomSpec};

const DT: f64 = 0.2;
const DT_NS: u64 = 200_000_000;
const RADIUS: f64 = 0.25;

fn room() -> RoomSpec {
    RoomSpec {
        obstacles: vec![
            ObstacleSpec::Box { center: [1.0, 1.0], half_extents: [0.3, 0.2], angle: 0.5 },
            ObstacleSpec::Circle { center: [-1.5, 0.5], radius: 0.4 },
            ObstacleSpec::Polygon {
                points: vec![[0.0, -2.0], [1.0, -2.0], [1.2, -1.2], [0.2, -1.0]],
            },
        ],
        ..RoomSpec::empty("test", 6.0)
    }
}

fn meta() -> LogMetadata {
    LogMetadata {
        run_id: "run-7".into(),
        actor: "actor-3".into(),
        actor_id: 3,
        config_hash: "abc123".into(),
        seed: 42,
    }
}

/// Ranges from `pose` to the room's walls and its circle, so scans vary like real ones.
fn scan_at(pose: [f64; 3], room: &RoomSpec, lidar: &LidarConfig) -> Vec<f32> {
    let half = 0.5 * room.side;
    let fov = lidar.fov_deg.to_radians();
    (0..lidar.beams)
        .map(|i| {
            let a = pose[2] - 0.5 * fov + fov * (i as f64 + 0.5) / lidar.beams as f64;
            let (c, s) = (a.cos(), a.sin());
            let wall = |p: f64, d: f64| {
                if d > 1e-12 {
                    (half - p) / d
                } else if d < -1e-12 {
                    (-half - p) / d
                } else {
                    f64::INFINITY
                }
            };
            let mut t = wall(pose[0], c).min(wall(pose[1], s));
            for o in &room.obstacles {
                if let ObstacleSpec::Circle { center, radius } = o {
                    let (dx, dy) = (pose[0] - center[0], pose[1] - center[1]);
                    let b = dx * c + dy * s;
                    let disc = b * b - (dx * dx + dy * dy - radius * radius);
                    if disc >= 0.0 {
                        let hit = -b - disc.sqrt();
                        if hit > 0.0 {
                            t = t.min(hit);
                        }
                    }
                }
            }
            t.clamp(lidar.range_min, lidar.range_max) as f32
        })
        .collect()
}

/// What an episode of the test looks like.
#[derive(Clone, Debug)]
struct Episode {
    id: u64,
    /// Steps after step 0.
    steps: u32,
    outcome: dvnav_proto::Outcome,
    stage: u32,
}

fn pose_at(ep: &Episode, step: u32) -> [f64; 3] {
    let k = f64::from(step);
    [-2.0 + 0.1 * k, -0.5 + 0.01 * ep.id as f64, 0.05 * k]
}

fn goal_of(ep: &Episode) -> [f64; 2] {
    [2.0, 0.5 + 0.1 * ep.id as f64]
}

/// Logs `ep` completely, recording the file size after it (it is flushed at the end).
fn log_episode(log: &mut EpisodeLogger, ep: &Episode, room: &RoomSpec, lidar: &LidarConfig) {
    log_episode_mu(log, ep, room, lidar, 1.0);
}

/// [`log_episode`] with DVST scale factor `mu`.
fn log_episode_mu(
    log: &mut EpisodeLogger,
    ep: &Episode,
    room: &RoomSpec,
    lidar: &LidarConfig,
    mu: f64,
) {
    log.begin_episode(&EpisodeStart {
        episode_id: ep.id,
        room,
        robot_radius: RADIUS,
        goal: goal_of(ep),
        lidar,
        dt: DT,
        mu,
    })
    .unwrap();
    for step in 0..=ep.steps {
        let pose = pose_at(ep, step);
        let scan = scan_at(pose, room, lidar);
        log.log_step(&StepLog {
            step,
            pose,
            scan: &scan,
            v: 0.5,
            omega: 0.1,
            action: [1.0, 0.06],
            reward: if step == 0 { 0.0 } else { 0.19 },
            goal_distance: 4.0 - 0.1 * f64::from(step),
            goal_angle: -0.05 * f64::from(step),
            subgoal: None,
            plan: None,
        })
        .unwrap();
    }
    log.end_episode(dvnav_proto::EpisodeSummary {
        stage: ep.stage,
        room: room.name.clone(),
        outcome: ep.outcome as i32,
        steps: ep.steps,
        episode_return: 0.19 * f64::from(ep.steps),
        ..Default::default()
    })
    .unwrap();
}

fn three_episodes() -> Vec<Episode> {
    vec![
        Episode { id: 10, steps: 5, outcome: dvnav_proto::Outcome::Success, stage: 0 },
        Episode { id: 11, steps: 3, outcome: dvnav_proto::Outcome::Collision, stage: 0 },
        Episode { id: 12, steps: 7, outcome: dvnav_proto::Outcome::Timeout, stage: 0 },
    ]
}

fn mcap_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    files
}

/// Every message of a finished file, in file order.
fn messages(path: &Path) -> Vec<mcap::Message<'static>> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes).unwrap().map(|m| m.unwrap()).collect()
}

fn assert_close(a: f64, b: f64) {
    assert!((a - b).abs() < 1e-9, "{a} != {b}");
}

/// Checks a dvnav channel's schema: protobuf, full name, and a descriptor set that defines it.
fn assert_dvnav_schema(m: &mcap::Message<'_>, full_name: &str) {
    let schema = m.channel.schema.as_ref().expect("dvnav channels have a schema");
    assert_eq!(schema.name, full_name);
    assert_eq!(schema.encoding, "protobuf");
    let fds = prost_types::FileDescriptorSet::decode(schema.data.as_ref()).unwrap();
    let (package, message) = full_name.rsplit_once('.').unwrap();
    assert!(
        fds.file
            .iter()
            .any(|f| f.package() == package && f.message_type.iter().any(|d| d.name() == message)),
        "{full_name} is not in the schema's FileDescriptorSet"
    );
}

fn assert_foxglove_schema(m: &mcap::Message<'_>, full_name: &str) {
    let schema = m.channel.schema.as_ref().expect("foxglove channels have a schema");
    assert_eq!(schema.name, full_name);
    assert_eq!(schema.encoding, "protobuf");
    assert!(!schema.data.is_empty());
}

#[test]
fn rotated_files_decode_against_their_schemas() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let episodes = three_episodes();
    let mut log = EpisodeLogger::create(dir.path(), "actor-3", meta(), 2).unwrap();
    assert!(mcap_files(dir.path()).is_empty(), "files open lazily");
    for ep in &episodes {
        log_episode(&mut log, ep, &room, &lidar);
    }
    log.close().unwrap();

    let files = mcap_files(dir.path());
    let names: Vec<_> = files.iter().map(|p| p.file_name().unwrap().to_str().unwrap()).collect();
    assert_eq!(names, ["actor-3-00000.mcap", "actor-3-00001.mcap"]);

    let by_file = [&episodes[..2], &episodes[2..]];
    for (index, (path, eps)) in files.iter().zip(by_file).enumerate() {
        // Metadata, through the summary section (so the file is also properly finished).
        let bytes = std::fs::read(path).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().expect("finished file has a summary");
        let [index_rec] = &summary.metadata_indexes[..] else { panic!("one metadata record") };
        let md = mcap::read::metadata(&bytes, index_rec).unwrap();
        assert_eq!(md.name, "dvnav");
        let expected: BTreeMap<String, String> = [
            ("run_id", "run-7"),
            ("actor", "actor-3"),
            ("actor_id", "3"),
            ("config_hash", "abc123"),
            ("seed", "42"),
            ("dvnav_version", env!("CARGO_PKG_VERSION")),
            ("file_index", &index.to_string()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
        assert_eq!(md.metadata, expected);

        let mut counts: BTreeMap<String, usize> = BTreeMap::new();
        let mut steps_seen = Vec::new();
        let mut summaries = Vec::new();
        let mut path_lengths = Vec::new();
        let mut current: Option<&Episode> = None;
        let mut ep_iter = eps.iter();
        for m in messages(path) {
            assert_eq!(m.channel.message_encoding, "protobuf");
            *counts.entry(m.channel.topic.clone()).or_default() += 1;
            match m.channel.topic.as_str() {
                TOPIC_SCENE => {
                    assert_foxglove_schema(&m, "foxglove.SceneUpdate");
                    let ep = ep_iter.next().expect("one scene per episode");
                    current = Some(ep);
                    let scene = SceneUpdate::decode(m.data.as_ref()).unwrap();
                    assert_eq!(scene.deletions.len(), 1, "each scene replaces the last");
                    let ids: BTreeSet<_> = scene.entities.iter().map(|e| e.id.as_str()).collect();
                    // No scaled footprint without DVST (μ = 1).
                    assert_eq!(ids, BTreeSet::from(["walls", "obstacles", "goal", "robot"]));
                    let get = |id: &str| scene.entities.iter().find(|e| e.id == id).unwrap();
                    assert_eq!(get("walls").cubes.len(), 4);
                    assert_eq!(get("walls").frame_id, "world");
                    let obstacles = get("obstacles");
                    assert_eq!(obstacles.cubes.len(), 1);
                    assert_eq!(obstacles.cylinders.len(), 1);
                    assert_eq!(obstacles.triangles.len(), 1);
                    // A quadrilateral prism: 2 top triangles + 2 per side.
                    assert_eq!(obstacles.triangles[0].points.len(), 3 * (2 + 2 * 4));
                    let robot = get("robot");
                    assert_eq!(robot.frame_id, "robot");
                    assert!(robot.frame_locked);
                    let size = robot.cylinders[0].size.unwrap();
                    assert_close(size.x, 2.0 * RADIUS);
                    let goal = get("goal").spheres[0].pose.unwrap().position.unwrap();
                    assert_close(goal.x, goal_of(ep)[0]);
                    assert_close(goal.y, goal_of(ep)[1]);
                }
                TOPIC_TF => {
                    assert_foxglove_schema(&m, "foxglove.FrameTransform");
                    let tf = FrameTransform::decode(m.data.as_ref()).unwrap();
                    assert_eq!(tf.parent_frame_id, "world");
                    assert_eq!(tf.child_frame_id, "robot");
                    let t = tf.translation.unwrap();
                    let stamp = tf.timestamp.unwrap().total_nanos();
                    assert_eq!(stamp, m.log_time);
                    let ep = current.unwrap();
                    // The pose of some step of the current episode.
                    assert!((0..=ep.steps).any(|k| {
                        let p = pose_at(ep, k);
                        (p[0] - t.x).abs() < 1e-12 && (p[1] - t.y).abs() < 1e-12
                    }));
                    let q = tf.rotation.unwrap();
                    assert_close(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, 1.0);
                }
                TOPIC_SCAN => {
                    assert_foxglove_schema(&m, "foxglove.LaserScan");
                    let scan = LaserScan::decode(m.data.as_ref()).unwrap();
                    assert_eq!(scan.frame_id, "robot");
                    assert_eq!(scan.ranges.len(), 540);
                    let half_beam = 0.25_f64.to_radians();
                    assert_close(scan.start_angle, -135f64.to_radians() + half_beam);
                    assert_close(scan.end_angle, 135f64.to_radians() - half_beam);
                    assert!(scan.ranges.iter().all(|&r| (0.02..=10.0).contains(&r)));
                }
                TOPIC_STEP => {
                    assert_dvnav_schema(&m, "dvnav.v1.StepRecord");
                    let rec = dvnav_proto::StepRecord::decode(m.data.as_ref()).unwrap();
                    let ep = current.unwrap();
                    assert_eq!(rec.episode_id, ep.id);
                    let p = pose_at(ep, rec.step);
                    assert_eq!([rec.x, rec.y, rec.yaw], p);
                    assert_eq!(rec.action_linear, 1.0);
                    assert_eq!(rec.reward, if rec.step == 0 { 0.0 } else { 0.19 });
                    steps_seen.push((ep.id, rec.step));
                }
                TOPIC_EPISODE => {
                    assert_dvnav_schema(&m, "dvnav.v1.EpisodeSummary");
                    summaries.push(dvnav_proto::EpisodeSummary::decode(m.data.as_ref()).unwrap());
                }
                TOPIC_PATH => {
                    assert_foxglove_schema(&m, "foxglove.SceneUpdate");
                    let update = SceneUpdate::decode(m.data.as_ref()).unwrap();
                    assert!(update.deletions.is_empty(), "a path update never deletes the room");
                    let [path] = &update.entities[..] else { panic!("one path entity") };
                    assert_eq!((path.id.as_str(), path.frame_id.as_str()), ("path", "world"));
                    let ep = current.unwrap();
                    // The path so far: the poses of steps 0..=k for the step k at this time.
                    let points = &path.lines[0].points;
                    let k = points.len() as u32 - 1;
                    assert!(
                        k.is_multiple_of(PATH_EVERY_STEPS) || k == ep.steps,
                        "path at step {k}"
                    );
                    for (i, p) in points.iter().enumerate() {
                        let pose = pose_at(ep, i as u32);
                        assert_eq!([p.x, p.y], [pose[0], pose[1]]);
                    }
                    path_lengths.push((ep.id, k));
                }
                other => panic!("unexpected topic {other}"),
            }
        }
        assert!(ep_iter.next().is_none(), "a scene for every episode");
        let expected_steps: Vec<_> =
            eps.iter().flat_map(|e| (0..=e.steps).map(move |k| (e.id, k))).collect();
        assert_eq!(steps_seen, expected_steps);
        let n_steps = expected_steps.len();
        // Every PATH_EVERY_STEPS steps from step 0, and the last step.
        let expected_paths: Vec<(u64, u32)> = eps
            .iter()
            .flat_map(|e| {
                let mut ks: Vec<u32> = (0..=e.steps).step_by(PATH_EVERY_STEPS as usize).collect();
                if !e.steps.is_multiple_of(PATH_EVERY_STEPS) {
                    ks.push(e.steps);
                }
                ks.into_iter().map(move |k| (e.id, k))
            })
            .collect();
        assert_eq!(path_lengths, expected_paths);
        let expected_counts: BTreeMap<String, usize> = [
            (TOPIC_SCENE, eps.len()),
            (TOPIC_PATH, expected_paths.len()),
            (TOPIC_TF, n_steps),
            (TOPIC_SCAN, n_steps),
            (TOPIC_STEP, n_steps),
            (TOPIC_EPISODE, eps.len()),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        assert_eq!(counts, expected_counts);
        let ids: Vec<_> = summaries.iter().map(|s| s.episode_id).collect();
        assert_eq!(ids, eps.iter().map(|e| e.id).collect::<Vec<_>>());
        for s in &summaries {
            assert_eq!((s.actor.as_str(), s.actor_id), ("actor-3", 3));
        }
    }
}

#[test]
fn scan_ranges_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let ep = Episode { id: 0, steps: 2, outcome: dvnav_proto::Outcome::Success, stage: 1 };
    let mut log = EpisodeLogger::create(dir.path(), "a", meta(), 5).unwrap();
    log_episode(&mut log, &ep, &room, &lidar);
    log.close().unwrap();
    let scans: Vec<_> = messages(&mcap_files(dir.path())[0])
        .into_iter()
        .filter(|m| m.channel.topic == TOPIC_SCAN)
        .map(|m| LaserScan::decode(m.data.as_ref()).unwrap().ranges)
        .collect();
    let expected: Vec<Vec<f64>> = (0..=ep.steps)
        .map(|k| scan_at(pose_at(&ep, k), &room, &lidar).iter().map(|&r| f64::from(r)).collect())
        .collect();
    assert_eq!(scans, expected);
}

#[test]
fn log_time_is_simulation_time_and_episodes_do_not_overlap() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let episodes = three_episodes();
    let mut log = EpisodeLogger::create(dir.path(), "t", meta(), 2).unwrap();
    for ep in &episodes {
        log_episode(&mut log, ep, &room, &lidar);
    }
    log.close().unwrap();

    for path in mcap_files(dir.path()) {
        let msgs = messages(&path);
        assert!(msgs.windows(2).all(|w| w[0].log_time <= w[1].log_time), "monotonic in {path:?}");
        assert_eq!(msgs[0].log_time, 0, "each file's clock starts at 0");
        let summaries: Vec<_> = msgs
            .iter()
            .filter(|m| m.channel.topic == TOPIC_EPISODE)
            .map(|m| (m.log_time, dvnav_proto::EpisodeSummary::decode(m.data.as_ref()).unwrap()))
            .collect();
        let mut expected_start = 0;
        for (log_time, s) in &summaries {
            assert_eq!(s.start_time_ns, expected_start);
            assert_eq!(s.end_time_ns, s.start_time_ns + u64::from(s.steps) * DT_NS);
            assert_eq!(*log_time, s.end_time_ns, "summary logged at the last step");
            // Every step of this episode lies in [start, end] at base + step·dt.
            for m in msgs.iter().filter(|m| m.channel.topic == TOPIC_STEP) {
                let rec = dvnav_proto::StepRecord::decode(m.data.as_ref()).unwrap();
                if rec.episode_id == s.episode_id {
                    assert_eq!(m.log_time, s.start_time_ns + u64::from(rec.step) * DT_NS);
                }
            }
            expected_start = s.end_time_ns + DT_NS;
        }
        for w in summaries.windows(2) {
            assert!(w[0].1.end_time_ns < w[1].1.start_time_ns, "episodes overlap");
        }
    }
}

#[test]
fn read_episodes_and_summarize() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let sub = dir.path().join("actor-3");
    let mut log = EpisodeLogger::create(&sub, "actor-3", meta(), 2).unwrap();
    // Written out of id order; read back sorted.
    let mut episodes = three_episodes();
    episodes.swap(0, 2);
    for ep in &episodes {
        log_episode(&mut log, ep, &room, &lidar);
    }
    log.close().unwrap();
    std::fs::write(dir.path().join("notes.txt"), "not a log").unwrap();

    let records = read_episodes(dir.path()).unwrap();
    let ids: Vec<_> = records.iter().map(|r| r.summary.episode_id).collect();
    assert_eq!(ids, [10, 11, 12]);
    assert!(records.iter().all(|r| r.file.starts_with(&sub)));
    assert_eq!(records[0].summary.outcome, dvnav_proto::Outcome::Success as i32);
    assert_eq!(records[2].summary.steps, 7);

    // One file on its own.
    let one = read_episodes(&sub.join("actor-3-00001.mcap")).unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(one[0].summary.episode_id, 10);

    let groups = summarize(&records);
    assert_eq!(groups.len(), 1);
    let g = &groups[0];
    assert_eq!((g.actor.as_str(), g.stage, g.episodes), ("actor-3", 0, 3));
    for rate in [g.success_rate, g.collision_rate, g.timeout_rate] {
        assert_close(rate, 1.0 / 3.0);
    }
    assert_close(g.mean_steps, 5.0);
    assert_close(g.mean_return, 0.19 * 5.0);

    assert!(read_episodes(&dir.path().join("missing")).is_err());
}

#[test]
fn summarize_groups_by_actor_and_stage() {
    let rec = |actor: &str, stage: u32, outcome: dvnav_proto::Outcome, steps: u32, ret: f64| {
        EpisodeRecord {
            file: PathBuf::from("x.mcap"),
            summary: dvnav_proto::EpisodeSummary {
                actor: actor.into(),
                stage,
                outcome: outcome as i32,
                steps,
                episode_return: ret,
                ..Default::default()
            },
        }
    };
    use dvnav_proto::Outcome::*;
    let records = [
        rec("b", 0, Success, 10, 8.0),
        rec("a", 1, Success, 20, 9.0),
        rec("a", 0, Success, 10, 10.0),
        rec("a", 0, Success, 30, 6.0),
        rec("a", 0, Collision, 5, -10.0),
        rec("a", 0, Timeout, 400, -4.0),
        rec("a", 1, Unspecified, 7, 0.0),
    ];
    let groups = summarize(&records);
    let keys: Vec<_> = groups.iter().map(|g| (g.actor.as_str(), g.stage)).collect();
    assert_eq!(keys, [("a", 0), ("a", 1), ("b", 0)]);
    let a0 = &groups[0];
    assert_eq!(a0.episodes, 4);
    assert_close(a0.success_rate, 0.5);
    assert_close(a0.collision_rate, 0.25);
    assert_close(a0.timeout_rate, 0.25);
    assert_close(a0.mean_steps, 445.0 / 4.0);
    assert_close(a0.mean_return, 0.5);
    let a1 = &groups[1];
    assert_eq!(a1.episodes, 2);
    assert_close(a1.success_rate, 0.5);
    assert_close(a1.collision_rate + a1.timeout_rate, 0.0);
    assert_close(groups[2].success_rate, 1.0);
    let json = serde_json::to_value(&groups[2]).unwrap();
    assert_eq!(json["actor"], "b");
    assert_eq!(json["episodes"], 1);
}

/// Writes `n` episodes into one file, returning its path and the file length after each
/// episode (the logger flushes whole chunks at every episode end).
fn one_file(dir: &Path, n: u64) -> (PathBuf, Vec<u64>) {
    let (room, lidar) = (room(), LidarConfig::default());
    let mut log = EpisodeLogger::create(dir, "cut", meta(), 100).unwrap();
    let mut ends = Vec::new();
    for id in 0..n {
        let ep = Episode { id, steps: 20, outcome: dvnav_proto::Outcome::Success, stage: 0 };
        log_episode(&mut log, &ep, &room, &lidar);
        ends.push(std::fs::metadata(log.current_file().unwrap()).unwrap().len());
    }
    let path = log.current_file().unwrap().to_path_buf();
    log.close().unwrap();
    (path, ends)
}

#[test]
fn truncated_files_yield_the_episodes_before_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let (path, ends) = one_file(dir.path(), 4);
    let bytes = std::fs::read(&path).unwrap();
    let len = bytes.len() as u64;
    assert!(ends.windows(2).all(|w| w[0] < w[1]) && *ends.last().unwrap() < len);

    let cut_dir = tempfile::tempdir().unwrap();
    let mut cuts: Vec<u64> =
        [0.0, 0.1, 0.3, 0.6, 0.9, 0.99].iter().map(|f| (f * len as f64) as u64).collect();
    cuts.extend([0, 7, 8, 9, len - 1]);
    cuts.extend(ends.iter().flat_map(|&e| [e - 1, e, e + 1]));
    for cut in cuts {
        let cut_path = cut_dir.path().join(format!("cut-{cut}.mcap"));
        std::fs::write(&cut_path, &bytes[..cut as usize]).unwrap();
        let records = read_episodes(&cut_path).unwrap_or_else(|e| panic!("cut at {cut}: {e:#}"));
        let ids: Vec<_> = records.iter().map(|r| r.summary.episode_id).collect();
        // Episode i's bytes are (ends[i-1], ends[i]]: its chunk, then the chunk's message
        // indexes. Cut at or after its end it must be there; cut at or before its start it
        // cannot be; cut inside its message indexes it may be (its chunk is whole).
        let whole = ends.iter().filter(|&&e| e <= cut).count() as u64;
        let started = ends.iter().filter(|&&e| e < cut).count() as u64 + 1;
        let n = ids.len() as u64;
        assert!(
            whole <= n && n <= started.min(ends.len() as u64),
            "cut at {cut} of {len}: read {ids:?}, ends {ends:?}"
        );
        assert_eq!(ids, (0..n).collect::<Vec<_>>(), "cut at {cut}: a prefix, in order");
        std::fs::remove_file(&cut_path).unwrap();
    }
    // At 90 % at least the first episode survives.
    let cut_path = cut_dir.path().join("cut-90.mcap");
    std::fs::write(&cut_path, &bytes[..bytes.len() * 9 / 10]).unwrap();
    assert!(!read_episodes(&cut_path).unwrap().is_empty());
}

/// Walks the records of an MCAP file as any streaming reader does (magic, then opcode,
/// length, body): the bytes up to the end of the last whole record, or where a record claims
/// more bytes than there are (a chunk header written with a placeholder length: 2⁶⁴−1).
fn whole_records(bytes: &[u8]) -> Result<usize, String> {
    assert_eq!(&bytes[..8], b"\x89MCAP0\r\n");
    let mut at = 8;
    while at < bytes.len() {
        let head = bytes.get(at..at + 9).ok_or(format!("a record header cut at {at}"))?;
        let len = u64::from_le_bytes(head[1..9].try_into().unwrap());
        let end = (at as u64 + 9).checked_add(len).filter(|&e| e <= bytes.len() as u64);
        at = end.ok_or(format!("opcode {:#x} at {at} claims {len} bytes", head[0]))? as usize;
    }
    Ok(at)
}

#[test]
fn a_file_still_being_written_reads_like_a_killed_actor_left_it() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let mut log = EpisodeLogger::create(dir.path(), "live", meta(), 100).unwrap();
    for id in 0..2 {
        let ep = Episode { id, steps: 30, outcome: dvnav_proto::Outcome::Timeout, stage: 2 };
        log_episode(&mut log, &ep, &room, &lidar);
    }
    let ends_of_two = std::fs::metadata(log.current_file().unwrap()).unwrap().len();
    // Half an episode that is never ended; the BufWriter spills part of the open chunk.
    let ep = Episode { id: 2, steps: 400, outcome: dvnav_proto::Outcome::Timeout, stage: 2 };
    log.begin_episode(&EpisodeStart {
        episode_id: 2,
        room: &room,
        robot_radius: RADIUS,
        goal: goal_of(&ep),
        lidar: &lidar,
        dt: DT,
        mu: 1.0,
    })
    .unwrap();
    for step in 0..200 {
        let pose = pose_at(&ep, step);
        let scan = scan_at(pose, &room, &lidar);
        log.log_step(&StepLog {
            step,
            pose,
            scan: &scan,
            v: 0.1,
            omega: 0.0,
            action: [0.0, 0.0],
            reward: 0.0,
            goal_distance: 1.0,
            goal_angle: 0.0,
            subgoal: None,
            plan: None,
        })
        .unwrap();
    }
    // The open episode's chunk is built in memory: nothing of it is on disk, and the file ends
    // at a record boundary, where any reader that walks records stops cleanly.
    let on_disk = std::fs::read(log.current_file().unwrap()).unwrap();
    assert_eq!(on_disk.len() as u64, ends_of_two, "no part of the open chunk reached the file");
    assert_eq!(whole_records(&on_disk), Ok(on_disk.len()));
    // What SIGKILL leaves: exactly the bytes the OS has now.
    let snapshot = dir.path().join("snapshot");
    std::fs::create_dir(&snapshot).unwrap();
    std::fs::copy(log.current_file().unwrap(), snapshot.join("live.mcap")).unwrap();
    let records = read_episodes(&snapshot).unwrap();
    let ids: Vec<_> = records.iter().map(|r| r.summary.episode_id).collect();
    assert_eq!(ids, [0, 1]);
    drop(log);
}

#[test]
fn restart_continues_numbering_and_never_overwrites() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let ep = Episode { id: 0, steps: 1, outcome: dvnav_proto::Outcome::Success, stage: 0 };
    for _ in 0..2 {
        let mut log = EpisodeLogger::create(dir.path(), "r", meta(), 10).unwrap();
        log_episode(&mut log, &ep, &room, &lidar);
        log.close().unwrap();
    }
    // Another prefix that shares the beginning does not count.
    std::fs::write(dir.path().join("r-x-00009.mcap"), b"").unwrap();
    let mut log = EpisodeLogger::create(dir.path(), "r", meta(), 10).unwrap();
    log_episode(&mut log, &ep, &room, &lidar);
    assert_eq!(log.current_file().unwrap(), dir.path().join("r-00002.mcap"));
    log.close().unwrap();
    assert_eq!(read_episodes(dir.path()).unwrap().len(), 3);
}

#[test]
fn misuse_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    assert!(EpisodeLogger::create(dir.path(), "m", meta(), 0).is_err());
    let mut log = EpisodeLogger::create(dir.path(), "m", meta(), 1).unwrap();
    let scan = vec![1.0_f32; lidar.beams];
    let step = |k: u32, scan: &'static [f32]| StepLog {
        step: k,
        pose: [0.0; 3],
        scan,
        v: 0.0,
        omega: 0.0,
        action: [0.0; 2],
        reward: 0.0,
        goal_distance: 1.0,
        goal_angle: 0.0,
        subgoal: None,
        plan: None,
    };
    let scan: &'static [f32] = scan.leak();
    assert!(log.log_step(&step(0, scan)).is_err(), "step outside an episode");
    assert!(log.end_episode(Default::default()).is_err(), "end without begin");
    let start = EpisodeStart {
        episode_id: 1,
        room: &room,
        robot_radius: 0.2,
        goal: [0.0; 2],
        lidar: &lidar,
        dt: 0.0,
        mu: 1.0,
    };
    assert!(log.begin_episode(&start).is_err(), "dt = 0");
    log.begin_episode(&EpisodeStart { dt: DT, ..start }).unwrap();
    assert!(log.log_step(&step(0, &scan[..10])).is_err(), "wrong beam count");
    log.log_step(&step(3, scan)).unwrap();
    assert!(log.log_step(&step(2, scan)).is_err(), "steps go backwards");
    log.end_episode(Default::default()).unwrap();
    log.close().unwrap();
}

#[test]
fn logger_is_send() {
    fn assert_send<T: Send>() {}
    assert_send::<EpisodeLogger>();
}

#[test]
fn scaled_footprint_is_drawn_only_when_mu_is_not_one() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let mut log = EpisodeLogger::create(dir.path(), "mu", meta(), 10).unwrap();
    let ep = |id| Episode { id, steps: 2, outcome: dvnav_proto::Outcome::Success, stage: 0 };
    log_episode_mu(&mut log, &ep(0), &room, &lidar, 1.0);
    log_episode_mu(&mut log, &ep(1), &room, &lidar, 1.5);
    log.close().unwrap();
    let msgs = messages(&mcap_files(dir.path())[0]);
    let scenes: Vec<SceneUpdate> = msgs
        .iter()
        .filter(|m| m.channel.topic == TOPIC_SCENE)
        .map(|m| SceneUpdate::decode(m.data.as_ref()).unwrap())
        .collect();
    let scaled = |s: &SceneUpdate| s.entities.iter().find(|e| e.id == "scaled_footprint").cloned();
    assert!(scaled(&scenes[0]).is_none());
    let e = scaled(&scenes[1]).expect("μ = 1.5 draws the scaled robot");
    assert_eq!(e.frame_id, "robot");
    assert!(e.frame_locked);
    assert_close(e.cylinders[0].size.unwrap().x, 2.0 * 1.5 * RADIUS);
    // The robot's own footprint keeps its size.
    let robot = scenes[1].entities.iter().find(|e| e.id == "robot").unwrap();
    assert_close(robot.cylinders[0].size.unwrap().x, 2.0 * RADIUS);
    let mus: Vec<f64> = msgs
        .iter()
        .filter(|m| m.channel.topic == TOPIC_EPISODE)
        .map(|m| dvnav_proto::EpisodeSummary::decode(m.data.as_ref()).unwrap().mu)
        .collect();
    assert_eq!(mus, [1.0, 1.5]);
}

#[test]
fn files_rotate_by_size_as_well_as_by_episode_count() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let ep = |id| Episode { id, steps: 10, outcome: dvnav_proto::Outcome::Timeout, stage: 0 };
    // Measure the size of a file after one such episode first.
    let mut probe = EpisodeLogger::create(&dir.path().join("probe"), "p", meta(), 100).unwrap();
    log_episode(&mut probe, &ep(0), &room, &lidar);
    let one_episode = std::fs::metadata(probe.current_file().unwrap()).unwrap().len();
    drop(probe);
    // A limit of 1.5 episodes: the file is finished after the 2nd episode, never mid-episode.
    let sized = dir.path().join("sized");
    let mut log = EpisodeLogger::create(&sized, "s", meta(), 100)
        .unwrap()
        .with_max_file_bytes(Some(one_episode * 3 / 2));
    for id in 0..5 {
        log_episode(&mut log, &ep(id), &room, &lidar);
    }
    log.close().unwrap();
    let files = mcap_files(&sized);
    assert_eq!(files.len(), 3, "{files:?}");
    let per_file: Vec<Vec<u64>> = files
        .iter()
        .map(|f| read_episodes(f).unwrap().iter().map(|r| r.summary.episode_id).collect())
        .collect();
    assert_eq!(per_file, [vec![0, 1], vec![2, 3], vec![4]]);
    for f in &files {
        let check = check_file(f).unwrap();
        assert!(check.finished && check.is_ok(), "{check:?}");
    }
    // No limit (None or 0): by count only.
    let unlimited = dir.path().join("unlimited");
    let mut log =
        EpisodeLogger::create(&unlimited, "u", meta(), 100).unwrap().with_max_file_bytes(Some(0));
    for id in 0..3 {
        log_episode(&mut log, &ep(id), &room, &lidar);
    }
    log.close().unwrap();
    assert_eq!(mcap_files(&unlimited).len(), 1);
}

#[test]
fn check_file_decodes_everything_and_tells_finished_from_cut_and_damaged() {
    let dir = tempfile::tempdir().unwrap();
    let (path, ends) = one_file(dir.path(), 3);
    let check = check_file(&path).unwrap();
    assert!(check.is_ok(), "{check:?}");
    assert!(check.finished && check.truncated.is_none());
    assert_eq!(check.complete_episodes, 3);
    assert_eq!(check.steps, 3 * 21);
    assert_eq!(check.metadata.get("run_id").map(String::as_str), Some("run-7"));
    let n = |t: &str| check.topics.get(t).copied().unwrap_or(0);
    assert_eq!((n(TOPIC_SCAN), n(TOPIC_TF), n(TOPIC_STEP)), (63, 63, 63));
    assert_eq!((n(TOPIC_SCENE), n(TOPIC_EPISODE)), (3, 3));
    // 20 steps: paths at 0, 5, 10, 15, 20.
    assert_eq!(n(TOPIC_PATH), 3 * 5);
    assert_eq!(check.messages, 63 * 3 + 3 + 3 + 15);

    // Cut after the second episode's chunk plus a little: unfinished, two complete episodes,
    // no errors.
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..ends[1] as usize + 100]).unwrap();
    let c = check_file(&cut).unwrap();
    assert!(c.is_ok() && !c.finished && c.truncated.is_some(), "{c:?}");
    assert_eq!(c.complete_episodes, 2);

    // A flipped byte inside a finished file's first chunk is an error, not a quiet tail.
    let mut damaged = bytes.clone();
    let at = (ends[0] / 2) as usize;
    damaged[at] ^= 0xff;
    let bad = dir.path().join("bad.mcap");
    std::fs::write(&bad, &damaged).unwrap();
    let c = check_file(&bad).unwrap();
    assert!(!c.is_ok(), "{c:?}");

    // A damaged chunk size field must not abort the process (the mcap crate reserves the
    // claimed size): every single-byte flip in the first two chunks' headers reads or reports.
    for at in (0..(ends[1] as usize).min(bytes.len())).step_by(211) {
        let mut d = bytes.clone();
        d[at] ^= 0xff;
        std::fs::write(&bad, &d).unwrap();
        check_file(&bad).unwrap();
        read_episodes(&bad).unwrap();
    }
    // A chunk claiming 2^60 bytes: reading stops before it, with an error, instead of
    // aborting on the allocation.
    let mut huge = bytes.clone();
    let mut at = 8;
    while huge[at] != 0x06 {
        at += 9 + u64::from_le_bytes(huge[at + 1..at + 9].try_into().unwrap()) as usize;
    }
    huge[at + 9 + 16..at + 9 + 24].copy_from_slice(&(1u64 << 60).to_le_bytes());
    let (prefix, why) = super::reader::sane_prefix(&huge);
    assert_eq!(prefix.len(), at);
    assert!(why.unwrap().contains("uncompressed"));
    assert_eq!(super::reader::sane_prefix(&bytes).0.len(), bytes.len());
    std::fs::write(&bad, &huge).unwrap();
    let c = check_file(&bad).unwrap();
    assert!(!c.is_ok() && c.complete_episodes == 0, "{c:?}");
    assert!(read_episodes(&bad).unwrap().is_empty());

    // Not MCAP at all.
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, b"hello").unwrap();
    assert!(!check_file(&junk).unwrap().is_ok());
}

#[test]
fn episode_detail_from_steps() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let mut log = EpisodeLogger::create(dir.path(), "d", meta(), 10).unwrap();
    let episodes = three_episodes();
    for ep in &episodes {
        log_episode(&mut log, ep, &room, &lidar);
    }
    log.close().unwrap();
    let records = read_episodes(dir.path()).unwrap();
    let rec = &records[1];
    let ids = BTreeSet::from([rec.summary.episode_id]);
    let steps = read_steps(&rec.file, &ids).unwrap();
    assert_eq!(steps.keys().copied().collect::<Vec<_>>(), [11]);
    let d = episode_detail(rec, &steps[&11]);
    assert_eq!((d.episode_id, d.outcome.as_str(), d.steps), (11, "collision", 3));
    assert_eq!(d.logged_steps, 4);
    // pose_at moves 0.1 m in x per step at constant y.
    assert_close(d.path_length_m, 0.3);
    assert_close(d.mean_v, 0.5);
    assert_close(d.final_goal_distance_m, 4.0 - 0.3);
    assert_close(d.min_goal_distance_m, 4.0 - 0.3);
    assert_close(d.end_time_s - d.start_time_s, 3.0 * DT);
    assert_eq!(d.actor, "actor-3");
}

/// The Foxglove layout shipped in `deploy/foxglove/` names only topics the logger writes and
/// only fields `dvnav.v1.StepRecord` has, so a renamed field or topic fails here, not in
/// Foxglove.
#[test]
fn foxglove_layout_refers_to_logged_topics_and_fields() {
    let layout: serde_json::Value =
        serde_json::from_str(include_str!("../../../../deploy/foxglove/dvnav-episode-layout.json"))
            .unwrap();
    let topics = [
        TOPIC_SCAN,
        TOPIC_TF,
        TOPIC_SCENE,
        TOPIC_PATH,
        TOPIC_PLAN,
        TOPIC_SUBGOAL,
        TOPIC_STEP,
        TOPIC_EPISODE,
    ];
    let fds = prost_types::FileDescriptorSet::decode(dvnav_proto::FILE_DESCRIPTOR_SET).unwrap();
    let step_fields: BTreeSet<String> = fds
        .file
        .iter()
        .flat_map(|f| &f.message_type)
        .filter(|m| m.name() == "StepRecord")
        .flat_map(|m| m.field.iter().map(|f| f.name().to_string()))
        .collect();
    assert!(step_fields.contains("reward"));
    let panels = layout["configById"].as_object().unwrap();
    let mut plotted = 0;
    for (id, cfg) in panels {
        if let Some(t) = cfg["topics"].as_object() {
            for topic in t.keys() {
                assert!(topics.contains(&topic.as_str()), "{id}: unknown topic {topic}");
            }
            for must in [TOPIC_SCENE, TOPIC_PATH, TOPIC_PLAN, TOPIC_SUBGOAL, TOPIC_SCAN] {
                assert_eq!(t[must]["visible"], true, "{id}: {must} shown");
            }
        }
        for path in cfg["paths"].as_array().into_iter().flatten() {
            let value = path["value"].as_str().unwrap();
            let (topic, field) = value.split_once('.').unwrap();
            assert_eq!(topic, TOPIC_STEP, "{id}: {value}");
            assert!(step_fields.contains(field), "{id}: {value}: no field {field}");
            plotted += 1;
        }
        if let Some(t) = cfg["topicPath"].as_str() {
            assert!(topics.contains(&t), "{id}: {t}");
        }
    }
    assert!(plotted >= 3, "reward and velocities are plotted");
    // Every panel the layout tree names is configured.
    let tree = layout["layout"].to_string();
    for id in panels.keys() {
        assert!(tree.contains(&format!("\"{id}\"")), "{id} is not in the layout tree");
    }
}

/// An episode that follows a planned path (with one replan), then a mapless one, in one file:
/// `/plan` carries the plan at the first step and at the replan only, `/subgoal` every followed
/// step, each step record its subgoal, and the mapless episode deletes both markers.
#[test]
fn plans_and_subgoals_are_drawn_and_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let (room, lidar) = (room(), LidarConfig::default());
    let mut log = EpisodeLogger::create(dir.path(), "p", meta(), 10).unwrap();
    let first: Vec<[f64; 2]> = vec![[-2.0, -0.5], [0.0, 1.0], [2.0, 0.5]];
    let replanned: Vec<[f64; 2]> = vec![[-1.0, -0.5], [1.0, -1.5], [2.0, 0.5]];
    let subgoal = |k: u32| [-1.0 + 0.1 * f64::from(k), 0.2];
    for (id, followed) in [(0u64, true), (1, false)] {
        let ep = Episode { id, steps: 6, outcome: dvnav_proto::Outcome::Success, stage: 0 };
        log.begin_episode(&EpisodeStart {
            episode_id: id,
            room: &room,
            robot_radius: RADIUS,
            goal: goal_of(&ep),
            lidar: &lidar,
            dt: DT,
            mu: 1.0,
        })
        .unwrap();
        for step in 0..=ep.steps {
            let pose = pose_at(&ep, step);
            let scan = scan_at(pose, &room, &lidar);
            let plan = if step < 4 { &first } else { &replanned };
            log.log_step(&StepLog {
                step,
                pose,
                scan: &scan,
                v: 0.5,
                omega: 0.0,
                action: [1.0, 0.0],
                reward: 0.1,
                goal_distance: 3.0,
                goal_angle: 0.0,
                subgoal: followed.then(|| subgoal(step)),
                plan: followed.then_some(plan.as_slice()),
            })
            .unwrap();
        }
        log.end_episode(dvnav_proto::EpisodeSummary { steps: ep.steps, ..Default::default() })
            .unwrap();
    }
    log.close().unwrap();

    let [file] = &mcap_files(dir.path())[..] else { panic!("one file") };
    let (mut plans, mut subgoals, mut records) = (Vec::new(), Vec::new(), Vec::new());
    for m in messages(file) {
        match m.channel.topic.as_str() {
            TOPIC_PLAN | TOPIC_SUBGOAL => {
                assert_foxglove_schema(&m, "foxglove.SceneUpdate");
                let u = SceneUpdate::decode(m.data.as_ref()).unwrap();
                let out = if m.channel.topic == TOPIC_PLAN { &mut plans } else { &mut subgoals };
                out.push((m.log_time, u));
            }
            TOPIC_STEP => records.push(dvnav_proto::StepRecord::decode(m.data.as_ref()).unwrap()),
            _ => {}
        }
    }
    // /plan: the first plan at step 0, the replan at step 4, and its deletion when the mapless
    // episode begins (one control period after the first ended).
    let times: Vec<u64> = plans.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, [0, 4 * DT_NS, 7 * DT_NS]);
    for ((_, u), want) in plans.iter().zip([&first, &replanned]) {
        let [e] = &u.entities[..] else { panic!("one plan entity") };
        assert_eq!((e.id.as_str(), e.frame_id.as_str()), ("plan", "world"));
        let got: Vec<[f64; 2]> = e.lines[0].points.iter().map(|p| [p.x, p.y]).collect();
        assert_eq!(&got, want);
    }
    let deleted = &plans[2].1;
    assert!(deleted.entities.is_empty());
    assert_eq!(deleted.deletions[0].id, "plan");
    // /subgoal: every step of the followed episode, then one deletion.
    assert_eq!(subgoals.len(), 7 + 1);
    for (k, (_, u)) in subgoals[..7].iter().enumerate() {
        let c = u.entities[0].spheres[0].pose.unwrap().position.unwrap();
        assert_eq!([c.x, c.y], subgoal(k as u32));
    }
    assert_eq!(subgoals[7].1.deletions[0].id, "subgoal");
    // Step records keep the subgoal, and none in the mapless episode.
    assert_eq!(records.len(), 14);
    for r in &records {
        let want = (r.episode_id == 0).then(|| subgoal(r.step));
        assert_eq!(r.subgoal.as_ref().map(|p| [p.x, p.y]), want, "{r:?}");
    }
}
