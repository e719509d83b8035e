//! `dvnav serve`: the DVST controller as a gRPC service (`dvnav.controller.v1.Controller`).
//! Robots call `Act` each control cycle with their scan (the meta agent's layout or any
//! LaserScan), goal and velocity and get (v, ω) back from the meta agent through DVST, and
//! `arrived` within the goal tolerance; `SetFootprint` sets one robot's footprint at run time.
//!
//! The service only translates: wire messages into [`RobotInput`] and footprint text, calls
//! [`DvstController`], and maps [`ControllerError`] to status codes in one place
//! ([`status`]). The server takes its listener and its shutdown from the caller ([`serve`]),
//! so tests and `dvnav bench serve` run it on `127.0.0.1:0` and stop it through a oneshot.

use clap::Args;
use dvnav_nav::dvst::LaserScan;
use dvnav_nav::dvst::controller::{
    Command, ControllerError, ControllerInfo, DEFAULT_MAX_ROBOTS, DEFAULT_ROBOT_IDLE,
    DvstController, FootprintState, ModelId, RobotInput, Scan,
};
use dvnav_nav::policy::MetaAgent;
use dvnav_proto::controller::v1 as pb;
use pb::controller_server::{Controller, ControllerServer};
use std::future::Future;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;
use tonic::{Request, Response, Status};

/// `dvnav serve`.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// The meta agent: a model directory (`models/meta-r0.2`), a checkpoint directory or a
    /// `policy.safetensors`, with the `config.toml` beside it.
    #[arg(long)]
    checkpoint: PathBuf,
    /// The robot at start-up: a footprint file (see `footprints/`); `SetFootprint` replaces it.
    #[arg(long)]
    footprint: PathBuf,
    /// Address to listen on (`0.0.0.0:50061` for robots on other machines); port 0 picks a
    /// free port.
    #[arg(long, default_value = "127.0.0.1:50061")]
    listen: String,
    /// Write the address actually bound to this file (for supervisors and tests using port 0).
    #[arg(long)]
    addr_file: Option<PathBuf>,
    /// File holding the shared access token callers must present as `authorization: Bearer
    /// TOKEN` (or set DVNAV_TOKEN).
    #[arg(long)]
    token_file: Option<PathBuf>,
    #[command(flatten)]
    tls: super::tls::ServerTlsArgs,
    /// Safety margin (m) for every footprint, replacing the files' own `margin`.
    #[arg(long)]
    margin: Option<f64>,
    /// Robots this server drives at once (each with its own footprint, by `robot_id`); a new
    /// robot beyond them is refused with RESOURCE_EXHAUSTED until one falls silent.
    #[arg(long, default_value_t = DEFAULT_MAX_ROBOTS)]
    max_robots: usize,
    /// Seconds a robot may be silent before it is forgotten (its footprint with it: it then
    /// drives with the default footprint, or is refused if it sends
    /// `expected_footprint_version`).
    #[arg(long, default_value_t = DEFAULT_ROBOT_IDLE.as_secs_f64())]
    robot_idle_s: f64,
    /// Robots whose calls arrive together share one forward pass: about a third of the cost
    /// per command at 64 robots, but a robot's command then depends in its last bits on who
    /// else is served, so identical runs can diverge. Default: one pass per robot,
    /// deterministic.
    #[arg(long)]
    batched_inference: bool,
    /// A collision monitor on every command: v is scaled down (ω kept) so that the robot,
    /// driving the command for this many seconds, would not touch a return of its scan
    /// (`dvnav eval --safety-horizon`; 0.6 measured best, docs/results.md "A collision
    /// monitor"). 0: off, the agent's own commands.
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    safety_horizon: f64,
    /// The stall escape for robots driving without a route: one that has come no closer to its
    /// goal for this many seconds gets the agent's own sampled action, tanh(μ + σ·ε), for as
    /// long, then the deterministic one again (`dvnav eval --escape-after`; 3 s was best on
    /// tuning rooms, docs/results.md "The stall escape"). Robots on a route replan instead.
    /// 0: off, the deterministic policy.
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    escape_after: f64,
}

