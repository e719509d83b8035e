//! Checkpoints by time (issue 16): a learner killed early in a run, long before its
//! `checkpoint_every_updates`, resumes from a checkpoint written by `checkpoint_every_s`.
//! Real processes: `dvnav learner` and `dvnav actor`; the learner is SIGKILLed once a timed
//! checkpoint exists, and `dvnav learner --resume` on its directory continues from it.

use dvnav_learner::checkpoint::Checkpoint;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use support::{KillOnDrop, wait_exit, wait_for};

mod support;

/// Updates would checkpoint only every 10^6; time every 2 s.
const CONFIG: &str = r#"
[run]
steps = 10000000

[sac]
batch_size = 32
learning_starts = 200
updates_per_env_step = 0.2

[learner]
checkpoint_every_updates = 1000000
checkpoint_every_s = 2.0
eval_every_updates = 0

[actor]
envs = 2
batch_transitions = 32

[warmup]
pid_episodes = 4

[logging]
every_nth_episode = 0
"#;

fn learner(out: &Path, config: &Path, log: &Path, resume: bool) -> KillOnDrop {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dvnav"));
    c.args(["learner", "--listen", "127.0.0.1:0", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .arg("--addr-file")
        .arg(out.join("addr"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap());
    if resume {
        c.arg("--resume");
    }
    KillOnDrop(c.spawn().unwrap())
}

fn actor(url: &str, out: &Path, log: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["actor", "--name", "a", "--learner", url, "--out"])
        .arg(out)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap()
}

#[test]
fn a_learner_killed_early_resumes_from_a_timed_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = dir.path().join("run");
    std::fs::create_dir_all(&out).unwrap();
    let first_log = dir.path().join("first.log");
    let mut first = learner(&out, &config, &first_log, false);
    let addr = wait_for("the learner's address file", Duration::from_secs(60), || {
        std::fs::read_to_string(out.join("addr")).ok().filter(|a| !a.trim().is_empty())
    });
    let mut a = KillOnDrop(actor(
        &format!("http://{}", addr.trim()),
        &dir.path().join("actor"),
        &dir.path().join("actor.log"),
    ));
    let log = |p: &Path| std::fs::read_to_string(p).unwrap_or_default();
    // A checkpoint with training in it, written by time: far below 10^6 updates.
    let saved = wait_for("a timed checkpoint with updates", Duration::from_secs(120), || {
        assert!(first.try_wait().unwrap().is_none(), "the learner exited: {}", log(&first_log));
        Checkpoint::latest(&out).ok().filter(|c| c.meta.updates > 0)
    });
    let killed_at = Instant::now();
    first.kill().unwrap(); // SIGKILL: no final checkpoint.
    first.wait().unwrap();
    a.kill().unwrap();
    a.wait().unwrap();
    // The newest complete checkpoint now (the learner may have written another since).
    let newest = Checkpoint::latest(&out).unwrap();
    assert!(newest.meta.updates >= saved.meta.updates);
    assert!(newest.meta.updates < 1_000_000, "written by time, not by updates");
    let age = std::fs::metadata(newest.dir.join("meta.json"))
        .unwrap()
        .modified()
        .unwrap()
        .elapsed()
        .unwrap()
        .saturating_sub(killed_at.elapsed());
    eprintln!(
        "checkpoint_time: killed with a checkpoint at {} updates, {:.2} s old (every 2 s)",
        newest.meta.updates,
        age.as_secs_f64()
    );
    assert!(age < Duration::from_secs(10), "{age:?}");

    let second_log = dir.path().join("second.log");
    let mut second = learner(&out, &config, &second_log, true);
    let resumed = wait_for("the resumed learner's log line", Duration::from_secs(60), || {
        assert!(second.try_wait().unwrap().is_none(), "it exited: {}", log(&second_log));
        Some(log(&second_log)).filter(|l| l.contains("resumed"))
    });
    assert!(resumed.contains("resumed"), "{resumed}");
    assert!(resumed.contains(&format!("updates={}", newest.meta.updates)), "{resumed}");
    // SAFETY: kill(2) on our own child.
    assert_eq!(unsafe { libc::kill(second.id() as i32, libc::SIGTERM) }, 0);
    let st =
        wait_exit(&mut second, "the resumed learner", Duration::from_secs(60), || log(&second_log));
    assert!(st.success(), "{}", log(&second_log));
}
