//! Tests of `lidar.rs`.

use super::*;
use crate::{ObstacleSpec, RoomSpec};
use rand::SeedableRng;
use rand_pcg::Pcg64;

const NO_NOISE: Option<&mut Pcg64> = None;

fn default_scan(room: &Room, pose: Pose2) -> (Lidar, Vec<f32>) {
    let lidar = Lidar::new(&LidarConfig::default());
    let mut out = vec![0.0; lidar.beams()];
    lidar.scan(room, pose, NO_NOISE, &mut out);
    (lidar, out)
}

fn close(a: f32, b: f64) -> bool {
    (a as f64 - b).abs() < 2e-4
}

#[test]
fn beam_angles_are_half_degree_apart_and_centred() {
    let lidar = Lidar::new(&LidarConfig::default());
    let a = lidar.beam_angles();
    assert_eq!(a.len(), 540);
    assert!((a[0] - (-135.0f64 + 0.25).to_radians()).abs() < 1e-12);
    assert!((a[539] - (135.0f64 - 0.25).to_radians()).abs() < 1e-12);
    assert!((a[270] - 0.25f64.to_radians()).abs() < 1e-12);
    assert!((a[1] - a[0] - 0.5f64.to_radians()).abs() < 1e-12);
    assert!((a[269] + a[270]).abs() < 1e-12, "symmetric about straight ahead");
}

#[test]
fn walls_only_room_matches_hand_geometry() {
    // Side 4 m, robot at the origin facing +x: walls at x = ±2, y = ±2.
    let room = Room::new(RoomSpec::empty("walls", 4.0));
    let (lidar, scan) = default_scan(&room, Pose2::default());
    for (i, &theta) in lidar.beam_angles().iter().enumerate() {
        // Distance to the square's boundary along the beam.
        let expect = (2.0 / theta.cos().abs()).min(2.0 / theta.sin().abs());
        assert!(close(scan[i], expect), "beam {i}: {} vs {expect}", scan[i]);
    }
    // The two beams beside straight ahead read 2/cos(0.25°).
    let expect = 2.0 / 0.25f64.to_radians().cos();
    assert!(close(scan[269], expect) && close(scan[270], expect));
    // Beam 0 at −134.75° hits the bottom wall (y = −2): 2/sin(134.75°).
    assert!(close(scan[0], 2.0 / 134.75f64.to_radians().sin()));
}

#[test]
fn heading_rotates_the_scan() {
    // Facing +y from (0.5, 0): the beam nearest ahead hits the top wall at y = 2.
    let room = Room::new(RoomSpec::empty("walls", 4.0));
    let pose = Pose2::new(0.5, 0.0, std::f64::consts::FRAC_PI_2);
    let (lidar, scan) = default_scan(&room, pose);
    let theta = lidar.beam_angles()[270];
    assert!(close(scan[270], 2.0 / theta.cos()));
    // Beam 0 points at yaw − 134.75° = −44.75° in the room: right wall, x = 2.
    let world = std::f64::consts::FRAC_PI_2 + lidar.beam_angles()[0];
    assert!(close(scan[0], 1.5 / world.cos()));
}

#[test]
fn circle_ahead_reads_exact_chord_distance() {
    // Circle of radius 0.5 centred 3 m ahead; beam at angle θ from the centre line meets it
    // at t = d·cosθ − sqrt(r² − d²·sin²θ).
    let mut spec = RoomSpec::empty("circle", 20.0);
    spec.obstacles.push(ObstacleSpec::Circle { center: [3.0, 0.0], radius: 0.5 });
    let room = Room::new(spec);
    let (lidar, scan) = default_scan(&room, Pose2::default());
    let (d, r) = (3.0f64, 0.5f64);
    let mut hits = 0;
    for (i, &theta) in lidar.beam_angles().iter().enumerate() {
        let disc = r * r - d * d * theta.sin().powi(2);
        if theta.cos() > 0.0 && disc > 0.0 {
            let expect = d * theta.cos() - disc.sqrt();
            assert!(close(scan[i], expect), "beam {i}: {} vs {expect}", scan[i]);
            hits += 1;
        } else if theta.abs() < 0.5 {
            assert_eq!(scan[i], 10.0, "beam {i} passes the circle: no return in 10 m");
        }
    }
    // ±9.59° / 0.5° ≈ 38 beams see the circle.
    assert!((36..=40).contains(&hits), "{hits}");
}

