//! [`EpisodeLogger`]: one actor's logged episodes, written into rotated MCAP files.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context as _, Result, bail, ensure};
use foxglove::messages::{FrameTransform, LaserScan, SceneUpdate, Timestamp, Vector3};
use foxglove::{Channel, Context, McapCompression, McapWriteOptions, McapWriterHandle};
use mcap::write::NoSeek;

use super::proto_msg::Dvnav;
use super::scene::{
    ROBOT_FRAME, WORLD_FRAME, episode_scene, path_update, plan_update, subgoal_update,
    yaw_quaternion,
};
use super::{
    METADATA_NAME, TOPIC_EPISODE, TOPIC_PATH, TOPIC_PLAN, TOPIC_SCAN, TOPIC_SCENE, TOPIC_STEP,
    TOPIC_SUBGOAL, TOPIC_TF,
};
use dvnav_config::LidarConfig;
use dvnav_sim::RoomSpec;

/// Target uncompressed chunk size (bytes). A 540-beam step is about 4.7 KB before compression,
/// so a 400-step episode (~1.9 MB) fits one chunk. The logger also closes the chunk at
/// every episode end, so chunk size only bounds how much of the *open* episode a crash loses,
/// and how much memory a file's chunk buffer holds (chunks are built in memory, see
/// [`EpisodeLogger`]).
const CHUNK_SIZE: u64 = 2 * 1024 * 1024;

/// The path so far goes out on `/path` every this many steps (and at the episode's last step).
/// Each update carries the whole path, so Foxglove's seek (which replays the latest message of
/// a topic) always shows it complete; every step would cost O(steps²) points per episode, every
/// 5th step keeps `/path` at a few percent of a file (see the README's disk costs).
pub const PATH_EVERY_STEPS: u32 = 5;

/// Who wrote a log file; stored as MCAP metadata record `dvnav` at the start of every file, so
/// any file can be traced back to its run, actor and configuration on its own.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LogMetadata {
    /// Identifier of the training run.
    pub run_id: String,
    /// Actor name.
    pub actor: String,
    /// Actor id assigned by the learner.
    pub actor_id: u32,
    /// Hash of the run configuration, to tell which settings produced a file.
    pub config_hash: String,
    /// The actor's base seed.
    pub seed: u64,
}

impl LogMetadata {
    /// The key/value map written as MCAP metadata, with dvnav's version added.
    fn to_map(&self, file_index: u64) -> BTreeMap<String, String> {
        BTreeMap::from([
            ("run_id".to_string(), self.run_id.clone()),
            ("actor".to_string(), self.actor.clone()),
            ("actor_id".to_string(), self.actor_id.to_string()),
            ("config_hash".to_string(), self.config_hash.clone()),
            ("seed".to_string(), self.seed.to_string()),
            ("dvnav_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("file_index".to_string(), file_index.to_string()),
        ])
    }
}

/// What the logger needs to know when an episode starts.
#[derive(Clone, Copy, Debug)]
pub struct EpisodeStart<'a> {
    /// Episode id, unique within the actor; copied into every step and the summary.
    pub episode_id: u64,
    /// The room, drawn on `/scene`.
    pub room: &'a RoomSpec,
    /// Radius of the robot's footprint (m), drawn as a cylinder in frame `robot`.
    pub robot_radius: f64,
    /// Goal position in the world frame (m).
    pub goal: [f64; 2],
    /// The LiDAR; its beam angles go into every `/scan` message.
    pub lidar: &'a LidarConfig,
    /// Control period (s): step `k` is logged at `episode start + k·dt` on the file's clock.
    pub dt: f64,
    /// DVST scale factor μ (design §5); 1 without DVST. When μ ≠ 1 the scene also shows the
    /// dimension-scaled robot: a disc of radius μ·`robot_radius` (the meta robot scaled about
    /// the axle centre). The logger copies μ into the episode summary.
    pub mu: f64,
}

