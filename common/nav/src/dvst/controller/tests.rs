use super::*;
use crate::dvst::Dvst;
use crate::policy::MetaAgent;
use dvnav_sim::Footprint;
use std::path::Path;
use std::sync::Arc;

const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/meta-r0.2");
const FOOTPRINTS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../footprints");

fn footprint(file: &str) -> String {
    std::fs::read_to_string(Path::new(FOOTPRINTS).join(file)).unwrap()
}

fn model_id() -> ModelId {
    ModelId { name: "test".into(), version: "v-test".into() }
}

/// A meta policy of 3 beams that counts its calls and answers (0.4 m/s, goal angle) when asked.
#[derive(Default)]
struct Counter {
    calls: Arc<AtomicU64>,
}

impl NavPolicy for Counter {
    fn beams(&self) -> usize {
        3
    }
    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        self.calls.fetch_add(1, Ordering::SeqCst);
        Ok((0.4, obs[3 + GOAL_ANGLE] as f64))
    }
    fn velocity_bounds(&self) -> (f64, f64) {
        (0.5, 1.5)
    }
}

fn three_beam_config() -> Config {
    let mut cfg = Config::default();
    cfg.env.lidar.beams = 3;
    cfg
}

fn counter_controller(toml: &str) -> (DvstController, Arc<AtomicU64>) {
    let policy = Counter::default();
    let calls = policy.calls.clone();
    let ctl = DvstController::new(policy, &three_beam_config(), model_id(), toml, "t.toml", None)
        .unwrap();
    (ctl, calls)
}

/// A scan of `beams` ranges that varies with `k`, like a robot moving through a room.
fn scan(beams: usize, k: usize) -> Vec<f32> {
    (0..beams).map(|i| 0.3 + 4.0 * (1.0 + ((i + 7 * k) as f32 * 0.05).sin())).collect()
}

#[test]
fn commands_are_those_of_the_meta_agent_through_dvst() {
    let (agent, cfg) = MetaAgent::load(Path::new(MODEL)).unwrap();
    let text = footprint("paper-medium.toml");
    let ctl =
        DvstController::new(agent, &cfg, model_id(), &text, "paper-medium.toml", None).unwrap();
    assert_eq!(ctl.beams(), 540);
    let info = ctl.info("");
    assert!((info.footprint.mu - 1.85).abs() < 1e-12, "{info:?}");
    assert_eq!(info.footprint.version, 1);
    assert_eq!(info.scan_range, [0.02, 10.0]);
    assert_eq!(info.control_period_s, cfg.env.dt);
    assert_eq!(info.footprint.bounds, info.meta_bounds, "the file gives no bounds of its own");

    // The same agent wrapped by hand, as `dvnav eval` does.
    let (agent, _) = MetaAgent::load(Path::new(MODEL)).unwrap();
    let robot = VariedRobot::from_toml_str(&text, "paper-medium.toml").unwrap();
    let mut direct = Dvst::new(agent, robot).unwrap().with_scan_range(Some([0.02, 10.0])).unwrap();
    let mut moved = 0;
    for k in 0..20 {
        let s = scan(540, k);
        let (d, a, v, w) = (0.5 + 0.4 * k as f64, -1.5 + 0.15 * k as f64, 0.02 * k as f64, 0.1);
        let mut obs = s.clone();
        obs.extend([d as f32, a as f32, v as f32, w as f32]);
        let want = direct.act(&obs).unwrap();
        let input = RobotInput::new(Scan::Meta(&s), d, a, v, w);
        let got = ctl.act(&input).unwrap();
        assert_eq!((got.v, got.omega), want, "call {k}: bit for bit");
        assert_eq!((got.mu, got.footprint_version), (ctl.info("").footprint.mu, 1));
        assert_eq!(got.footprint, "paper medium robot");
        moved += (got.v.abs() > 1e-3 || got.omega.abs() > 1e-3) as usize;
    }
    assert!(moved > 10, "the agent drives: {moved} of 20 commands move the robot");
    assert_eq!(ctl.info("").commands, 20);
}

