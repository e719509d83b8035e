use super::*;
use crate::{EnvConfig, NavEnv};
use rand_pcg::Pcg64;
use std::sync::Arc;

fn spec(text: &str) -> SensorSpec {
    SensorSpec::from_toml_str(text, "test.toml").unwrap()
}

const HOKUYO_AHEAD: &str =
    "beams = 1081\nfov_deg = 270.0\nrange_min = 0.06\nrange_max = 10.0\nx = 0.1\n";
const URG_240: &str = "beams = 683\nfov_deg = 240.0\nrange_min = 0.02\nrange_max = 5.6\nx = 0.05\n";
const RPLIDAR_BEHIND: &str = "beams = 720\nfov_deg = 360.0\nrange_min = 0.15\nrange_max = 12.0\nx = -0.09\nyaw = 3.14159265\nno_return = \"zero\"\n";

/// For `n` start poses in a furnished room (each with the meta robot's clearance), the meta
/// scan taken at the axle centre and the one the controller computes from `sensor`'s scan:
/// `(truth, resampled, seen)` per beam, the truth clipped to the sensor's range.
fn compare(sensor: &SensorSpec, n: usize) -> Vec<(f32, f32, bool)> {
    let cfg = EnvConfig::default();
    let room: Arc<Room> = Room::builtin("env3").unwrap();
    let mut env = NavEnv::new(room.clone(), &cfg, 7);
    let mut mounted = MountedSensor::new(sensor);
    // Seen: a beam whose interval the sensor's readings reach (the fill rule off).
    let blocked = SensorSpec { uncovered_range: Some(0.0), ..sensor.clone() };
    let mut probe = MountedSensor::new(&blocked);
    let mut out = vec![0.0f32; cfg.lidar.beams];
    let mut marks = vec![0.0f32; cfg.lidar.beams];
    let mut rows = Vec::new();
    for _ in 0..n {
        env.reset();
        let truth = env.scan().to_vec();
        let none: Option<&mut Pcg64> = None;
        mounted.meta_scan(&room, env.pose(), 0, none, &cfg.lidar, &mut out);
        let none: Option<&mut Pcg64> = None;
        probe.meta_scan(&room, env.pose(), 0, none, &cfg.lidar, &mut marks);
        for i in 0..out.len() {
            let t = truth[i].min(sensor.range_max as f32);
            rows.push((t, out[i], marks[i] != 0.0));
        }
    }
    rows
}

/// Shares of the seen beams within `tol` m of the truth and more than `tol` beyond it, and the
/// shortest beam of all.
fn stats(rows: &[(f32, f32, bool)], tol: f32) -> (f64, f64, f32) {
    let seen: Vec<_> = rows.iter().filter(|r| r.2).collect();
    let close = seen.iter().filter(|r| (r.0 - r.1).abs() <= tol).count();
    let beyond = seen.iter().filter(|r| r.1 - r.0 > tol).count();
    let shortest = rows.iter().map(|r| r.1).fold(f32::MAX, f32::min);
    let n = seen.len() as f64;
    (close as f64 / n, beyond as f64 / n, shortest)
}

// The stated tolerance: at least 97 % of the seen meta beams within 5 cm of the scan taken at
// the axle centre, at most 0.5 % more than 5 cm beyond it. Measured: 98.0-98.3 % and 0.02-0.15 %;
// the beams beyond lie at the edge of the sensor's field, where an obstacle the axle centre sees
// is outside the sensor's view and the sensor sees past it.

#[test]
fn a_sensor_ahead_of_the_axle_gives_the_meta_scan_and_nothing_inside_the_body() {
    let rows = compare(&spec(HOKUYO_AHEAD), 40);
    let (close, beyond, shortest) = stats(&rows, 0.05);
    assert!(close >= 0.97, "{close} of the seen beams within 5 cm");
    assert!(beyond <= 0.005, "{beyond} of the seen beams read more than 5 cm beyond the truth");
    // The meta robot's radius is 0.2 m: no beam, seen or filled, inside it.
    assert!(shortest >= 0.2, "a beam reads {shortest} m");
    let unseen = rows.iter().filter(|r| !r.2).count() as f64 / rows.len() as f64;
    assert!(unseen > 0.0 && unseen < 0.1, "{unseen} of the beams unseen");
}

