//! The curriculum end to end: a real `dvnav train` (learner + 2 actor processes) with an easy
//! stage threshold moves from the first room to the second, records the change, reaches the
//! last room's threshold ("skilled") and, with `--stop-when-skilled`, ends there well inside
//! its step budget.

use serde_json::Value;
use std::process::Command;

/// Goals within reach of almost any motion (tolerance 0.97 m, starts ≥ 1 m away), so the
/// untrained policy succeeds now and then; a window of 4 at 50 % moves the run on. No updates
/// (`learning_starts` beyond the budget): the successes the curriculum counts are the untrained,
/// seeded policy's, not a matter of where a thousand early SAC updates take it. With training,
/// one run in a loaded `make test` collapsed to no success at all and reached the budget.
const EASY: &str = r#"
[run]
steps = 30000
seed = 3

[env]
goal_tolerance = 0.97
min_start_goal_distance = 1.0
max_steps = 60

[sac]
batch_size = 32
learning_starts = 1000000
updates_per_env_step = 0.05

[learner]
publish_every_updates = 10
checkpoint_every_updates = 1000
max_steps_ahead = 1000
eval_every_updates = 0

[actor]
envs = 2
batch_transitions = 64

[warmup]
pid_episodes = 0

[curriculum]
rooms = ["env0", "env1"]
window = 4
threshold = 0.5

[logging]
every_nth_episode = 0
"#;

#[test]
fn an_easy_threshold_moves_the_run_to_the_next_room_and_stops_when_skilled() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("easy.toml");
    std::fs::write(&config, EASY).unwrap();
    let out = dir.path().join("run");
    let status = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["train", "--actors", "2", "--stop-when-skilled", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .env("CANDLE_NUM_THREADS", "1")
        .status()
        .expect("dvnav train runs");
    assert!(status.success(), "dvnav train failed: {status}");
    let s: Value =
        serde_json::from_slice(&std::fs::read(out.join("run_summary.json")).unwrap()).unwrap();
    assert_eq!(s["stage"], 1, "{s:#}");
    let changes = s["stage_changes"].as_array().expect("stage changes");
    assert_eq!(changes.len(), 1, "{changes:?}");
    assert_eq!(changes[0]["room"], "env1");
    let skilled = &s["skilled"];
    assert_eq!(skilled["room"], "env1", "{s:#}");
    let (changed, skilled_at) =
        (changes[0]["env_steps"].as_u64().unwrap(), skilled["env_steps"].as_u64().unwrap());
    assert!(changed <= skilled_at, "skilled at {skilled_at} before the change at {changed}");
    let received = s["transitions_received"].as_u64().unwrap();
    assert!(received < 30_000, "stopped when skilled, not at the budget: {received}");
    // The learner's log says so too.
    let log = std::fs::read_to_string(out.join("logs/learner.log")).unwrap();
    assert!(log.contains("curriculum: next stage") && log.contains("skilled"), "{log}");
}