/// One control step. Step 0 is the pose after reset (reward 0); each later step is the state
/// after the action.
#[derive(Clone, Copy, Debug)]
pub struct StepLog<'a> {
    /// Step number within the episode, starting at 0; must not decrease.
    pub step: u32,
    /// Robot pose in the world frame: x (m), y (m), yaw (rad).
    pub pose: [f64; 3],
    /// LiDAR ranges (m), one per beam of the episode's [`LidarConfig`].
    pub scan: &'a [f32],
    /// Linear velocity (m/s).
    pub v: f64,
    /// Angular velocity (rad/s).
    pub omega: f64,
    /// The policy's normalized action in [−1, 1]² (linear, angular).
    pub action: [f32; 2],
    /// Reward received for reaching this step.
    pub reward: f32,
    /// Distance to the goal (m).
    pub goal_distance: f64,
    /// Goal bearing in the robot frame (rad).
    pub goal_angle: f64,
    /// The point the agent was fed as its goal when following a planned path
    /// (`env.subgoals`, world frame, m); `None` when it saw the final goal. Drawn on
    /// `/subgoal` and kept in the step record.
    pub subgoal: Option<[f64; 2]>,
    /// The episode's current planned path (world frame, m), if it has one: drawn on `/plan`
    /// at the first step and again at every step where it differs (a replan).
    pub plan: Option<&'a [[f64; 2]]>,
}

/// The channels of one logger, all in the logger's own [`Context`].
struct Channels {
    scan: Channel<LaserScan>,
    tf: Channel<FrameTransform>,
    scene: Channel<SceneUpdate>,
    path: Channel<SceneUpdate>,
    plan: Channel<SceneUpdate>,
    subgoal: Channel<SceneUpdate>,
    step: Channel<Dvnav<dvnav_proto::StepRecord>>,
    episode: Channel<Dvnav<dvnav_proto::EpisodeSummary>>,
}

impl Channels {
    fn new(ctx: &Arc<Context>) -> Self {
        Self {
            scan: ctx.channel_builder(TOPIC_SCAN).build(),
            tf: ctx.channel_builder(TOPIC_TF).build(),
            scene: ctx.channel_builder(TOPIC_SCENE).build(),
            path: ctx.channel_builder(TOPIC_PATH).build(),
            plan: ctx.channel_builder(TOPIC_PLAN).build(),
            subgoal: ctx.channel_builder(TOPIC_SUBGOAL).build(),
            step: ctx.channel_builder(TOPIC_STEP).build(),
            episode: ctx.channel_builder(TOPIC_EPISODE).build(),
        }
    }
}

/// The file being written.
struct OpenFile {
    handle: McapWriterHandle<NoSeek<BufWriter<File>>>,
    path: PathBuf,
    /// Episodes finished in this file.
    episodes: u64,
    /// Where the next episode starts on this file's clock (ns).
    next_base_ns: u64,
    /// `/plan` and `/subgoal` show an entity that the next episode must delete.
    plan_shown: bool,
    subgoal_shown: bool,
}

/// The episode being written.
struct OpenEpisode {
    id: u64,
    /// Simulation time of step 0 on the file's clock (ns).
    base_ns: u64,
    /// Control period (ns).
    dt_ns: u64,
    /// Log time of the latest step, `None` before the first.
    last_ns: Option<u64>,
    beams: usize,
    start_angle: f64,
    end_angle: f64,
    mu: f64,
    /// Robot positions so far (world frame), for `/path`.
    path: Vec<[f64; 2]>,
    /// Whether `/path` already has the latest step.
    path_published: bool,
    /// The plan last drawn on `/plan` in this episode (empty: none).
    plan: Vec<[f64; 2]>,
}

