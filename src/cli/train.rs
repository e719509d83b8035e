//! `dvnav train`: a learner and N actor processes on this machine, supervised.
//!
//! The supervisor starts `dvnav learner` on a free loopback port, then the actors, polls the
//! learner's `Status` for a progress line, and when the learner finishes (step budget reached,
//! or Ctrl-C) waits for every child, then merges the learner's and actors' summaries into
//! `run_summary.json`. Children write their logs to `DIR/logs/`; `DIR/pids.json` names the
//! running processes while the run lasts.
//!
//! **Actor restarts.** An actor that fails (exits with an error, or is killed by a signal)
//! while the run goes on is started again after a backoff ([`RESTART_BACKOFF_FIRST`] doubling
//! to [`RESTART_BACKOFF_MAX`]; back to the first after a process that ran
//! [`RESTART_BACKOFF_RESET_AFTER`]), at most `--max-actor-restarts` times per actor. The new
//! process runs as `actor-N-rK` (restart K of `actor-N`): a new actor id at the learner, a new
//! environment seed, its own log, summary and MCAP files, so the learner's counts of the dead
//! process stay its own and nothing of it is counted twice. What the dead process had sent
//! and the learner had not yet acknowledged is lost with it (the learner drops a batch whose
//! stream broke before it was inserted); every acknowledged batch stays counted once.

use clap::Args;
use dvnav_config::Config;
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

/// Wait before restarting a failed actor the first time.
pub const RESTART_BACKOFF_FIRST: Duration = Duration::from_secs(1);
/// Longest wait before a restart; the wait doubles with each failure in a row.
pub const RESTART_BACKOFF_MAX: Duration = Duration::from_secs(30);
/// A process that ran this long before failing was healthy: the wait starts over.
pub const RESTART_BACKOFF_RESET_AFTER: Duration = Duration::from_secs(60);

struct Proc {
    name: String,
    child: Child,
    status: Option<std::process::ExitStatus>,
    started: Instant,
    /// How long it ran, from start until the supervisor saw it end.
    ran: Option<Duration>,
}

impl Proc {
    fn new(name: String, child: Child) -> Self {
        Self { name, child, status: None, started: Instant::now(), ran: None }
    }

    fn poll(&mut self) -> Option<std::process::ExitStatus> {
        if self.status.is_none() {
            self.status = self.child.try_wait().ok().flatten();
            if self.status.is_some() {
                self.ran = Some(self.started.elapsed());
            }
        }
        self.status
    }
}

/// A failed actor process and what the supervisor did about it.
#[derive(Clone, Debug, serde::Serialize)]
struct ActorFailure {
    /// The actor it ran as (`actor-0`).
    actor: String,
    /// The process's name at the learner (`actor-0`, `actor-0-r1`, …).
    process: String,
    pid: u32,
    /// How it ended, e.g. `signal: 9 (SIGKILL)` or `exit status: 1`.
    exit_status: String,
    /// Seconds from the start of the run until the supervisor saw it end.
    at_s: f64,
    /// Seconds it ran.
    ran_s: f64,
    /// The last lines of its log.
    log_tail: String,
    /// The process that replaced it, when one was started.
    restarted_as: Option<String>,
    /// Seconds from seeing it end to starting the replacement.
    restart_delay_s: Option<f64>,
    /// Why it was not restarted, when it was not.
    not_restarted: Option<String>,
}

/// One actor of the run: the process running for it now and those it replaced.
struct ActorSlot {
    /// The actor's name (`actor-0`); restart K runs as `actor-0-rK`.
    actor: String,
    /// Every process started for it, oldest first; the last is the current one.
    procs: Vec<Proc>,
    /// Wait before the next restart.
    backoff: Duration,
    /// A restart is due at this time (with the index of its failure in `failures`).
    restart_due: Option<(Instant, usize)>,
}

impl ActorSlot {
    fn current(&mut self) -> &mut Proc {
        self.procs.last_mut().expect("an actor slot holds at least one process")
    }

    fn restarts(&self) -> usize {
        self.procs.len() - 1
    }

    fn next_name(&self) -> String {
        format!("{}-r{}", self.actor, self.procs.len())
    }
}

/// What an actor process needs to start.
struct ActorLaunch<'a> {
    exe: &'a Path,
    url: &'a str,
    out: &'a Path,
    threads: usize,
}

impl ActorLaunch<'_> {
    fn spawn(&self, name: &str) -> anyhow::Result<Proc> {
        let child = spawn(
            self.exe,
            &[
                "actor".into(),
                "--learner".into(),
                self.url.to_string(),
                "--name".into(),
                name.to_string(),
                "--out".into(),
                self.out.display().to_string(),
            ],
            &self.out.join(format!("logs/{name}.log")),
            self.threads,
        )?;
        Ok(Proc::new(name.to_string(), child))
    }
}

