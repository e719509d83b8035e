//! An actor survives its learner dying: a real `dvnav learner` process is killed with SIGKILL
//! mid-run and a new one is started on the same address; the `dvnav actor` process reconnects,
//! registers again, resends what had not been acknowledged, and finishes cleanly when the new
//! learner's budget is reached. Nothing is lost: every batch the actor produced was
//! acknowledged by one learner or the other.

use dvnav_proto::StatusRequest;
use dvnav_proto::learner_client::LearnerClient;
use serde_json::Value;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use support::{INGEST_ONLY_CONFIG, wait_exit, wait_for};

mod support;

fn learner(dir: &Path, config: &Path, addr: &str, steps: u64) -> Child {
    Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["learner", "--listen", addr, "--steps", &steps.to_string(), "--config"])
        .arg(config)
        .arg("--out")
        .arg(dir)
        .arg("--addr-file")
        .arg(dir.join("addr"))
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.with_extension("log")).unwrap())
        .spawn()
        .unwrap()
}

#[test]
fn actor_survives_a_killed_learner_and_loses_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, INGEST_ONLY_CONFIG).unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");

    let first_dir = dir.path().join("first");
    let mut first = learner(&first_dir, &config, &addr, 1_000_000);
    wait_for("the first learner's address file", Duration::from_secs(60), || {
        first_dir.join("addr").exists().then_some(())
    });
    let actor_out = dir.path().join("actor");
    let mut actor = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["actor", "--name", "survivor", "--learner", &format!("http://{addr}"), "--out"])
        .arg(&actor_out)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.path().join("actor.log")).unwrap())
        .spawn()
        .unwrap();

    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let received_by_first = rt.block_on(async {
        let mut c = LearnerClient::connect(format!("http://{addr}")).await.unwrap();
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let s = c.status(StatusRequest {}).await.unwrap().into_inner();
            if s.transitions_received >= 200 {
                return s.transitions_received;
            }
            assert!(Instant::now() < deadline, "the first learner got only {s:?}");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    assert!(received_by_first >= 200);
    first.kill().unwrap(); // SIGKILL: no goodbye, no flush.
    first.wait().unwrap();
    std::thread::sleep(Duration::from_millis(500));

    let second_dir = dir.path().join("second");
    let mut second = learner(&second_dir, &config, &addr, 600);
    let actor_log = || std::fs::read_to_string(dir.path().join("actor.log")).unwrap_or_default();
    let actor_status = wait_exit(&mut actor, "the actor", Duration::from_secs(120), actor_log);
    let log = actor_log();
    assert!(actor_status.success(), "actor failed: {log}");
    let second_log =
        || std::fs::read_to_string(second_dir.with_extension("log")).unwrap_or_default();
    assert!(
        wait_exit(&mut second, "the second learner", Duration::from_secs(60), second_log).success()
    );

    let summary: Value = serde_json::from_slice(
        &std::fs::read(actor_out.join("actors/survivor/summary.json")).unwrap(),
    )
    .unwrap();
    let n = |v: &Value| v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"));
    assert!(n(&summary["link"]["reconnects"]) >= 1, "{summary}");
    assert_eq!(n(&summary["link"]["transitions_undelivered"]), 0, "{summary}");
    // Every batch was acknowledged exactly once, by one learner or the other.
    assert_eq!(n(&summary["transitions_acked"]), n(&summary["transitions_sent"]), "{summary}");
    assert_eq!(summary["stop_reason"], "learner said stop", "{summary}");
    let second_summary: Value =
        serde_json::from_slice(&std::fs::read(second_dir.join("learner_summary.json")).unwrap())
            .unwrap();
    assert!(n(&second_summary["transitions_received"]) >= 600, "{second_summary}");
    assert!(log.contains("reconnected to the learner"), "{log}");
}
