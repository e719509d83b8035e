//! The shipped agents do on a fresh checkout what docs/results.md says they do.
//! `models/meta-r0.2`, the default agent (the generalist of issue 29, experiment g29): the
//! curriculum rooms (random episodes and every evaluation route), the gate test through DVST, the
//! dynamic scenario, samples of the held-out suite, long routes with a planner and a sensor ahead
//! of the axle. `models/paper-r0.2`, the paper-faithful agent it replaced: the paper's gate test
//! and its comparison with the SAC_RI baseline. The floors are the documented figures less a
//! margin for evaluation seeds; a regression in the simulator, the networks, DVST or the
//! evaluator that costs real performance fails here.

use serde_json::Value;
use std::process::Command;

const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/meta-r0.2");
const PAPER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/paper-r0.2");
const SAC_RI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/sac-ri");

fn eval(args: &[&str]) -> Vec<Value> {
    eval_model(MODEL, args)
}

fn eval_model(model: &str, args: &[&str]) -> Vec<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["eval", "--checkpoint", model, "--json"])
        .args(args)
        .env("CANDLE_NUM_THREADS", "1")
        .output()
        .expect("dvnav runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    v.as_array().expect("a list").clone()
}

/// Local tasks in a building, as the held-out suite draws them: 2-5 m, path ≤ 1.5× the line.
const LOCAL_TASKS: &[&str] =
    &["--min-distance", "2", "--max-distance", "5", "--max-path-ratio", "1.5"];

fn by_key<'a>(rows: &'a [Value], key: &str, value: &str) -> &'a Value {
    rows.iter().find(|r| r[key].to_string().trim_matches('"') == value).unwrap_or_else(|| {
        panic!("no row with {key} = {value}: {rows:?}");
    })
}

/// The paper's rooms, Env_0 to Env_3, which the shipped agent met only in its last stages (its
/// curriculum is generated rooms): measured 100 % in each over these 100 episodes.
#[test]
fn navigates_the_papers_rooms() {
    let rooms = ["env0", "env1", "env2", "env3"];
    let mut args = vec!["--episodes", "100", "--seed", "7"];
    for room in &rooms {
        args.extend(["--room", room]);
    }
    let rows = eval(&args);
    assert_eq!(rows.len(), 4);
    for r in &rows {
        let success = r["success_rate"].as_f64().unwrap();
        assert!(success >= 0.97, "{}: success {success}", r["room"]);
    }
    let env3 = by_key(&rows, "room", "env3")["success_rate"].as_f64().unwrap();
    assert!(env3 >= 0.99, "Env_3: {env3} (the issue's kept check: 99 %)");
}

/// The paper agent on its own curriculum (`--scenario training` reads the checkpoint's): random
/// episodes and every evaluation route of Env_0 to Env_3.
#[test]
fn the_paper_agent_navigates_every_curriculum_room_and_passes_the_gate_test() {
    let rows = eval_model(PAPER, &["--episodes", "100", "--seed", "7"]);
    assert_eq!(rows.len(), 4);
    for r in &rows {
        let success = r["success_rate"].as_f64().unwrap();
        assert!(success >= 0.95, "{}: success {success}", r["room"]);
        assert_eq!(
            r["route"]["completed"],
            Value::Bool(true),
            "{}: route {}",
            r["room"],
            r["route"]
        );
    }
    assert!(by_key(&rows, "room", "env3")["success_rate"].as_f64().unwrap() >= 0.95);
    assert_passes_the_gate_test(&eval_model(PAPER, &["--scenario", "gate"]));
}

/// The paper's gate test, passed: every one of the twelve robots arrives, the small ones
/// through the gate on a near-straight path, all the others round the wall's left end.
fn assert_passes_the_gate_test(rows: &[Value]) {
    assert_eq!(rows.len(), 12, "the paper's twelve robots");
    for row in rows {
        let r = row["radius"].as_f64().unwrap();
        assert_eq!(row["outcome"], "success", "R = {r}: {row}");
        let expected = if r <= 0.25 { "gate" } else { "left" };
        assert_eq!(row["route"], expected, "R = {r}: {row}");
        if r <= 0.25 {
            assert!(row["path_length_m"].as_f64().unwrap() < 3.2, "{row}");
        }
    }
}