/// Runs `dvnav serve` until Ctrl-C or SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<ExitCode> {
    single_candle_thread();
    anyhow::ensure!(
        args.robot_idle_s.is_finite() && args.robot_idle_s > 0.0 && args.robot_idle_s <= 1e7,
        "--robot-idle-s must be a positive number of seconds, got {}",
        args.robot_idle_s
    );
    let ctl = load_controller(&args.checkpoint, &args.footprint, args.margin)?
        .with_robot_limits(args.max_robots, Duration::from_secs_f64(args.robot_idle_s))
        .map_err(|e| anyhow::anyhow!("--max-robots / --robot-idle-s: {e:#}"))?
        .with_batched_inference(args.batched_inference)
        .with_safety_horizon(args.safety_horizon)
        .map_err(|e| anyhow::anyhow!("--safety-horizon: {e:#}"))?
        .with_stall_escape(args.escape_after)
        .map_err(|e| anyhow::anyhow!("--escape-after: {e:#}"))?;
    let warm = std::time::Instant::now();
    ctl.warm_up().map_err(|e| {
        anyhow::anyhow!("{}: the policy failed its first pass: {e:#}", args.checkpoint.display())
    })?;
    tracing::debug!(ms = warm.elapsed().as_secs_f64() * 1e3, "policy warmed up");
    let ctl = Arc::new(ctl);
    let token = super::read_token(args.token_file.as_deref())?;
    let tls = args.tls.load()?;
    super::runtime()?.block_on(async move {
        // Before the address file: from then on a SIGTERM stops the server gracefully.
        let shutdown = super::shutdown_signal();
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
        let addr = listener.local_addr()?;
        let info = ctl.info("");
        let fp = &info.footprint;
        tracing::info!(
            %addr,
            model = %info.model.name,
            model_version = %info.model.version,
            footprint = %fp.robot.footprint.name,
            mu = fp.mu,
            scaled_robot = %fp.scaled.describe(),
            v_max = fp.bounds.v_max,
            omega_max = fp.bounds.omega_max,
            beams = info.beams,
            max_robots = info.max_robots,
            robot_idle_s = info.robot_idle.as_secs_f64(),
            token = token.is_some(),
            tls = tls.is_some(),
            "controller listening"
        );
        if let Some(f) = &args.addr_file {
            write_addr_file(f, addr)?;
        }
        serve(listener, shutdown, ctl.clone(), token, tls).await?;
        tracing::info!(commands = ctl.info("").commands, "controller stopped");
        Ok(ExitCode::SUCCESS)
    })
}

/// Batch-1 inference is small; candle's spinning thread pool would only add latency and take
/// cores from the robot's other work. Set before any candle use; no other thread runs yet.
pub(super) fn single_candle_thread() {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // SAFETY: called before the runtime or any other thread starts.
        unsafe { std::env::set_var("CANDLE_NUM_THREADS", "1") };
    }
}

/// The meta agent of `checkpoint` driving the robot of the footprint file `footprint`.
pub fn load_controller(
    checkpoint: &Path,
    footprint: &Path,
    margin: Option<f64>,
) -> anyhow::Result<DvstController> {
    let text = std::fs::read_to_string(footprint).map_err(|e| {
        anyhow::anyhow!("{}: cannot read the footprint file: {e}", footprint.display())
    })?;
    controller_for(checkpoint, &text, Some(footprint), margin, None)
}

/// The meta agent of `checkpoint` driving the robot of the footprint file text
/// `footprint_toml` (read from `source`); `None` drives the meta robot itself (a model trained
/// as a circle). `lidar`, when given, is the sensor's mounting `[x, y, yaw]` in place of the
/// file's `[lidar]` position (its other keys kept).
pub(super) fn controller_for(
    checkpoint: &Path,
    footprint_toml: &str,
    source: Option<&Path>,
    margin: Option<f64>,
    lidar: Option<[f64; 3]>,
) -> anyhow::Result<DvstController> {
    let file = dvnav_nav::policy::read_policy(checkpoint)?;
    let agent = MetaAgent::from_policy_file(&file)?;
    let model = model_id(&file)?;
    let cfg = file.config;
    let mounted = |text: &str| match lidar {
        Some(mount) => with_lidar_mount(text, mount),
        None => Ok(text.to_string()),
    };
    match source {
        Some(path) => {
            let source = path.display().to_string();
            let text = mounted(footprint_toml)?;
            DvstController::new(agent, &cfg, model, &text, &source, margin)
        }
        None => {
            anyhow::ensure!(
                cfg.env.footprint.is_none(),
                "the model was trained as a footprint of its own; give the robot's with --footprint"
            );
            let meta = format!(
                "name = \"meta robot\"\n[[parts]]\nshape = \"circle\"\ncenter = [0.0, 0.0]\nradius = {}\n",
                cfg.env.robot_radius
            );
            let meta = mounted(&meta)?;
            DvstController::new(agent, &cfg, model, &meta, "the meta robot", margin)
        }
    }
}

