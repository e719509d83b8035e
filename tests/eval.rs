//! `dvnav eval` as a user runs it: on a checkpoint of a tiny, freshly initialized network, the
//! JSON of each scenario carries the field names dashboards read, `--out-dir` and `--out`
//! write what they say, and bad input fails with a clear message.

use candle_core::Device;
use dvnav_config::Config;
use dvnav_eval::episode_log::read_episodes;
use dvnav_learner::sac::SacNetworks;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

/// A small network and short episodes, so the test is quick.
fn tiny_config() -> Config {
    let mut cfg = Config::default();
    cfg.network.conv1_channels = 4;
    cfg.network.conv2_channels = 4;
    cfg.network.scan_features = 16;
    cfg.network.hidden = 16;
    cfg.env.max_steps = 40;
    cfg
}

/// A checkpoint directory: `policy.safetensors` of a fresh policy and its `config.toml`.
fn write_checkpoint(dir: &Path, cfg: &Config) {
    std::fs::create_dir_all(dir).unwrap();
    let nets = SacNetworks::new(cfg, 5, &Device::Cpu).unwrap();
    let bytes = dvnav_nav::nets::varmap_to_safetensors(&nets.actor.vars).unwrap();
    std::fs::write(dir.join("policy.safetensors"), bytes).unwrap();
    std::fs::write(dir.join("config.toml"), cfg.to_toml_string()).unwrap();
}

fn eval(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .arg("eval")
        .args(args)
        .env("CANDLE_NUM_THREADS", "1")
        .output()
        .expect("dvnav runs")
}

fn json(out: &Output) -> Vec<Value> {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)));
    v.as_array().expect("a JSON list").clone()
}

fn share(v: &Value) -> f64 {
    let x = v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"));
    assert!((0.0..=1.0).contains(&x), "{x}");
    x
}

#[test]
fn training_json_has_one_object_per_room_with_the_dashboard_fields() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let rows = json(&eval(&["--checkpoint", ckpt.to_str().unwrap(), "--episodes", "3", "--json"]));
    let rooms: Vec<&str> = rows.iter().map(|r| r["room"].as_str().unwrap()).collect();
    assert_eq!(rooms, ["env0", "env1", "env2", "env3"]);
    for r in &rows {
        assert_eq!(r["episodes"], 3, "{r}");
        let total =
            share(&r["success_rate"]) + share(&r["collision_rate"]) + share(&r["timeout_rate"]);
        assert!((total - 1.0).abs() < 1e-9, "{r}");
        let s = r["mean_score"].as_f64().unwrap();
        assert!((-1.0..=1.0).contains(&s), "{r}");
        // A time when something succeeded, null otherwise.
        assert!(r["mean_time_s"].is_null() == (r["success_rate"].as_f64() == Some(0.0)), "{r}");
        let route = &r["route"];
        assert_eq!(route["goals"], 4, "{r}");
        assert!(route["completed"].is_boolean() && route["legs"].as_array().unwrap().len() == 4);
    }
    // The same seed gives the same report; the file path alone works too.
    let again = json(&eval(&[
        "--checkpoint",
        ckpt.join("policy.safetensors").to_str().unwrap(),
        "--episodes",
        "3",
        "--json",
    ]));
    assert_eq!(rows, again);
}