#[test]
fn malformed_requests_name_the_field_and_never_reach_the_policy() {
    let (ctl, calls) =
        counter_controller("[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.2\n");
    let good = [1.0f32, 2.0, 3.0];
    let ok = RobotInput::new(Scan::Meta(&good), 1.0, 0.5, 0.1, 0.0);
    assert_eq!(ctl.act(&ok).unwrap().v, 0.4);
    assert_eq!(calls.load(Ordering::SeqCst), 1);

    let field = |input: RobotInput| match ctl.act(&input) {
        Err(ControllerError::InvalidArgument { field, reason }) => (field, reason),
        other => panic!("not refused: {other:?}"),
    };
    let (f, why) = field(RobotInput { scan: Scan::Meta(&good[..2]), ..ok });
    assert_eq!(f, "scan");
    assert!(why.contains("2 ranges") && why.contains("3 beams"), "{why}");
    let (f, why) = field(RobotInput { scan: Scan::Meta(&[1.0, 2.0, 3.0, 4.0]), ..ok });
    assert_eq!(f, "scan", "{why}");
    let (f, why) = field(RobotInput { scan: Scan::Meta(&[1.0, f32::NAN, f32::NAN]), ..ok });
    assert_eq!(f, "scan[1]");
    assert!(why.contains("NaN") && why.contains("1 more bad range after it"), "{why}");
    let (f, why) = field(RobotInput { scan: Scan::Meta(&[f32::INFINITY, 1.0, 1.0]), ..ok });
    assert_eq!(f, "scan[0]");
    assert!(why.contains("range_max (10 m)"), "{why}");
    let (f, why) = field(RobotInput { scan: Scan::Meta(&[1.0, 1.0, -0.1]), ..ok });
    assert_eq!(f, "scan[2]");
    assert!(why.contains("negative"), "{why}");
    for (input, name) in [
        (RobotInput { goal_distance: -0.5, ..ok }, "goal_distance"),
        (RobotInput { goal_distance: f64::NAN, ..ok }, "goal_distance"),
        (RobotInput { goal_angle: f64::INFINITY, ..ok }, "goal_angle"),
        (RobotInput { v: f64::NAN, ..ok }, "v"),
        (RobotInput { omega: f64::NEG_INFINITY, ..ok }, "omega"),
    ] {
        let (f, why) = field(input);
        assert_eq!(f, name, "{why}");
        let e = ControllerError::invalid(f, why);
        assert!(e.to_string().starts_with(&format!("`{name}`: ")), "{e}");
    }
    assert_eq!(calls.load(Ordering::SeqCst), 1, "no malformed request reached the policy");
    assert_eq!(ctl.info("").commands, 1);

    // A goal angle outside [−π, π] is the same direction, wrapped.
    let turned = ctl.act(&RobotInput { goal_angle: 0.5 + 4.0 * PI, ..ok }).unwrap();
    assert!((turned.omega - 0.5).abs() < 1e-6, "{turned:?}");
    let turned = ctl.act(&RobotInput { goal_angle: 1.0 - 2.0 * PI, ..ok }).unwrap();
    assert!((turned.omega - 1.0).abs() < 1e-6, "{turned:?}");
}

#[test]
fn wrapped_angles_keep_their_direction() {
    assert_eq!(wrap_angle(0.3), 0.3);
    assert_eq!(wrap_angle(-PI), -PI);
    assert_eq!(wrap_angle(PI), PI);
    assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
    assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12);
    for k in -50..50 {
        let a = k as f64 * 0.7;
        let w = wrap_angle(a);
        assert!((-PI..=PI).contains(&w), "{a} -> {w}");
        assert!((w.sin() - a.sin()).abs() < 1e-9 && (w.cos() - a.cos()).abs() < 1e-9, "{a}");
    }
}