#[test]
fn gate_test_through_dvst() {
    assert_passes_the_gate_test(&eval(&["--scenario", "gate"]));
    // Without DVST the meta agent drives only its own size home.
    let plain = eval(&["--scenario", "gate", "--transfer", "none"]);
    let reached = plain.iter().filter(|r| r["outcome"] == "success").count();
    assert!(reached <= 2, "{reached} without DVST: {plain:?}");
}

#[test]
fn robots_of_other_shapes_arrive_through_dvst() {
    let root = env!("CARGO_MANIFEST_DIR");
    let files: Vec<String> = ["rect-with-cargo", "circle-with-cargo", "paper-medium"]
        .iter()
        .map(|f| format!("{root}/footprints/{f}.toml"))
        .collect();
    let mut args = vec!["--scenario", "gate"];
    for f in &files {
        args.extend(["--footprint", f.as_str()]);
    }
    let rows = eval(&args);
    assert_eq!(rows.len(), 3);
    for row in &rows {
        assert_eq!(row["outcome"], "success", "{row}");
    }
}

#[test]
fn dynamic_obstacles_for_three_sizes() {
    let rows = eval(&["--scenario", "dynamic"]);
    assert_eq!(rows.len(), 3);
    for r in &rows {
        assert_eq!(r["success_rate"].as_f64(), Some(1.0), "{r}");
    }
}

/// The paper's comparison: the radius-as-input baseline drives each robot with its own radius
/// and fails where DVST, on the paper agent trained on the same curriculum, does not
/// (docs/results.md).
#[test]
fn the_sac_ri_baseline_fails_beyond_its_training_range_and_detours_small_robots() {
    let rows = eval_model(SAC_RI, &["--scenario", "gate"]);
    assert_eq!(rows.len(), 12);
    for row in &rows {
        let r = row["radius"].as_f64().unwrap();
        assert_eq!(row["transfer"], "radius", "{row}");
        if r >= 0.5 {
            assert_ne!(row["outcome"], "success", "R = {r} beyond the training range: {row}");
        }
    }
    let small = by_key(&rows, "radius", "0.2");
    assert_eq!(
        (small["outcome"].as_str(), small["route"].as_str()),
        (Some("success"), Some("left"))
    );
    let dvst = eval_model(PAPER, &["--scenario", "gate"]);
    let reached = |rows: &[Value]| rows.iter().filter(|r| r["outcome"] == "success").count();
    assert!(
        reached(&dvst) > reached(&rows),
        "DVST {} vs SAC_RI {}",
        reached(&dvst),
        reached(&rows)
    );
}

/// A small sample of the held-out suite of docs/results.md (§ Rooms anywhere): generated
/// rooms at held-out seeds and a real building's map, as the shipped agent drives them.
#[test]
fn held_out_sample_as_documented() {
    // The paper's layout at held-out seeds: 40 of 40 measured, no reversal (the paper agent:
    // 40 of 40, 0.9-3.1 %).
    let rows = eval(&[
        "--scenario",
        "generated",
        "--kind",
        "paper",
        "--seeds",
        "9000:9004",
        "--radii",
        "0.2",
        "--episodes",
        "10",
    ]);
    assert_eq!(rows.len(), 4);
    let ok: f64 = rows.iter().map(|r| r["success_rate"].as_f64().unwrap()).sum::<f64>() / 4.0;
    assert!(ok >= 0.9, "{rows:?}");
    for r in &rows {
        assert!(r["reversal_rate"].as_f64().unwrap() < 0.08, "{r}");
    }
    // Issue 29's command, any task: measured 87 / 81 / 56 % at R = 0.2 / 0.4 / 0.6 m (the
    // paper agent: 89 / 77 / 56 %).
    let root = env!("CARGO_MANIFEST_DIR");
    let rows = eval(&["--room", "generated:corridors:9001", "--radii", "0.2:0.6:0.2"]);
    assert_eq!(rows.len(), 3, "one row per radius: {rows:?}");
    let floors = [0.79, 0.67, 0.46];
    for (r, floor) in rows.iter().zip(floors) {
        assert!(r["success_rate"].as_f64().unwrap() >= floor, "{r}");
    }
    // Willow Garage, local tasks, the meta robot: measured 40 of 40 (the suite: 99.2 % over
    // five maps).
    let willow = format!("{root}/maps/willow.yaml");
    let rows = eval(&[&["--room", &willow, "--episodes", "40"], LOCAL_TASKS].concat());
    assert!(rows[0]["success_rate"].as_f64().unwrap() >= 0.9, "{}", rows[0]);
}

