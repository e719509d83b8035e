//! Command-line definitions and dispatch.

mod actor;
mod bench;
mod certs;
mod eval;
mod eval_out;
mod inspect;
mod learner;
mod plot;
mod replay;
mod rooms;
mod serve;
mod tls;
mod train;
mod transfer;

use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Dimension-variable mapless navigation with deep RL: distributed SAC training in rapier2d
/// rooms, MCAP episode logs, and skill transfer to robots of other sizes.
#[derive(Parser, Debug)]
#[command(name = "dvnav", version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    command: Command,
}

impl Cli {
    /// True for commands that only read or write files and print (inspect, eval, plot, rooms,
    /// transfer, certs): they may die quietly on a closed stdout pipe. The others hold network
    /// sockets, where a default SIGPIPE would kill a learner, an actor, the supervisor or the
    /// controller the moment it writes to a connection its peer has reset.
    pub fn prints_only(&self) -> bool {
        matches!(
            self.command,
            Command::Inspect(_)
                | Command::Eval(_)
                | Command::Plot(_)
                | Command::Rooms(_)
                | Command::Transfer(_)
                | Command::Certs(_)
        )
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train on this machine: one learner plus N actor processes, supervised, with progress.
    Train(train::TrainArgs),
    /// Run only the learner (gRPC server, replay, SAC), for runs across machines.
    Learner(learner::LearnerArgs),
    /// Run only an actor that connects to a learner.
    Actor(actor::ActorArgs),
    /// Summarize, list, detail or check MCAP episode logs (a file, a directory, or a run
    /// directory).
    Inspect(inspect::InspectArgs),
    /// Evaluate a policy checkpoint: rates, score and time per room, evaluation routes, the
    /// gate test, the dynamic scenario.
    Eval(eval::EvalArgs),
    /// Draw figures from episode logs (PNG).
    Plot(plot::PlotArgs),
    /// Benchmarks that print figures (JSON with --json).
    Bench(bench::BenchArgs),
    /// List the built-in rooms or draw one (or a room file) to a PNG.
    Rooms(rooms::RoomsArgs),
    /// DVST: the dimension-scaled robot and its scale μ for a varied robot (a footprint file),
    /// as text, JSON, or a figure.
    Transfer(transfer::TransferArgs),
    /// DVST controller service (gRPC): robots send their scan (the meta layout or any
    /// LaserScan), goal and velocity each control cycle and get (v, ω) back, `arrived` at the
    /// goal; each robot's footprint can change at run time.
    Serve(serve::ServeArgs),
    /// The controller over a recorded ROS 2 bag (MCAP, CDR): what it would have commanded at
    /// each LaserScan, given the odometry and a goal; to CSV and a figure.
    Replay(replay::ReplayArgs),
    /// Write a CA and TLS certificates for runs across machines (`--tls-cert`, `--tls-ca`).
    ///
    /// Writes into --out: `ca.pem` and `ca.key`, a new private CA (clients trust `ca.pem`:
    /// `dvnav actor --tls-ca`; keep `ca.key` private); `server.pem` and `server.key`, signed by
    /// it for the --host names and addresses (`--tls-cert` / `--tls-key` of `dvnav learner` or
    /// `dvnav serve`); `client.pem` and `client.key`, a client certificate for mutual TLS
    /// (`dvnav actor --tls-cert/--tls-key` against a learner run with `--tls-client-ca
    /// ca.pem`). ECDSA P-256 keys, written with mode 0600. Existing files are never replaced
    /// without --force.
    Certs(certs::CertsArgs),
}

/// Sets up logging to stderr.
pub fn init_tracing(verbose: u8) {
    let default = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .init();
}

/// Runs the chosen subcommand.
pub fn dispatch(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Train(a) => train::run(a),
        Command::Learner(a) => learner::run(a),
        Command::Actor(a) => actor::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Plot(a) => plot::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Rooms(a) => rooms::run(a),
        Command::Transfer(a) => transfer::run(a),
        Command::Serve(a) => serve::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Certs(a) => certs::run(a),
    }
}