#[test]
fn a_new_footprint_changes_mu_and_a_bad_one_changes_nothing() {
    let (agent, cfg) = MetaAgent::load(Path::new(MODEL)).unwrap();
    let ctl =
        DvstController::new(agent, &cfg, model_id(), &footprint("small-0.15.toml"), "s", None)
            .unwrap();
    let s = scan(540, 3);
    let input = RobotInput::new(Scan::Meta(&s), 2.0, 0.4, 0.1, 0.0);
    let before = ctl.act(&input).unwrap();
    assert!((before.mu - 0.75).abs() < 1e-12 && before.footprint_version == 1, "{before:?}");

    // It picks up cargo: the 0.5 m circle.
    let state = ctl.set_footprint_toml("", &footprint("circle-0.5.toml")).unwrap();
    assert!((state.mu - 2.5).abs() < 1e-12, "{state:?}");
    assert_eq!((state.version, state.scaled), (2, MetaRobot::Circle { radius: 0.5 }));
    assert_eq!(state.robot.footprint.name, "circle r=0.5");
    let after = ctl.act(&input).unwrap();
    assert_eq!((after.mu, after.footprint_version), (state.mu, 2));
    assert_eq!(after.footprint, "circle r=0.5");
    assert_ne!((after.v, after.omega), (before.v, before.omega), "the command follows μ");

    // Bad files: refused with the field and the line, and nothing changes.
    let refused = |text: &str| match ctl.set_footprint_toml("", text) {
        Err(ControllerError::InvalidArgument { field, reason }) => {
            assert_eq!(field, "footprint_toml");
            reason
        }
        other => panic!("not refused: {other:?}"),
    };
    let why =
        refused("name = \"x\"\n[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = -1\n");
    assert!(why.starts_with("line 2: `parts[0]`: "), "{why}");
    let why = refused("[[parts]\n");
    assert!(why.contains("line 1"), "{why}");
    let why = refused("name = \"no parts\"\n");
    assert!(why.contains("parts"), "{why}");
    let why = refused(&(footprint("circle-0.5.toml") + "margin = -0.1\n"));
    assert!(why.contains("`margin`"), "{why}");
    // A meta robot other than the model's.
    let why = refused(
        &(footprint("circle-0.5.toml").replace(
            "name = \"circle r=0.5\"",
            "name = \"x\"\n[meta]\nshape = \"circle\"\nradius = 0.3\n",
        )),
    );
    assert!(why.contains("`meta`") && why.contains("trained as a circle r = 0.200 m"), "{why}");
    let now = ctl.footprint("");
    assert_eq!((now.version, now.robot), (2, state.robot.clone()));
    assert_eq!(ctl.act(&input).unwrap(), after, "the same command as before the refusals");

    // The model's own meta robot, named in the file, is accepted; the file's margin counts.
    let named = footprint("paper-medium.toml")
        .replace("margin = 0.03", "margin = 0.03\n[meta]\nshape = \"circle\"\nradius = 0.2\n");
    let state = ctl.set_footprint_toml("", &named).unwrap();
    assert!((state.mu - 1.85).abs() < 1e-12 && state.version == 3, "{state:?}");
}

#[test]
fn a_forced_margin_holds_for_every_footprint() {
    let text = "[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.3\nmargin = 0.2\n";
    // `margin` after `[[parts]]` belongs to the part, which has no such key: refused.
    assert!(
        DvstController::new(Counter::default(), &three_beam_config(), model_id(), text, "m", None)
            .is_err()
    );
    let text = "margin = 0.2\n[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.3\n";
    let (own, _) = counter_controller(text);
    assert!((own.footprint("").mu - 2.5).abs() < 1e-12, "the file's margin: (0.3 + 0.2) / 0.2");
    let forced = DvstController::new(
        Counter::default(),
        &three_beam_config(),
        model_id(),
        text,
        "m",
        Some(0.1),
    )
    .unwrap();
    assert!((forced.footprint("").mu - 2.0).abs() < 1e-12, "--margin 0.1: (0.3 + 0.1) / 0.2");
    let state = forced.set_footprint_toml("", &text.replace("0.3", "0.5")).unwrap();
    assert!((state.mu - 3.0).abs() < 1e-12 && state.robot.margin == 0.1, "{state:?}");
    assert!(
        DvstController::new(
            Counter::default(),
            &three_beam_config(),
            model_id(),
            text,
            "m",
            Some(-1.0)
        )
        .is_err()
    );
}

