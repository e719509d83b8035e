use super::*;
use crate::{EnvConfig, Lidar, NavEnv, Room};
use rand_pcg::Pcg64;

#[test]
fn the_motion_since_is_the_unicycles_arcs() {
    // 0.5 m/s for two periods of 0.2 s: 0.2 m straight ahead.
    let p = motion_since([(0.5, 0.0), (0.5, 0.0)], 0.2);
    assert!((p.x - 0.2).abs() < 1e-12 && p.y.abs() < 1e-12 && p.yaw.abs() < 1e-12, "{p:?}");
    // Turning in place: the heading only, wrapped.
    let p = motion_since([(0.0, 1.5); 12], 0.2);
    assert!(p.x.abs() < 1e-12 && p.y.abs() < 1e-12, "{p:?}");
    assert!((p.yaw - wrap_angle(3.6)).abs() < 1e-12, "{p:?}");
    // A quarter circle of radius 1 m: (1, 1), facing left.
    let quarter = std::f64::consts::FRAC_PI_2;
    let p = motion_since([(1.0, 1.0)], quarter);
    assert!((p.x - 1.0).abs() < 1e-9 && (p.y - 1.0).abs() < 1e-9, "{p:?}");
    assert!((p.yaw - quarter).abs() < 1e-12);
    assert_eq!(motion_since([], 0.2), Pose2::default());
}

#[test]
fn a_goal_is_seen_from_where_the_robot_is_now() {
    // 2 m ahead; the robot drove 0.5 m ahead: 1.5 m ahead.
    let (d, b) = predict_goal(2.0, 0.0, Pose2::new(0.5, 0.0, 0.0));
    assert!((d - 1.5).abs() < 1e-12 && b.abs() < 1e-12, "{d} {b}");
    // 1 m to the left; the robot turned 1.5 rad left in place: a little left of ahead.
    let (d, b) = predict_goal(1.0, std::f64::consts::FRAC_PI_2, Pose2::new(0.0, 0.0, 1.5));
    assert!(
        (d - 1.0).abs() < 1e-9 && (b - (std::f64::consts::FRAC_PI_2 - 1.5)).abs() < 1e-9,
        "{d} {b}"
    );
    // No motion: unchanged.
    let (d, b) = predict_goal(3.0, -2.0, Pose2::default());
    assert!((d - 3.0).abs() < 1e-12 && (b + 2.0).abs() < 1e-12);
}

/// The scan of one control cycle ago, carried forward by the command sent since, against the
/// scan taken where the robot is now and against the old scan itself, at random poses in
/// Env_3 (furnished, 5 x 5 m) under a command at full speed while turning.
#[test]
fn a_scan_carried_forward_reads_the_scan_taken_now() {
    let cfg = EnvConfig::default();
    let room = Room::builtin("env3").unwrap();
    let lidar = Lidar::new(&cfg.lidar);
    let layout = BeamLayout::new(cfg.lidar.beams, cfg.lidar.fov_deg);
    let range = [cfg.lidar.range_min, cfg.lidar.range_max];
    let mut env = NavEnv::new(room.clone(), &cfg, 3);
    let none = || -> Option<&mut Pcg64> { None };
    let (mut old, mut now, mut carried) = (vec![0.0f32; 540], vec![0.0f32; 540], vec![0.0; 540]);
    let (mut close_carried, mut close_old, mut total) = (0usize, 0usize, 0usize);
    let mut shortest = f32::MAX;
    for k in 0..40 {
        env.reset();
        let then = env.pose();
        let command = [(0.5, 1.0), (0.5, -1.5), (0.3, 0.5), (0.0, 1.5)][k % 4];
        let moved = motion_since([command], cfg.dt);
        let here = crate::advance(then, command.0, command.1, cfg.dt);
        lidar.scan(&room, then, none(), &mut old);
        lidar.scan(&room, here, none(), &mut now);
        predict_scan(&old, layout, range, moved, &mut carried);
        for i in 0..540 {
            total += 1;
            close_carried += ((carried[i] - now[i]).abs() <= 0.05) as usize;
            close_old += ((old[i] - now[i]).abs() <= 0.05) as usize;
        }
        shortest = shortest.min(carried.iter().copied().fold(f32::MAX, f32::min));
    }
    let (carried_share, old_share) =
        (close_carried as f64 / total as f64, close_old as f64 / total as f64);
    // Measured: 94.7 % of the carried beams within 5 cm of the scan now, 19.3 % of the old
    // scan's; the rest are directions the old scan did not see (past the edge of its field
    // after a turn, behind an obstacle it looked past), filled from their neighbours.
    assert!(carried_share >= 0.93, "{carried_share} of the carried beams within 5 cm");
    assert!(old_share <= 0.5, "{old_share}: the robot must move for the test to mean anything");
    assert!(shortest >= range[0] as f32, "a beam reads {shortest} m");
    // No motion: the same scan.
    predict_scan(&old, layout, range, Pose2::default(), &mut carried);
    assert_eq!(carried, old);
}

#[test]
fn a_command_log_drives_what_was_in_force_over_the_window() {
    let mut log = CommandLog::default();
    // Nothing sent yet: the robot stood still.
    assert_eq!(log.motion_over(0.0, 1.0), Pose2::default());
    log.record(10.0, 0.5, 0.0);
    log.record(10.2, 0.0, 1.0);
    log.record(10.4, 0.3, 0.0);
    // The last 0.3 s before 10.5: 0.1 s of turning at 1 rad/s, then 0.1 s at 0.3 m/s.
    let p = log.motion_over(10.2 + 0.1, 10.5);
    assert!((p.yaw - 0.1).abs() < 1e-12, "{p:?}");
    assert!((p.x - 0.03 * 0.1f64.cos()).abs() < 1e-9 && (p.y - 0.03 * 0.1f64.sin()).abs() < 1e-9);
    // A window reaching before the first command: standing still until it.
    let q = log.motion_over(9.0, 10.2);
    assert!((q.x - 0.1).abs() < 1e-12 && q.y.abs() < 1e-12 && q.yaw == 0.0, "{q:?}");
    // The same as motion_since for whole periods.
    let (r, whole) =
        (log.motion_over(10.0, 10.6), motion_since([(0.5, 0.0), (0.0, 1.0), (0.3, 0.0)], 0.2));
    let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(near(r.x, whole.x) && near(r.y, whole.y) && near(r.yaw, whole.yaw), "{r:?} {whole:?}");
    // Old commands are forgotten, but the one in force at the horizon is kept.
    for k in 0..100 {
        log.record(11.0 + 0.1 * f64::from(k), 0.1, 0.0);
    }
    assert!(log.sent.len() <= 22, "{}", log.sent.len());
    let s = log.motion_over(20.9 - MAX_SCAN_AGE_S, 20.9);
    assert!((s.x - 0.1 * MAX_SCAN_AGE_S).abs() < 1e-9, "{s:?}");
}
