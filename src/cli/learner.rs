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
}

pub fn run(args: LearnerArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = super::load_config(args.config.as_ref())?;
    if let Some(s) = args.steps {
        cfg.run.steps = s;
    }
    cfg.validate()?;
    if cfg.learner.threads > 0 {
        // candle sizes its CPU thread pool from this variable when the pool is first used,
        // which is after this point; nothing else runs yet, so setting it is sound.
        unsafe { std::env::set_var("CANDLE_NUM_THREADS", cfg.learner.threads.to_string()) };
    }
    let token = super::read_token(args.token_file.as_deref())?;
    let rt = super::runtime()?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&args.listen)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
        let addr = listener.local_addr()?;
        tracing::info!(%addr, out = %args.out.display(), "learner listening");
        if let Some(f) = &args.addr_file {
            let tmp = f.with_extension("tmp");
            std::fs::write(&tmp, addr.to_string())?;
            std::fs::rename(&tmp, f)?;
        }
        let summary = dvnav_learner::run(
            cfg,
            listener,
            dvnav_learner::LearnerOptions { out_dir: args.out.clone(), token, run_id: None },
            super::shutdown_signal(),
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