#[test]
fn a_model_trained_as_a_rectangle_gives_its_meta_robot() {
    let mut cfg = three_beam_config();
    cfg.env.footprint = Some(Footprint {
        name: "box".into(),
        parts: vec![dvnav_sim::ObstacleSpec::Box {
            center: [0.05, 0.0],
            half_extents: [0.2, 0.15],
            angle: 0.0,
        }],
    });
    let text = "[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.3\n";
    let ctl = DvstController::new(Counter::default(), &cfg, model_id(), text, "r", None).unwrap();
    // The rectangle reaches 0.25 ahead, 0.15 behind, 0.15 to each side: μ = 0.3 / 0.15.
    let info = ctl.info("");
    assert!((info.footprint.mu - 2.0).abs() < 1e-12, "{info:?}");
    assert!(matches!(info.footprint.robot.meta, MetaRobot::Rectangle { .. }));
}

/// Footprint changes racing with commands: every command is computed wholly with one
/// footprint, and says which.
#[test]
fn footprint_changes_are_atomic_for_concurrent_commands() {
    let small = "name = \"a\"\n[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.1\n";
    let large = "name = \"b\"\n[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.4\n";
    let (ctl, _) = counter_controller(small);
    let ctl = Arc::new(ctl);
    let changer = {
        let ctl = ctl.clone();
        std::thread::spawn(move || {
            for k in 0..200 {
                let v = ctl.set_footprint_toml("", if k % 2 == 0 { large } else { small }).unwrap();
                assert_eq!(v.version, k + 2);
            }
        })
    };
    let readers: Vec<_> = (0..3)
        .map(|_| {
            let ctl = ctl.clone();
            std::thread::spawn(move || {
                let s = [1.0f32, 1.0, 1.0];
                let input = RobotInput::new(Scan::Meta(&s), 1.0, 0.0, 0.0, 0.0);
                for _ in 0..500 {
                    let c = ctl.act(&input).unwrap();
                    // Odd versions are the small robot (μ = 0.5), even ones the large (μ = 2).
                    let (mu, name) =
                        if c.footprint_version % 2 == 1 { (0.5, "a") } else { (2.0, "b") };
                    assert!((c.mu - mu).abs() < 1e-12 && c.footprint == name, "{c:?}");
                    // Straight ahead at μ · 0.4 m/s, within v_max = 0.5.
                    assert!((c.v - (mu * 0.4).min(0.5)).abs() < 1e-12, "{c:?}");
                }
            })
        })
        .collect();
    changer.join().unwrap();
    for r in readers {
        r.join().unwrap();
    }
    assert_eq!(ctl.footprint("").version, 201);
    assert_eq!(ctl.info("").commands, 1500);
}

