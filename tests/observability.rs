//! Seeing a run from outside, end to end with real processes: episode logs survive an actor
//! killed with SIGKILL, and a running `dvnav train` serves its metrics over HTTP.

use dvnav_eval::episode_log::{check_file, read_episodes};
use serde_json::Value;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use support::{KillOnDrop, http_get, wait_for};

mod support;

const DVNAV: &str = env!("CARGO_BIN_EXE_dvnav");

/// Every episode logged, short episodes, 4 episodes per file, one environment (so an actor's
/// episode ids are consecutive in its one file series), no training in the way.
const CRASH_CONFIG: &str = r#"
[run]
steps = 10000000
seed = 11

[env]
max_steps = 120

[sac]
batch_size = 8
learning_starts = 20000
updates_per_env_step = 0.01

[replay]
capacity = 40000

[learner]
max_steps_ahead = 100000000

[actor]
envs = 1
batch_transitions = 32

[warmup]
pid_episodes = 1000000

[logging]
every_nth_episode = 1
episodes_per_file = 4
"#;

fn spawn(args: &[&str], log: &Path) -> KillOnDrop {
    let log = std::fs::File::create(log).unwrap();
    KillOnDrop(
        Command::new(DVNAV)
            .args(args)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap(),
    )
}

fn mcap_files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).collect())
        .unwrap_or_default();
    v.retain(|p| p.extension().is_some_and(|e| e == "mcap"));
    v.sort();
    v
}

#[test]
fn sigkill_leaves_rotated_files_whole_and_the_open_files_complete_episodes_readable() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("crash.toml");
    std::fs::write(&config, CRASH_CONFIG).unwrap();
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    let addr_file = run.join("learner.addr");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let _learner = spawn(
        &[
            "learner",
            "--config",
            &s(&config),
            "--out",
            &s(&run),
            "--listen",
            "127.0.0.1:0",
            "--addr-file",
            &s(&addr_file),
        ],
        &dir.path().join("learner.log"),
    );
    let addr = wait_for("the learner to listen", Duration::from_secs(60), || {
        std::fs::read_to_string(&addr_file).ok()
    });
    let mut actor = spawn(
        &[
            "actor",
            "--learner",
            &format!("http://{}", addr.trim()),
            "--name",
            "victim",
            "--out",
            &s(&run),
        ],
        &dir.path().join("actor.log"),
    );

    // Wait until two files are rotated and the open one holds one finished episode, then kill
    // the actor mid-way through its next episode.
    let logs = run.join("mcap/victim");
    let before =
        wait_for("two rotated files and a finished episode", Duration::from_secs(90), || {
            if let Ok(Some(st)) = actor.0.try_wait() {
                panic!(
                    "the actor exited early ({st}):\n{}",
                    std::fs::read_to_string(dir.path().join("actor.log")).unwrap_or_default()
                );
            }
            let files = mcap_files(&logs);
            let open = files.last()?;
            (files.len() >= 3).then_some(())?;
            let n = read_episodes(open).ok()?.len();
            // 1 of its 4: three more episodes (~0.1 s) before it rotates (and a file with 3 or
            // 4 may already be rotating: its fsync takes a while), so the kill lands in it.
            (n == 1).then_some(n)
        });
    actor.0.kill().unwrap(); // SIGKILL
    let status = actor.0.wait().unwrap();
    assert!(!status.success(), "killed, not exited: {status}");

    let files = mcap_files(&logs);
    let (open, rotated) = files.split_last().unwrap();
    assert!(rotated.len() >= 2, "{files:?}");
    // Every rotated file is finished, decodes completely and holds four whole episodes with
    // consecutive ids.
    for (k, f) in rotated.iter().enumerate() {
        let c = check_file(f).unwrap();
        assert!(c.finished && c.is_ok() && c.truncated.is_none(), "{c:?}");
        assert_eq!(c.complete_episodes, 4, "{c:?}");
        let ids: Vec<u64> =
            read_episodes(f).unwrap().iter().map(|r| r.summary.episode_id).collect();
        let first = 4 * k as u64;
        assert_eq!(ids, (first..first + 4).collect::<Vec<_>>(), "{}", f.display());
        // The same through the summary section the writer finished the file with.
        let bytes = std::fs::read(f).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary section");
        assert_eq!(
            summary.stats.unwrap().message_count,
            c.messages,
            "{}: statistics and messages agree",
            f.display()
        );
    }
    // The open file has no summary section, yet every episode finished in it reads back whole.
    let c = check_file(open).unwrap();
    assert!(!c.finished, "{c:?}");
    assert!(c.is_ok(), "complete episodes decode; only the tail is missing: {c:?}");
    assert!(c.complete_episodes as usize >= before, "{c:?}");

    // `dvnav inspect` (the real command) reads them, and its file check passes.
    let inspect =
        Command::new(DVNAV).args(["inspect", "--list", "--json"]).arg(open).output().unwrap();
    assert!(inspect.status.success(), "{}", String::from_utf8_lossy(&inspect.stderr));
    let report: Value = serde_json::from_slice(&inspect.stdout).unwrap();
    let ids: Vec<u64> = report["list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["episode_id"].as_u64().unwrap())
        .collect();
    let first = 4 * rotated.len() as u64;
    assert_eq!(ids, (first..first + c.complete_episodes).collect::<Vec<_>>());
    assert_eq!(report["episodes"].as_u64().unwrap(), c.complete_episodes);
    let check =
        Command::new(DVNAV).args(["inspect", "--check", "--json"]).arg(&logs).output().unwrap();
    let report: Value = serde_json::from_slice(&check.stdout).unwrap();
    assert!(check.status.success(), "{report}");
    assert_eq!(report["totals"]["unfinished"], 1, "{report}");
    assert_eq!(report["totals"]["finished"].as_u64().unwrap(), rotated.len() as u64);
}

