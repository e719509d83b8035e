//! Fault test: an actor process of `dvnav train` is killed with SIGKILL mid-run. The learner
//! notices within seconds and names it in its log, the supervisor restarts it (as
//! `actor-0-r1`, a new actor id), the run reaches its budget and ends cleanly, and the books
//! balance: every transition the learner counted is in the replay buffer once, every surviving
//! process had all it sent received, and the killed process's accepted batches stay counted.
//!
//! What cannot be asserted: how many transitions the killed process had produced but not yet
//! had acknowledged (its summary dies with it); those are lost with it by design.
//!
//! Then the learner alone as a supervisor (Kubernetes, systemd) runs it: `dvnav learner
//! --resume-if-present` starts fresh on an empty directory, resumes on the run's checkpoints,
//! and answers its health probes.

use dvnav_proto::StatusRequest;
use dvnav_proto::learner_client::LearnerClient;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use support::{http_get, http_status, wait_exit, wait_for};

mod support;

/// The smoke test's config with a larger budget, so the kill and the restart fall well inside
/// the run, and no episode logs.
const CONFIG: &str = r#"
[run]
steps = 4000
seed = 11

[sac]
batch_size = 32
learning_starts = 500
updates_per_env_step = 0.1

[learner]
publish_every_updates = 10
checkpoint_every_updates = 100
max_steps_ahead = 1000

[actor]
envs = 2
batch_transitions = 64

[warmup]
pid_episodes = 10

[logging]
every_nth_episode = 0
"#;

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}

/// Actor `index`'s pid once `out/pids.json` names its process `process`.
fn actor_pid(out: &Path, index: usize, process: &str) -> i32 {
    wait_for(process, Duration::from_secs(60), || {
        let pids = read_json(&out.join("pids.json"))?;
        let a = &pids["actors"][index];
        (a["process"] == process).then(|| a["pid"].as_i64().unwrap() as i32)
    })
}

/// The learner of a running `dvnav train` in `out`: its Status RPC, and its metrics address.
struct Learner {
    rt: tokio::runtime::Runtime,
    client: LearnerClient<tonic::transport::Channel>,
}

impl Learner {
    fn attach(out: &Path) -> (Self, String) {
        let addr = std::fs::read_to_string(out.join("learner.addr")).unwrap();
        let metrics = std::fs::read_to_string(out.join("metrics.addr")).unwrap();
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        let client =
            rt.block_on(LearnerClient::connect(format!("http://{}", addr.trim()))).unwrap();
        (Learner { rt, client }, metrics.trim().to_string())
    }

    fn status(&mut self) -> dvnav_proto::StatusReply {
        self.rt.block_on(self.client.status(StatusRequest {})).unwrap().into_inner()
    }
}

/// Waits up to two minutes for `dvnav train` to exit; kills it and fails with `log()` if not.
fn wait_train_exit(
    train: &mut std::process::Child,
    log: impl Fn() -> String,
) -> std::process::ExitStatus {
    wait_exit(train, "dvnav train", Duration::from_secs(120), log)
}

/// Starts `dvnav train --actors 2` with `config` into `out`, its stderr to `DIR/train.log`,
/// the learner's `/metrics` on a free port (`out/metrics.addr`), and `extra` flags.
fn spawn_train(dir: &Path, config: &Path, out: &Path, extra: &[&str]) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["train", "--actors", "2", "--metrics-addr", "127.0.0.1:0", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .args(extra)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("train.log")).unwrap())
        .spawn()
        .unwrap()
}

