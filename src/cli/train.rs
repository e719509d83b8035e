//! `dvnav train`: a learner and N actor processes on this machine, supervised.
//!
//! The supervisor starts `dvnav learner` on a free loopback port, then the actors, polls the
//! learner's `Status` for a progress line, and when the learner finishes (step budget reached,
//! or Ctrl-C) waits for every child, then merges the learner's and actors' summaries into
//! `run_summary.json`. Children write their logs to `DIR/logs/`.

use clap::Args;
use dvnav_common::config::Config;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

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
    /// Train the same config with this many seeds, one after the other (seed, seed+1, …), each
    /// in OUT/seed-<seed>/, then print a table and write OUT/seeds_summary.json (stage reached,
    /// when the last room reached the threshold, wall time). `dvnav plot curves OUT/seed-*`
    /// draws them together.
    #[arg(long, value_name = "N", conflicts_with = "resume")]
    pub seeds: Option<usize>,
    /// End each run once the last room reaches the curriculum threshold over a full window
    /// (sets curriculum.stop_when_skilled): measures "time to skill" without spending the
    /// rest of the step budget.
    #[arg(long)]
    pub stop_when_skilled: bool,
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
    /// Seconds between progress lines when stderr is not a terminal.
    #[arg(long, default_value_t = 10)]
    pub progress_every_s: u64,
}

struct Proc {
    name: String,
    child: Child,
    status: Option<std::process::ExitStatus>,
}

impl Proc {
    fn poll(&mut self) -> Option<std::process::ExitStatus> {
        if self.status.is_none() {
            self.status = self.child.try_wait().ok().flatten();
        }
        self.status
    }
}

fn spawn(exe: &Path, args: &[String], log: &Path, threads: usize) -> anyhow::Result<Child> {
    // Appending keeps the earlier logs of a resumed run.
    let file = std::fs::OpenOptions::new().create(true).append(true).open(log)?;
    let err = file.try_clone()?;
    Ok(Command::new(exe)
        .args(args)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .stdin(Stdio::null())
        .stdout(file)
        .stderr(err)
        .spawn()?)
}

fn default_out() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    PathBuf::from("runs").join(format!("run-{secs}"))
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
    unsafe {
        libc::kill(child.id() as i32, sig);
    }
}

pub fn run(args: TrainArgs) -> anyhow::Result<ExitCode> {
    match args.seeds {
        Some(n) => run_seeds(args, n),
        None => run_one(args),
    }
}

/// `--seeds N`: the runs one after the other, then their summary.
fn run_seeds(args: TrainArgs, n: usize) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(n >= 1, "--seeds must be at least 1");
    let base_cfg = super::load_config(args.config.as_ref())?;
    let first = args.seed.unwrap_or(base_cfg.run.seed);
    let out = args.out.clone().unwrap_or_else(default_out);
    let mut rows = Vec::new();
    let mut all_ok = true;
    for seed in first..first + n as u64 {
        let dir = out.join(format!("seed-{seed}"));
        eprintln!("dvnav train: seed {seed} ({} of {n}) in {}", seed - first + 1, dir.display());
        let one =
            TrainArgs { seed: Some(seed), out: Some(dir.clone()), seeds: None, ..args.clone() };
        let code = run_one(one)?;
        all_ok &= code == ExitCode::SUCCESS;
        rows.push(seed_row(seed, &dir));
    }
    eprintln!("\nseed  stage  skilled at (steps)  time to skill (s)  wall (s)");
    for r in &rows {
        let opt = |v: &Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.0}"));
        eprintln!(
            "{:<5} {:<6} {:<19} {:<18} {}",
            r["seed"],
            r["stage"],
            opt(&r["skilled_env_steps"]),
            opt(&r["time_to_skill_s"]),
            opt(&r["wall_time_s"])
        );
    }
    let skilled = rows.iter().filter(|r| !r["skilled_env_steps"].is_null()).count();
    eprintln!("{skilled} of {n} seeds reached the last room's threshold");
    let summary = json!({ "seeds": rows, "skilled": skilled, "runs": n });
    std::fs::write(out.join("seeds_summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    Ok(if all_ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// One seed's line of `seeds_summary.json`, from its run directory.
fn seed_row(seed: u64, dir: &Path) -> Value {
    let s = read_json(&dir.join("run_summary.json")).unwrap_or(Value::Null);
    let skilled_steps = s["skilled"]["env_steps"].as_u64();
    json!({
        "seed": seed,
        "run_dir": dir.display().to_string(),
        "stage": s["stage"],
        "stage_changes": s["stage_changes"],
        "skilled_env_steps": skilled_steps,
        "time_to_skill_s": skilled_steps.and_then(|n| time_at_steps(dir, n)),
        "wall_time_s": s["wall_time_s"],
        "env_steps": s["transitions_received"],
    })
}

/// Wall time (s) at which the run's `metrics.csv` first shows `steps` environment steps.
pub fn time_at_steps(dir: &Path, steps: u64) -> Option<f64> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).ok()?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next()?.split(',').collect();
    let (t, n) = (
        header.iter().position(|h| *h == "time_s")?,
        header.iter().position(|h| *h == "env_steps")?,
    );
    lines.find_map(|l| {
        let f: Vec<&str> = l.split(',').collect();
        let at: u64 = f.get(n)?.parse().ok()?;
        (at >= steps).then(|| f.get(t)?.parse().ok()).flatten()
    })
}