#[test]
fn gate_json_has_one_object_per_robot_and_out_dir_and_figure_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let out_dir = dir.path().join("eval");
    let png = dir.path().join("gate.png");
    let rows = json(&eval(&[
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--scenario",
        "gate",
        "--radii",
        "0.20:0.30:0.05",
        "--json",
        "--out-dir",
        out_dir.to_str().unwrap(),
        "--out",
        png.to_str().unwrap(),
    ]));
    let radii: Vec<f64> = rows.iter().map(|r| r["radius"].as_f64().unwrap()).collect();
    assert_eq!(radii, [0.2, 0.25, 0.3]);
    for r in &rows {
        assert!(
            ["success", "collision", "timeout"].contains(&r["outcome"].as_str().unwrap()),
            "{r}"
        );
        assert!(["gate", "left", "other"].contains(&r["route"].as_str().unwrap()), "{r}");
        assert!(r["path_length_m"].as_f64().unwrap() >= 0.0, "{r}");
        let t = r["time_s"].as_f64().unwrap();
        assert!(t > 0.0 && t <= 40.0 * 0.2 + 1e-9, "{r}");
        // DVST by default: μ = R / 0.2.
        let mu = r["mu"].as_f64().unwrap();
        assert!((mu - r["radius"].as_f64().unwrap() / 0.2).abs() < 1e-9, "{r}");
    }
    // Every route leg is in the MCAP files and in the CSV.
    let logged = read_episodes(&out_dir).unwrap();
    assert_eq!(logged.len(), 3);
    assert!(logged.iter().all(|e| e.summary.room == "gate" && e.summary.actor == "eval"));
    let csv = std::fs::read_to_string(out_dir.join("episodes.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3, "{csv}");
    assert!(csv.lines().nth(1).unwrap().starts_with("gate,gate,0.2,route,0,0,"), "{csv}");
    let summary: Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary.as_array().unwrap(), &rows);
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
}

/// The SAC_RI baseline's checkpoints: the gate robots are driven with their own radius as the
/// policy's input (no DVST, μ = 1); DVST and the plain agent are refused for them, and the
/// radius input for a checkpoint without it.
#[test]
fn a_radius_input_checkpoint_drives_each_robot_with_its_own_radius() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    let mut cfg = tiny_config();
    cfg.env.radius_input = true;
    cfg.env.radius_range = Some([0.2, 0.5]);
    cfg.curriculum.rooms = vec!["sac_ri".into()];
    write_checkpoint(&ckpt, &cfg);
    let path = ckpt.to_str().unwrap();
    let gate = ["--checkpoint", path, "--scenario", "gate", "--radii", "0.2:0.6:0.2", "--json"];
    let rows = json(&eval(&gate));
    let radii: Vec<f64> = rows.iter().map(|r| r["radius"].as_f64().unwrap()).collect();
    assert_eq!(radii, [0.2, 0.4, 0.6]);
    for r in &rows {
        assert_eq!((r["transfer"].as_str(), r["mu"].as_f64()), (Some("radius"), Some(1.0)), "{r}");
    }
    let explicit = json(&eval(&[&gate[..], &["--transfer", "radius"]].concat()));
    assert_eq!(explicit, rows);
    // The training scenario runs its own room.
    let rows = json(&eval(&["--checkpoint", path, "--episodes", "2", "--json"]));
    assert_eq!(rows.len(), 1);
    assert_eq!((rows[0]["room"].as_str(), rows[0]["episodes"].as_u64()), (Some("sac_ri"), Some(2)));

    let refused = |args: &[&str], words: &str| {
        let o = eval(args);
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(e.contains(words), "{e}");
    };
    for t in ["dvst", "none"] {
        refused(&[&gate[..], &["--transfer", t]].concat(), "takes the robot radius as an input");
    }
    let plain = dir.path().join("plain");
    write_checkpoint(&plain, &tiny_config());
    let plain_gate = ["--checkpoint", plain.to_str().unwrap(), "--scenario", "gate"];
    refused(&[&plain_gate[..], &["--transfer", "radius"]].concat(), "env.radius_input = true");
}