#[test]
fn rotated_box_ahead() {
    // A 45°-rotated square with half side 0.5 at (2, 0): vertices (2 ± 0.5·√2, 0) and
    // (2, ±0.5·√2). The faces at the near vertex (c, 0), c = 2 − 0.5·√2, are x ∓ y = c, so
    // a beam at angle θ (|θ| below ~19°) hits at t = c / (cosθ − |sinθ|).
    let mut spec = RoomSpec::empty("box", 20.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [2.0, 0.0],
        half_extents: [0.5, 0.5],
        angle: std::f64::consts::FRAC_PI_4,
    });
    let room = Room::new(spec);
    let (lidar, scan) = default_scan(&room, Pose2::default());
    let c = 2.0 - 0.5 * 2f64.sqrt();
    for (i, (&r, &theta)) in scan.iter().zip(lidar.beam_angles()).enumerate() {
        if theta.abs() < 5f64.to_radians() {
            let expect = c / (theta.cos() - theta.sin().abs());
            assert!(close(r, expect), "beam {i}: {r} vs {expect}");
        }
    }
}

/// A lidar whose middle beam (15 of 31) points exactly ahead.
fn odd_lidar() -> Lidar {
    Lidar::new(&LidarConfig { fov_deg: 90.0, beams: 31, ..LidarConfig::default() })
}

#[test]
fn polygon_and_compound_ranges_are_exact() {
    // A triangle whose face x = 2 (from (2, 1) down to (2, 0)) faces the sensor: beam θ > 0
    // hits at 2/cosθ while it meets that face; below it a triangle whose face x − y = 2
    // faces the sensor; and a compound (a bar and a disc) seen along +y.
    let mut spec = RoomSpec::empty("shapes", 20.0);
    spec.obstacles
        .push(ObstacleSpec::Polygon { points: vec![[2.0, 0.0], [3.0, -1.0], [2.0, 1.0]] });
    spec.obstacles
        .push(ObstacleSpec::Polygon { points: vec![[1.0, -1.0], [3.0, -1.0], [2.0, 0.0]] });
    spec.obstacles.push(ObstacleSpec::Compound {
        at: [0.0, 3.0],
        parts: vec![
            ObstacleSpec::Box { center: [0.0, 0.0], half_extents: [1.0, 0.1], angle: 0.0 },
            ObstacleSpec::Circle { center: [0.0, -0.5], radius: 0.2 },
        ],
    });
    let room = Room::new(spec);
    let lidar = odd_lidar();
    let mut out = vec![0.0; 31];
    lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    // Straight ahead: the vertex (2, 0) shared by both triangles.
    assert!((out[15] as f64 - 2.0).abs() < 1e-6, "{}", out[15]);
    for (i, &theta) in
        lidar.beam_angles().iter().enumerate().filter(|(_, t)| **t > 0.0 && **t < 0.46)
    {
        let expect = 2.0 / theta.cos();
        assert!((out[i] as f64 - expect).abs() < 1e-6, "beam {i}: {} vs {expect}", out[i]);
    }
    // Below: beam θ < 0 meets x − y = 2 at 2/(cosθ − sinθ) until it passes the edge's end
    // (1, −1) at −45°.
    for (i, &theta) in
        lidar.beam_angles().iter().enumerate().filter(|(_, t)| **t < 0.0 && **t > -0.7)
    {
        let expect = 2.0 / (theta.cos() - theta.sin());
        assert!((out[i] as f64 - expect).abs() < 1e-6, "beam {i}: {} vs {expect}", out[i]);
    }
    // Facing +y: the compound's circle (bottom at y = 2.3), then its box beside it.
    lidar.scan(&room, Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), NO_NOISE, &mut out);
    assert!((out[15] as f64 - 2.3).abs() < 1e-6, "{}", out[15]);
    // Beam 11 (−11.6°) passes 0.5 m right of the circle's centre and meets the bar.
    let side = lidar.beam_angles()[11];
    assert!((out[11] as f64 - 2.9 / side.cos()).abs() < 1e-6, "bar face y = 2.9: {}", out[11]);
}