/// Writes one actor's logged episodes into rotated MCAP files `DIR/{prefix}-{index:05}.mcap`.
///
/// Call [`begin_episode`](Self::begin_episode), then [`log_step`](Self::log_step) for step 0
/// and every later step, then [`end_episode`](Self::end_episode); at the end of the actor,
/// [`close`](Self::close). One episode is open at a time; an actor that runs several
/// environments uses one logger per environment (distinct prefixes) or buffers an episode and
/// replays it.
///
/// **Time.** Log time is simulation time: each file's clock starts at 0, step `k` of an episode
/// is at `base + k·dt`, and the next episode in the same file starts one control period after
/// the previous one ended, so episodes never overlap within a file.
///
/// **Crash safety.** Files are zstd-compressed and chunked. At every episode end the logger
/// closes the current chunk and flushes it to the operating system
/// ([`McapWriterHandle::flush`]), so a process killed at any point (SIGKILL) leaves every
/// finished episode in complete chunks on disk and loses only the open episode. Chunks are
/// built in memory and written whole (the writer does not seek: [`NoSeek`]): a writer that
/// seeks writes a chunk's header first with a placeholder length and patches it when the
/// chunk closes, so a killed process left a chunk "of 2⁶⁴−1 bytes" at the end of the file,
/// which stops every reader that walks records (the PyPI `mcap` package, even as a stream,
/// read 0 messages of such a file). Now the bytes on disk always end at a record boundary
/// (short of a kill in the middle of writing one); our reader ([`super::read_episodes`]) and
/// any other read such a file up to there.
///
/// **Rotation.** After `episodes_per_file` episodes, or at the first episode end at which the
/// file has reached [`with_max_file_bytes`](Self::with_max_file_bytes), the file is finished
/// (summary, indexes, footer) and synced to disk. Episodes never straddle files, so a file can
/// pass the size limit by at most one episode (~0.2–0.5 MB for 400 steps).
///
/// **Closing.** Call [`close`](Self::close): it reports errors. Dropping the logger also
/// finishes the open file, but can only log its errors.
///
/// **Restarts.** Files are never overwritten: a new logger continues after the highest index
/// already in `dir` for its prefix.
pub struct EpisodeLogger {
    dir: PathBuf,
    prefix: String,
    meta: LogMetadata,
    episodes_per_file: u64,
    /// Finish a file at the first episode end at which it is at least this large (bytes).
    max_file_bytes: Option<u64>,
    /// Kept alive for the channels and the writer; never the global context.
    ctx: Arc<Context>,
    channels: Channels,
    next_index: u64,
    file: Option<OpenFile>,
    episode: Option<OpenEpisode>,
    /// Reused `/scan` message, so a step allocates nothing for its ranges.
    scan_msg: LaserScan,
}

impl std::fmt::Debug for EpisodeLogger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EpisodeLogger")
            .field("dir", &self.dir)
            .field("prefix", &self.prefix)
            .field("next_index", &self.next_index)
            .field("file", &self.file.as_ref().map(|f| &f.path))
            .field("episode", &self.episode.as_ref().map(|e| e.id))
            .finish_non_exhaustive()
    }
}

/// Nanoseconds as a Foxglove timestamp (the file's clock starts at 0).
fn timestamp(ns: u64) -> Timestamp {
    // Seconds fit u32 for 136 years of simulated time per file.
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

/// The highest `{prefix}-NNNNN.mcap` index in `dir`, if any.
fn highest_index(dir: &Path, prefix: &str) -> Result<Option<u64>> {
    let mut best = None;
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let name = entry?.file_name();
        let Some(name) = name.to_str() else { continue };
        let index = name
            .strip_prefix(prefix)
            .and_then(|s| s.strip_prefix('-'))
            .and_then(|s| s.strip_suffix(".mcap"))
            .filter(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|s| s.parse::<u64>().ok());
        best = best.max(index);
    }
    Ok(best)
}

