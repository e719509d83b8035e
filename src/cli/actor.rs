//! `dvnav actor`.

use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// Run an actor: simulate rooms, act with the newest policy, stream transitions to a learner.
#[derive(Args, Debug)]
pub struct ActorArgs {
    /// Learner address, e.g. http://10.0.0.5:50051 (https://… over TLS, see --tls-ca).
    #[arg(long)]
    pub learner: String,
    /// Name of this actor, unique within the run (default: actor-PID).
    #[arg(long)]
    pub name: Option<String>,
    /// Run directory: MCAP logs under mcap/NAME/, summary under actors/NAME/.
    #[arg(long, default_value = "runs/actor")]
    pub out: PathBuf,
    /// Keep trying to reach the learner this long at start-up (seconds).
    #[arg(long, default_value_t = 120)]
    pub connect_timeout_s: u64,
    /// File holding the shared access token (or set DVNAV_TOKEN).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    #[command(flatten)]
    pub tls: super::tls::ClientTlsArgs,
}

pub fn run(args: ActorArgs) -> anyhow::Result<ExitCode> {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // The policy's forward pass is small; candle's spinning thread pool would only take
        // cores from the simulator. Set before any candle use; no other thread runs yet.
        unsafe { std::env::set_var("CANDLE_NUM_THREADS", "1") };
    }
    let token = super::read_token(args.token_file.as_deref())?;
    let tls = args.tls.load()?;
    let name = args.name.unwrap_or_else(|| format!("actor-{}", std::process::id()));
    let rt = super::runtime()?;
    rt.block_on(async move {
        let summary = dvnav_actor::run(
            dvnav_actor::ActorOptions {
                learner_url: args.learner,
                name,
                out_dir: args.out,
                token,
                tls,
                connect_timeout: Duration::from_secs(args.connect_timeout_s),
            },
            super::shutdown_signal(),
        )
        .await?;
        tracing::info!(steps = summary.loop_counters.env_steps, reason = %summary.stop_reason, "actor done");
        Ok(ExitCode::SUCCESS)
    })
}
