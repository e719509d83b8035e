//! The step budget keeps the replay ratio (issue 16): `dvnav train --actors 2 --steps 3000`
//! with the default config. Ingestion may run `learner.max_steps_ahead` (2,000) steps ahead of
//! training, so the budget is reached long before the trainer has caught up; the run must
//! still end with the ⌊(N − learning_starts + 1)·ratio⌋ updates its N steps allow (N: the count
//! when the budget was reached; batches still in flight then go in but owe nothing), and then
//! stop. (Before, it stopped at the budget: 1 update.)

use serde_json::Value;
use std::process::{Command, Stdio};
use std::time::Duration;
use support::wait_exit;

mod support;

#[test]
fn a_short_default_run_does_the_updates_its_steps_allow() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let log_path = dir.path().join("train.log");
    let mut train = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["train", "--actors", "2", "--steps", "3000", "--progress-every-s", "30", "--out"])
        .arg(&out)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log_path).unwrap())
        .spawn()
        .unwrap();
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    let exit = wait_exit(&mut train, "dvnav train", Duration::from_secs(400), log);
    assert!(exit.success(), "{}", log());
    let s: Value =
        serde_json::from_slice(&std::fs::read(out.join("run_summary.json")).unwrap()).unwrap();
    let cfg = dvnav_config::Config::default();
    let received = s["transitions_received"].as_u64().unwrap();
    let updates = s["updates"].as_u64().unwrap();
    let owed = |n: u64| {
        ((n + 1 - cfg.sac.learning_starts) as f64 * cfg.sac.updates_per_env_step).floor() as u64
    };
    eprintln!(
        "budget: {received} steps received, {updates} updates (the ratio allows {} for the \
         budget, {} for all received)",
        owed(3000),
        owed(received)
    );
    assert!(received >= 3000, "{s}");
    // At least what the budget's steps allow, at most what every step received allows.
    assert!((owed(3000)..=owed(received)).contains(&updates), "{s}");
    assert!(updates >= 250, "{s}");
    assert_eq!(s["clean_shutdown"], true, "{s}");
    let learner_log = std::fs::read_to_string(out.join("logs").join("learner.log")).unwrap();
    assert!(learner_log.contains("owed updates done"), "{learner_log}");
}