impl EpisodeLogger {
    /// A logger writing `dir/{prefix}-{index:05}.mcap`, `episodes_per_file` episodes per file.
    /// Creates `dir`; the first file is opened at the first episode.
    pub fn create(
        dir: &Path,
        prefix: &str,
        meta: LogMetadata,
        episodes_per_file: u64,
    ) -> Result<Self> {
        ensure!(episodes_per_file > 0, "episodes_per_file must be at least 1");
        ensure!(
            !prefix.is_empty() && !prefix.contains(['/', '\\']),
            "log file prefix {prefix:?} must be a non-empty file name"
        );
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let next_index = highest_index(dir, prefix)?.map_or(0, |i| i + 1);
        let ctx = Context::new();
        let channels = Channels::new(&ctx);
        Ok(Self {
            dir: dir.to_path_buf(),
            prefix: prefix.to_string(),
            meta,
            episodes_per_file,
            max_file_bytes: None,
            ctx,
            channels,
            next_index,
            file: None,
            episode: None,
            scan_msg: LaserScan { frame_id: ROBOT_FRAME.to_string(), ..Default::default() },
        })
    }

    /// Also rotates files by size: a file is finished at the first episode end at which it
    /// holds at least `bytes` bytes (`None`: by episode count only).
    pub fn with_max_file_bytes(mut self, bytes: Option<u64>) -> Self {
        self.max_file_bytes = bytes.filter(|&b| b > 0);
        self
    }

    /// Path of the file being written, if one is open.
    pub fn current_file(&self) -> Option<&Path> {
        self.file.as_ref().map(|f| f.path.as_path())
    }

    /// Opens the next file and writes its metadata.
    fn open_file(&mut self) -> Result<OpenFile> {
        let options = McapWriteOptions::new()
            .compression(Some(McapCompression::Zstd))
            .chunk_size(Some(CHUNK_SIZE))
            // Compress on the logging thread: an actor machine runs many actors, and zstd's
            // default of one worker per physical core per file would oversubscribe it.
            .compression_threads(0)
            // Chunks in memory, written whole: no placeholder header on disk (see the type).
            .disable_seeking(true);
        loop {
            let index = self.next_index;
            self.next_index += 1;
            let path = self.dir.join(format!("{}-{index:05}.mcap", self.prefix));
            let file = match File::create_new(&path) {
                Ok(f) => f,
                // Someone else took this name since we listed the directory: take the next one.
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => {
                    return Err(e).with_context(|| format!("creating {}", path.display()));
                }
            };
            let handle = self
                .ctx
                .mcap_writer_with_options(options.clone())
                .create(NoSeek::new(BufWriter::new(file)))
                .with_context(|| format!("starting {}", path.display()))?;
            handle
                .write_metadata(METADATA_NAME, self.meta.to_map(index))
                .with_context(|| format!("writing metadata to {}", path.display()))?;
            tracing::debug!(path = %path.display(), "episode log opened");
            return Ok(OpenFile {
                handle,
                path,
                episodes: 0,
                next_base_ns: 0,
                plan_shown: false,
                subgoal_shown: false,
            });
        }
    }

    /// Finishes the open file (chunk, summary, indexes, footer) and syncs it to disk.
    fn finish_file(file: OpenFile) -> Result<()> {
        let OpenFile { handle, path, .. } = file;
        let writer = handle.close().with_context(|| format!("finishing {}", path.display()))?;
        let file = writer
            .into_inner()
            .into_inner()
            .map_err(|e| e.into_error())
            .with_context(|| format!("flushing {}", path.display()))?;
        file.sync_all().with_context(|| format!("syncing {}", path.display()))?;
        tracing::debug!(path = %path.display(), "episode log finished");
        Ok(())
    }

