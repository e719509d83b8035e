//! The supervisor's parts: the learner's and actors' child processes, the restart policy with
//! its backoff, and `pids.json`.
//!
//! An actor that fails (exits with an error, or is killed by a signal) while the run goes on is
//! started again after a backoff ([`RESTART_BACKOFF_FIRST`] doubling to [`RESTART_BACKOFF_MAX`];
//! back to the first after a process that ran [`RESTART_BACKOFF_RESET_AFTER`]), at most
//! `--max-actor-restarts` times per actor.

use serde_json::json;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Wait before restarting a failed actor the first time.
pub const RESTART_BACKOFF_FIRST: Duration = Duration::from_secs(1);
/// Longest wait before a restart; the wait doubles with each failure in a row.
pub const RESTART_BACKOFF_MAX: Duration = Duration::from_secs(30);
/// A process that ran this long before failing was healthy: the wait starts over.
pub const RESTART_BACKOFF_RESET_AFTER: Duration = Duration::from_secs(60);

pub(super) struct Proc {
    pub(super) name: String,
    pub(super) child: Child,
    pub(super) status: Option<std::process::ExitStatus>,
    pub(super) started: Instant,
    /// How long it ran, from start until the supervisor saw it end.
    pub(super) ran: Option<Duration>,
}

impl Proc {
    pub(super) fn new(name: String, child: Child) -> Self {
        Self { name, child, status: None, started: Instant::now(), ran: None }
    }

    pub(super) fn poll(&mut self) -> Option<std::process::ExitStatus> {
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
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub(super) struct ActorFailure {
    /// The actor it ran as (`actor-0`).
    pub(super) actor: String,
    /// The process's name at the learner (`actor-0`, `actor-0-r1`, …).
    pub(super) process: String,
    pub(super) pid: u32,
    /// How it ended, e.g. `signal: 9 (SIGKILL)` or `exit status: 1`.
    pub(super) exit_status: String,
    /// Seconds from the start of the run until the supervisor saw it end.
    pub(super) at_s: f64,
    /// Seconds it ran.
    pub(super) ran_s: f64,
    /// The last lines of its log.
    pub(super) log_tail: String,
    /// The process that replaced it, when one was started.
    pub(super) restarted_as: Option<String>,
    /// Seconds from seeing it end to starting the replacement.
    pub(super) restart_delay_s: Option<f64>,
    /// Why it was not restarted, when it was not.
    pub(super) not_restarted: Option<String>,
}

/// One actor of the run: the process running for it now and those it replaced.
pub(super) struct ActorSlot {
    /// The actor's name (`actor-0`); restart K runs as `actor-0-rK`.
    pub(super) actor: String,
    /// Every process started for it, oldest first; the last is the current one.
    pub(super) procs: Vec<Proc>,
    /// Wait before the next restart.
    pub(super) backoff: Duration,
    /// A restart is due at this time (with the index of its failure in `failures`).
    pub(super) restart_due: Option<(Instant, usize)>,
}

impl ActorSlot {
    pub(super) fn current(&mut self) -> &mut Proc {
        self.procs.last_mut().expect("an actor slot holds at least one process")
    }

    pub(super) fn restarts(&self) -> usize {
        self.procs.len() - 1
    }

    pub(super) fn next_name(&self) -> String {
        format!("{}-r{}", self.actor, self.procs.len())
    }
}

/// What an actor process needs to start.
pub(super) struct ActorLaunch<'a> {
    pub(super) exe: &'a Path,
    pub(super) url: &'a str,
    pub(super) out: &'a Path,
    pub(super) threads: usize,
}

impl ActorLaunch<'_> {
    pub(super) fn spawn(&self, name: &str) -> anyhow::Result<Proc> {
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
pub(super) fn write_pids(out: &Path, learner: &Proc, actors: &[ActorSlot]) {
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
pub(super) struct Restarts {
    /// `--max-actor-restarts`.
    pub(super) max: u32,
    /// The run is ending (Ctrl-C, or the learner reached its budget): failures are not
    /// restarted any more.
    pub(super) stopping: bool,
}

impl Restarts {
    /// Notices a failed actor process (logging which, how, and the end of its log) and
    /// schedules its restart, or starts a restart that is due. True when a process started.
    pub(super) fn supervise(
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
pub(super) fn indent(text: &str) -> String {
    text.lines().map(|l| format!("    {l}")).collect::<Vec<_>>().join("\n")
}

pub(super) fn spawn(
    exe: &Path,
    args: &[String],
    log: &Path,
    threads: usize,
) -> anyhow::Result<Child> {
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

pub(super) fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let v: Vec<&str> = text.lines().collect();
    v[v.len().saturating_sub(lines)..].join("\n")
}

pub(super) fn signal(child: &Child, sig: i32) {
    // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
    unsafe {
        libc::kill(child.id() as i32, sig);
    }
}
