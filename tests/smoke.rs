//! End-to-end smoke test: `dvnav train` with a learner and two actor processes on this
//! machine, a few thousand environment steps, real gRPC over loopback, real SAC updates, real
//! MCAP files. It checks the run's bookkeeping, not learning progress.

use dvnav_eval::episode_log::read_episodes;
use serde_json::Value;
use std::collections::BTreeSet;
use std::process::Command;

const SMOKE_CONFIG: &str = r#"
[run]
steps = 3000
seed = 7

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
every_nth_episode = 2
episodes_per_file = 5
"#;

#[test]
fn learner_and_two_actors_train_and_shut_down_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("smoke.toml");
    std::fs::write(&config, SMOKE_CONFIG).unwrap();
    let out = dir.path().join("run");
    let result = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["train", "--actors", "2", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .env("RUST_LOG", "info")
        .output()
        .expect("dvnav runs");
    let stderr = String::from_utf8_lossy(&result.stderr);
    let logs =
        |name: &str| std::fs::read_to_string(out.join("logs").join(name)).unwrap_or_default();
    assert!(
        result.status.success(),
        "dvnav train failed: {stderr}\nlearner log:\n{}\nactor-0 log:\n{}",
        logs("learner.log"),
        logs("actor-0.log")
    );

    let summary: Value =
        serde_json::from_slice(&std::fs::read(out.join("run_summary.json")).unwrap()).unwrap();
    let n = |v: &Value| v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"));

    // Every transition sent was received or counted as rejected, overall and per actor.
    let (sent, received, rejected) = (
        n(&summary["transitions_sent"]),
        n(&summary["transitions_received"]),
        n(&summary["transitions_rejected"]),
    );
    assert!(received >= 3000, "the budget was reached: {summary}");
    assert_eq!(sent, received + rejected, "{summary}");
    let actors = summary["actors"].as_array().unwrap();
    assert_eq!(actors.len(), 2);
    for a in actors {
        assert_eq!(
            n(&a["transitions_sent"]),
            n(&a["transitions_received"]) + n(&a["transitions_rejected"]),
            "{a}"
        );
        assert!(n(&a["transitions_received"]) > 0, "{a}");
        // Acted with weights newer than the initial version 1.
        assert!(n(&a["max_policy_version"]) > 1, "{a}");
        assert_eq!(a["clean_exit"], true, "{a}");
    }
    assert!(n(&summary["updates"]) > 0);
    assert!(n(&summary["weight_version"]) > 1);
    assert_eq!(summary["losses_finite"], true);
    assert!(summary["critic_loss"].as_f64().unwrap().is_finite());
    assert_eq!(summary["clean_shutdown"], true);
    assert!(std::fs::read_dir(out.join("checkpoints")).unwrap().count() > 0);

    // MCAP files were written and read back, with episodes from both actors.
    let episodes = read_episodes(&out.join("mcap")).unwrap();
    let names: BTreeSet<String> = episodes.iter().map(|e| e.summary.actor.clone()).collect();
    assert_eq!(names, BTreeSet::from(["actor-0".to_string(), "actor-1".to_string()]), "{names:?}");

    // `dvnav inspect --json` sees the same episodes.
    let inspect = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["inspect", "--json"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(inspect.status.success());
    let report: Value = serde_json::from_slice(&inspect.stdout).unwrap();
    assert_eq!(n(&report["episodes"]), episodes.len() as u64);
}

/// `dvnav train --resume DIR`: a stopped run continues from its newest checkpoint with fresh
/// actors, in the same directory, with its counters, curriculum and weight versions going on.
#[test]
fn a_stopped_run_resumes_from_its_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("resume.toml");
    // The smoke config, one actor, no episode logs, a smaller first budget.
    let text = SMOKE_CONFIG
        .replace("steps = 3000", "steps = 1500")
        .replace("every_nth_episode = 2", "every_nth_episode = 0");
    std::fs::write(&config, text).unwrap();
    let out = dir.path().join("run");
    let train = |extra: &[&str]| {
        let r = Command::new(env!("CARGO_BIN_EXE_dvnav"))
            .args(["train", "--actors", "1"])
            .args(extra)
            .env("RUST_LOG", "info")
            .output()
            .expect("dvnav runs");
        let learner_log = std::fs::read_to_string(out.join("logs/learner.log")).unwrap_or_default();
        (r, learner_log)
    };
    let summary = || -> Value {
        serde_json::from_slice(&std::fs::read(out.join("run_summary.json")).unwrap()).unwrap()
    };
    let (first, log) =
        train(&["--config", config.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(first.status.success(), "{}\n{log}", String::from_utf8_lossy(&first.stderr));
    let s1 = summary();

    // Without --resume a used directory is refused.
    let (refused, _) = train(&["--out", out.to_str().unwrap()]);
    assert!(!refused.status.success());

    // The first run overshoots its budget by what was in flight when it said stop (up to
    // `max_steps_ahead` on a fast machine, with few updates done). The checkpoint holds no
    // replay buffer, so the resumed run trains only after `learning_starts` new transitions, and
    // the rate limiter makes it train only beyond `learning_starts + max_steps_ahead` (1,500):
    // 2,000 more steps make the resumed run's updates certain, not a matter of timing.
    let n = |v: &Value| v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"));
    let steps = (n(&s1["transitions_received"]) + 2000).max(3000);
    let steps_flag = steps.to_string();
    let (second, log) = train(&["--resume", out.to_str().unwrap(), "--steps", &steps_flag]);
    assert!(second.status.success(), "{}\n{log}", String::from_utf8_lossy(&second.stderr));
    assert!(log.contains("resumed"), "{log}");
    let s2 = summary();
    assert!(n(&s2["transitions_received"]) >= steps, "{s2}");
    assert!(
        n(&s2["transitions_received"])
            >= n(&s1["transitions_received"]) + n(&s2["transitions_sent"]),
        "counted on from the checkpoint: {s1}\n{s2}"
    );
    assert!(n(&s2["updates"]) > n(&s1["updates"]), "{s1}\n{s2}");
    assert!(n(&s2["weight_version"]) >= n(&s1["weight_version"]), "{s1}\n{s2}");
    assert_eq!(s2["clean_shutdown"], true, "{s2}");
}