#[test]
fn within_the_scaled_goal_tolerance_the_robot_has_arrived_and_stops() {
    // The 0.5 m circle: μ = 2.5, the meta agent's 0.2 m tolerance becomes 0.5 m.
    let (ctl, calls) = counter_controller(&footprint("circle-0.5.toml"));
    assert!((ctl.footprint("").goal_tolerance - 0.5).abs() < 1e-12);
    let s = [1.0f32; 3];
    let near = RobotInput::new(Scan::Meta(&s), 0.49, 0.3, 0.2, 0.1);
    let c = ctl.act(&near).unwrap();
    assert_eq!((c.v, c.omega, c.arrived), (0.0, 0.0, true), "{c:?}");
    assert_eq!(calls.load(Ordering::SeqCst), 0, "no policy call once arrived");
    let c = ctl.act(&RobotInput { goal_distance: 0.51, ..near }).unwrap();
    assert!(!c.arrived && c.v > 0.0, "{c:?}");
    let c = ctl.act(&RobotInput { goal_distance: 0.0, ..near }).unwrap();
    assert_eq!((c.v, c.omega, c.arrived), (0.0, 0.0, true), "at the goal itself");
}

#[test]
fn each_robot_drives_with_its_own_footprint_and_expires_when_silent() {
    let (ctl, _) = counter_controller(&footprint("small-0.15.toml"));
    let ctl = ctl.with_robot_limits(2, std::time::Duration::from_millis(300)).unwrap();
    let s = [1.0f32; 3];
    let of = |id: &'static str| RobotInput {
        robot_id: id,
        ..RobotInput::new(Scan::Meta(&s), 2.0, 0.0, 0.0, 0.0)
    };
    let big = ctl.set_footprint_toml("big", &footprint("circle-0.5.toml")).unwrap();
    assert!((big.mu - 2.5).abs() < 1e-12 && big.version == 2, "{big:?}");
    let (b, other) = (ctl.act(&of("big")).unwrap(), ctl.act(&of("other")).unwrap());
    assert_eq!((b.footprint_version, b.footprint.as_str()), (2, "circle r=0.5"));
    assert!((other.mu - 0.75).abs() < 1e-12 && other.footprint_version == 1, "the default");
    assert!(b.v > other.v, "the bigger robot drives faster: {b:?} {other:?}");
    assert_eq!(ctl.info("big").footprint.version, 2);
    assert_eq!(ctl.info("nobody").footprint.version, 1);
    assert_eq!((ctl.info("").robots, ctl.info("").max_robots), (2, 2));

    // A third robot while both are active: refused, and nothing of theirs changed.
    match ctl.act(&of("third")) {
        Err(ControllerError::TooManyRobots(full)) => assert_eq!(full.capacity, 2),
        other => panic!("not refused: {other:?}"),
    }
    assert!(ctl.set_footprint_toml("third", &footprint("circle-0.5.toml")).is_err());

    // A robot that expects the footprint it set is refused once another replaced it.
    let expecting = RobotInput { expected_footprint_version: Some(2), ..of("big") };
    assert_eq!(ctl.act(&expecting).unwrap().footprint_version, 2);
    let again = ctl.set_footprint_toml("big", &footprint("circle-0.5.toml")).unwrap();
    assert!(again.version > 2, "a new version, never used before: {again:?}");
    let v = again.version;
    match ctl.act(&expecting) {
        Err(e @ ControllerError::FootprintChanged { expected: 2, .. }) => {
            assert!(e.to_string().contains("SetFootprint"), "{e}");
            assert!(e.to_string().contains(&format!("version {v}")), "{e}");
        }
        other => panic!("not refused: {other:?}"),
    }

    // Silent past the idle time: `big` drives with the default again, and a robot expecting
    // its own footprint learns it is gone rather than being driven as a smaller robot.
    std::thread::sleep(std::time::Duration::from_millis(350));
    assert_eq!(ctl.info("").robots, 0);
    let expecting = RobotInput { expected_footprint_version: Some(v), ..of("big") };
    assert!(matches!(
        ctl.act(&expecting),
        Err(ControllerError::FootprintChanged { current: 1, .. })
    ));
    assert_eq!(ctl.act(&of("big")).unwrap().footprint_version, 1);
    assert!(ctl.with_robot_limits_checked().is_err());
}

impl DvstController {
    fn with_robot_limits_checked(self) -> anyhow::Result<Self> {
        self.with_robot_limits(0, std::time::Duration::from_secs(1))
    }
}

