//! `dvnav inspect`.

use clap::Args;
use dvnav_common::episode_log::{read_episodes, summarize};
use std::path::PathBuf;
use std::process::ExitCode;

/// Summarize MCAP episode logs per actor and stage: episodes, success / collision / timeout
/// rates, mean steps, mean return.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// An .mcap file, a directory of them, or a run directory (its mcap/ is searched).
    pub path: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: InspectArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.path.exists(), "{} does not exist", args.path.display());
    let records = read_episodes(&args.path)?;
    let groups = summarize(&records);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "path": args.path,
                "episodes": records.len(),
                "groups": groups,
            }))?
        );
        return Ok(ExitCode::SUCCESS);
    }
    if records.is_empty() {
        println!("no logged episodes under {}", args.path.display());
        return Ok(ExitCode::SUCCESS);
    }
    println!("{} logged episodes under {}", records.len(), args.path.display());
    println!(
        "{:<16} {:>5} {:>8} {:>8} {:>9} {:>8} {:>10} {:>11}",
        "actor",
        "stage",
        "episodes",
        "success",
        "collision",
        "timeout",
        "mean steps",
        "mean return"
    );
    for g in &groups {
        println!(
            "{:<16} {:>5} {:>8} {:>7.1}% {:>8.1}% {:>7.1}% {:>10.1} {:>11.2}",
            g.actor,
            g.stage,
            g.episodes,
            100.0 * g.success_rate,
            100.0 * g.collision_rate,
            100.0 * g.timeout_rate,
            g.mean_steps,
            g.mean_return
        );
    }
    Ok(ExitCode::SUCCESS)
}