#[test]
fn a_narrower_shorter_sensor_and_one_turned_backwards_too() {
    for (text, seen_share) in [(URG_240, 0.85), (RPLIDAR_BEHIND, 0.97)] {
        let rows = compare(&spec(text), 30);
        let (close, beyond, shortest) = stats(&rows, 0.05);
        assert!(close >= 0.97, "{text}: {close} of the seen beams within 5 cm");
        assert!(beyond <= 0.005, "{text}: {beyond} of the seen beams more than 5 cm beyond");
        assert!(shortest >= 0.2, "{text}: a beam reads {shortest} m");
        let seen = rows.iter().filter(|r| r.2).count() as f64 / rows.len() as f64;
        assert!(seen >= seen_share, "{text}: {seen} seen");
    }
}

#[test]
fn the_driver_writes_no_return_its_way() {
    let room = Room::new(crate::RoomSpec::empty("big", 40.0));
    let mut s = MountedSensor::new(&spec(RPLIDAR_BEHIND));
    let none: Option<&mut Pcg64> = None;
    let scan = s.laser_scan(&room, Pose2::new(0.0, 0.0, 0.0), 0, none);
    // Walls 20 m away, beyond the 12 m range: no return anywhere, written as 0.0.
    assert!(scan.ranges.iter().all(|&r| r == 0.0));
    let mut a = MountedSensor::new(&spec(HOKUYO_AHEAD));
    let none: Option<&mut Pcg64> = None;
    let scan = a.laser_scan(&room, Pose2::new(0.0, 0.0, 0.0), 0, none);
    assert!(scan.ranges.iter().all(|&r| r == f32::INFINITY));
    // Both read as open space, range_max, for the meta agent.
    let mut out = vec![0.0f32; 540];
    let none: Option<&mut Pcg64> = None;
    s.meta_scan(&room, Pose2::new(0.0, 0.0, 0.0), 0, none, &LidarConfig::default(), &mut out);
    assert!(out.iter().all(|&r| r == 10.0), "clipped to the meta agent's range");
}

#[test]
fn the_sensor_pose_follows_the_robot() {
    let s = MountedSensor::new(&spec(
        "beams = 10\nfov_deg = 90\nrange_min = 0\nrange_max = 5\nx = 0.2\ny = 0.1\nyaw = 0.5\n",
    ));
    let p = s.pose(Pose2::new(1.0, 2.0, std::f64::consts::FRAC_PI_2));
    assert!((p.x - 0.9).abs() < 1e-12 && (p.y - 2.2).abs() < 1e-12, "{p:?}");
    assert!((p.yaw - (std::f64::consts::FRAC_PI_2 + 0.5)).abs() < 1e-12);
}

#[test]
fn bad_sensor_files_name_the_key_and_line() {
    let err = |text: &str| SensorSpec::from_toml_str(text, "s.toml").unwrap_err();
    let e = err("beams = 0\nfov_deg = 270\nrange_min = 0\nrange_max = 5\n");
    assert_eq!((e.key.as_str(), e.line), ("beams", Some(1)));
    let e = err("beams = 10\nfov_deg = 400\nrange_min = 0\nrange_max = 5\n");
    assert_eq!((e.key.as_str(), e.line), ("fov_deg", Some(2)));
    let e = err("beams = 10\nfov_deg = 90\nrange_min = 1\nrange_max = 0.5\n");
    assert_eq!(e.key, "range_max");
    let e = err("beams = 10\nfov_deg = 90\nrange_min = 0\nrange_max = 5\nx = 1e300\n");
    assert_eq!((e.key.as_str(), e.line), ("x", Some(5)));
    let e = err("beams = 10\nfov_deg = 90\nrange_min = 0\nrange_max = 5\nuncovered_range = -1\n");
    assert_eq!(e.key, "uncovered_range");
    let e = err("beams = 10\nfov = 90\n");
    assert!(e.reason.contains("unknown field"), "{e}");
}