/// docs/results.md, "Through a whole building (issue 28)": long tasks in Willow Garage (goals
/// 5-10 m away, any route the planner finds) followed along the planner's path, against the
/// mapless agent, each task's time limit scaled by its route, the rotation shim on as the
/// shipped agent's config has it since 2026-12-07 (off, as it was trained: 100 and 100 % with
/// the planner, 72.5 and 82.5 % mapless; the paper agent, with its shim: 100 and 97.5 %, 70.0
/// and 62.5 %).
#[test]
fn long_tasks_in_willow_with_subgoals_as_documented() {
    let willow = format!("{}/maps/willow.yaml", env!("CARGO_MANIFEST_DIR"));
    let run = |mode: &str| {
        let args = ["--room", &willow, "--tasks", "long", "--subgoals", mode];
        eval(&[&args[..], &["--radii", "0.2:0.4:0.2", "--episodes", "40"]].concat())
    };
    let planner = run("planner");
    let mapless = run("none");
    assert_eq!((planner.len(), mapless.len()), (2, 2));
    let rate = |rows: &[Value]| {
        rows.iter().map(|r| r["success_rate"].as_f64().unwrap()).sum::<f64>() / rows.len() as f64
    };
    for r in &planner {
        assert!(r["success_rate"].as_f64().unwrap() >= 0.9, "{r}");
        assert!(r["blocked_rate"].as_f64().unwrap() <= 0.05, "{r}");
    }
    assert!(rate(&planner) > rate(&mapless), "{planner:?} vs {mapless:?}");
}

/// docs/results.md, "Latency compensation": with one control cycle of latency the shipped agent
/// collides in tight places (the paper layout at R = 0.4 on tuning rooms, long tasks with the
/// planner: these 69 give 92.8 % success, 7.2 % collisions), and carried forward by the
/// commands sent since it drives as without latency (100 %, no collision).
#[test]
fn latency_compensation_takes_the_collisions_of_a_delayed_scan_away() {
    let run = |extra: &[&str]| {
        let args = [
            "--scenario",
            "generated",
            "--kind",
            "paper",
            "--seeds",
            "8000:8010",
            "--radii",
            "0.4",
            "--episodes",
            "8",
            "--tasks",
            "long",
            "--latency",
            "1",
        ];
        let rows = eval(&[&args[..], extra].concat());
        let (mut n, mut ok, mut hit) = (0.0, 0.0, 0.0);
        for r in rows.iter().filter(|r| r["episodes"].as_u64().unwrap_or(0) > 0) {
            let e = r["episodes"].as_f64().unwrap();
            n += e;
            ok += e * r["success_rate"].as_f64().unwrap();
            hit += e * r["collision_rate"].as_f64().unwrap();
        }
        (ok / n, hit / n)
    };
    let (late_ok, late_hit) = run(&[]);
    let (ok, hit) = run(&["--latency-compensation"]);
    assert!(late_hit >= 0.03, "latency should cost collisions here: {late_ok} {late_hit}");
    assert!(ok >= 0.97 && hit <= 0.015, "compensated: {ok} success, {hit} collisions");
}

