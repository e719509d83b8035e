//! The step budget keeps the replay ratio (issue 16): `dvnav train --actors 2 --steps 3000`
//! with the default config. Ingestion may run `learner.max_steps_ahead` (2,000) steps ahead of
//! training, so the budget is reached long before the trainer has caught up; the run must
//! still end with the ⌊(N − learning_starts + 1)·ratio⌋ updates its N steps allow (N: the count
//! when the budget was reached; batches still in flight then go in but owe nothing), and then
//! stop. (Before, it stopped at the budget: 1 update.)

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;
use support::wait_exit;

mod support;

/// `dvnav train FLAGS --PATH_FLAG PATH…` to its end, its stderr (the progress and summary) into
/// `log`; fails the test unless it exits successfully within `limit`.
fn train_to_end(flags: &[&str], paths: &[(&str, &Path)], log: &Path, limit: Duration) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_dvnav"));
    cmd.arg("train").args(flags);
    for (flag, path) in paths {
        cmd.arg(flag).arg(path);
    }
    let mut train = cmd
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap();
    let read_log = || std::fs::read_to_string(log).unwrap_or_default();
    let exit = wait_exit(&mut train, "dvnav train", limit, read_log);
    assert!(exit.success(), "{}", read_log());
}

#[test]
fn a_short_default_run_does_the_updates_its_steps_allow() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let log_path = dir.path().join("train.log");
    let flags = ["--actors", "2", "--steps", "3000", "--progress-every-s", "30"];
    train_to_end(&flags, &[("--out", &out)], &log_path, Duration::from_secs(400));
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

/// `--max-wall-s` (run.max_wall_s): a run whose step budget is far away stops when its time is
/// spent, as Ctrl-C would stop it: a clean shutdown with a final checkpoint and the summaries.
#[test]
fn a_run_stops_cleanly_when_its_wall_clock_budget_is_spent() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let log_path = dir.path().join("train.log");
    let started = std::time::Instant::now();
    let flags = ["--actors", "1", "--steps", "100000000", "--max-wall-s", "6"];
    train_to_end(&flags, &[("--out", &out)], &log_path, Duration::from_secs(300));
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(started.elapsed() >= Duration::from_secs(6), "stopped before its time: {}", log());
    let s: Value =
        serde_json::from_slice(&std::fs::read(out.join("run_summary.json")).unwrap()).unwrap();
    assert_eq!(s["clean_shutdown"], true, "{s}");
    assert!(s["transitions_received"].as_u64().unwrap() < 100_000_000, "{s}");
    let learner_log = std::fs::read_to_string(out.join("logs").join("learner.log")).unwrap();
    assert!(learner_log.contains("run.max_wall_s reached"), "{learner_log}");
    // A run that trained at all ends with a checkpoint of its last update.
    if s["updates"].as_u64().unwrap() > 0 {
        assert!(dvnav_learner::checkpoint::latest(&out).unwrap().is_some(), "{s}");
    }
    let cfg = dvnav_config::Config::load(&out.join("config.toml")).unwrap();
    assert_eq!(cfg.run.max_wall_s, 6.0, "the run's config records the budget");
}

/// `--seeds 2`, each seed stopped by its wall-clock budget: every seed keeps its best agent by
/// its own training-time evaluation, and the higher-scoring one becomes OUT/best, named in
/// seeds_summary.json.
#[test]
fn of_several_seeds_the_best_agent_by_their_evaluation_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("runs");
    let config = dir.path().join("quick-eval.toml");
    std::fs::write(
        &config,
        "[sac]\nlearning_starts = 200\n[learner]\neval_every_updates = 20\neval_episodes = 2\n",
    )
    .unwrap();
    let log_path = dir.path().join("train.log");
    let flags = ["--actors", "1", "--seeds", "2", "--steps", "100000000", "--max-wall-s", "8"];
    let paths = [("--config", config.as_path()), ("--out", out.as_path())];
    train_to_end(&flags, &paths, &log_path, Duration::from_secs(400));
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    let summary: Value =
        serde_json::from_slice(&std::fs::read(out.join("seeds_summary.json")).unwrap()).unwrap();
    let best = &summary["best"];
    let seed = best["seed"].as_u64().unwrap_or_else(|| panic!("no best seed: {summary}"));
    let score = |s: u64| -> Option<f64> {
        let path = out.join(format!("seed-{s}")).join("best").join("best.json");
        let record: Value = serde_json::from_slice(&std::fs::read(path).ok()?).ok()?;
        record["score"].as_f64()
    };
    let other = if seed == 1 { 2 } else { 1 };
    assert_eq!(best["score"].as_f64(), score(seed), "{summary}");
    assert!(score(other).is_none_or(|s| s <= score(seed).unwrap()), "{summary}");
    let kept = std::fs::read(out.join("best").join("policy.safetensors")).unwrap();
    let from = out.join(format!("seed-{seed}")).join("best").join("policy.safetensors");
    assert_eq!(kept, std::fs::read(from).unwrap(), "OUT/best is the best seed's agent");
    assert!(log().contains(&format!("best agent: seed {seed}")), "{}", log());
}