#[test]
fn train_serves_prometheus_metrics_while_running_and_writes_metrics_csv() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("m.toml");
    // Long enough to be scraped while running; the test ends it with SIGTERM (Ctrl-C).
    std::fs::write(
        &config,
        "[run]\nsteps = 10000000\n[sac]\nbatch_size = 16\nlearning_starts = 200\n\
         updates_per_env_step = 0.02\n[actor]\nenvs = 1\nbatch_transitions = 32\n\
         [learner]\npublish_every_updates = 2\n[warmup]\npid_episodes = 2\n\
         [logging]\nevery_nth_episode = 0\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let mut train = KillOnDrop(
        Command::new(DVNAV)
            .args(["train", "--actors", "1", "--metrics-addr", "127.0.0.1:0", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let addr = wait_for("metrics.addr", Duration::from_secs(60), || {
        std::fs::read_to_string(out.join("metrics.addr")).ok()
    });
    let addr = addr.trim();
    // Scrape until training shows: transitions in, an update done, a newer weight version.
    let value = |text: &str, name: &str| -> Option<f64> {
        text.lines().find(|l| l.starts_with(&format!("{name} ")))?.rsplit(' ').next()?.parse().ok()
    };
    let text = wait_for("updates on /metrics", Duration::from_secs(120), || {
        let r = http_get(addr, "/metrics");
        let (head, body) = r.split_once("\r\n\r\n")?;
        assert!(head.starts_with("HTTP/1.1 200"), "{head}");
        (value(body, "dvnav_updates_total")? > 0.0 && value(body, "dvnav_connected_actors")? >= 1.0)
            .then(|| body.to_string())
    });
    for name in [
        "dvnav_env_steps_per_second",
        "dvnav_updates_per_second",
        "dvnav_replay_size",
        "dvnav_connected_actors",
        "dvnav_policy_lag_versions_mean",
        "dvnav_policy_lag_versions_max",
        "dvnav_critic_loss",
        "dvnav_actor_loss",
        "dvnav_alpha",
        "dvnav_transitions_received_total",
        "dvnav_transitions_rejected_total",
    ] {
        assert!(value(&text, name).is_some(), "{name} missing:\n{text}");
    }
    assert!(value(&text, "dvnav_env_steps_total").unwrap() > 0.0);
    assert!(text.contains("dvnav_stage_success_rate{stage=\"0\",room=\"env0\"}"), "{text}");

    // Ctrl-C: the run ends cleanly and metrics.csv has a header and rows.
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(train.0.id() as i32, libc::SIGTERM) };
    let status =
        wait_for("train to stop", Duration::from_secs(120), || train.0.try_wait().unwrap());
    let mut stderr = String::new();
    train.0.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    assert!(status.success(), "{status}: {stderr}");
    assert!(stderr.contains(&format!("metrics at http://{addr}/metrics")), "{stderr}");
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert!(header.contains(&"policy_lag_mean") && header.contains(&"env_steps_per_s"));
    let rows: Vec<&str> = lines.collect();
    assert!(rows.len() >= 2, "{csv}");
    assert!(rows.iter().all(|r| r.split(',').count() == header.len()), "{csv}");
}