    /// Starts an episode: opens a file if none is open and publishes the scene (room, goal,
    /// footprint). An episode still open is abandoned with a warning: its steps stay in the file
    /// without a summary, and readers skip it.
    pub fn begin_episode(&mut self, ep: &EpisodeStart<'_>) -> Result<()> {
        ensure!(
            ep.dt.is_finite() && ep.dt > 0.0,
            "episode {}: control period dt = {} s must be positive",
            ep.episode_id,
            ep.dt
        );
        ensure!(ep.lidar.beams > 0, "episode {}: LiDAR has no beams", ep.episode_id);
        ensure!(
            ep.mu.is_finite() && ep.mu > 0.0,
            "episode {}: scale factor mu = {} must be positive",
            ep.episode_id,
            ep.mu
        );
        if let Some(open) = self.episode.take() {
            tracing::warn!(
                abandoned = open.id,
                next = ep.episode_id,
                "episode log: episode begun while another was open; the open one has no summary"
            );
            if let Some(file) = self.file.as_mut() {
                let end = open.last_ns.unwrap_or(open.base_ns);
                file.next_base_ns = end + open.dt_ns;
            }
        }
        if self.file.is_none() {
            self.file = Some(self.open_file()?);
        }
        let base_ns = self.file.as_ref().map_or(0, |f| f.next_base_ns);
        let dt_ns = ((ep.dt * 1e9).round() as u64).max(1);

        let fov = ep.lidar.fov_deg.to_radians();
        let n = ep.lidar.beams as f64;
        self.episode = Some(OpenEpisode {
            id: ep.episode_id,
            base_ns,
            dt_ns,
            last_ns: None,
            beams: ep.lidar.beams,
            start_angle: -0.5 * fov + fov * 0.5 / n,
            end_angle: -0.5 * fov + fov * (n - 0.5) / n,
            mu: ep.mu,
            path: Vec::with_capacity(512),
            path_published: false,
            plan: Vec::new(),
        });
        let stamp = timestamp(base_ns);
        self.channels.scene.log_with_time(&episode_scene(ep, stamp), base_ns);
        // The scene's "delete all" covers `/scene` only: the last episode's plan and subgoal
        // live on their own topics.
        let file = self.file.as_mut().expect("opened above");
        if std::mem::take(&mut file.plan_shown) {
            self.channels.plan.log_with_time(&plan_update(&[], stamp), base_ns);
        }
        if std::mem::take(&mut file.subgoal_shown) {
            self.channels.subgoal.log_with_time(&subgoal_update(None, stamp), base_ns);
        }
        Ok(())
    }

    /// Logs one step on `/tf`, `/scan` and `/dvnav/step` at `episode start + step·dt`, and on
    /// `/plan` and `/subgoal` when the episode follows a planned path.
    pub fn log_step(&mut self, s: &StepLog<'_>) -> Result<()> {
        let Some(ep) = self.episode.as_mut() else {
            bail!("episode log: step {} logged outside an episode", s.step);
        };
        ensure!(
            s.scan.len() == ep.beams,
            "episode {} step {}: scan has {} ranges, the LiDAR has {} beams",
            ep.id,
            s.step,
            s.scan.len(),
            ep.beams
        );
        let t = ep.base_ns + u64::from(s.step) * ep.dt_ns;
        if let Some(last) = ep.last_ns {
            ensure!(t >= last, "episode {}: step {} logged after a later step", ep.id, s.step);
        }
        ep.last_ns = Some(t);
        let stamp = timestamp(t);
        let [x, y, yaw] = s.pose;
        ep.path.push([x, y]);
        ep.path_published = s.step.is_multiple_of(PATH_EVERY_STEPS);
        if ep.path_published {
            self.channels.path.log_with_time(&path_update(&ep.path, stamp), t);
        }
        if let Some(file) = self.file.as_mut() {
            let plan = s.plan.unwrap_or_default();
            if plan != ep.plan.as_slice() {
                self.channels.plan.log_with_time(&plan_update(plan, stamp), t);
                file.plan_shown = !plan.is_empty();
                ep.plan.clear();
                ep.plan.extend_from_slice(plan);
            }
            if s.subgoal.is_some() || file.subgoal_shown {
                self.channels.subgoal.log_with_time(&subgoal_update(s.subgoal, stamp), t);
                file.subgoal_shown = s.subgoal.is_some();
            }
        }

        self.channels.tf.log_with_time(
            &FrameTransform {
                timestamp: Some(stamp),
                parent_frame_id: WORLD_FRAME.to_string(),
                child_frame_id: ROBOT_FRAME.to_string(),
                translation: Some(Vector3 { x, y, z: 0.0 }),
                rotation: Some(yaw_quaternion(yaw)),
            },
            t,
        );

        let scan = &mut self.scan_msg;
        scan.timestamp = Some(stamp);
        scan.start_angle = ep.start_angle;
        scan.end_angle = ep.end_angle;
        scan.ranges.clear();
        scan.ranges.extend(s.scan.iter().map(|&r| f64::from(r)));
        self.channels.scan.log_with_time(scan, t);

        self.channels.step.log_with_time(
            &Dvnav(dvnav_proto::StepRecord {
                episode_id: ep.id,
                step: s.step,
                v: s.v,
                omega: s.omega,
                action_linear: s.action[0],
                action_angular: s.action[1],
                reward: s.reward,
                goal_distance: s.goal_distance,
                goal_angle: s.goal_angle,
                x,
                y,
                yaw,
                subgoal: s.subgoal.map(|[x, y]| dvnav_proto::Point2 { x, y }),
            }),
            t,
        );
        Ok(())
    }