/// The footprint file `text` with its `[lidar]` table's `x`, `y`, `yaw` set to `mount` (the
/// table made if missing). The file was read once as it is, so its errors name its own lines.
fn with_lidar_mount(text: &str, [x, y, yaw]: [f64; 3]) -> anyhow::Result<String> {
    let mut doc: toml::Table =
        toml::from_str(text).map_err(|e| anyhow::anyhow!("the footprint file: {e}"))?;
    let lidar = doc.entry("lidar").or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let toml::Value::Table(lidar) = lidar else {
        anyhow::bail!("the footprint file: `lidar` must be a table");
    };
    for (key, v) in [("x", x), ("y", y), ("yaw", yaw)] {
        lidar.insert(key.to_string(), toml::Value::Float(v));
    }
    toml::to_string(&doc).map_err(|e| anyhow::anyhow!("the footprint file: {e}"))
}

/// The model's name (its directory) and version: FNV-1a 64 of its weights, so two servers (or
/// a robot's log and a server) can tell whether they drive with the same policy.
fn model_id(policy: &dvnav_nav::policy::PolicyFile) -> anyhow::Result<ModelId> {
    let mut h = fnv::FnvHasher::default();
    std::hash::Hasher::write(&mut h, &policy.weights);
    let h = std::hash::Hasher::finish(&h);
    let dir = policy.path.parent().and_then(|d| d.canonicalize().ok());
    let name = dir
        .as_deref()
        .and_then(Path::file_name)
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| policy.path.display().to_string());
    Ok(ModelId { name, version: format!("fnv1a64:{h:016x}") })
}

/// Written whole or not at all: a supervisor polling for it never reads half an address.
fn write_addr_file(f: &Path, addr: std::net::SocketAddr) -> anyhow::Result<()> {
    if let Some(parent) = f.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    let tmp = f.with_extension("tmp");
    std::fs::write(&tmp, addr.to_string())
        .and_then(|()| std::fs::rename(&tmp, f))
        .map_err(|e| anyhow::anyhow!("cannot write --addr-file {}: {e}", f.display()))
}

/// How long calls in flight and clients' connections get to finish once shutdown begins.
/// A command takes milliseconds; a robot whose process hangs with its connection open must
/// not keep the server from stopping.
const DRAIN_GRACE: Duration = Duration::from_secs(2);

/// Serves `ctl` on `listener` (over TLS with `tls`) until `shutdown` resolves, then lets calls
/// in flight finish (for at most [`DRAIN_GRACE`]).
pub async fn serve(
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()>,
    ctl: Arc<DvstController>,
    token: Option<String>,
    tls: Option<tonic::transport::ServerTlsConfig>,
) -> anyhow::Result<()> {
    // Small messages, one per control cycle: Nagle's algorithm would hold replies back.
    let incoming = tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
    let draining = tokio_util::sync::CancellationToken::new();
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = tls {
        builder = builder
            .tls_config(tls)
            .map_err(|e| anyhow::anyhow!("cannot set up TLS for the controller service: {e}"))?;
    }
    let server = builder
        .add_service(ControllerServer::new(ControllerService {
            beams: ctl.info("").beams,
            ctl,
            token,
            unseen_warned: Default::default(),
            refused: Default::default(),
        }))
        .serve_with_incoming_shutdown(incoming, async {
            shutdown.await;
            draining.cancel();
        });
    tokio::select! {
        r = server => r?,
        () = async {
            draining.cancelled().await;
            tokio::time::sleep(DRAIN_GRACE).await;
        } => tracing::warn!(grace = ?DRAIN_GRACE, "connections still open at shutdown; closed"),
    }
    Ok(())
}

/// The one place domain errors become status codes: a malformed request is the caller's
/// (`INVALID_ARGUMENT`, the message names the field), a full server a resource
/// (`RESOURCE_EXHAUSTED`: retry later), a footprint other than the one expected the robot's
/// state (`FAILED_PRECONDITION`: set it again), a failing policy the server's (`INTERNAL`).
fn status(e: ControllerError) -> Status {
    let msg = e.to_string();
    match e {
        ControllerError::InvalidArgument { .. } => Status::invalid_argument(msg),
        ControllerError::TooManyRobots(_) => Status::resource_exhausted(msg),
        ControllerError::FootprintChanged { .. } => Status::failed_precondition(msg),
        ControllerError::Policy(_) => Status::internal(msg),
        ControllerError::NoMap => Status::failed_precondition(msg),
    }
}