#[test]
fn huge_values_are_refused_as_the_caller_s_not_the_policy_s() {
    let (ctl, calls) = counter_controller(&footprint("small-0.15.toml"));
    let s = [1.0f32; 3];
    let ok = RobotInput::new(Scan::Meta(&s), 2.0, 0.0, 0.0, 0.0);
    let field = |input: RobotInput| match ctl.act(&input) {
        Err(ControllerError::InvalidArgument { field, .. }) => field,
        other => panic!("not refused: {other:?}"),
    };
    assert_eq!(field(RobotInput { goal_distance: 1e39, ..ok }), "goal_distance");
    assert_eq!(field(RobotInput { v: 1e308, ..ok }), "v");
    assert_eq!(field(RobotInput { omega: -1e10, ..ok }), "omega");
    assert_eq!(field(RobotInput { goal_angle: 1e300, ..ok }), "goal_angle");
    for age in [-0.1, f64::NAN, MAX_SCAN_AGE_S + 0.1] {
        assert_eq!(field(RobotInput { scan_age_s: age, ..ok }), "scan_age_s");
    }
    assert_eq!(field(RobotInput { scan: Scan::Meta(&[1.0, 3e38, 1.0]), ..ok }), "scan[1]");
    let long = "r".repeat(MAX_ROBOT_ID + 1);
    assert_eq!(field(RobotInput { robot_id: &long, ..ok }), "robot_id");
    let scan = LaserScan {
        angle_min: -1.0,
        angle_increment: 0.5,
        range_min: 0.1,
        range_max: 1e39,
        ranges: &[1.0; 5],
    };
    assert_eq!(field(RobotInput { scan: Scan::Laser(scan), ..ok }), "laser_scan.range_max");
    assert_eq!(calls.load(Ordering::SeqCst), 0);
    let huge = "#".repeat(MAX_FOOTPRINT_TOML + 1);
    assert!(matches!(
        ctl.set_footprint_toml("", &huge),
        Err(ControllerError::InvalidArgument { field, .. }) if field == "footprint_toml"
    ));
}

#[test]
fn a_laser_scan_drives_the_agent_like_the_same_scan_in_its_own_layout() {
    let (agent, cfg) = MetaAgent::load(Path::new(MODEL)).unwrap();
    let ctl =
        DvstController::new(agent, &cfg, model_id(), &footprint("paper-medium.toml"), "p", None)
            .unwrap();
    // A Hokuyo UTM-30LX: 1,081 readings 0.25° apart, over the meta agent's 270°.
    let meta = scan(540, 4);
    let hokuyo: Vec<f32> = (0..1081).map(|j| meta[(j / 2).min(539)]).collect();
    let laser = LaserScan {
        angle_min: -135f64.to_radians(),
        angle_increment: 0.25f64.to_radians(),
        range_min: 0.02,
        range_max: 30.0,
        ranges: &hokuyo,
    };
    let mut resampled = vec![0.0; 540];
    let layout = BeamLayout::new(540, 270.0);
    let filled = laser_scan::resample(&laser, &Default::default(), layout, &mut resampled).unwrap();
    assert_eq!(filled, 0);
    let by_laser = ctl.act(&RobotInput::new(Scan::Laser(laser), 2.0, 0.4, 0.1, 0.0)).unwrap();
    let by_meta = ctl.act(&RobotInput::new(Scan::Meta(&resampled), 2.0, 0.4, 0.1, 0.0)).unwrap();
    assert_eq!((by_laser.v, by_laser.omega), (by_meta.v, by_meta.omega));
    assert_eq!(by_laser.filled_beams, 0);

    // A 180° sensor: 178 meta beams unseen, reported.
    let front: Vec<f32> = vec![5.0; 721];
    let narrow = LaserScan { angle_min: -PI / 2.0, ranges: &front, ..laser };
    let c = ctl.act(&RobotInput::new(Scan::Laser(narrow), 2.0, 0.4, 0.1, 0.0)).unwrap();
    assert_eq!(c.filled_beams, 178);
    // +inf readings (no return) are accepted in this form.
    let open = vec![f32::INFINITY; 1081];
    let c = ctl.act(&RobotInput::new(
        Scan::Laser(LaserScan { ranges: &open, ..laser }),
        2.0,
        0.0,
        0.0,
        0.0,
    ));
    assert!(c.unwrap().v > 0.0);
}