fn run_one(args: TrainArgs) -> anyhow::Result<ExitCode> {
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
    if args.stop_when_skilled {
        cfg.curriculum.stop_when_skilled = true;
    }
    cfg.validate()?;
    let out = args.resume.clone().or_else(|| args.out.clone()).unwrap_or_else(default_out);
    if args.resume.is_some() {
        anyhow::ensure!(
            dvnav_learner::checkpoint::latest(&out)?.is_some(),
            "{} holds no complete checkpoint to resume from",
            out.display()
        );
    } else if out.exists() && std::fs::read_dir(&out)?.next().is_some() {
        anyhow::bail!(
            "{} already holds files (another run?); choose another --out or remove it",
            out.display()
        );
    }
    std::fs::create_dir_all(out.join("logs"))?;
    let config_path = out.join("config.toml");
    std::fs::write(&config_path, cfg.to_toml_string())?;
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
    ];
    if args.resume.is_some() {
        learner_args.push("--resume".into());
    }
    let metrics_addr_file = out.join("metrics.addr");
    let _ = std::fs::remove_file(&metrics_addr_file);
    if let Some(a) = &args.metrics_addr {
        learner_args.extend(["--metrics-addr".into(), a.clone()]);
    }
    let mut learner = Proc {
        name: "learner".into(),
        child: spawn(&exe, &learner_args, &learner_log, cores)?,
        status: None,
    };
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

    let mut actors: Vec<Proc> = Vec::new();
    for i in 0..args.actors {
        let name = format!("actor-{i}");
        let child = spawn(
            &exe,
            &[
                "actor".into(),
                "--learner".into(),
                url.clone(),
                "--name".into(),
                name.clone(),
                "--out".into(),
                out.display().to_string(),
            ],
            &out.join(format!("logs/{name}.log")),
            actor_threads,
        )?;
        actors.push(Proc { name, child, status: None });
    }

    // Ctrl-C / SIGTERM reach this process; pass them on once, then wait for a clean finish.
    let interrupted = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    {
        let flag = interrupted.clone();
        std::thread::spawn(move || {
            if let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_all().build() {
                rt.block_on(super::shutdown_signal());
                flag.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        });
    }

    let rt = super::runtime()?;
    let mut client =
        rt.block_on(dvnav_actor::run::connect(&url, None, Duration::from_secs(30))).ok();
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut last_print = Instant::now() - Duration::from_secs(3600);
    let mut forwarded = false;
    let mut last_line = String::new();
    while learner.poll().is_none() {
        if interrupted.load(std::sync::atomic::Ordering::SeqCst) && !forwarded {
            eprintln!("\ndvnav train: stopping (Ctrl-C); waiting for a clean shutdown");
            signal(&learner.child, libc::SIGTERM);
            forwarded = true;
        }
        for a in actors.iter_mut() {
            if a.status.is_none()
                && let Some(st) = a.poll()
                && !st.success()
            {
                eprintln!(
                    "\ndvnav train: {} exited ({st}); see {}/logs/{}.log",
                    a.name,
                    out.display(),
                    a.name
                );
            }
        }
        if let Some(c) = client.as_mut()
            && let Ok(st) = rt.block_on(c.status(dvnav_proto::StatusRequest {}))
        {
            let s = st.into_inner();
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
    while actors.iter_mut().any(|a| a.poll().is_none()) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    for a in actors.iter_mut().filter(|a| a.status.is_none()) {
        eprintln!("dvnav train: {} did not stop; terminating it", a.name);
        signal(&a.child, libc::SIGTERM);
        std::thread::sleep(Duration::from_secs(2));
        if a.poll().is_none() {
            let _ = a.child.kill();
            a.status = a.child.wait().ok();
        }
    }

    let summary = merge_summaries(&out, &learner, &actors, started.elapsed().as_secs_f64())?;
    std::fs::write(out.join("run_summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    let clean = summary["clean_shutdown"].as_bool().unwrap_or(false);
    eprintln!("{last_line}");
    eprintln!(
        "dvnav train: done in {:.0} s: {} steps sent, {} received, {} rejected, {} episodes, {} updates, weights v{}; summary {}",
        started.elapsed().as_secs_f64(),
        summary["transitions_sent"],
        summary["transitions_received"],
        summary["transitions_rejected"],
        summary["episodes"],
        summary["updates"],
        summary["weight_version"],
        out.join("run_summary.json").display()
    );
    if !learner_status.success() {
        eprintln!(
            "dvnav train: the learner failed ({learner_status}); its log:\n{}",
            tail(&learner_log, 30)
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(if clean { ExitCode::SUCCESS } else { ExitCode::FAILURE })
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

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// `run_summary.json`: the learner's counters, each actor's own counts, and how each process
/// ended.
fn merge_summaries(
    out: &Path,
    learner: &Proc,
    actors: &[Proc],
    wall: f64,
) -> anyhow::Result<Value> {
    let l = read_json(&out.join("learner_summary.json")).unwrap_or(Value::Null);
    let learner_actors = l["actors"].as_array().cloned().unwrap_or_default();
    let mut per_actor = Vec::new();
    let mut sent_total = 0u64;
    let mut all_clean = learner.status.is_some_and(|s| s.success()) && !l.is_null();
    for a in actors {
        let s = read_json(&out.join("actors").join(&a.name).join("summary.json"))
            .unwrap_or(Value::Null);
        let at_learner = learner_actors
            .iter()
            .find(|x| x["name"] == a.name.as_str())
            .cloned()
            .unwrap_or(Value::Null);
        let sent = s["transitions_sent"].as_u64().unwrap_or(0);
        sent_total += sent;
        let ok = a.status.is_some_and(|s| s.success()) && !s.is_null();
        all_clean &= ok;
        per_actor.push(json!({
            "name": a.name,
            "actor_id": at_learner["actor_id"],
            "transitions_sent": sent,
            "transitions_received": at_learner["transitions_received"],
            "transitions_rejected": at_learner["transitions_rejected"],
            "episodes": at_learner["episodes"],
            "batches": at_learner["batches"],
            "min_policy_version": s["min_policy_version"],
            "max_policy_version": s["max_policy_version"],
            "env_steps": s["env_steps"],
            "env_steps_per_s": s["env_steps_per_s"],
            "logged_episodes": s["logged_episodes"],
            "exit_status": a.status.map(|s| s.to_string()),
            "clean_exit": ok,
            "stop_reason": s["stop_reason"],
        }));
    }
    Ok(json!({
        "run_id": l["run_id"],
        "transitions_sent": sent_total,
        "transitions_received": l["transitions_received"],
        "transitions_rejected": l["transitions_rejected"],
        "episodes": l["episodes"],
        "updates": l["updates"],
        "weight_version": l["weight_version"],
        "replay_size": l["replay_size"],
        "stage": l["stage"],
        "stage_changes": l["stage_changes"],
        "skilled": l["skilled"],
        "success_rate": l["success_rate"],
        "critic_loss": l["critic_loss"],
        "actor_loss": l["actor_loss"],
        "alpha": l["alpha"],
        "losses_finite": l["losses_finite"],
        "step_budget": l["step_budget"],
        "final_checkpoint": l["final_checkpoint"],
        "wall_time_s": wall,
        "env_steps_per_s": l["transitions_received"].as_u64().unwrap_or(0) as f64 / wall,
        "updates_per_s": l["updates"].as_u64().unwrap_or(0) as f64 / wall,
        "learner_exit_status": learner.status.map(|s| s.to_string()),
        "clean_shutdown": all_clean,
        "actors": per_actor,
    }))
}