/// `DIR/pids.json`: the supervisor's, the learner's and each actor's current process id, for
/// operators and fault tests (written whole, by rename; removed at the end of the run).
fn write_pids(out: &Path, learner: &Proc, actors: &[ActorSlot]) {
    let doc = json!({
        "supervisor": std::process::id(),
        "learner": learner.child.id(),
        "actors": actors
            .iter()
            .map(|s| {
                let p = s.procs.last().expect("an actor slot holds at least one process");
                json!({ "actor": s.actor, "process": p.name, "pid": p.child.id(), "restarts": s.restarts() })
            })
            .collect::<Vec<_>>(),
    });
    let (path, tmp) = (out.join("pids.json"), out.join("pids.json.tmp"));
    let written = serde_json::to_vec_pretty(&doc)
        .map_err(std::io::Error::other)
        .and_then(|b| std::fs::write(&tmp, b))
        .and_then(|()| std::fs::rename(&tmp, &path));
    if let Err(e) = written {
        eprintln!("dvnav train: cannot write {}: {e}", path.display());
    }
}

/// The restart policy of one supervision round.
struct Restarts {
    /// `--max-actor-restarts`.
    max: u32,
    /// The run is ending (Ctrl-C, or the learner reached its budget): failures are not
    /// restarted any more.
    stopping: bool,
}

impl Restarts {
    /// Notices a failed actor process (logging which, how, and the end of its log) and
    /// schedules its restart, or starts a restart that is due. True when a process started.
    fn supervise(
        &self,
        slot: &mut ActorSlot,
        launch: &ActorLaunch,
        failures: &mut Vec<ActorFailure>,
        run_started: Instant,
    ) -> bool {
        let actor = slot.actor.clone();
        let (restarts, next) = (slot.restarts(), slot.next_name());
        let cur = slot.current();
        if cur.status.is_none()
            && let Some(st) = cur.poll()
            && !st.success()
        {
            let ran = cur.ran.unwrap_or_default();
            let log = launch.out.join(format!("logs/{}.log", cur.name));
            let log_tail = tail(&log, 5);
            let (process, pid) = (cur.name.clone(), cur.child.id());
            let why_not = if self.stopping {
                Some("the run was stopping".to_string())
            } else if restarts >= self.max as usize {
                Some(format!("--max-actor-restarts {} reached", self.max))
            } else {
                None
            };
            if ran >= RESTART_BACKOFF_RESET_AFTER {
                slot.backoff = RESTART_BACKOFF_FIRST;
            }
            let what =
                format!("{process} (pid {pid}) failed ({st}) after {:.1} s", ran.as_secs_f64());
            match &why_not {
                Some(why) => eprintln!(
                    "\ndvnav train: {what}; not restarting it: {why}; the end of {}:\n{}",
                    log.display(),
                    indent(&log_tail)
                ),
                None => {
                    eprintln!(
                        "\ndvnav train: {what}; restarting it as {next} in {:.0} s (restart {} of at most {}); the end of {}:\n{}",
                        slot.backoff.as_secs_f64(),
                        restarts + 1,
                        self.max,
                        log.display(),
                        indent(&log_tail)
                    );
                    slot.restart_due = Some((Instant::now() + slot.backoff, failures.len()));
                    slot.backoff = (slot.backoff * 2).min(RESTART_BACKOFF_MAX);
                }
            }
            failures.push(ActorFailure {
                actor,
                process,
                pid,
                exit_status: st.to_string(),
                at_s: run_started.elapsed().as_secs_f64(),
                ran_s: ran.as_secs_f64(),
                log_tail,
                restarted_as: None,
                restart_delay_s: None,
                not_restarted: why_not,
            });
        }
        let Some((due, i)) = slot.restart_due else { return false };
        if Instant::now() < due {
            return false;
        }
        slot.restart_due = None;
        if self.stopping {
            failures[i].not_restarted = Some("the run was stopping".into());
            return false;
        }
        match launch.spawn(&next) {
            Ok(p) => {
                eprintln!("dvnav train: restarted {} as {next} (pid {})", slot.actor, p.child.id());
                let f = &mut failures[i];
                f.restart_delay_s = Some(run_started.elapsed().as_secs_f64() - f.at_s);
                f.restarted_as = Some(next);
                slot.procs.push(p);
                true
            }
            Err(e) => {
                eprintln!(
                    "dvnav train: cannot start {next}: {e}; trying again in {:.0} s",
                    slot.backoff.as_secs_f64()
                );
                slot.restart_due = Some((Instant::now() + slot.backoff, i));
                slot.backoff = (slot.backoff * 2).min(RESTART_BACKOFF_MAX);
                false
            }
        }
    }
}