#[test]
fn warming_up_runs_the_policy_but_counts_no_command_and_no_robot() {
    let (ctl, calls) = counter_controller(&footprint("paper-medium.toml"));
    ctl.warm_up().unwrap();
    assert_eq!(calls.load(Ordering::SeqCst), WARM_UP_PASSES as u64);
    let info = ctl.info("");
    assert_eq!((info.commands, info.robots), (0, 0));
}

/// `scan_age_s`: a scan and goal measured a while ago are carried forward by the commands this
/// robot was sent since. The counting policy steers at the goal's bearing, so the command
/// shows the bearing the controller computed: after 0.25 s of the robot's first command, a
/// goal observed 0.2 s ago is where that command's last 0.2 s of driving puts it; a robot that
/// was sent nothing stood still, so its old observation is its present.
#[test]
fn an_old_scan_and_goal_are_carried_forward_by_the_commands_sent_since() {
    let (ctl, _) = counter_controller(&footprint("small-0.15.toml"));
    let s = [3.0f32; 3];
    let of = |robot_id, scan_age_s| RobotInput {
        robot_id,
        scan_age_s,
        ..RobotInput::new(Scan::Meta(&s), 2.0, 0.5, 0.0, 0.0)
    };
    let first = ctl.act(&of("a", 0.0)).unwrap();
    assert!(first.v > 0.0 && (first.omega - 0.5).abs() < 1e-6, "{first:?}");
    std::thread::sleep(Duration::from_millis(250));
    let carried = ctl.act(&of("a", 0.2)).unwrap();
    let moved = dvnav_sim::latency::motion_since([(first.v, first.omega)], 0.2);
    let (_, bearing) = latency::predict_goal(2.0, 0.5, moved);
    assert!(bearing < 0.45, "the robot turned towards the goal: {bearing}");
    assert!((carried.omega - bearing).abs() < 1e-5, "{carried:?} against {bearing}");
    let fresh = ctl.act(&of("b", 0.2)).unwrap();
    assert!((fresh.omega - 0.5).abs() < 1e-6, "nothing sent, nothing moved: {fresh:?}");
}

/// Every per-robot table follows the robot limits: with room for more robots than the default
/// 256, each of them is driven (its command log included).
#[test]
fn more_robots_than_the_default_are_driven_when_the_limit_allows() {
    let (ctl, _) = counter_controller(&footprint("small-0.15.toml"));
    let ctl = ctl.with_robot_limits(DEFAULT_MAX_ROBOTS + 10, Duration::from_secs(60)).unwrap();
    let s = [1.0f32; 3];
    for n in 0..DEFAULT_MAX_ROBOTS + 10 {
        let id = format!("robot-{n}");
        let input =
            RobotInput { robot_id: &id, ..RobotInput::new(Scan::Meta(&s), 2.0, 0.0, 0.0, 0.0) };
        ctl.act(&input).unwrap_or_else(|e| panic!("robot {n}: {e}"));
    }
}

