//! A whole learner process: state, trainer thread, gRPC server, end of run and summary.

use crate::checkpoint::{self, Checkpoint};
use crate::sac::{SacLearner, SacNetworks};
use crate::service::LearnerService;
use crate::state::{LearnerState, StatusSnapshot};
use crate::{metrics, trainer, watchdog};
use candle_core::Device;
use dvnav_config::Config;
use serde::Serialize;
use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::net::TcpListener;
use tokio_stream::wrappers::TcpListenerStream;

/// How long the learner waits for actors to disconnect after the step budget is reached.
pub const ACTOR_DRAIN_TIMEOUT: Duration = Duration::from_secs(30);

/// Options of a learner process beyond the config file.
#[derive(Clone, Debug)]
pub struct LearnerOptions {
    /// Run directory: config, checkpoints, summary.
    pub out_dir: PathBuf,
    /// Shared token actors must present, if any.
    pub token: Option<String>,
    /// Per-actor tokens (`--actor-tokens`), if any.
    pub actor_tokens: Option<crate::actor_tokens::ActorTokens>,
    /// Run id (defaults to the directory name).
    pub run_id: Option<String>,
    /// Continue from the newest complete checkpoint in `out_dir` (`--resume`).
    pub resume: bool,
    /// Serve Prometheus metrics (`GET /metrics`) on this listener, bound by the caller
    /// (`--metrics-addr`). `metrics.csv` in `out_dir` is written either way.
    pub metrics_listener: Option<Arc<std::net::TcpListener>>,
    /// Where the networks train (`--device`): the CPU, or a CUDA GPU.
    pub device: Device,
    /// Serve gRPC over TLS (`--tls-cert`, `--tls-key`; see [`dvnav_tls`]).
    pub tls: Option<tonic::transport::ServerTlsConfig>,
}

/// The learner's part of `run_summary.json` (`learner_summary.json`); `dvnav train` reads it
/// back as this type.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct LearnerSummary {
    /// Counters at the end.
    #[serde(flatten)]
    pub status: StatusSnapshot,
    /// Wall time of the learner (s).
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub wall_time_s: f64,
    /// Transitions received per second of wall time.
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub env_steps_per_s: f64,
    /// Updates per second of wall time.
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub updates_per_s: f64,
    /// Directory of the final checkpoint.
    pub final_checkpoint: Option<PathBuf>,
}

/// Creates `dir` if needed and proves it writable by creating and removing a probe file, so an
/// unwritable output directory fails at start with its path and the OS error, not at the first
/// checkpoint.
pub fn check_writable(dir: &std::path::Path) -> anyhow::Result<()> {
    let fail = |e: std::io::Error| {
        anyhow::anyhow!("output directory {} is not writable: {e}", dir.display())
    };
    std::fs::create_dir_all(dir).map_err(fail)?;
    let probe = dir.join(".dvnav-write-probe");
    std::fs::write(&probe, b"probe").map_err(fail)?;
    std::fs::remove_file(&probe).map_err(fail)?;
    Ok(())
}

