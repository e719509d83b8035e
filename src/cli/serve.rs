//! `dvnav serve`: the DVST controller as a gRPC service (`dvnav.controller.v1.Controller`). A
//! robot calls `Act` each control cycle with its scan, goal and velocity and gets (v, ω) back
//! from the meta agent through DVST; `SetFootprint` changes its footprint at run time.
//!
//! The service only translates: wire messages into [`RobotInput`] and footprint text, calls
//! [`DvstController`], and maps [`ControllerError`] to status codes in one place
//! ([`status`]). The server takes its listener and its shutdown from the caller ([`serve`]),
//! so tests and `dvnav bench serve` run it on `127.0.0.1:0` and stop it through a oneshot.

use clap::Args;
use dvnav_nav::dvst::controller::{
    Command, ControllerError, ControllerInfo, DvstController, FootprintState, ModelId, RobotInput,
};
use dvnav_nav::policy::MetaAgent;
use dvnav_proto::controller::v1 as pb;
use pb::controller_server::{Controller, ControllerServer};
use std::future::Future;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};
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
}

/// Runs `dvnav serve` until Ctrl-C or SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<ExitCode> {
    single_candle_thread();
    let ctl = Arc::new(load_controller(&args.checkpoint, &args.footprint, args.margin)?);
    let token = super::read_token(args.token_file.as_deref())?;
    let tls = args.tls.load()?;
    super::runtime()?.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
        let addr = listener.local_addr()?;
        let info = ctl.info();
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
            token = token.is_some(),
            tls = tls.is_some(),
            "controller listening"
        );
        if let Some(f) = &args.addr_file {
            write_addr_file(f, addr)?;
        }
        serve(listener, super::shutdown_signal(), ctl.clone(), token, tls).await?;
        tracing::info!(commands = ctl.info().commands, "controller stopped");
        Ok(ExitCode::SUCCESS)
    })
}

