//! `dvnav train`: a learner and N actor processes on this machine, supervised.
//!
//! The supervisor starts `dvnav learner` on a free loopback port, then the actors, polls the
//! learner's `Status` for a progress line, and when the learner finishes (step budget reached,
//! or Ctrl-C) waits for every child, then merges the learner's and actors' summaries into
//! `run_summary.json`. Children write their logs to `DIR/logs/`; `DIR/pids.json` names the
//! running processes while the run lasts.
//!
//! Files: this one holds the flags and one supervised run; [`supervisor`] the child processes
//! and the restart policy; [`seeds`] `--seeds N`; [`summary`] `run_summary.json`.
//!
//! **Actor restarts.** An actor that fails (exits with an error, or is killed by a signal)
//! while the run goes on is started again after a backoff, at most `--max-actor-restarts` times
//! per actor ([`supervisor`]). The new process runs as `actor-N-rK` (restart K of `actor-N`):
//! a new actor id at the learner, a new environment seed, its own log, summary and MCAP files,
//! so the learner's counts of the dead process stay its own and nothing of it is counted
//! twice. What the dead process had sent and the learner had not yet acknowledged is lost with
//! it (the learner drops a batch whose stream broke before it was inserted); every
//! acknowledged batch stays counted once.

mod seeds;
mod summary;
mod supervisor;

use clap::Args;
use dvnav_config::Config;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use summary::merge_summaries;
use supervisor::{
    ActorFailure, ActorLaunch, ActorSlot, Proc, RESTART_BACKOFF_FIRST, Restarts, signal, spawn,
    tail, write_pids,
};

/// Train with a learner plus N actors on this machine.
#[derive(Args, Debug, Clone)]
pub struct TrainArgs {
    /// Run configuration (TOML); every key it leaves out keeps its default.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Number of actor processes.
    #[arg(long, default_value_t = 2)]
    pub actors: usize,
    /// Step budget (environment steps); overrides run.steps.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Seed; overrides run.seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop the run after this many wall-clock seconds, as Ctrl-C would (final checkpoint,
    /// summaries, `best/` kept); overrides run.max_wall_s. With `--seeds`, per seed.
    #[arg(long, value_name = "SECONDS")]
    pub max_wall_s: Option<f64>,
    /// Train the same config with this many seeds, one after the other (seed, seed+1, …), each
    /// in OUT/seed-<seed>/, then print a table and write OUT/seeds_summary.json (stage reached,
    /// when the last room reached the threshold, wall time). The seeds' best agents (each
    /// run's `best/`, kept by its training-time evaluation) are ranked as within a run (the
    /// gate bar first when `learner.selection.gate_min_passed` sets one, then the score) and
    /// the highest becomes OUT/best (`best` in the summary). `dvnav plot curves
    /// OUT/seed-*` draws them together.
    #[arg(long, value_name = "N", conflicts_with = "resume")]
    pub seeds: Option<usize>,
    /// End each run once the last room reaches the curriculum threshold over a full window
    /// (sets curriculum.stop_when_skilled): measures "time to skill" without spending the
    /// rest of the step budget.
    #[arg(long)]
    pub stop_when_skilled: bool,
    /// Train on past the skill milestone (clears curriculum.stop_when_skilled): with
    /// `--resume`, continues a run that stopped once skilled, which would otherwise end at once.
    #[arg(long, conflicts_with = "stop_when_skilled")]
    pub no_stop_when_skilled: bool,
    /// Run directory (must not hold another run). Default: runs/run-UNIXTIME.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in DIR: the learner restarts from DIR's newest checkpoint with DIR's
    /// `config.toml` (`dvnav learner --resume`) and fresh actors join it. `--steps` may raise
    /// the budget.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["out", "config", "seed"])]
    pub resume: Option<PathBuf>,
    /// Serve the learner's Prometheus metrics at this address (`GET /metrics`), e.g.
    /// `127.0.0.1:9100` (port 0: a free port, printed at start).
    #[arg(long, value_name = "ADDR")]
    pub metrics_addr: Option<String>,
    /// Where the learner trains: `cpu`, or `cuda` / `cuda:N` (a build with `--features cuda`).
    /// Actors stay on the CPU.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Seconds between progress lines when stderr is not a terminal.
    #[arg(long, default_value_t = 10)]
    pub progress_every_s: u64,
    /// Restart an actor that fails while the run goes on (exits with an error or is killed by
    /// a signal) at most this many times per actor; 0: never. Waits 1 s, 2 s, 4 s … up to
    /// 30 s before each restart (1 s again after a process that ran a minute).
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub max_actor_restarts: u32,
}