/// Resolves when the process gets Ctrl-C (SIGINT) or SIGTERM.
///
/// The handlers are installed by this call, not when the future is first polled: a process
/// that writes its address file or logs `resumed` before it polls its shutdown would otherwise
/// die of a SIGTERM sent in between (the signal's default action) instead of stopping
/// gracefully. Call it inside the runtime, before anything tells the outside world the process
/// is up.
pub fn shutdown_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let handlers = signal(SignalKind::interrupt())
            .and_then(|int| Ok((int, signal(SignalKind::terminate())?)));
        async move {
            match handlers {
                Ok((mut int, mut term)) => {
                    tokio::select! {
                        _ = int.recv() => {},
                        _ = term.recv() => {},
                    }
                }
                Err(_) => {
                    let _ = tokio::signal::ctrl_c().await;
                }
            }
        }
    }
    #[cfg(not(unix))]
    {
        async {
            let _ = tokio::signal::ctrl_c().await;
        }
    }
}

/// Reads a token from `--token-file` or the `DVNAV_TOKEN` environment variable (never logged).
pub fn read_token(file: Option<&Path>) -> anyhow::Result<Option<String>> {
    if let Some(f) = file {
        let t = std::fs::read_to_string(f)
            .map_err(|e| anyhow::anyhow!("cannot read token file {}: {e}", f.display()))?;
        let t = t.trim().to_string();
        anyhow::ensure!(!t.is_empty(), "token file {} is empty", f.display());
        return Ok(Some(t));
    }
    Ok(std::env::var("DVNAV_TOKEN")
        .ok()
        .filter(|t| !t.trim().is_empty())
        .map(|t| t.trim().to_string()))
}

/// Loads `--config` or the defaults.
pub fn load_config(path: Option<&PathBuf>) -> anyhow::Result<dvnav_config::Config> {
    match path {
        Some(p) => Ok(dvnav_config::Config::load(p)?),
        None => Ok(dvnav_config::Config::default()),
    }
}

/// Keeps candle's own CPU parallelism (its element-wise thread pool, sized from
/// `CANDLE_NUM_THREADS`, and gemm's rayon split, from `RAYON_NUM_THREADS`) at one thread: the
/// learner spreads an update over threads of its own (`learner.threads`,
/// `dvnav_learner::sac::shards`), and candle's split of every small operation only costs
/// synchronizations. Call before anything uses candle or starts a thread.
pub fn candle_single_threaded() {
    // SAFETY: called at the start of a command, before any other thread exists.
    unsafe {
        std::env::set_var("CANDLE_NUM_THREADS", "1");
        std::env::set_var("RAYON_NUM_THREADS", "1");
    }
}

/// A multi-threaded tokio runtime with few workers: the heavy work runs on its own threads.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?)
}

#[cfg(test)]
mod sigpipe_tests {
    use super::Cli;
    use clap::Parser;

    /// Processes that hold network connections keep SIGPIPE ignored: with the default
    /// disposition a write to a connection reset by its peer kills the process.
    #[test]
    fn only_printing_commands_die_on_a_closed_pipe() {
        let cli = |args: &[&str]| Cli::try_parse_from(args).unwrap();
        assert!(cli(&["dvnav", "inspect", "runs/x"]).prints_only());
        assert!(cli(&["dvnav", "rooms", "list"]).prints_only());
        assert!(cli(&["dvnav", "certs", "--out", "tls", "--host", "h"]).prints_only());
        for server in [
            vec!["dvnav", "learner"],
            vec!["dvnav", "actor", "--learner", "http://127.0.0.1:1", "--name", "a"],
            vec!["dvnav", "train"],
            vec!["dvnav", "bench", "transport"],
        ] {
            assert!(!cli(&server).prints_only(), "{server:?}");
        }
    }
}