/// docs/results.md, "The stall escape": on the tuning rooms' dense clutter at R = 0.4 the
/// shipped agent stalls in 8.5 % of its local tasks (88.0 % success); with `--escape-after 3`
/// it was measured at 92.0 % with 4.0 % timeouts, and ω reversals no higher (2.6 → 2.3 %).
#[test]
fn the_stall_escape_frees_robots_that_stall_in_clutter() {
    let run = |extra: &[&str]| {
        let args = [
            "--scenario",
            "generated",
            "--kind",
            "clutter",
            "--seeds",
            "8000:8010",
            "--radii",
            "0.4",
            "--episodes",
            "20",
            "--tasks",
            "local",
        ];
        let rows = eval(&[&args[..], extra].concat());
        let (mut n, mut ok, mut late, mut rev) = (0.0, 0.0, 0.0, 0.0);
        for r in rows.iter().filter(|r| r["episodes"].as_u64().unwrap_or(0) > 0) {
            let e = r["episodes"].as_f64().unwrap();
            n += e;
            ok += e * r["success_rate"].as_f64().unwrap();
            late += e * r["timeout_rate"].as_f64().unwrap();
            rev += e * r["reversal_rate"].as_f64().unwrap();
        }
        (ok / n, late / n, rev / n)
    };
    let (ok, late, rev) = run(&[]);
    let (esc_ok, esc_late, esc_rev) = run(&["--escape-after", "3"]);
    assert!(late >= 0.05, "the deterministic agent should stall here: {ok} {late}");
    assert!(esc_ok >= ok + 0.02 && esc_late <= late - 0.03, "{ok} {late} -> {esc_ok} {esc_late}");
    assert!(esc_rev <= rev + 0.01, "reversals {rev} -> {esc_rev}");
}

/// docs/results.md, "Real sensors (issue 27)": through a Hokuyo UST-10LX mounted 0.1 m ahead of
/// the axle, the shipped agent does on Willow Garage's local tasks as with its own scan
/// (measured 40 of 40 at R = 0.2 and 0.4; the paper agent 95 / 92 / 92 % at R = 0.2 / 0.3 / 0.4
/// over 100 episodes, 53-70 % when the beams the sensor does not see read 0 m).
#[test]
fn through_a_sensor_ahead_of_the_axle_as_documented() {
    let root = env!("CARGO_MANIFEST_DIR");
    let willow = format!("{root}/maps/willow.yaml");
    let sensor = format!("{root}/sensors/hokuyo-ust10lx-front.toml");
    let args: &[&str] =
        &["--room", &willow, "--sensor", &sensor, "--radii", "0.2:0.4:0.2", "--episodes", "40"];
    let rows = eval(&[args, LOCAL_TASKS].concat());
    assert_eq!(rows.len(), 2, "{rows:?}");
    for r in &rows {
        assert!(r["success_rate"].as_f64().unwrap() >= 0.9, "{r}");
    }
}

/// A sample of the held-out maps (local tasks, another seed than the suite's) at the shipped
/// agent's documented level: the full tables are `make heldout`.
#[test]
fn reaches_local_goals_in_the_held_out_maps() {
    let root = env!("CARGO_MANIFEST_DIR");
    let maps = ["aws_bookstore", "aws_small_house", "nav2_depot", "nav2_warehouse", "willow"];
    let mut args: Vec<String> = Vec::new();
    for m in maps {
        args.extend(["--room".into(), format!("{root}/maps/{m}.yaml")]);
    }
    for a in ["--radii", "0.2,0.4", "--episodes", "20", "--seed", "11"].iter().chain(LOCAL_TASKS) {
        args.push((*a).into());
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let rows = eval(&args);
    // Measured: 100 % at R = 0.2 and 96 % at R = 0.4 over these 100 episodes each (the paper
    // agent: 100 and 94 %); floors a few episodes below.
    for (radius, floor) in [(0.2, 0.97), (0.4, 0.92)] {
        let of: Vec<&Value> =
            rows.iter().filter(|r| (r["radius"].as_f64().unwrap() - radius).abs() < 1e-9).collect();
        let episodes: f64 = of.iter().map(|r| r["episodes"].as_f64().unwrap()).sum();
        let reached: f64 = of
            .iter()
            .map(|r| r["success_rate"].as_f64().unwrap() * r["episodes"].as_f64().unwrap())
            .sum();
        assert_eq!(episodes, 100.0, "{of:?}");
        assert!(reached / episodes >= floor, "R = {radius}: {} < {floor}", reached / episodes);
    }
}