    /// Ends the episode: logs `summary` on `/dvnav/episode` at the last step's time, with
    /// `episode_id`, `actor`, `actor_id`, `start_time_ns` and `end_time_ns` set by the logger,
    /// then flushes the episode into finished chunks. After `episodes_per_file` episodes the file
    /// is finished; the next episode opens a new one.
    pub fn end_episode(&mut self, mut summary: dvnav_proto::EpisodeSummary) -> Result<()> {
        let Some(ep) = self.episode.take() else {
            bail!("episode log: episode {} ended but none was begun", summary.episode_id);
        };
        let Some(file) = self.file.as_mut() else {
            bail!("episode log: episode {} has no open file", ep.id);
        };
        let end_ns = ep.last_ns.unwrap_or(ep.base_ns);
        if !ep.path_published && !ep.path.is_empty() {
            // The complete path at the last step.
            self.channels.path.log_with_time(&path_update(&ep.path, timestamp(end_ns)), end_ns);
        }
        summary.episode_id = ep.id;
        summary.mu = ep.mu;
        summary.actor = self.meta.actor.clone();
        summary.actor_id = self.meta.actor_id;
        summary.start_time_ns = ep.base_ns;
        summary.end_time_ns = end_ns;
        self.channels.episode.log_with_time(&Dvnav(summary), end_ns);

        file.episodes += 1;
        file.next_base_ns = end_ns + ep.dt_ns;
        if file.episodes >= self.episodes_per_file {
            let file = self.file.take().expect("file is open");
            return Self::finish_file(file);
        }
        // Close the chunk and hand it to the OS: a crash from here on keeps this episode.
        file.handle.flush().with_context(|| format!("flushing {}", file.path.display()))?;
        if let Some(limit) = self.max_file_bytes {
            let len = std::fs::metadata(&file.path)
                .with_context(|| format!("reading the size of {}", file.path.display()))?
                .len();
            if len >= limit {
                let file = self.file.take().expect("file is open");
                return Self::finish_file(file);
            }
        }
        Ok(())
    }

    /// Finishes the open file, if any, and reports any error writing it. An episode still open
    /// stays in the file without a summary (with a warning).
    pub fn close(mut self) -> Result<()> {
        if let Some(ep) = self.episode.take() {
            tracing::warn!(episode = ep.id, "episode log closed inside an episode");
        }
        match self.file.take() {
            Some(file) => Self::finish_file(file),
            None => Ok(()),
        }
    }
}