/// Batch-1 inference is small; candle's spinning thread pool would only add latency and take
/// cores from the robot's other work. Set before any candle use; no other thread runs yet.
fn single_candle_thread() {
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
) -> anyhow::Result<DvstController<MetaAgent>> {
    let file = dvnav_nav::policy::read_policy(checkpoint)?;
    let agent = MetaAgent::from_policy_file(&file)?;
    let model = model_id(&file)?;
    let cfg = file.config;
    let text = std::fs::read_to_string(footprint).map_err(|e| {
        anyhow::anyhow!("{}: cannot read the footprint file: {e}", footprint.display())
    })?;
    DvstController::new(agent, &cfg, model, &text, &footprint.display().to_string(), margin)
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
    ctl: Arc<DvstController<MetaAgent>>,
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
        .add_service(ControllerServer::new(ControllerService { ctl, token }))
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
/// (`INVALID_ARGUMENT`, the message names the field), a failing policy the server's.
fn status(e: ControllerError) -> Status {
    let msg = e.to_string();
    match e {
        ControllerError::InvalidArgument { .. } => Status::invalid_argument(msg),
        ControllerError::Policy(_) => Status::internal(msg),
    }
}

/// The gRPC face of a [`DvstController`].
struct ControllerService {
    ctl: Arc<DvstController<MetaAgent>>,
    /// The shared token callers must present, if any.
    token: Option<String>,
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

fn act_reply(c: Command, model: &ModelId) -> pb::ActReply {
    pb::ActReply {
        v: c.v,
        omega: c.omega,
        mu: c.mu,
        footprint: c.footprint,
        model_version: model.version.clone(),
        footprint_version: c.footprint_version,
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
        footprint: s.robot.footprint.name,
    }
}

fn info_reply(i: ControllerInfo) -> pb::InfoReply {
    let fp = i.footprint;
    pb::InfoReply {
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
        footprint: fp.robot.footprint.name,
        model: i.model.name,
        model_version: i.model.version,
    }
}

#[tonic::async_trait]
impl Controller for ControllerService {
    async fn act(&self, req: Request<pb::ActRequest>) -> Result<Response<pb::ActReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        let input = RobotInput {
            scan: &r.scan,
            goal_distance: r.goal_distance,
            goal_angle: r.goal_angle,
            v: r.v,
            omega: r.omega,
        };
        // One inference runs on this thread: it takes less than handing it to the blocking pool
        // and back would add (`dvnav bench serve`; figures in docs/results.md).
        let command = self.ctl.act(&input).inspect_err(|e| {
            tracing::debug!(robot = %r.robot_id, error = %e, "Act refused");
        });
        let command = command.map_err(status)?;
        tracing::trace!(robot = %r.robot_id, v = command.v, omega = command.omega, "Act");
        Ok(Response::new(act_reply(command, self.ctl.model())))
    }

    async fn set_footprint(
        &self,
        req: Request<pb::SetFootprintRequest>,
    ) -> Result<Response<pb::SetFootprintReply>, Status> {
        self.authorize(&req)?;
        let r = req.into_inner();
        let state = self.ctl.set_footprint_toml(&r.footprint_toml).inspect_err(|e| {
            tracing::warn!(robot = %r.robot_id, error = %e, "SetFootprint refused");
        });
        let state = state.map_err(status)?;
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
        Ok(Response::new(info_reply(self.ctl.info())))
    }
}

/// What `dvnav bench serve --json` prints: latency of one command at batch 1 (ms), through
/// the gRPC service over loopback and in-process (checks, DVST and the policy, no network).
#[derive(serde::Serialize)]
pub struct ServeBench {
    calls: usize,
    grpc_p50_ms: f64,
    grpc_p99_ms: f64,
    grpc_mean_ms: f64,
    grpc_max_ms: f64,
    in_process_p50_ms: f64,
    in_process_p99_ms: f64,
    in_process_mean_ms: f64,
    in_process_max_ms: f64,
    target_p99_ms: f64,
    meets_target: bool,
    beams: usize,
    mu: f64,
    model: String,
    footprint: String,
}

/// Latency of `calls` commands, one at a time, through the service over loopback gRPC (client
/// and server in this process, on `dvnav`'s 2-worker runtime) and in-process.
pub fn bench(checkpoint: &Path, footprint: &Path, calls: usize) -> anyhow::Result<ServeBench> {
    anyhow::ensure!(calls >= 100, "--calls must be at least 100 for a p99");
    single_candle_thread();
    let ctl = Arc::new(load_controller(checkpoint, footprint, None)?);
    let info = ctl.info();
    let beams = info.beams;
    // Scans that change from call to call, like a robot moving through a room.
    let request = |k: usize| pb::ActRequest {
        scan: (0..beams).map(|i| 0.3 + 4.0 * (1.0 + ((i + 7 * k) as f32 * 0.05).sin())).collect(),
        goal_distance: 0.5 + (k % 40) as f64 * 0.1,
        goal_angle: ((k % 60) as f64 - 30.0) * 0.05,
        v: 0.2,
        omega: 0.1,
        robot_id: "bench".into(),
    };
    let warmup = 50;

    let mut local = Vec::with_capacity(calls);
    for k in 0..warmup + calls {
        let r = request(k);
        let input = RobotInput {
            scan: &r.scan,
            goal_distance: r.goal_distance,
            goal_angle: r.goal_angle,
            v: r.v,
            omega: r.omega,
        };
        let t = Instant::now();
        ctl.act(&input)?;
        if k >= warmup {
            local.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }

    let remote = super::runtime()?.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(serve(
            listener,
            async {
                let _ = stopped.await;
            },
            ctl.clone(),
            None,
            None,
        ));
        let mut client =
            pb::controller_client::ControllerClient::connect(format!("http://{addr}")).await?;
        let mut times = Vec::with_capacity(calls);
        for k in 0..warmup + calls {
            let r = request(k);
            let t = Instant::now();
            client.act(r).await?;
            if k >= warmup {
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        let _ = stop.send(());
        server.await??;
        anyhow::Ok(times)
    })?;
    let (g, l) = (Latency::of(remote), Latency::of(local));
    let fp = &info.footprint;
    Ok(ServeBench {
        calls,
        grpc_p50_ms: g.p50,
        grpc_p99_ms: g.p99,
        grpc_mean_ms: g.mean,
        grpc_max_ms: g.max,
        in_process_p50_ms: l.p50,
        in_process_p99_ms: l.p99,
        in_process_mean_ms: l.mean,
        in_process_max_ms: l.max,
        target_p99_ms: 2.0,
        meets_target: g.p99 < 2.0,
        beams,
        mu: fp.mu,
        model: format!("{} ({})", info.model.name, info.model.version),
        footprint: footprint.display().to_string(),
    })
}

impl ServeBench {
    /// One line for people.
    pub fn summary(&self) -> String {
        format!(
            "controller, batch 1, {} calls: gRPC over loopback p50 {:.3} ms, p99 {:.3} ms, mean \
             {:.3} ms, max {:.3} ms (target p99 < {} ms: {}); in-process p50 {:.3} ms, p99 {:.3} ms",
            self.calls,
            self.grpc_p50_ms,
            self.grpc_p99_ms,
            self.grpc_mean_ms,
            self.grpc_max_ms,
            self.target_p99_ms,
            if self.meets_target { "met" } else { "missed" },
            self.in_process_p50_ms,
            self.in_process_p99_ms
        )
    }
}

/// Percentiles of a sample of latencies (ms): the nearest-rank definition.
struct Latency {
    p50: f64,
    p99: f64,
    mean: f64,
    max: f64,
}

impl Latency {
    fn of(mut ms: Vec<f64>) -> Latency {
        ms.sort_by(f64::total_cmp);
        let rank = |q: f64| ms[((q * ms.len() as f64).ceil() as usize).clamp(1, ms.len()) - 1];
        Latency {
            p50: rank(0.50),
            p99: rank(0.99),
            mean: ms.iter().sum::<f64>() / ms.len() as f64,
            max: ms[ms.len() - 1],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let l = Latency::of((1..=200).rev().map(f64::from).collect());
        assert_eq!((l.p50, l.p99, l.max), (100.0, 198.0, 200.0));
        assert!((l.mean - 100.5).abs() < 1e-12);
        let one = Latency::of(vec![3.0]);
        assert_eq!((one.p50, one.p99, one.max), (3.0, 3.0, 3.0));
    }

    #[test]
    fn domain_errors_map_to_status_codes() {
        let invalid = ControllerError::InvalidArgument { field: "scan".into(), reason: "x".into() };
        let s = status(invalid);
        assert_eq!((s.code(), s.message()), (tonic::Code::InvalidArgument, "`scan`: x"));
        let s = status(ControllerError::Policy(anyhow::anyhow!("boom")));
        assert_eq!(s.code(), tonic::Code::Internal);
    }
}