pub fn run(args: TrainArgs) -> anyhow::Result<ExitCode> {
    match args.seeds {
        Some(n) => seeds::run_seeds(args, n),
        None => run_one(args),
    }
}

pub(super) fn run_one(args: TrainArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.actors >= 1, "--actors must be at least 1");
    let mut cfg: Config = match &args.resume {
        Some(dir) => Config::load(&dir.join("config.toml"))?,
        None => super::load_config(args.config.as_ref())?,
    };
    if let Some(s) = args.steps {
        cfg.run.steps = s;
    }
    if let Some(s) = args.seed {
        cfg.run.seed = s;
    }
    if let Some(s) = args.max_wall_s {
        cfg.run.max_wall_s = s;
    }
    if args.stop_when_skilled {
        cfg.curriculum.stop_when_skilled = true;
    }
    if args.no_stop_when_skilled {
        cfg.curriculum.stop_when_skilled = false;
    }
    cfg.validate()?;
    if let Some(dir) = &args.resume {
        let summary = std::fs::read(dir.join("run_summary.json"))
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
        anyhow::ensure!(
            !resume_stops_at_once(&cfg, summary.as_ref()),
            "{} stopped once skilled (curriculum.stop_when_skilled in its config.toml): resumed \
             as it is, it would stop again at once; add --no-stop-when-skilled to train on",
            dir.display()
        );
    }
    let out = args.resume.clone().or_else(|| args.out.clone()).unwrap_or_else(default_out);
    if args.resume.is_some() {
        anyhow::ensure!(
            dvnav_learner::checkpoint::latest(&out)?.is_some(),
            "{} holds no complete checkpoint to resume from",
            out.display()
        );
    } else if out.exists()
        && std::fs::read_dir(&out)
            .map_err(|e| anyhow::anyhow!("cannot use {} as --out: {e}", out.display()))?
            .next()
            .is_some()
    {
        anyhow::bail!(
            "{} already holds files (another run?); choose another --out or remove it",
            out.display()
        );
    }
    // An unwritable --out (read-only, full, a path through a file) fails here, naming it.
    dvnav_learner::run::check_writable(&out.join("logs"))?;
    let config_path = out.join("config.toml");
    std::fs::write(&config_path, cfg.to_toml_string())
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", config_path.display()))?;
    let exe = std::env::current_exe()?;
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let actor_threads = (cores / args.actors).max(1);
    let started = Instant::now();

    let addr_file = out.join("learner.addr");
    // A resumed run's directory still has the old learner's address.
    let _ = std::fs::remove_file(&addr_file);
    let learner_log = out.join("logs/learner.log");
    let mut learner_args: Vec<String> = vec![
        "learner".into(),
        "--config".into(),
        config_path.display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--listen".into(),
        "127.0.0.1:0".into(),
        "--addr-file".into(),
        addr_file.display().to_string(),
        "--device".into(),
        args.device.clone(),
    ];
    if args.resume.is_some() {
        learner_args.push("--resume".into());
    }
    let metrics_addr_file = out.join("metrics.addr");
    let _ = std::fs::remove_file(&metrics_addr_file);
    if let Some(a) = &args.metrics_addr {
        learner_args.extend(["--metrics-addr".into(), a.clone()]);
    }
    let mut learner = Proc::new("learner".into(), spawn(&exe, &learner_args, &learner_log, cores)?);
    eprintln!(
        "dvnav train: {} actors, {} steps, run directory {}",
        args.actors,
        cfg.run.steps,
        out.display()
    );
    let deadline = Instant::now() + Duration::from_secs(120);
    let addr = loop {
        if let Ok(a) = std::fs::read_to_string(&addr_file) {
            break a.trim().to_string();
        }
        if let Some(st) = learner.poll() {
            anyhow::bail!(
                "the learner exited ({st}) before listening; its log ({}):\n{}",
                learner_log.display(),
                tail(&learner_log, 20)
            );
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "the learner did not start listening within 120 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let url = format!("http://{addr}");
    if args.metrics_addr.is_some()
        && let Ok(a) = std::fs::read_to_string(&metrics_addr_file)
    {
        eprintln!("dvnav train: metrics at http://{}/metrics", a.trim());
    }

    let launch = ActorLaunch { exe: &exe, url: &url, out: &out, threads: actor_threads };
    let mut actors: Vec<ActorSlot> = Vec::new();
    for i in 0..args.actors {
        let actor = format!("actor-{i}");
        actors.push(ActorSlot {
            procs: vec![launch.spawn(&actor)?],
            actor,
            backoff: RESTART_BACKOFF_FIRST,
            restart_due: None,
        });
    }
    write_pids(&out, &learner, &actors);
    let mut failures: Vec<ActorFailure> = Vec::new();

    // Ctrl-C / SIGTERM reach this process; pass them on once, then wait for a clean finish.
    let interrupted = tokio_util::sync::CancellationToken::new();
    {
        let interrupted = interrupted.clone();
        std::thread::spawn(move || {
            if let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_all().build() {
                // The handlers need the runtime's reactor (see `shutdown_signal`).
                let signal = {
                    let _in_runtime = rt.enter();
                    super::shutdown_signal()
                };
                rt.block_on(signal);
                interrupted.cancel();
            }
        });
    }

    let rt = super::runtime()?;
    let mut client =
        rt.block_on(dvnav_actor::run::connect(&url, None, None, Duration::from_secs(30))).ok();
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut last_print = Instant::now() - Duration::from_secs(3600);
    let mut forwarded = false;
    let mut learner_done = false;
    let mut last_line = String::new();
    while learner.poll().is_none() {
        if interrupted.is_cancelled() && !forwarded {
            eprintln!("\ndvnav train: stopping (Ctrl-C); waiting for a clean shutdown");
            signal(&learner.child, libc::SIGTERM);
            forwarded = true;
        }
        let restarts =
            Restarts { max: args.max_actor_restarts, stopping: forwarded || learner_done };
        let mut started_any = false;
        for slot in actors.iter_mut() {
            started_any |= restarts.supervise(slot, &launch, &mut failures, started);
        }
        if started_any {
            write_pids(&out, &learner, &actors);
        }
        if let Some(c) = client.as_mut()
            && let Ok(st) = rt.block_on(c.status(dvnav_proto::StatusRequest {}))
        {
            let s = st.into_inner();
            learner_done |= s.done;
            last_line = progress_line(&s);
            if tty {
                eprint!("\r{last_line:<170}");
            } else if last_print.elapsed() >= Duration::from_secs(args.progress_every_s) {
                eprintln!("{last_line}");
                last_print = Instant::now();
            }
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    if tty {
        eprintln!();
    }
    let learner_status = learner.poll().expect("learner exited");
    // The learner is gone: actors stop by themselves (stop flag or closed stream); give them
    // time to flush, then make sure.
    let deadline = Instant::now() + Duration::from_secs(60);
    while actors.iter_mut().any(|s| s.current().poll().is_none()) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    for slot in actors.iter_mut() {
        // A restart still waiting for its backoff is not started: the run is over.
        if let Some((_, i)) = slot.restart_due.take() {
            failures[i].not_restarted = Some("the run ended first".into());
        }
        let a = slot.current();
        if a.status.is_none() {
            eprintln!("dvnav train: {} did not stop; terminating it", a.name);
            signal(&a.child, libc::SIGTERM);
            std::thread::sleep(Duration::from_secs(2));
            if a.poll().is_none() {
                let _ = a.child.kill();
                a.status = a.child.wait().ok();
                a.ran = Some(a.started.elapsed());
            }
        }
    }
    let _ = std::fs::remove_file(out.join("pids.json"));

    let summary =
        merge_summaries(&out, &learner, &actors, &failures, started.elapsed().as_secs_f64());
    std::fs::write(out.join("run_summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    eprintln!("{last_line}");
    let sent = match summary.unreported_actors.len() {
        0 => format!("{} steps sent", summary.transitions_sent),
        n => format!(
            "{} steps sent (+ what {n} killed actor process{} sent)",
            summary.transitions_sent,
            if n == 1 { "" } else { "es" }
        ),
    };
    // `null` where the learner wrote no summary, as in run_summary.json.
    let n = |v: Option<u64>| v.map_or("null".to_string(), |v| v.to_string());
    eprintln!(
        "dvnav train: done in {:.0} s: {sent}, {} received, {} rejected, {} episodes, {} updates, weights v{}, {} actor restart{}; summary {}",
        started.elapsed().as_secs_f64(),
        n(summary.transitions_received),
        n(summary.transitions_rejected),
        n(summary.episodes),
        n(summary.updates),
        n(summary.weight_version),
        summary.actor_restarts,
        if summary.actor_restarts == 1 { "" } else { "s" },
        out.join("run_summary.json").display()
    );
    if !learner_status.success() {
        eprintln!(
            "dvnav train: the learner failed ({learner_status}); its log:\n{}",
            tail(&learner_log, 30)
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(if summary.clean_shutdown { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// The progress line: the same headline figures as the learner's `/metrics` (rates over the
/// last ~10 s, policy lag of the last ~2 s).
fn progress_line(s: &dvnav_proto::StatusReply) -> String {
    format!(
        "steps {}/{} ({:.0}%) {:.0}/s | updates {} {:.1}/s | replay {} | actors {} | lag {:.1}/{} | episodes {} | stage {} {:.0}% | v{} | critic {:.3} α {:.3}",
        s.transitions_received,
        s.step_budget,
        100.0 * s.transitions_received as f64 / s.step_budget.max(1) as f64,
        s.env_steps_per_s,
        s.updates,
        s.updates_per_s,
        s.replay_size,
        s.connected_actors,
        s.policy_lag_mean,
        s.policy_lag_max,
        s.episodes,
        s.stage,
        100.0 * s.success_rate,
        s.weight_version,
        s.critic_loss,
        s.alpha,
    )
}

/// Whether resuming a run whose last `run_summary.json` is `summary` would end as soon as it
/// starts: it reached the skill milestone and `curriculum.stop_when_skilled` is still set.
fn resume_stops_at_once(cfg: &Config, summary: Option<&serde_json::Value>) -> bool {
    cfg.curriculum.stop_when_skilled && summary.is_some_and(|s| !s["skilled"].is_null())
}

pub(super) fn default_out() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    PathBuf::from("runs").join(format!("run-{secs}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_skilled_run_that_still_stops_when_skilled_would_end_at_once() {
        let skilled =
            serde_json::json!({"skilled": {"stage": 4, "env_steps": 128768, "updates": 31161}});
        let unskilled = serde_json::json!({"skilled": null});
        let mut cfg = Config::default();
        cfg.curriculum.stop_when_skilled = true;
        assert!(resume_stops_at_once(&cfg, Some(&skilled)));
        assert!(!resume_stops_at_once(&cfg, Some(&unskilled)));
        // A run stopped by Ctrl-C or a timeout before any summary, or an older summary.
        assert!(!resume_stops_at_once(&cfg, None));
        assert!(!resume_stops_at_once(&cfg, Some(&serde_json::json!({}))));
        // --no-stop-when-skilled cleared the key.
        cfg.curriculum.stop_when_skilled = false;
        assert!(!resume_stops_at_once(&cfg, Some(&skilled)));
    }
}