#[test]
fn a_killed_actor_is_restarted_and_nothing_is_counted_twice() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("faults.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = dir.path().join("run");
    let started = Instant::now();
    let mut train = spawn_train(dir.path(), &config, &out, &["--progress-every-s", "5"]);
    let log = |name: &str| std::fs::read_to_string(out.join("logs").join(name)).unwrap_or_default();
    let train_log = || std::fs::read_to_string(dir.path().join("train.log")).unwrap_or_default();

    let victim_pid = actor_pid(&out, 0, "actor-0");
    let (mut learner, metrics) = Learner::attach(&out);
    let mut status = || learner.status();
    let received_by = |s: &dvnav_proto::StatusReply, name: &str| {
        s.actors.iter().find(|a| a.actor_name == name).map_or(0, |a| a.transitions_received)
    };
    // Mid-run: training has begun, the victim has had batches accepted, the budget is far.
    let before = wait_for("updates and actor-0's first batches", Duration::from_secs(60), || {
        let s = status();
        (s.updates > 0 && received_by(&s, "actor-0") >= 128).then_some(s)
    });
    assert!(before.transitions_received < 3000, "killed too late to test a restart: {before:?}");
    assert_eq!(http_status(&metrics, "/readyz"), "HTTP/1.1 200 OK");
    assert_eq!(http_status(&metrics, "/healthz"), "HTTP/1.1 200 OK");

    // SAFETY: kill(2) on a process id read from the run's pids.json, a child of our child.
    assert_eq!(unsafe { libc::kill(victim_pid, libc::SIGKILL) }, 0);
    let killed_at = Instant::now();
    let at_kill = status();

    // The learner names the lost actor within a few seconds.
    let noticed = wait_for("the learner's log line about actor-0", Duration::from_secs(10), || {
        log("learner.log")
            .lines()
            .any(|l| l.contains("ended abnormally") && l.contains("actor=actor-0 "))
            .then(|| killed_at.elapsed())
    });
    // The restarted process delivers: the time from the kill to its first accepted batch.
    let recovered = wait_for("actor-0-r1's first accepted batch", Duration::from_secs(60), || {
        (received_by(&status(), "actor-0-r1") > 0).then(|| killed_at.elapsed())
    });
    eprintln!(
        "faults: actor-0 killed at {:.1} s into the run (learner at {} steps); the learner \
         logged it after {:.2} s; actor-0-r1's first batch was accepted {:.2} s after the kill",
        (killed_at - started).as_secs_f64(),
        at_kill.transitions_received,
        noticed.as_secs_f64(),
        recovered.as_secs_f64()
    );
    assert!(noticed < Duration::from_secs(5), "{noticed:?}");
    let pids = read_json(&out.join("pids.json")).unwrap();
    assert_eq!(pids["actors"][0]["process"], "actor-0-r1", "{pids}");
    assert_eq!(pids["actors"][0]["restarts"], 1, "{pids}");

    let exit = wait_train_exit(&mut train, train_log);
    let train_log = train_log();
    assert!(exit.success(), "dvnav train failed: {train_log}\nlearner:\n{}", log("learner.log"));
    assert!(
        train_log.contains("actor-0 (pid") && train_log.contains("SIGKILL"),
        "the supervisor says which actor died and how: {train_log}"
    );
    assert!(train_log.contains("1 actor restart;"), "{train_log}");
    assert!(!out.join("pids.json").exists(), "no stale process ids after the run");

    let s = read_json(&out.join("run_summary.json")).unwrap();
    let n = |v: &Value| v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"));
    assert_eq!(s["clean_shutdown"], true, "a restarted actor leaves the run clean: {s}");
    assert_eq!(n(&s["actor_restarts"]), 1, "{s}");
    assert_eq!(s["restarts"], serde_json::json!({ "actor-0": 1, "actor-1": 0 }), "{s}");
    let failure = &s["actor_failures"][0];
    assert_eq!(failure["process"], "actor-0");
    assert_eq!(failure["pid"].as_i64(), Some(victim_pid as i64));
    assert!(failure["exit_status"].as_str().unwrap().contains("SIGKILL"), "{failure}");
    assert_eq!(failure["restarted_as"], "actor-0-r1");
    assert!(failure["restart_delay_s"].as_f64().unwrap() >= 1.0, "the first backoff is 1 s");

    let received = n(&s["transitions_received"]);
    assert!(received >= 4000, "the budget was reached: {s}");
    assert_eq!(n(&s["transitions_rejected"]), 0, "{s}");
    // Every transition counted is in the replay buffer exactly once (it holds 10^6).
    assert_eq!(n(&s["replay_size"]), received, "{s}");
    let actors = s["actors"].as_array().unwrap();
    let names: Vec<&str> = actors.iter().map(|a| a["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["actor-0", "actor-0-r1", "actor-1"], "{s}");
    // The learner's total is the sum of what it accepted from each process: no batch counted
    // twice, none counted that no process sent.
    assert_eq!(actors.iter().map(|a| n(&a["transitions_received"])).sum::<u64>(), received);
    for a in actors {
        assert_eq!(n(&a["duplicate_batches"]), 0, "{a}");
        assert!(n(&a["transitions_received"]) > 0, "{a}");
    }

    // The killed process: no summary, so what it sent is unknown; what the learner accepted
    // from it before the kill stays counted (nothing of a finished batch lost).
    let killed = &actors[0];
    assert!(killed["transitions_sent"].is_null(), "{killed}");
    assert_eq!(killed["clean_exit"], false);
    assert_eq!(killed["replaced_by"], "actor-0-r1");
    assert!(n(&killed["transitions_received"]) >= received_by(&at_kill, "actor-0"), "{killed}");
    assert_eq!(s["unreported_actors"], serde_json::json!(["actor-0"]));
    assert_eq!(n(&s["transitions_received_from_unreported"]), n(&killed["transitions_received"]));

    // The survivors: everything they sent was received, each acknowledged once.
    for a in &actors[1..] {
        assert_eq!(a["clean_exit"], true, "{a}");
        assert_eq!(n(&a["transitions_sent"]), n(&a["transitions_received"]), "{a}");
        let own =
            read_json(&out.join("actors").join(a["name"].as_str().unwrap()).join("summary.json"))
                .unwrap();
        assert_eq!(n(&own["transitions_acked"]), n(&own["transitions_sent"]), "{own}");
        assert_eq!(n(&own["link"]["transitions_undelivered"]), 0, "{own}");
    }
    assert_eq!(s["transitions_accounted"], true, "{s}");
    assert_eq!(
        n(&s["transitions_sent"]) + n(&s["transitions_received_from_unreported"]),
        received,
        "{s}"
    );
    assert!(started.elapsed() < Duration::from_secs(120));

    // The same command on an empty directory and on the run's: fresh, then resumed.
    let fresh = dir.path().join("fresh");
    let log = learner_under_a_supervisor(&fresh);
    assert!(log.contains("no complete checkpoint yet; starting fresh"), "{log}");
    let log = learner_under_a_supervisor(&out);
    assert!(log.contains("--resume-if-present: resuming") && log.contains("resumed"), "{log}");
}

/// Starts `dvnav learner --resume-if-present` on `out`, waits until `/readyz` answers 200
/// (`/healthz` too), stops it with SIGTERM and returns its log.
fn learner_under_a_supervisor(out: &Path) -> String {
    std::fs::create_dir_all(out).unwrap();
    let log_path = out.join("supervised-learner.log");
    let mut learner = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["learner", "--resume-if-present", "--listen", "127.0.0.1:0"])
        .args(["--metrics-addr", "127.0.0.1:0", "--out"])
        .arg(out)
        .arg("--addr-file")
        .arg(out.join("supervised.addr"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log_path).unwrap())
        .spawn()
        .unwrap();
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    wait_for("the learner's address file", Duration::from_secs(60), || {
        out.join("supervised.addr").exists().then_some(())
    });
    let metrics = std::fs::read_to_string(out.join("metrics.addr")).unwrap().trim().to_string();
    wait_for("/readyz 200", Duration::from_secs(60), || {
        assert!(learner.try_wait().unwrap().is_none(), "the learner exited: {}", log());
        (http_status(&metrics, "/readyz") == "HTTP/1.1 200 OK").then_some(())
    });
    assert_eq!(http_status(&metrics, "/healthz"), "HTTP/1.1 200 OK");
    // SAFETY: kill(2) on our own child.
    assert_eq!(unsafe { libc::kill(learner.id() as i32, libc::SIGTERM) }, 0);
    let status = learner.wait().unwrap();
    assert!(status.success(), "{}", log());
    log()
}

/// Hangs are named: an actor process frozen with SIGSTOP keeps its connection open and sends
/// nothing. The learner's watchdog names it, with what it is not doing, in `/readyz` and its
/// log within one heartbeat interval (`learner.heartbeat_s`, 5 s here) of the freeze, says it
/// moves again after SIGCONT, and the run ends with every transition sent received.
#[test]
fn a_frozen_actor_is_named_within_one_heartbeat() {
    const HEARTBEAT_S: f64 = 5.0;
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("hang.toml");
    // Ingestion never waits for the trainer here, so nothing excuses the silence; a low
    // replay ratio keeps the updates owed at the budget (which the run does before it ends)
    // to a few hundred.
    let cfg = CONFIG
        .replace("steps = 4000", "steps = 60000")
        .replace("max_steps_ahead = 1000", "max_steps_ahead = 100000")
        .replace("updates_per_env_step = 0.1", "updates_per_env_step = 0.01")
        .replace("[learner]", &format!("[learner]\nheartbeat_s = {HEARTBEAT_S}"));
    std::fs::write(&config, cfg).unwrap();
    let out = dir.path().join("run");
    let mut train = spawn_train(dir.path(), &config, &out, &["--progress-every-s", "5"]);
    let learner_log =
        || std::fs::read_to_string(out.join("logs").join("learner.log")).unwrap_or_default();
    let frozen_pid = actor_pid(&out, 1, "actor-1");
    let (mut learner, metrics) = Learner::attach(&out);
    let mut status = || learner.status();
    let batches_of = |s: &dvnav_proto::StatusReply, name: &str| {
        s.actors.iter().find(|a| a.actor_name == name).map_or(0, |a| a.batches)
    };
    wait_for("actor-1 streaming", Duration::from_secs(60), || {
        (batches_of(&status(), "actor-1") >= 3).then_some(())
    });
    let readyz = || http_get(&metrics, "/readyz");
    assert!(!readyz().contains("stalled:"), "a healthy run names nothing: {}", readyz());

    // When actor-1's last batch arrived, as the test can know it: the start of the Status poll
    // before the one that saw its batch count move, never later than the arrival itself.
    let mut polled_at = Instant::now();
    let mut batches = batches_of(&status(), "actor-1");
    let mut batch_arrived = || {
        let now = Instant::now();
        let b = batches_of(&status(), "actor-1");
        let arrived = (b != batches).then_some(polled_at);
        (batches, polled_at) = (b, now);
        arrived
    };
    // Freeze it just after a batch arrived, so its last progress before the freeze is known.
    let mut last_batch_at =
        wait_for("a batch from actor-1", Duration::from_secs(10), &mut batch_arrived);
    // SAFETY: kill(2) on a process id read from the run's pids.json, a child of our child.
    assert_eq!(unsafe { libc::kill(frozen_pid, libc::SIGSTOP) }, 0);
    let frozen_at = Instant::now();
    // Batches already on their way still arrive after the freeze (later on a loaded machine):
    // the heartbeat bound counts from the last one, the watchdog's "last progress".
    let named = loop {
        if let Some(at) = batch_arrived() {
            last_batch_at = at;
        }
        let r = readyz();
        if r.contains("stalled: actor:actor-1") {
            break (last_batch_at.elapsed(), r, frozen_at.elapsed());
        }
        assert!(train.try_wait().unwrap().is_none(), "the run ended: {}", learner_log());
        assert!(
            frozen_at.elapsed() < Duration::from_secs(20),
            "actor-1 not named in 20 s; /readyz: {r}\nlearner log:\n{}",
            learner_log()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let after_freeze = status();
    // SAFETY: as above.
    assert_eq!(unsafe { libc::kill(frozen_pid, libc::SIGCONT) }, 0);
    eprintln!(
        "faults: actor-1 frozen with SIGSTOP; named by the watchdog {:.2} s after its last \
         batch arrived, {:.2} s after the freeze (heartbeat {HEARTBEAT_S} s)",
        named.0.as_secs_f64(),
        named.2.as_secs_f64()
    );
    // Within one heartbeat, and in fact by 0.8 of one plus the time a sample takes
    // (learner/src/watchdog.rs): 0.9 catches a stall named a sample late, as it was while the
    // watchdog timed samples by when its task ran (4.8-4.9 s here) rather than by the tick.
    assert!(
        named.0 <= Duration::from_secs_f64(0.9 * HEARTBEAT_S),
        "named {:?} after the last batch, a sample later than the watchdog's 0.8 heartbeat: {}",
        named.0,
        named.1
    );
    assert!(named.1.starts_with("HTTP/1.1 200 OK"), "a stalled actor leaves it ready: {}", named.1);
    assert!(named.1.contains("stream open but no batch arrives"), "{}", named.1);
    assert!(
        !named.1.contains("stalled: actor:actor-0"),
        "the live actor is not named: {}",
        named.1
    );
    assert!(
        after_freeze.transitions_received < 50000,
        "the run went on meanwhile: {after_freeze:?}"
    );
    let moving = "watchdog: component moving again component=actor:actor-1";
    let deadline = Instant::now() + Duration::from_secs(20);
    while !learner_log().contains(moving) {
        assert!(
            Instant::now() < deadline,
            "actor-1 not moving again in 20 s; /readyz: {}\nlearner log:\n{}",
            readyz(),
            learner_log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let log = learner_log();
    assert!(
        log.contains("watchdog: component stalled component=actor:actor-1"),
        "the log names it too: {log}"
    );

    let exit = wait_train_exit(&mut train, learner_log);
    assert!(exit.success(), "{}", learner_log());
    let s = read_json(&out.join("run_summary.json")).unwrap();
    assert_eq!(s["transitions_accounted"], true, "{s}");
    assert_eq!(s["transitions_sent"], s["transitions_received"], "{s}");
}

/// The restart policy: with `--max-actor-restarts 2`, an actor killed three times is restarted
/// after 1 s, then after 2 s (the backoff doubles while its processes keep dying young), and
/// the third time not at all, with the reason in the run summary; the run goes on with the
/// other actor to its budget, and `dvnav train` exits non-zero: it lost an actor for good.
#[test]
fn restarts_back_off_and_stop_at_the_limit() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("restarts.toml");
    std::fs::write(
        &config,
        CONFIG
            .replace("steps = 4000", "steps = 60000")
            .replace("max_steps_ahead = 1000", "max_steps_ahead = 100000")
            // A few hundred updates owed at the budget, not thousands.
            .replace("updates_per_env_step = 0.1", "updates_per_env_step = 0.01"),
    )
    .unwrap();
    let out = dir.path().join("run");
    let mut train = spawn_train(dir.path(), &config, &out, &["--max-actor-restarts", "2"]);
    let train_log = || std::fs::read_to_string(dir.path().join("train.log")).unwrap_or_default();
    // Kills actor-0's current process once it runs as `process`, returns its pid.
    let kill = |process: &str| {
        let pid = actor_pid(&out, 0, process);
        // SAFETY: kill(2) on a process id read from the run's pids.json, a child of our child.
        assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0);
    };
    for process in ["actor-0", "actor-0-r1", "actor-0-r2"] {
        kill(process);
    }
    let exit = wait_train_exit(&mut train, train_log);
    let log = train_log();
    assert_eq!(exit.code(), Some(1), "{log}");
    assert!(log.contains("not restarting it: --max-actor-restarts 2 reached"), "{log}");

    let s = read_json(&out.join("run_summary.json")).unwrap();
    assert_eq!(s["clean_shutdown"], false, "{s}");
    assert!(s["transitions_received"].as_u64().unwrap() >= 60000, "the budget was reached: {s}");
    assert_eq!(s["actor_restarts"], 2, "{s}");
    let f = s["actor_failures"].as_array().unwrap();
    assert_eq!(f.len(), 3, "{s}");
    let delay = |i: usize| f[i]["restart_delay_s"].as_f64().unwrap();
    assert_eq!(
        (f[0]["restarted_as"].as_str(), f[1]["restarted_as"].as_str()),
        (Some("actor-0-r1"), Some("actor-0-r2"))
    );
    assert!((1.0..1.9).contains(&delay(0)), "first backoff 1 s: {}", delay(0));
    assert!((2.0..2.9).contains(&delay(1)), "second backoff 2 s: {}", delay(1));
    assert!(f[2]["restarted_as"].is_null(), "{s}");
    assert_eq!(f[2]["not_restarted"], "--max-actor-restarts 2 reached", "{s}");
    assert_eq!(s["transitions_accounted"], true, "{s}");
}
