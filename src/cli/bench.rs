//! `dvnav bench`.

use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// Measure the learner's SAC update rate and policy latency.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(Subcommand, Debug)]
enum BenchWhat {
    /// SAC updates/s at a batch size, and policy inference latency at batch 1 and 64.
    Learner {
        /// Config whose network and SAC settings are measured (default: the defaults).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Minibatch size.
        #[arg(long, default_value_t = 256)]
        batch: usize,
        /// Updates timed.
        #[arg(long, default_value_t = 20)]
        updates: usize,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(args: BenchArgs) -> anyhow::Result<ExitCode> {
    match args.what {
        BenchWhat::Learner { config, batch, updates, json } => {
            let cfg = super::load_config(config.as_ref())?;
            let r = dvnav_learner::bench::sac_updates(&cfg, batch, 3, updates)?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!(
                    "SAC updates/s at batch {}: {:.2} ({:.1} ms/update), {} threads, {}; inference {:.2} ms (batch 1), {:.2} ms (batch 64)",
                    r.batch, r.sac_updates_per_s, r.ms_per_update, r.threads, r.network,
                    r.inference_ms_batch1, r.inference_ms_batch64
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