/// Runs a learner on `listener` until the step budget is reached and the actors have left, or
/// until `shutdown` resolves. Writes checkpoints and `learner_summary.json` into the run dir.
pub async fn run(
    cfg: Config,
    listener: TcpListener,
    opts: LearnerOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<LearnerSummary> {
    let started = Instant::now();
    // First: a TLS setting the server cannot use fails before anything starts.
    let mut transport = crate::service::transport_server(opts.tls.clone())?;
    check_writable(&opts.out_dir)?;
    let config_path = opts.out_dir.join("config.toml");
    std::fs::write(&config_path, cfg.to_toml_string())
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", config_path.display()))?;
    let run_id = opts.run_id.clone().unwrap_or_else(|| {
        opts.out_dir.file_name().and_then(|n| n.to_str()).unwrap_or("run").to_string()
    });

    let device = opts.device.clone();
    tracing::info!(device = %crate::device::name(&device), "learner device");
    // `auto` is timed here, before the networks exist; the run's config keeps `auto`, so a
    // resumed run chooses again on the machine it resumes on.
    let (precision, choice) = crate::bench::precision::resolve(&cfg, &device)?;
    match &choice {
        Some(c) => tracing::info!(choice = %c, "learner matrix products: precision auto chose"),
        None => tracing::info!(%precision, "learner matrix products"),
    }
    let nets = {
        let mut c = cfg.clone();
        c.learner.precision = precision;
        SacNetworks::new(&c, cfg.run.seed, &device)?
    };
    let mut learner = SacLearner::new(nets, cfg.sac.clone(), device, cfg.run.seed ^ 0x0005_ac00)?
        .with_threads(cfg.learner.threads)?
        .with_cuda_graphs(cfg.learner.cuda_graph);
    tracing::info!(threads = learner.threads(), "learner threads");
    let mut sample_rng = trainer::sample_rng(cfg.run.seed);
    let state = Arc::new(
        LearnerState::new(cfg.clone(), run_id, opts.token.clone(), learner.policy_safetensors()?)
            .with_actor_tokens(opts.actor_tokens.clone()),
    );
    if opts.resume {
        let ckpt = Checkpoint::latest(&opts.out_dir)?;
        sample_rng = ckpt.resume(&mut learner, &state)?.unwrap_or(sample_rng);
        tracing::info!(
            checkpoint = %ckpt.dir.display(),
            updates = ckpt.meta.updates,
            env_steps = ckpt.meta.env_steps,
            stage = state.curriculum_state().stage,
            "resumed"
        );
    }

    let trainer = {
        let state = state.clone();
        let out = opts.out_dir.clone();
        std::thread::Builder::new()
            .name("trainer".into())
            .spawn(move || trainer::train(state, learner, sample_rng, out))?
    };

    // Live metrics: a sample every few seconds into metrics.csv, and /metrics over HTTP.
    let metrics = tokio::spawn(metrics::record(
        state.clone(),
        Some(opts.out_dir.join("metrics.csv")),
        state.shutdown_signal(),
    ));
    // The watchdog: names a stuck component within one heartbeat.
    let watchdog = {
        let heartbeat = Duration::from_secs_f64(state.config().learner.heartbeat_s);
        tokio::spawn(watchdog::run(
            state.clone(),
            watchdog::Timing::for_heartbeat(heartbeat),
            state.shutdown_signal(),
        ))
    };
    let metrics_http = match &opts.metrics_listener {
        Some(l) => {
            let l = l.try_clone()?;
            l.set_nonblocking(true)?;
            let l = TcpListener::from_std(l)?;
            tracing::info!(addr = %l.local_addr()?, "serving Prometheus metrics at /metrics");
            Some(tokio::spawn(metrics::serve(l, state.shutdown_signal(), state.clone())))
        }
        None => None,
    };

    let service = LearnerService::server(state.clone());
    let server = tokio::spawn(transport.add_service(service).serve_with_incoming_shutdown(
        TcpListenerStream::new(listener),
        state.shutdown_signal().cancelled_owned(),
    ));

    // Until the budget is reached or we are told to stop, or the wall-clock budget is spent.
    let done = state.done_signal();
    tokio::pin!(shutdown);
    let wall_budget = cfg.run.wall_budget();
    let out_of_time = async move {
        match wall_budget {
            Some(budget) => tokio::time::sleep_until((started + budget).into()).await,
            None => std::future::pending().await,
        }
    };
    let mut interrupted = tokio::select! {
        () = done.cancelled() => false,
        () = &mut shutdown => {
            tracing::info!("shutdown requested; telling actors to stop");
            true
        }
        // As Ctrl-C: the time is spent, so the updates the replay ratio owes are not trained.
        () = out_of_time => {
            tracing::info!(max_wall_s = cfg.run.max_wall_s, "run.max_wall_s reached; telling actors to stop");
            true
        }
    };
    if interrupted {
        state.finish();
    }
    // Let actors flush their last batches and leave.
    let deadline = Instant::now() + ACTOR_DRAIN_TIMEOUT;
    while state.status().actors.iter().any(|a| a.connected) && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The budget keeps the replay ratio: ingestion may have run `learner.max_steps_ahead`
    // ahead of training, and those updates are owed before the run ends.
    if !interrupted {
        let (_, from) = state.limiter().counters();
        let owed = state.limiter().pressure().updates_owed;
        if owed > 0 {
            tracing::info!(owed, "budget reached; training the updates the replay ratio owes");
        }
        while !state.limiter().is_paid() && !trainer.is_finished() {
            tokio::select! {
                () = tokio::time::sleep(Duration::from_millis(50)) => {}
                () = &mut shutdown => {
                    tracing::info!("shutdown requested; the owed updates are not all done");
                    interrupted = true;
                    break;
                }
            }
        }
        let (_, to) = state.limiter().counters();
        if owed > 0 && !interrupted {
            tracing::info!(updates = to - from, "owed updates done");
        }
    }
    state.begin_shutdown();
    let (learner, sample_rng) = tokio::task::spawn_blocking(move || trainer.join())
        .await?
        .map_err(|_| anyhow::anyhow!("the trainer thread panicked"))??;
    let final_checkpoint = if learner.updates() > 0 {
        match checkpoint::save(&opts.out_dir, &state, &learner, &sample_rng) {
            Ok(path) => Some(path),
            Err(e) => {
                state.record_write_failure(
                    "checkpoint",
                    &opts.out_dir.join("checkpoints"),
                    &format!("{e:#}"),
                );
                None
            }
        }
    } else {
        None
    };
    watchdog.await?;
    server.await??;
    metrics.await??;
    if let Some(h) = metrics_http {
        h.await??;
    }

    let status = state.status();
    let wall = started.elapsed().as_secs_f64();
    let summary = LearnerSummary {
        env_steps_per_s: status.transitions_received as f64 / wall,
        updates_per_s: status.updates as f64 / wall,
        wall_time_s: wall,
        final_checkpoint,
        status,
    };
    let path = opts.out_dir.join("learner_summary.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&summary)?)?;
    tracing::info!(path = %path.display(), "learner finished");
    Ok(summary)
}