/// A request's scan: the meta form, or the LaserScan, not both.
fn scan_of(r: &pb::ActRequest) -> Result<Scan<'_>, Status> {
    match &r.laser_scan {
        None => Ok(Scan::Meta(&r.scan)),
        Some(_) if !r.scan.is_empty() => Err(status(ControllerError::InvalidArgument {
            field: "laser_scan".into(),
            reason: "send the scan once: as `scan` (the meta agent's layout) or as `laser_scan`, \
                     not both"
                .into(),
        })),
        Some(l) => Ok(Scan::Laser(LaserScan {
            angle_min: l.angle_min,
            angle_increment: l.angle_increment,
            range_min: l.range_min,
            range_max: l.range_max,
            ranges: &l.ranges,
        })),
    }
}

/// The domain input of an Act request.
pub(super) fn robot_input(r: &pb::ActRequest) -> Result<RobotInput<'_>, Status> {
    Ok(RobotInput {
        scan: scan_of(r)?,
        goal_distance: r.goal_distance,
        goal_angle: r.goal_angle,
        v: r.v,
        omega: r.omega,
        robot_id: &r.robot_id,
        expected_footprint_version: (r.expected_footprint_version != 0)
            .then_some(r.expected_footprint_version),
        pose: r.pose.as_ref().map(|p| dvnav_sim::Pose2::new(p.x, p.y, p.yaw)),
        scan_age_s: r.scan_age_s,
    })
}

/// The gRPC face of a [`DvstController`].
struct ControllerService {
    ctl: Arc<DvstController>,
    /// The shared token callers must present, if any.
    token: Option<String>,
    /// The meta agent's beams.
    beams: usize,
    /// Robots already warned that their sensor leaves most meta beams unseen (once each).
    unseen_warned: std::sync::Mutex<std::collections::HashSet<String>>,
    /// Requests refused as malformed since the server started (InfoReply.refused).
    refused: std::sync::atomic::AtomicU64,
}

impl ControllerService {
    /// The learner's rule ([`dvnav_tls::auth`]).
    fn authorize<T>(&self, req: &Request<T>) -> Result<(), Status> {
        let presented = dvnav_tls::auth::bearer_token(req.metadata());
        if dvnav_tls::auth::token_accepted(self.token.as_deref(), presented) {
            Ok(())
        } else {
            Err(Status::unauthenticated("missing or wrong access token"))
        }
    }
}