#[test]
fn robot_touching_a_wall_reads_its_radius_and_collides() {
    let room = Room::new(RoomSpec::empty("walls", 4.0));
    let lidar = odd_lidar();
    let mut out = vec![0.0; 31];
    // The meta robot's disc touches the wall at x = 2.
    let pose = Pose2::new(1.8, 0.0, 0.0);
    lidar.scan(&room, pose, NO_NOISE, &mut out);
    assert!((out[15] as f64 - 0.2).abs() < 1e-6, "{}", out[15]);
    assert!(room.circle_collides(pose.position(), 0.2), "touching is contact");
    assert!(!room.circle_collides(pose.position(), 0.199));
    // On the wall's face itself the sensor is on the boundary: every beam reads range_min.
    lidar.scan(&room, Pose2::new(2.0, 0.0, 0.0), NO_NOISE, &mut out);
    assert!(out.iter().all(|&r| r == lidar.range_min() as f32), "{out:?}");
}

#[test]
fn beam_along_an_edge_hits_its_near_vertex() {
    // The box's bottom edge lies on the beam's line y = 0: the beam grazes the whole edge
    // and first touches the corner (1, 0).
    let mut spec = RoomSpec::empty("graze", 10.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [1.5, 0.5],
        half_extents: [0.5, 0.5],
        angle: 0.0,
    });
    let room = Room::new(spec);
    let lidar = odd_lidar();
    let mut out = vec![0.0; 31];
    lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    assert!((out[15] as f64 - 1.0).abs() < 1e-6, "{}", out[15]);
    // The next beam to the right (−3°) passes below the box: the wall at x = 5.
    assert!((out[14] as f64 - 5.0 / lidar.beam_angles()[14].cos()).abs() < 1e-5);
    let mut reference = vec![0.0; 31];
    lidar.scan_reference(&room, Pose2::default(), NO_NOISE, &mut reference);
    assert!((reference[15] - out[15]).abs() < 1e-4, "rapier {}", reference[15]);
}

#[test]
fn no_return_reads_range_max_and_short_ranges_clamp() {
    let cfg = LidarConfig { range_max: 1.0, ..LidarConfig::default() };
    let lidar = Lidar::new(&cfg);
    let room = Room::new(RoomSpec::empty("big", 20.0));
    let mut out = vec![0.0; lidar.beams()];
    lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    assert!(out.iter().all(|&r| r == 1.0));
    // Hugging the wall: the beam straight into it would read ~0.01 m, reported as range_min.
    let pose = Pose2::new(9.99, 0.0, 0.0);
    lidar.scan(&room, pose, NO_NOISE, &mut out);
    assert_eq!(out[270], 0.02);
}

#[test]
fn noise_only_with_std_and_rng() {
    let room = Room::new(RoomSpec::empty("walls", 4.0));
    let cfg = LidarConfig { noise_std: 0.05, ..LidarConfig::default() };
    let noisy = Lidar::new(&cfg);
    let (_, exact) = default_scan(&room, Pose2::default());
    let mut out = vec![0.0; noisy.beams()];
    noisy.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    assert_eq!(out, exact, "no rng: exact");
    let mut rng = Pcg64::seed_from_u64(3);
    noisy.scan(&room, Pose2::default(), Some(&mut rng), &mut out);
    let diff: Vec<f64> = out.iter().zip(&exact).map(|(a, b)| (a - b) as f64).collect();
    let mean = diff.iter().sum::<f64>() / diff.len() as f64;
    let std = (diff.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / diff.len() as f64).sqrt();
    assert!(mean.abs() < 0.01 && (std - 0.05).abs() < 0.01, "mean {mean}, std {std}");
    // Exact config with an rng: still exact.
    let mut rng = Pcg64::seed_from_u64(3);
    let exact_lidar = Lidar::new(&LidarConfig::default());
    exact_lidar.scan(&room, Pose2::default(), Some(&mut rng), &mut out);
    assert_eq!(out, exact);
}
