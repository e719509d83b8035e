//! `dvnav learner`.

use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

/// Run the learner: serve gRPC, train SAC, publish weights, checkpoint.
#[derive(Args, Debug)]
pub struct LearnerArgs {
    /// Run configuration (TOML). Defaults apply to everything it leaves out.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Run directory for the config used, checkpoints and summaries.
    #[arg(long, default_value = "runs/learner")]
    pub out: PathBuf,
    /// Address to listen on; port 0 picks a free port.
    #[arg(long, default_value = "0.0.0.0:50051")]
    pub listen: String,
    /// Write the address actually bound to this file (for supervisors using port 0).
    #[arg(long)]
    pub addr_file: Option<PathBuf>,
    /// Step budget override (environment steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// File holding the shared access token actors must present (or set DVNAV_TOKEN).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Per-actor tokens: a file of `NAME TOKEN` lines. A listed actor registers only with its
    /// own token; others need the shared token (--token-file), or are refused without one.
    #[arg(long, value_name = "FILE")]
    pub actor_tokens: Option<PathBuf>,
    #[command(flatten)]
    pub tls: super::tls::ServerTlsArgs,
    /// Continue from the newest complete checkpoint in `--out`: networks, optimizers,
    /// temperature, counters, curriculum, random generators (and the replay buffer when it was
    /// saved). Without `--config`, the run directory's `config.toml` is used.
    #[arg(long)]
    pub resume: bool,
    /// `--resume` when `--out` holds a complete checkpoint, else a fresh start: one command
    /// for a supervisor that restarts the learner after a crash (Kubernetes, systemd).
    #[arg(long, conflicts_with = "resume")]
    pub resume_if_present: bool,
    /// Serve Prometheus metrics over HTTP at this address (`GET /metrics`), e.g.
    /// `127.0.0.1:9100`; port 0 picks a free port. The address bound is logged and written to
    /// `OUT/metrics.addr`. `OUT/metrics.csv` is written with or without it.
    #[arg(long, value_name = "ADDR")]
    pub metrics_addr: Option<String>,
    /// Where the networks train: `cpu`, or `cuda` / `cuda:N` for an NVIDIA GPU (a build with
    /// `--features cuda`). Actors stay on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

pub fn run(mut args: LearnerArgs) -> anyhow::Result<ExitCode> {
    let device = dvnav_learner::device::parse(&args.device)?;
    if args.resume_if_present {
        match dvnav_learner::checkpoint::latest(&args.out)? {
            Some(ckpt) => {
                tracing::info!(checkpoint = %ckpt.display(), "--resume-if-present: resuming");
                args.resume = true;
            }
            None => tracing::info!(
                out = %args.out.display(),
                "--resume-if-present: no complete checkpoint yet; starting fresh"
            ),
        }
    }
    let run_config = args.out.join("config.toml");
    let mut cfg = if args.resume && args.config.is_none() && run_config.exists() {
        super::load_config(Some(&run_config))?
    } else {
        super::load_config(args.config.as_ref())?
    };
    if let Some(s) = args.steps {
        cfg.run.steps = s;
    }
    cfg.validate()?;
    // The learner's threads are its own (`learner.threads`, SacLearner::with_threads).
    super::candle_single_threaded();
    let token = super::read_token(args.token_file.as_deref())?;
    let actor_tokens = args
        .actor_tokens
        .as_deref()
        .map(dvnav_learner::actor_tokens::ActorTokens::load)
        .transpose()?;
    let tls = args.tls.load()?;
    let rt = super::runtime()?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
        // Before the address file and the `resumed` line: a SIGTERM from then on stops the
        // learner gracefully.
        let shutdown = super::shutdown_signal();
        let addr = listener.local_addr()?;
        tracing::info!(
            %addr,
            out = %args.out.display(),
            tls = tls.is_some(),
            token = token.is_some(),
            actor_tokens = actor_tokens.is_some(),
            "learner listening"
        );
        // Bound before the address file appears, so a supervisor that sees it finds both.
        let metrics_listener = match &args.metrics_addr {
            Some(a) => {
                let l = std::net::TcpListener::bind(a)
                    .map_err(|e| anyhow::anyhow!("cannot serve metrics on {a}: {e}"))?;
                let bound = l.local_addr()?;
                dvnav_learner::run::check_writable(&args.out)?;
                let file = args.out.join("metrics.addr");
                let tmp = file.with_extension("tmp");
                std::fs::write(&tmp, bound.to_string())?;
                std::fs::rename(&tmp, &file)?;
                Some(std::sync::Arc::new(l))
            }
            None => None,
        };
        if let Some(f) = &args.addr_file {
            // Written whole or not at all: a supervisor polling for it never reads half an address.
            if let Some(parent) = f.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)?;
            }
            let tmp = f.with_extension("tmp");
            std::fs::write(&tmp, addr.to_string())
                .and_then(|()| std::fs::rename(&tmp, f))
                .map_err(|e| anyhow::anyhow!("cannot write --addr-file {}: {e}", f.display()))?;
        }
        let summary = dvnav_learner::run(
            cfg,
            listener,
            dvnav_learner::LearnerOptions {
                out_dir: args.out.clone(),
                token,
                actor_tokens,
                run_id: None,
                resume: args.resume,
                metrics_listener,
                device,
                tls,
            },
            shutdown,
        )
        .await?;
        tracing::info!(
            received = summary.status.transitions_received,
            updates = summary.status.updates,
            "learner done"
        );
        Ok(ExitCode::SUCCESS)
    })
}