impl ControllerService {
    /// The status of a refusal, counted when the request was malformed.
    fn refuse(&self, e: ControllerError) -> Status {
        if matches!(e, ControllerError::InvalidArgument { .. }) {
            self.refused.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        status(e)
    }

    /// A scan that leaves most of the meta agent's beams unseen drives on guesses (a sensor
    /// turned the wrong way, a narrow field, a driver's invalid readings): said once per robot,
    /// naming its sensor, the first time it happens.
    fn warn_if_mostly_unseen(&self, robot: &str, c: &Command) {
        if c.filled_beams * 2 <= self.beams {
            return;
        }
        let mut warned = self.unseen_warned.lock().unwrap_or_else(|e| e.into_inner());
        // Bounded like the robot table: a server does not grow with robot names.
        if warned.len() < 4096 && warned.insert(robot.to_string()) {
            let info = self.ctl.info(robot);
            let lidar = info.footprint.robot.lidar;
            tracing::warn!(
                robot,
                footprint = %c.footprint,
                filled_beams = c.filled_beams,
                beams = self.beams,
                lidar_x = lidar.x,
                lidar_y = lidar.y,
                lidar_yaw = lidar.yaw,
                "most of the meta agent's beams are not seen by this robot's sensor and are \
                 filled: check the footprint file's [lidar] mounting and the scan's angles"
            );
        }
    }
}

fn act_reply(c: Command, model: &ModelId) -> pb::ActReply {
    let route = c.route;
    pb::ActReply {
        following_route: route.is_some(),
        subgoal_x: route.map_or(0.0, |r| r.subgoal[0]),
        subgoal_y: route.map_or(0.0, |r| r.subgoal[1]),
        remaining_m: route.map_or(0.0, |r| r.remaining_m),
        replan_wanted: route.is_some_and(|r| r.replan_wanted),
        replans: route.map_or(0, |r| r.replans),
        replanning: route.is_some_and(|r| r.replanning),
        blocked: route.is_some_and(|r| r.blocked),
        v: c.v,
        omega: c.omega,
        mu: c.mu,
        footprint: c.footprint,
        model_version: model.version.clone(),
        footprint_version: c.footprint_version,
        arrived: c.arrived,
        goal_tolerance: c.goal_tolerance,
        filled_beams: c.filled_beams as u32,
    }
}

fn route_reply(set: dvnav_nav::dvst::controller::RouteSet) -> pb::SetRouteReply {
    pb::SetRouteReply {
        poses: set.poses as u32,
        length_m: set.length_m,
        lookahead_m: set.lookahead_m,
    }
}

fn footprint_reply(s: FootprintState) -> pb::SetFootprintReply {
    pb::SetFootprintReply {
        mu: s.mu,
        scaled_robot: s.scaled.describe(),
        margin: s.robot.margin,
        v_max: s.bounds.v_max,
        omega_max: s.bounds.omega_max,
        footprint_version: s.version,
        goal_tolerance: s.goal_tolerance,
        footprint: s.robot.footprint.name,
    }
}

fn info_reply(
    i: ControllerInfo,
    subgoals: &dvnav_sim::subgoal::SubgoalConfig,
    refused: u64,
) -> pb::InfoReply {
    let fp = i.footprint;
    pb::InfoReply {
        lookahead_m: subgoals.lookahead_m,
        replan_distance_m: subgoals.replan_distance_m,
        stall_s: subgoals.stall_s,
        safety_horizon_s: i.safety_horizon_s,
        escape_after_s: i.escape_after_s,
        known_tolerance_m: subgoals.planner.known_tolerance_m,
        rotation_shim: subgoals.rotation_shim,
        rotation_shim_angle_deg: subgoals.shim_angle_deg,
        refused,
        scan_beams: i.beams as u32,
        scan_fov_deg: i.fov_deg,
        range_min: i.scan_range[0],
        range_max: i.scan_range[1],
        control_period_s: i.control_period_s,
        v_max: fp.bounds.v_max,
        omega_max: fp.bounds.omega_max,
        meta_v_max: i.meta_bounds.v_max,
        meta_omega_max: i.meta_bounds.omega_max,
        mu: fp.mu,
        scaled_robot: fp.scaled.describe(),
        meta_robot: fp.robot.meta.describe(),
        margin: fp.robot.margin,
        footprint_version: fp.version,
        goal_tolerance: fp.goal_tolerance,
        lidar_x: fp.robot.lidar.x,
        lidar_y: fp.robot.lidar.y,
        lidar_yaw: fp.robot.lidar.yaw,
        lidar_uncovered_range: fp.robot.lidar.uncovered.range().unwrap_or(0.0),
        lidar_uncovered: match fp.robot.lidar.uncovered {
            dvnav_nav::dvst::Uncovered::Nearest => "nearest".into(),
            dvnav_nav::dvst::Uncovered::Range(_) => "range".into(),
        },
        footprint: fp.robot.footprint.name,
        model: i.model.name,
        model_version: i.model.version,
        robots: i.robots as u32,
        max_robots: i.max_robots as u32,
        robot_idle_s: i.robot_idle.as_secs_f64(),
    }
}

#[tonic::async_trait]
impl Controller for ControllerService {
    async fn act(&self, req: Request<pb::ActRequest>) -> Result<Response<pb::ActReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        let input = robot_input(&r).inspect_err(|_| {
            self.refused.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        })?;
        // Calls arriving together share one forward pass; a waiting call does not hold its
        // worker (`dvst::shared_policy`).
        let command = self.ctl.act_async(&input).await.inspect_err(|e| {
            tracing::debug!(robot = %r.robot_id, error = %e, "Act refused");
        });
        let command = command.map_err(|e| self.refuse(e))?;
        tracing::trace!(robot = %r.robot_id, v = command.v, omega = command.omega, "Act");
        self.warn_if_mostly_unseen(&r.robot_id, &command);
        Ok(Response::new(act_reply(command, self.ctl.model())))
    }