#[test]
fn dynamic_reports_three_sizes_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let rows = json(&eval(&[
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--scenario",
        "dynamic",
        "--transfer",
        "none",
        "--json",
    ]));
    let radii: Vec<f64> = rows.iter().map(|r| r["radius"].as_f64().unwrap()).collect();
    assert_eq!(radii, [0.2, 0.4, 0.6]);
    for r in &rows {
        assert_eq!((r["room"].as_str(), r["episodes"].as_u64()), (Some("dynamic"), Some(1)), "{r}");
        assert_eq!(r["route"]["goals"], 1, "{r}");
    }
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let stderr = |o: &Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let missing = dir.path().join("nope");
    let e = stderr(&eval(&["--checkpoint", missing.to_str().unwrap()]));
    assert!(e.contains("no such file or directory"), "{e}");

    // Weights of one network under the config of another.
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let mut other = tiny_config();
    other.network.hidden = 32;
    std::fs::write(ckpt.join("config.toml"), other.to_toml_string()).unwrap();
    let e = stderr(&eval(&["--checkpoint", ckpt.to_str().unwrap()]));
    assert!(e.contains("not a policy of the network"), "{e}");

    let e = stderr(&eval(&[
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--scenario",
        "gate",
        "--radii",
        "0.5:0.2:0.1",
    ]));
    assert!(e.contains("--radii") && e.contains("START:STOP:STEP"), "{e}");

    // Subgoal options: a lookahead must be a length, and is for planned routes only.
    let ck = ckpt.to_str().unwrap();
    let ckpt_ok = dir.path().join("ok");
    write_checkpoint(&ckpt_ok, &tiny_config());
    let ok = ckpt_ok.to_str().unwrap();
    let e = stderr(&eval(&["--checkpoint", ok, "--tasks", "long", "--lookahead", "0"]));
    assert!(e.contains("--lookahead") && e.contains("above 0"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--lookahead", "1.0"]));
    assert!(e.contains("--lookahead") && e.contains("--subgoals planner"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--tasks", "long", "--planner-margin=-0.1"]));
    assert!(e.contains("--planner-margin") && e.contains("≥ 0"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--planner-margin", "0.1"]));
    assert!(e.contains("--planner-margin") && e.contains("--subgoals planner"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--tasks", "long", "--time-limit-factor=-1"]));
    assert!(e.contains("--time-limit-factor") && e.contains("≥ 0"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--latency-compensation"]));
    assert!(e.contains("--latency-compensation") && e.contains("--latency K"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--safety-horizon=-0.5"]));
    assert!(e.contains("--safety-horizon") && e.contains("at least 0 s"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ok, "--escape-after=-3"]));
    assert!(e.contains("--escape-after") && e.contains("at least 0 s") && e.contains("-3"), "{e}");
    let e = stderr(&eval(&["--checkpoint", ck, "--tasks", "medium"]));
    assert!(e.contains("--tasks") && e.contains("long"), "{e}");
}

/// `--tasks long` plans a path for each task: the rows carry the route figures, and with
/// `--subgoals none` the agent is mapless while the plan is still measured.
#[test]
fn long_tasks_report_planned_routes() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let ck = ckpt.to_str().unwrap();
    for (mode, replans) in [("planner", true), ("none", false)] {
        let out = eval(&[
            "--checkpoint",
            ck,
            "--room",
            "env3",
            "--tasks",
            "long",
            "--subgoals",
            mode,
            "--episodes",
            "6",
            "--json",
        ]);
        let rows = json(&out);
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert_eq!(r["subgoals"], mode, "{r}");
        assert!(r["path_length_m"].as_f64().unwrap() >= 5.0, "{r}");
        assert!(r["blocked_rate"].as_f64().is_some() && r["replans"].as_f64().is_some(), "{r}");
        if !replans {
            assert_eq!(r["replans"], 0.0, "mapless never replans: {r}");
        }
    }
    // A robot with no long task in the room is skipped, said on stderr, and its row has no
    // episodes; the others run.
    let out = eval(&[
        "--checkpoint",
        ck,
        "--room",
        "env3",
        "--tasks",
        "long",
        "--radii",
        "0.2,3.0",
        "--episodes",
        "3",
        "--json",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("skipped, no task for a robot of radius 3")
    );
    let rows = json(&out);
    assert_eq!((rows[0]["episodes"].as_u64(), rows[1]["episodes"].as_u64()), (Some(3), Some(0)));
    assert!(rows[1]["success_rate"].is_null(), "{}", rows[1]);
    // Local tasks carry no route figures.
    let out = eval(&[
        "--checkpoint",
        ck,
        "--room",
        "env3",
        "--tasks",
        "local",
        "--episodes",
        "4",
        "--json",
    ]);
    assert!(json(&out)[0].get("subgoals").is_none());
}

/// The rotation shim follows the checkpoint's `[env.subgoals] rotation_shim` unless a flag says
/// otherwise: `--rotation-shim` on a checkpoint trained without it drives exactly as a checkpoint
/// whose config turns it on, and differently from the config's own setting; the two flags
/// together, or either without planned routes, are refused.
#[test]
fn the_rotation_shim_flags_override_the_checkpoints_setting() {
    let dir = tempfile::tempdir().unwrap();
    let with = |shim: bool| {
        let mut cfg = tiny_config();
        cfg.env.subgoals =
            Some(dvnav_sim::subgoal::SubgoalConfig { rotation_shim: shim, ..Default::default() });
        let ckpt = dir.path().join(format!("shim-{shim}"));
        write_checkpoint(&ckpt, &cfg);
        ckpt.to_str().unwrap().to_string()
    };
    let (off, on) = (with(false), with(true));
    let run = |ck: &str, flag: Option<&str>| {
        let mut args =
            vec!["--checkpoint", ck, "--room", "env3", "--tasks", "long", "--episodes", "8"];
        args.extend(flag);
        args.push("--json");
        json(&eval(&args))[0].clone()
    };
    let forced = run(&off, Some("--rotation-shim"));
    assert_eq!(forced, run(&on, None), "--rotation-shim drives as a config with the shim");
    assert_ne!(forced, run(&off, None), "the flag changes a shim-less checkpoint's episodes");
    assert_eq!(run(&on, Some("--no-rotation-shim")), run(&off, None));

    let stderr = |o: Output| {
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = stderr(eval(&["--checkpoint", &off, "--rotation-shim"]));
    assert!(e.contains("--rotation-shim") && e.contains("--subgoals planner"), "{e}");
    let e = stderr(eval(&[
        "--checkpoint",
        &off,
        "--tasks",
        "long",
        "--rotation-shim",
        "--no-rotation-shim",
    ]));
    assert!(e.contains("--rotation-shim") && e.contains("--no-rotation-shim"), "{e}");
}

/// An agent trained with `env.latency_compensation` is evaluated with it; `--latency-compensation`
/// turns it on for any checkpoint and `--no-latency-compensation` off for any.
#[test]
fn the_latency_compensation_flags_override_the_checkpoints_setting() {
    let dir = tempfile::tempdir().unwrap();
    let with = |on: bool| {
        let mut cfg = tiny_config();
        cfg.env.latency_compensation = on;
        let ckpt = dir.path().join(format!("compensation-{on}"));
        write_checkpoint(&ckpt, &cfg);
        ckpt.to_str().unwrap().to_string()
    };
    let (off, on) = (with(false), with(true));
    let run = |ck: &str, flag: Option<&str>| {
        let mut args =
            vec!["--checkpoint", ck, "--room", "env3", "--episodes", "8", "--latency", "1"];
        args.extend(flag);
        args.push("--json");
        json(&eval(&args))[0].clone()
    };
    let forced = run(&off, Some("--latency-compensation"));
    assert_eq!(forced, run(&on, None), "the flag drives as a config with compensation");
    assert_ne!(forced, run(&off, None), "compensation changes the episodes");
    assert_eq!(run(&on, Some("--no-latency-compensation")), run(&off, None));
    let o = eval(&[
        "--checkpoint",
        &on,
        "--latency",
        "1",
        "--latency-compensation",
        "--no-latency-compensation",
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("--latency-compensation") && e.contains("--no-latency-compensation"), "{e}");
}

/// `dvnav train` evaluates every `learner.eval_every_updates` updates: rows per curriculum room
/// in `eval.csv`, the route legs in `mcap/eval/`, a line per room in the learner's log.
#[test]
fn training_appends_evaluation_rows_every_n_updates() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("train.toml");
    std::fs::write(
        &config,
        "[run]\nsteps = 3000\nseed = 7\n\
         [sac]\nbatch_size = 32\nlearning_starts = 500\nupdates_per_env_step = 0.1\n\
         [learner]\npublish_every_updates = 10\ncheckpoint_every_updates = 1000\n\
         max_steps_ahead = 1000\neval_every_updates = 50\neval_episodes = 2\n\
         [actor]\nenvs = 2\nbatch_transitions = 64\n\
         [warmup]\npid_episodes = 10\n[logging]\nevery_nth_episode = 0\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let r = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["train", "--actors", "1", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .env("RUST_LOG", "info")
        .env("CANDLE_NUM_THREADS", "1")
        .output()
        .expect("dvnav runs");
    let log = std::fs::read_to_string(out.join("logs/learner.log")).unwrap_or_default();
    assert!(r.status.success(), "{}\n{log}", String::from_utf8_lossy(&r.stderr));
    let csv = std::fs::read_to_string(out.join("eval.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        &header[..9],
        [
            "updates",
            "env_steps",
            "room",
            "route_completed",
            "score",
            "success_rate",
            "collision_rate",
            "timeout_rate",
            "mean_time_s"
        ]
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // ~150 updates: evaluations at 50, 100 (and 150 when the run got there), 4 rooms each.
    assert!(rows.len() >= 8 && rows.len().is_multiple_of(4), "{csv}");
    // (An evaluation due while the previous one is still queued is skipped, so the updates
    // are multiples of 50, increasing, one value per group of four rooms.)
    let updates: Vec<u64> = rows.iter().map(|r| r[0].parse().unwrap()).collect();
    for (i, row) in rows.iter().enumerate() {
        assert!(updates[i].is_multiple_of(50) && updates[i] == updates[i - i % 4], "{csv}");
        assert_eq!(row[2], ["env0", "env1", "env2", "env3"][i % 4], "{csv}");
        assert!(row[1].parse::<u64>().unwrap() > 0);
    }
    assert!(updates.windows(5).all(|w| w[4] > w[0]), "{csv}");
    assert!(log.contains("evaluation"), "{log}");
    let logged = read_episodes(&out.join("mcap/eval")).unwrap();
    assert!(logged.len() >= 8, "at least one leg per room and evaluation");
}

#[test]
fn footprint_files_drive_robots_of_any_shape_through_dvst() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("ckpt");
    write_checkpoint(&ckpt, &tiny_config());
    let root = env!("CARGO_MANIFEST_DIR");
    let rect = format!("{root}/footprints/rect-with-cargo.toml");
    let circ = format!("{root}/footprints/circle-0.5.toml");
    let c = ckpt.to_str().unwrap();
    let rows = json(&eval(&[
        "--checkpoint",
        c,
        "--scenario",
        "gate",
        "--footprint",
        &rect,
        "--footprint",
        &circ,
        "--json",
    ]));
    assert_eq!(rows.len(), 2);
    // μ as `dvnav transfer` computes it: (farthest point 0.461 m + margin 0.03 m) / 0.2 m.
    let mu = rows[0]["mu"].as_f64().unwrap();
    assert!((mu - 2.457).abs() < 1e-3, "{mu}");
    assert!((rows[0]["radius"].as_f64().unwrap() - 0.461).abs() < 1e-3, "{}", rows[0]);
    assert!((rows[1]["mu"].as_f64().unwrap() - 2.5).abs() < 1e-9, "{}", rows[1]);
    // A file whose meta robot is not the checkpoint's is refused; so is --footprint with --radii
    // or in the training scenario.
    let cart = format!("{root}/footprints/cart-with-cargo.toml");
    let out = eval(&["--checkpoint", c, "--scenario", "gate", "--footprint", &cart]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("meta robot differs"));
    let out = eval(&["--checkpoint", c, "--footprint", &rect]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("gate and dynamic"));
    let out = eval(&[
        "--checkpoint",
        c,
        "--scenario",
        "gate",
        "--footprint",
        &rect,
        "--radii",
        "0.2:0.3:0.1",
    ]);
    assert!(!out.status.success());
}