/// Indents a log excerpt under a message.
fn indent(text: &str) -> String {
    text.lines().map(|l| format!("    {l}")).collect::<Vec<_>>().join("\n")
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
        rt.block_on(dvnav_actor::run::connect(&url, None, None, Duration::from_secs(30))).ok();
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut last_print = Instant::now() - Duration::from_secs(3600);
    let mut forwarded = false;
    let mut learner_done = false;
    let mut last_line = String::new();
    while learner.poll().is_none() {
        if interrupted.load(std::sync::atomic::Ordering::SeqCst) && !forwarded {
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
        merge_summaries(&out, &learner, &actors, &failures, started.elapsed().as_secs_f64())?;
    std::fs::write(out.join("run_summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    let clean = summary["clean_shutdown"].as_bool().unwrap_or(false);
    eprintln!("{last_line}");
    let sent = match summary["unreported_actors"].as_array().map(Vec::len).unwrap_or(0) {
        0 => format!("{} steps sent", summary["transitions_sent"]),
        n => format!(
            "{} steps sent (+ what {n} killed actor process{} sent)",
            summary["transitions_sent"],
            if n == 1 { "" } else { "es" }
        ),
    };
    eprintln!(
        "dvnav train: done in {:.0} s: {sent}, {} received, {} rejected, {} episodes, {} updates, weights v{}, {} actor restart{}; summary {}",
        started.elapsed().as_secs_f64(),
        summary["transitions_received"],
        summary["transitions_rejected"],
        summary["episodes"],
        summary["updates"],
        summary["weight_version"],
        summary["actor_restarts"],
        if summary["actor_restarts"] == 1 { "" } else { "s" },
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

/// `run_summary.json`: the learner's counters, each actor process's own counts, how each
/// process ended, and the actor failures and restarts.
///
/// `actors` has one entry per process, restarts included (`actor` names the actor it ran as,
/// `restart` counts from 0). A killed process writes no summary: its `transitions_sent` is
/// null and it is listed in `unreported_actors`; the learner's counts of it stand.
/// `transitions_sent` is the sum over the processes that reported, and
/// `transitions_accounted` says whether each of them had every transition it sent received or
/// rejected by the learner (nothing lost, nothing counted twice). `clean_shutdown` holds when
/// the learner and every actor's last process ended cleanly: a failed process that was
/// replaced does not spoil it (`actor_failures` tells what happened), one that was not does.
fn merge_summaries(
    out: &Path,
    learner: &Proc,
    actors: &[ActorSlot],
    failures: &[ActorFailure],
    wall: f64,
) -> anyhow::Result<Value> {
    let l = read_json(&out.join("learner_summary.json")).unwrap_or(Value::Null);
    let learner_actors = l["actors"].as_array().cloned().unwrap_or_default();
    let mut per_actor = Vec::new();
    let mut sent_total = 0u64;
    let mut accounted = !l.is_null();
    let mut unreported = Vec::new();
    let mut unreported_received = 0u64;
    let mut restarts = serde_json::Map::new();
    let mut all_clean = learner.status.is_some_and(|s| s.success()) && !l.is_null();
    for slot in actors {
        restarts.insert(slot.actor.clone(), json!(slot.restarts()));
        for (k, a) in slot.procs.iter().enumerate() {
            let s = read_json(&out.join("actors").join(&a.name).join("summary.json"))
                .unwrap_or(Value::Null);
            let at_learner = learner_actors
                .iter()
                .find(|x| x["name"] == a.name.as_str())
                .cloned()
                .unwrap_or(Value::Null);
            let count = |v: &Value| v.as_u64().unwrap_or(0);
            let (received, rejected) = (
                count(&at_learner["transitions_received"]),
                count(&at_learner["transitions_rejected"]),
            );
            let sent = s["transitions_sent"].as_u64();
            match sent {
                Some(n) => {
                    sent_total += n;
                    accounted &= n == received + rejected;
                }
                None => {
                    unreported.push(a.name.clone());
                    unreported_received += received;
                }
            }
            let ok = a.status.is_some_and(|s| s.success()) && !s.is_null();
            if k + 1 == slot.procs.len() {
                all_clean &= ok;
            }
            per_actor.push(json!({
                "name": a.name,
                "actor": slot.actor,
                "restart": k,
                "pid": a.child.id(),
                "actor_id": at_learner["actor_id"],
                "transitions_sent": sent,
                "transitions_received": at_learner["transitions_received"],
                "transitions_rejected": at_learner["transitions_rejected"],
                "episodes": at_learner["episodes"],
                "batches": at_learner["batches"],
                "duplicate_batches": at_learner["duplicate_batches"],
                "min_policy_version": s["min_policy_version"],
                "max_policy_version": s["max_policy_version"],
                "env_steps": s["env_steps"],
                "env_steps_per_s": s["env_steps_per_s"],
                "logged_episodes": s["logged_episodes"],
                "exit_status": a.status.map(|s| s.to_string()),
                "ran_s": a.ran.map(|d| d.as_secs_f64()),
                "clean_exit": ok,
                "stop_reason": s["stop_reason"],
                "replaced_by": slot.procs.get(k + 1).map(|p| p.name.clone()),
            }));
        }
    }
    let actor_restarts: usize = actors.iter().map(ActorSlot::restarts).sum();
    Ok(json!({
        "run_id": l["run_id"],
        "transitions_sent": sent_total,
        "transitions_received": l["transitions_received"],
        "transitions_rejected": l["transitions_rejected"],
        "transitions_accounted": accounted,
        "unreported_actors": unreported,
        "transitions_received_from_unreported": unreported_received,
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
        "actor_restarts": actor_restarts,
        "restarts": restarts,
        "actor_failures": failures,
        "actors": per_actor,
    }))
}