    async fn set_footprint(
        &self,
        req: Request<pb::SetFootprintRequest>,
    ) -> Result<Response<pb::SetFootprintReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        let state = self.ctl.set_footprint_toml(&r.robot_id, &r.footprint_toml).inspect_err(|e| {
            tracing::warn!(robot = %r.robot_id, error = %e, "SetFootprint refused");
        });
        let state = state.map_err(|e| self.refuse(e))?;
        tracing::info!(
            robot = %r.robot_id,
            footprint = %state.robot.footprint.name,
            mu = state.mu,
            scaled_robot = %state.scaled.describe(),
            version = state.version,
            "footprint changed"
        );
        Ok(Response::new(footprint_reply(state)))
    }

    async fn info(&self, req: Request<pb::InfoRequest>) -> Result<Response<pb::InfoReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        dvnav_nav::dvst::controller::check_robot_id(&r.robot_id).map_err(|e| self.refuse(e))?;
        let refused = self.refused.load(std::sync::atomic::Ordering::Relaxed);
        let info = self.ctl.info(&r.robot_id);
        Ok(Response::new(info_reply(info, self.ctl.subgoal_config(), refused)))
    }

    async fn set_route(
        &self,
        req: Request<pb::SetRouteRequest>,
    ) -> Result<Response<pb::SetRouteReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        if r.clear {
            if !r.poses.is_empty() {
                return Err(self.refuse(ControllerError::InvalidArgument {
                    field: "poses".into(),
                    reason: "`clear` drops the route: send no poses with it".into(),
                }));
            }
            let had = self.ctl.clear_route(&r.robot_id).map_err(|e| self.refuse(e))?;
            tracing::info!(robot = %r.robot_id, had, "route cleared");
            return Ok(Response::new(pb::SetRouteReply::default()));
        }
        let points = r.poses.iter().map(|p| [p.x, p.y]).collect();
        let set = self.ctl.set_route(&r.robot_id, points).map_err(|e| {
            tracing::warn!(robot = %r.robot_id, error = %e, "SetRoute refused");
            self.refuse(e)
        })?;
        tracing::info!(robot = %r.robot_id, poses = set.poses, length_m = set.length_m, "route set");
        Ok(Response::new(route_reply(set)))
    }

    async fn set_map(
        &self,
        req: Request<pb::SetMapRequest>,
    ) -> Result<Response<pb::SetMapReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        // Decoding and rastering a building's map takes a while: off the async workers.
        let ctl = self.ctl.clone();
        let map = tokio::task::spawn_blocking(move || ctl.set_map(&r.map_yaml, &r.image))
            .await
            .map_err(|e| Status::internal(format!("SetMap failed: {e}")))?
            .map_err(|e| {
                tracing::warn!(error = %e, "SetMap refused");
                self.refuse(e)
            })?;
        tracing::info!(
            width = map.width,
            height = map.height,
            resolution = map.resolution,
            "map set"
        );
        Ok(Response::new(pb::SetMapReply {
            width: map.width as u32,
            height: map.height as u32,
            resolution: map.resolution,
        }))
    }

    async fn set_goal(
        &self,
        req: Request<pb::SetGoalRequest>,
    ) -> Result<Response<pb::SetRouteReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        let missing = |field: &str| ControllerError::InvalidArgument {
            field: field.into(),
            reason: "is required: the robot's pose now and its goal, in the map frame".into(),
        };
        let start = r.start.ok_or_else(|| self.refuse(missing("start")))?;
        let goal = r.goal.ok_or_else(|| self.refuse(missing("goal")))?;
        let start = dvnav_sim::Pose2::new(start.x, start.y, start.yaw);
        // Planning takes milliseconds on a building's map: off the async workers, so other
        // robots' Act calls are not held up.
        let ctl = self.ctl.clone();
        let id = r.robot_id.clone();
        let set = tokio::task::spawn_blocking(move || ctl.set_goal(&id, start, [goal.x, goal.y]))
            .await
            .map_err(|e| Status::internal(format!("SetGoal failed: {e}")))?
            .map_err(|e| {
                tracing::warn!(robot = %r.robot_id, error = %e, "SetGoal refused");
                self.refuse(e)
            })?;
        tracing::info!(robot = %r.robot_id, poses = set.poses, length_m = set.length_m, "goal planned");
        Ok(Response::new(route_reply(set)))
    }
}

mod bench;
mod latency;
mod route_bench;
pub use bench::{FleetLoad, bench};
pub use route_bench::RouteLoad;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domain_errors_map_to_status_codes() {
        let invalid = ControllerError::InvalidArgument { field: "scan".into(), reason: "x".into() };
        let s = status(invalid);
        assert_eq!((s.code(), s.message()), (tonic::Code::InvalidArgument, "`scan`: x"));
        let s = status(ControllerError::Policy(anyhow::anyhow!("boom")));
        assert_eq!(s.code(), tonic::Code::Internal);
    }
}