/// The collision monitor (`with_safety_horizon`): with an obstacle 0.35 m ahead of a 0.2 m
/// robot, the policy's 0.4 m/s becomes what stops the disc (and its 1 % margin) short of it
/// within the horizon; ω is kept, open space is untouched, and a bad horizon is refused.
#[test]
fn the_collision_monitor_slows_a_robot_short_of_an_obstacle_ahead() {
    let circle = "[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.2\n";
    let blocked = [10.0f32, 0.35, 10.0];
    let open = [10.0f32; 3];
    let input = |s| RobotInput::new(Scan::Meta(s), 2.0, 0.0, 0.0, 0.0);
    let (plain, _) = counter_controller(circle);
    assert_eq!(plain.act(&input(&blocked)).unwrap().v, 0.4);
    let (ctl, _) = counter_controller(circle);
    let ctl = ctl.with_safety_horizon(1.0).unwrap();
    let c = ctl.act(&input(&blocked)).unwrap();
    assert!((c.v - 0.148).abs() < 0.005 && c.omega == 0.0, "{c:?}");
    assert_eq!(ctl.act(&input(&open)).unwrap().v, 0.4);
    for bad in [-1.0, f64::NAN] {
        let (ctl, _) = counter_controller(circle);
        let e = ctl.with_safety_horizon(bad).unwrap_err().to_string();
        assert!(e.contains("horizon"), "{e}");
    }
}

/// A meta policy of 3 beams that stands still when asked for its deterministic action and
/// answers (0.3 m/s, ε₀) for a sampled one.
struct FrozenUnlessNoisy;

impl NavPolicy for FrozenUnlessNoisy {
    fn beams(&self) -> usize {
        3
    }
    fn act(&mut self, _obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        Ok((0.0, 0.0))
    }
    fn velocity_bounds(&self) -> (f64, f64) {
        (0.5, 1.5)
    }
    fn act_batch_noisy(
        &mut self,
        obs: &[f32],
        noise: &[Option<[f32; 2]>],
    ) -> anyhow::Result<Vec<(f64, f64)>> {
        assert_eq!(obs.len(), noise.len() * obs_dim(3));
        Ok(noise
            .iter()
            .map(|n| n.map_or((0.0, 0.0), |e| (0.3, (e[0] as f64).clamp(-1.5, 1.5))))
            .collect())
    }
}

/// The stall escape: a robot that makes no progress gets the sampled action after the delay;
/// a goal distance that jumps further than it could drive is a new goal, watched afresh; Info
/// reports the delay, and a bad one is refused.
#[test]
fn the_stall_escape_samples_for_a_robot_that_makes_no_progress() {
    let circle = "[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.2\n";
    let ctl = DvstController::new(
        FrozenUnlessNoisy,
        &three_beam_config(),
        model_id(),
        circle,
        "t.toml",
        None,
    )
    .unwrap()
    .with_stall_escape(0.05)
    .unwrap();
    assert_eq!(ctl.info("r").escape_after_s, 0.05);
    let scan = [10.0f32; 3];
    let act = |d: f64| {
        let mut input = RobotInput::new(Scan::Meta(&scan), d, 0.0, 0.0, 0.0);
        input.robot_id = "r";
        ctl.act(&input).unwrap()
    };
    assert_eq!(act(2.0).v, 0.0, "deterministic while the watch runs");
    std::thread::sleep(Duration::from_millis(70));
    assert_eq!(act(2.0).v, 0.3, "no progress for longer than the delay: sampled");
    // A goal 6 m further at once: a new goal, deterministic again.
    assert_eq!(act(8.0).v, 0.0);
    // Another robot has a watch of its own.
    let mut other = RobotInput::new(Scan::Meta(&scan), 2.0, 0.0, 0.0, 0.0);
    other.robot_id = "other";
    assert_eq!(ctl.act(&other).unwrap().v, 0.0);
    // Off by default.
    let (plain, _) = counter_controller(circle);
    assert_eq!(plain.info("").escape_after_s, 0.0);
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let (ctl, _) = counter_controller(circle);
        let e = ctl.with_stall_escape(bad).unwrap_err().to_string();
        assert!(e.contains("stall escape") && e.contains("at least 0 s"), "{e}");
    }
}
