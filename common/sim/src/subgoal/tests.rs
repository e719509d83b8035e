use super::*;

/// An L: 4 m east, then 3 m north.
fn ell() -> PlannedPath {
    PlannedPath::new(vec![[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])
}

fn close(a: Point, b: Point) -> bool {
    dist(a, b) < 1e-9
}

#[test]
fn the_subgoal_is_the_lookahead_along_the_path_then_the_final_goal() {
    let mut f = PathFollower::new(ell());
    let la = f.update([1.0, 0.2], 1.5);
    assert!(close(la.subgoal, [2.5, 0.0]), "{la:?}");
    assert!((la.off_path_m - 0.2).abs() < 1e-12 && (la.progress_m - 1.0).abs() < 1e-12);
    assert!((la.remaining_m - (6.0 + 0.2)).abs() < 1e-12);
    assert!(!la.final_goal);
    // Round the corner: 3.5 + 1.5 = 5 m along is 1 m up the second leg.
    let la = f.update([3.5, 0.0], 1.5);
    assert!(close(la.subgoal, [4.0, 1.0]), "{la:?}");
    // Within L of the end: the final goal.
    let la = f.update([4.0, 1.8], 1.5);
    assert!(la.final_goal && close(la.subgoal, [4.0, 3.0]));
    // Also when the goal is within L in a straight line though farther along the path.
    let mut f =
        PathFollower::new(PlannedPath::new(vec![[0.0, 0.0], [5.0, 0.0], [5.0, 1.0], [0.0, 1.0]]));
    let la = f.update([0.5, 0.0], 1.5);
    assert!(la.final_goal && close(la.subgoal, [0.0, 1.0]));
}

#[test]
fn a_path_folding_back_past_a_wall_is_not_jumped() {
    // A hairpin: out 6 m east, back 6 m west 0.6 m higher (a thin wall between).
    let path = PlannedPath::new(vec![[0.0, 0.0], [6.0, 0.0], [6.0, 0.6], [0.0, 0.6]]);
    let mut f = PathFollower::new(path);
    // Nearer the return leg, but the projection stays on the first leg.
    let la = f.update([1.0, 0.35], 1.0);
    assert!((la.progress_m - 1.0).abs() < 1e-9, "{la:?}");
    assert!(close(la.subgoal, [2.0, 0.0]));
}

#[test]
fn replans_on_drift_and_on_no_progress() {
    let mut g = RouteGuide::new(SubgoalConfig::default(), 1.0, [4.0, 3.0]);
    g.set_path(ell());
    let at = |x, y| Pose2::new(x, y, 0.0);
    assert_eq!(g.update(at(0.5, 0.0), 0.2).replan, None);
    assert_eq!(g.update(at(1.0, 0.9), 0.2).replan, None);
    assert_eq!(g.update(at(1.0, 1.1), 0.2).replan, Some(Replan::Drift));
    // A bigger robot (μ = 2) may stray twice as far.
    let mut big = RouteGuide::new(SubgoalConfig::default(), 2.0, [4.0, 3.0]);
    big.set_path(ell());
    assert_eq!(big.update(at(1.0, 1.9), 0.2).replan, None);
    assert!((big.lookahead_m() - 3.0).abs() < 1e-12);
    // Standing still (or creeping) for stall_s asks for a plan; moving on resets the watch.
    let mut g = RouteGuide::new(SubgoalConfig::default(), 1.0, [4.0, 3.0]);
    g.set_path(ell());
    let mut asked = None;
    for k in 0..60 {
        let x = 1.0 + 0.001 * k as f64;
        if let Some(r) = g.update(at(x, 0.0), 0.2).replan {
            asked = Some((k, r));
            break;
        }
    }
    // Progress at k = 0 (1 m along), then none: 50 cycles of 0.2 s make 10 s.
    assert_eq!(asked, Some((50, Replan::Stall)));
    g.set_path(ell());
    assert_eq!(g.update(at(1.0, 0.0), 0.2).replan, None);
}

#[test]
fn the_rotation_shim_turns_towards_the_subgoal_then_hands_over() {
    let mut g = RouteGuide::new(SubgoalConfig::default(), 1.0, [4.0, 3.0]);
    g.set_path(ell());
    // Facing nearly west: the subgoal is behind; turn at full speed the shorter way.
    let mut pose = Pose2::new(0.0, 0.0, 3.0);
    g.update(pose, 0.0);
    let (v, w) = g.shim_command(pose, 1.5).unwrap();
    assert_eq!(v, 0.0);
    assert_eq!(w, -1.5, "yaw 3.0 faces a little north of west: east is 3.0 rad to the right");
    pose.yaw = -2.0;
    g.update(pose, 0.2);
    assert_eq!(g.shim_command(pose, 1.5), Some((0.0, 1.5)));
    pose.yaw = -0.5;
    g.update(pose, 0.2);
    assert_eq!(g.shim_command(pose, 1.5), None, "within 45°: the agent drives");
    // Once handed over it stays off until the next plan, even if the robot turns away.
    pose.yaw = 2.0;
    g.update(pose, 0.2);
    assert_eq!(g.shim_command(pose, 1.5), None);
    g.set_path(ell());
    g.update(pose, 0.0);
    assert!(g.shim_command(pose, 1.5).is_some());
    // Off by the key.
    let cfg = SubgoalConfig { rotation_shim: false, ..SubgoalConfig::default() };
    let mut g = RouteGuide::new(cfg, 1.0, [4.0, 3.0]);
    g.set_path(ell());
    g.update(pose, 0.0);
    assert_eq!(g.shim_command(pose, 1.5), None);
}

#[test]
fn without_a_path_the_subgoal_is_the_goal() {
    let mut g = RouteGuide::new(SubgoalConfig::default(), 1.0, [4.0, 3.0]);
    let out = g.update(Pose2::new(0.0, 0.0, 0.0), 0.2);
    assert_eq!(out, Guidance { subgoal: [4.0, 3.0], remaining_m: 5.0, replan: None });
    g.set_path(ell());
    g.clear_path();
    assert_eq!(g.update(Pose2::new(0.0, 0.0, 0.0), 0.2).subgoal, [4.0, 3.0]);
}

#[test]
fn bad_keys_are_named() {
    let bad = SubgoalConfig { lookahead_m: 0.0, ..SubgoalConfig::default() };
    assert_eq!(bad.check().unwrap_err().0, "env.subgoals.lookahead_m");
    let bad = SubgoalConfig { shim_angle_deg: 180.0, ..SubgoalConfig::default() };
    assert_eq!(bad.check().unwrap_err().0, "env.subgoals.shim_angle_deg");
    let mut bad = SubgoalConfig::default();
    bad.planner.clearance_weight = f64::NAN;
    assert_eq!(bad.check().unwrap_err().0, "env.subgoals.planner.clearance_weight");
    assert!(SubgoalConfig::default().check().is_ok());
}

#[test]
fn a_subgoal_past_a_corner_is_drawn_back_into_sight() {
    let mut f = PathFollower::new(ell());
    // A wall hides everything with x > 3.9 and y > 0.3 from the robot.
    let hidden = |q: Point| q[0] > 3.9 && q[1] > 0.3;
    let visible = move |a: Point, b: Point| {
        (0..=100).all(|k| {
            let t = k as f64 / 100.0;
            !hidden([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])])
        })
    };
    let la = f.update_seeing([3.0, -0.5], 1.5, &visible);
    // The pure lookahead (4.0, 0.5) is behind the corner; the subgoal stays on the path, in
    // sight, short of it.
    assert!(visible([3.0, -0.5], la.subgoal), "{la:?}");
    assert!(la.subgoal[0] > 3.9 && la.subgoal[1] <= 0.3 && !la.final_goal, "{la:?}");
}
