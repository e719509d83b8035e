//! Tests of `caster.rs`.

use super::*;
use crate::LidarConfig;
use crate::{Lidar, Pose2, Room};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::f64::consts::{FRAC_PI_4, PI};

const NO_NOISE: Option<&mut Pcg64> = None;
const TOL: f64 = 1e-4;
/// Poses closer than this to a shape's boundary are left out of the comparisons: there,
/// rapier's `f32` and the exact `f64` geometry may disagree on inside versus outside.
const MARGIN: f64 = 1e-3;

fn dist_to_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let t = (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / (ex * ex + ey * ey)).clamp(0.0, 1.0);
    (p[0] - a[0] - t * ex).hypot(p[1] - a[1] - t * ey)
}

/// Distance from `p` to the nearest shape boundary (inside or outside).
fn boundary_distance(c: &Caster, p: [f64; 2]) -> f64 {
    let mut d = f64::INFINITY;
    for &[cx, cy, r] in &c.circles {
        d = d.min(((cx - p[0]).hypot(cy - p[1]) - r).abs());
    }
    for &(start, n) in &c.polys {
        let v = &c.verts[start..start + n];
        for k in 0..n {
            d = d.min(dist_to_segment(p, v[k], v[(k + 1) % n]));
        }
    }
    d
}

/// An independent exact first hit along unit `d` from `p` (f64), 0 from inside a shape:
/// Cyrus–Beck clipping for polygons, the cancellation-free quadratic root for circles.
fn oracle(c: &Caster, p: [f64; 2], d: [f64; 2]) -> Option<f64> {
    let mut best: Option<f64> = None;
    let mut keep = |t: f64| {
        if best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    };
    for &[cx, cy, r] in &c.circles {
        let (ox, oy) = (p[0] - cx, p[1] - cy);
        let b = ox * d[0] + oy * d[1];
        let cc = ox * ox + oy * oy - r * r;
        let disc = b * b - cc;
        if cc <= 0.0 {
            keep(0.0);
        } else if disc >= 0.0 && b < 0.0 {
            keep(cc / (-b + disc.sqrt()));
        }
    }
    for &(start, n) in &c.polys {
        let v = &c.verts[start..start + n];
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        let mut empty = false;
        for k in 0..n {
            let (a, b) = (v[k], v[(k + 1) % n]);
            // Outward normal of a CCW edge.
            let nrm = [b[1] - a[1], a[0] - b[0]];
            let num = nrm[0] * (a[0] - p[0]) + nrm[1] * (a[1] - p[1]);
            let den = nrm[0] * d[0] + nrm[1] * d[1];
            if den == 0.0 {
                if num < 0.0 {
                    empty = true;
                }
            } else if den < 0.0 {
                t0 = t0.max(num / den);
            } else {
                t1 = t1.min(num / den);
            }
        }
        if !empty && t0 <= t1 {
            keep(t0);
        }
    }
    best
}

/// What one comparison saw.
#[derive(Default, Debug)]
pub(crate) struct Tally {
    pub poses: usize,
    pub inside: usize,
    /// Beams that read less than range_max (a return).
    pub returns: usize,
    /// Beams compared.
    pub beams: usize,
    /// Beams where rapier is off by more than TOL (grazing incidence, f32 direction).
    pub grazing: usize,
}

/// Scans at `pose` both ways and asserts that every beam agrees within [`TOL`]. Returns
/// false (and checks nothing) when the pose is too close to a boundary. Also used by the tests
/// of `grid_map.rs`.
pub(crate) fn agree(room: &Room, lidar: &Lidar, pose: Pose2, tally: &mut Tally) -> bool {
    let p = pose.position();
    if boundary_distance(room.caster(), p) < MARGIN {
        return false;
    }
    let n = lidar.beams();
    let (mut fast, mut slow) = (vec![0.0f32; n], vec![0.0f32; n]);
    lidar.scan(room, pose, NO_NOISE, &mut fast);
    lidar.scan_reference(room, pose, NO_NOISE, &mut slow);
    let (lo, hi) = (lidar.range_min(), lidar.range_max());
    for i in 0..n {
        let (f, s) = (fast[i] as f64, slow[i] as f64);
        let a = pose.yaw + lidar.beam_angles()[i];
        // The oracle's reading with the beam turned by `da` (rad) and moved sideways by `dl` (m).
        let at = |da: f64, dl: f64| {
            let d = [(a + da).cos(), (a + da).sin()];
            let q = [p[0] - d[1] * dl, p[1] + d[0] * dl];
            let t = oracle(room.caster(), q, d);
            t.map_or(hi, |t| if t > hi { hi } else { t.max(lo) })
        };
        // The independent f64 oracle: agrees to rounding (up to a hair at range_max).
        let o = at(0.0, 0.0);
        assert!(
            (f - o).abs() <= 1e-6 || (f.min(o) - hi).abs() < 1e-5,
            "room `{}`, {pose:?}, beam {i}/{n}: fast {f} vs f64 oracle {o}",
            room.name()
        );
        // rapier: within TOL, unless the beam is so ill-conditioned (grazing incidence) that
        // rapier's own error explains more: turning the beam by 2 µrad or moving it sideways
        // by 0.3 mm (its f32 ray, and the tolerance of its GJK ray cast on convex polygons,
        // which is off by up to ~1 mm on beams at grazing incidence to an edge) changes the
        // hit by more. The f64 oracle above holds those beams to 1e-6 all the same.
        let cond = [(2e-6, 0.0), (-2e-6, 0.0), (0.0, 3e-4), (0.0, -3e-4)]
            .iter()
            .map(|&(da, dl)| (at(da, dl) - o).abs())
            .fold(0.0, f64::max);
        if (f - s).abs() > TOL {
            tally.grazing += 1;
        }
        assert!(
            (f - s).abs() <= TOL + cond,
            "room `{}`, {pose:?}, beam {i}/{n}: fast {f} vs rapier {s}",
            room.name()
        );
        tally.beams += 1;
    }
    tally.poses += 1;
    tally.inside += room.caster().inside_any(p) as usize;
    tally.returns += fast.iter().filter(|&&r| (r as f64) < lidar.range_max()).count();
    true
}

/// A uniformly random pose inside the room (walls excluded).
fn random_pose(rng: &mut Pcg64, side: f64) -> Pose2 {
    let h = side / 2.0;
    Pose2::new(rng.random_range(-h..h), rng.random_range(-h..h), rng.random_range(-PI..PI))
}

/// Poses just inside and just outside each obstacle (about 2 mm from its boundary) and at
/// its centre.
fn poses_at_obstacles(rng: &mut Pcg64, obstacles: &[ObstacleSpec]) -> Vec<Pose2> {
    let mut out = Vec::new();
    let parts: Vec<ObstacleSpec> = obstacles.iter().flat_map(|o| o.primitives()).collect();
    for o in &parts {
        let mut yaw = || rng.random_range(-PI..PI);
        match o {
            ObstacleSpec::Circle { center, radius } => {
                for rr in [0.0, radius - 2e-3, radius + 2e-3, radius + 0.05] {
                    let a = yaw();
                    out.push(Pose2::new(center[0] + rr * a.cos(), center[1] + rr * a.sin(), yaw()));
                }
            }
            ObstacleSpec::Box { center, half_extents, angle } => {
                let (s, c) = angle.sin_cos();
                let (hx, hy) = (half_extents[0], half_extents[1]);
                for (lx, ly) in [
                    (0.0, 0.0),
                    (hx - 2e-3, 0.0),
                    (hx + 2e-3, 0.0),
                    (0.0, -hy + 2e-3),
                    (0.0, -hy - 2e-3),
                    (hx + 2e-3, hy + 2e-3),
                    (-hx - 0.01, hy * 0.5),
                ] {
                    out.push(Pose2::new(
                        center[0] + c * lx - s * ly,
                        center[1] + s * lx + c * ly,
                        yaw(),
                    ));
                }
            }
            ObstacleSpec::Polygon { points } => {
                let n = points.len() as f64;
                let cen = points.iter().fold([0.0, 0.0], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
                out.push(Pose2::new(cen[0], cen[1], yaw()));
                // Just inside and just outside each vertex, along the ray from the centroid.
                for p in points {
                    let (dx, dy) = (p[0] - cen[0], p[1] - cen[1]);
                    let l = dx.hypot(dy);
                    for k in [-5e-3, 5e-3] {
                        let f = 1.0 + k / l;
                        out.push(Pose2::new(cen[0] + dx * f, cen[1] + dy * f, yaw()));
                    }
                }
            }
            ObstacleSpec::Compound { .. } => unreachable!("split into parts above"),
        }
    }
    out
}

/// The static shapes inside a room: obstacles and wall segments (not the square's walls).
fn inner_shapes(spec: &RoomSpec) -> Vec<ObstacleSpec> {
    let segments = spec.wall_segments.iter().map(|w| w.to_box(spec.wall_thickness));
    spec.obstacles.iter().cloned().chain(segments).collect()
}

fn configs() -> Vec<LidarConfig> {
    let d = LidarConfig::default();
    vec![
        d.clone(),
        LidarConfig { fov_deg: 360.0, beams: 720, ..d.clone() },
        LidarConfig { fov_deg: 90.0, beams: 31, ..d.clone() },
        LidarConfig { range_max: 3.0, ..d.clone() },
        LidarConfig { fov_deg: 359.0, beams: 97, range_min: 0.3, range_max: 1.5, ..d.clone() },
        LidarConfig { fov_deg: 10.0, beams: 2, ..d },
    ]
}

#[test]
fn builtin_rooms_match_rapier() {
    let mut rng = Pcg64::seed_from_u64(11);
    for name in Room::builtin_names() {
        let room = Room::builtin(&name).unwrap();
        let lidar = Lidar::new(&LidarConfig::default());
        let mut tally = Tally::default();
        for _ in 0..300 {
            agree(&room, &lidar, random_pose(&mut rng, room.side()), &mut tally);
        }
        for pose in poses_at_obstacles(&mut rng, &inner_shapes(room.spec())) {
            agree(&room, &lidar, pose, &mut tally);
        }
        assert!(tally.poses >= 300, "{name}: {tally:?}");
        assert!(tally.inside >= 5, "{name}: too few poses inside obstacles: {tally:?}");
        assert!(tally.returns > 100 * lidar.beams(), "{name}: {tally:?}");
        assert!(tally.grazing * 5000 < tally.beams, "{name}: {tally:?}");
        eprintln!("{name}: {tally:?}");
    }
}

#[test]
fn builtin_rooms_match_rapier_with_other_lidars() {
    let mut rng = Pcg64::seed_from_u64(12);
    for cfg in configs() {
        let lidar = Lidar::new(&cfg);
        for name in Room::builtin_names() {
            let room = Room::builtin(&name).unwrap();
            let mut tally = Tally::default();
            for _ in 0..60 {
                agree(&room, &lidar, random_pose(&mut rng, room.side()), &mut tally);
            }
            for pose in poses_at_obstacles(&mut rng, &inner_shapes(room.spec())) {
                agree(&room, &lidar, pose, &mut tally);
            }
            assert!(tally.poses >= 60 && tally.inside > 0, "{name}, {cfg:?}: {tally:?}");
        }
    }
}

/// A random valid obstacle somewhere in `[-h, h]²` (it may cross the walls).
fn random_obstacle(rng: &mut Pcg64, h: f64) -> ObstacleSpec {
    let center = [rng.random_range(-h..h), rng.random_range(-h..h)];
    match rng.random_range(0..3) {
        0 => ObstacleSpec::Box {
            center,
            half_extents: [rng.random_range(0.02..0.8), rng.random_range(0.02..0.8)],
            angle: rng.random_range(-PI..PI),
        },
        1 => ObstacleSpec::Circle { center, radius: rng.random_range(0.02..0.8) },
        _ => {
            // Points on an ellipse at sorted angles: convex and counter-clockwise.
            let n = rng.random_range(3..9);
            let (a, b) = (rng.random_range(0.1..0.8), rng.random_range(0.1..0.8));
            let rot = rng.random_range(-PI..PI);
            // Jittered even spacing: no vanishing edges, which rapier's GJK (the reference)
            // handles poorly.
            let gap = TAU / n as f64;
            let angles: Vec<f64> =
                (0..n).map(|k| gap * (k as f64 + rng.random_range(-0.3..0.3))).collect();
            let points = angles
                .iter()
                .map(|t| {
                    let (x, y) = (a * t.cos(), b * t.sin());
                    let (s, c) = rot.sin_cos();
                    [center[0] + c * x - s * y, center[1] + s * x + c * y]
                })
                .collect();
            ObstacleSpec::Polygon { points }
        }
    }
}

#[test]
fn random_rooms_match_rapier() {
    let mut rng = Pcg64::seed_from_u64(13);
    let cfgs = configs();
    let (mut rooms, mut tally) = (0, Tally::default());
    while rooms < 60 {
        let side = rng.random_range(2.0..12.0);
        let mut spec = RoomSpec::empty("random", side);
        for _ in 0..rng.random_range(0..16) {
            spec.obstacles.push(random_obstacle(&mut rng, side / 2.0));
        }
        // Thin or nearly flat polygons may be refused; draw again.
        let Ok(room) = Room::try_new(spec) else { continue };
        rooms += 1;
        let lidar = Lidar::new(&cfgs[rooms % cfgs.len()]);
        for _ in 0..40 {
            agree(&room, &lidar, random_pose(&mut rng, side), &mut tally);
        }
        for pose in poses_at_obstacles(&mut rng, &room.spec().obstacles) {
            agree(&room, &lidar, pose, &mut tally);
        }
    }
    assert!(tally.poses > 2000 && tally.inside > 100, "{tally:?}");
    assert!(tally.grazing * 1000 < tally.beams, "{tally:?}");
    eprintln!("random rooms: {tally:?}");
}

#[test]
fn obstacles_across_the_field_of_view_seam_and_the_angle_cut() {
    // A 360° LiDAR's first and last beams sit either side of straight behind; obstacles
    // straddling that seam (and the ±π cut of atan2, at every heading) must be cast whole.
    let mut spec = RoomSpec::empty("seam", 6.0);
    spec.obstacles.push(ObstacleSpec::Circle { center: [-1.0, 0.0], radius: 0.3 });
    spec.obstacles.push(ObstacleSpec::Box {
        center: [1.5, 0.0],
        half_extents: [0.2, 0.6],
        angle: 0.1,
    });
    let room = Room::new(spec);
    let mut tally = Tally::default();
    for cfg in [
        LidarConfig { fov_deg: 360.0, beams: 720, ..LidarConfig::default() },
        LidarConfig { fov_deg: 360.0, beams: 7, ..LidarConfig::default() },
        LidarConfig::default(),
    ] {
        let lidar = Lidar::new(&cfg);
        for k in 0..64 {
            let yaw = -PI + TAU * k as f64 / 64.0;
            assert!(agree(&room, &lidar, Pose2::new(0.0, 0.0, yaw), &mut tally));
        }
        assert!(agree(&room, &lidar, Pose2::new(0.0, 0.0, PI), &mut tally));
    }
    // Straight behind at heading 0 (360°, 720 beams): the beams either side of the seam
    // see the circle at 0.7 m.
    let lidar = Lidar::new(&LidarConfig { fov_deg: 360.0, beams: 720, ..Default::default() });
    let mut out = vec![0.0; 720];
    lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    assert!((out[0] as f64 - 0.7).abs() < 1e-4 && (out[719] as f64 - 0.7).abs() < 1e-4);
}

#[test]
fn beam_through_a_vertex_hits_it() {
    // A diamond whose near vertex lies exactly on the middle beam of an odd beam count.
    let mut spec = RoomSpec::empty("diamond", 10.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [2.0, 0.0],
        half_extents: [0.5, 0.5],
        angle: FRAC_PI_4,
    });
    spec.obstacles
        .push(ObstacleSpec::Polygon { points: vec![[-2.0, -1.0], [-1.0, 0.0], [-2.0, 1.0]] });
    let room = Room::new(spec);
    let lidar = Lidar::new(&LidarConfig { fov_deg: 90.0, beams: 31, ..Default::default() });
    let mut out = vec![0.0; 31];
    lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
    let expect = 2.0 - 0.5 * 2f64.sqrt();
    assert!((out[15] as f64 - expect).abs() < 1e-6, "{} vs {expect}", out[15]);
    lidar.scan(&room, Pose2::new(0.0, 0.0, PI), NO_NOISE, &mut out);
    assert!((out[15] as f64 - 1.0).abs() < 1e-6, "triangle vertex: {}", out[15]);
    let mut tally = Tally::default();
    assert!(agree(&room, &lidar, Pose2::default(), &mut tally));
    assert!(agree(&room, &lidar, Pose2::new(0.0, 0.0, PI), &mut tally));
}

#[test]
fn inside_or_on_a_shape_every_beam_reads_range_min() {
    let mut spec = RoomSpec::empty("inside", 6.0);
    spec.obstacles.push(ObstacleSpec::Circle { center: [1.0, 1.0], radius: 0.5 });
    spec.obstacles.push(ObstacleSpec::Box {
        center: [-1.0, -1.0],
        half_extents: [0.5, 0.2],
        angle: 0.3,
    });
    let room = Room::new(spec);
    let lidar = Lidar::new(&LidarConfig::default());
    let mut out = vec![0.0; lidar.beams()];
    for p in [[1.0, 1.0], [1.3, 1.3], [1.5, 1.0], [-1.0, -1.0], [-1.4, -1.1]] {
        lidar.scan(&room, Pose2::new(p[0], p[1], 0.7), NO_NOISE, &mut out);
        assert!(out.iter().all(|&r| r == 0.02), "{p:?}: {out:?}");
    }
    // The rapier reference agrees away from the boundary.
    let mut tally = Tally::default();
    for p in [[1.0, 1.0], [1.3, 1.3], [-1.0, -1.0], [-1.4, -1.1]] {
        assert!(agree(&room, &lidar, Pose2::new(p[0], p[1], 0.7), &mut tally));
    }
    assert_eq!(tally.inside, 4);
    // Just outside the circle: the beams facing it read range_min, the others do not.
    lidar.scan(&room, Pose2::new(1.51, 1.0, PI), NO_NOISE, &mut out);
    assert!((out[270] as f64 - 0.02).abs() < 1e-6, "{}", out[270]);
    assert!(out[0] > 1.0 && out[539] > 1.0);
}

#[test]
fn beyond_range_max_reads_range_max() {
    // A circle 2.5 m ahead: seen by a 3 m LiDAR, not by a 2 m one; walls 5 m away never.
    let mut spec = RoomSpec::empty("far", 10.0);
    spec.obstacles.push(ObstacleSpec::Circle { center: [3.0, 0.0], radius: 0.5 });
    let room = Room::new(spec);
    let theta = 0.25f64.to_radians(); // beam 270
    let hit = 3.0 * theta.cos() - (0.25 - 9.0 * theta.sin().powi(2)).sqrt(); // ≈ 2.50014
    for (range_max, ahead) in [(3.0, hit), (2.0, 2.0), (2.5, 2.5)] {
        let lidar = Lidar::new(&LidarConfig { range_max, ..Default::default() });
        let mut out = vec![0.0; lidar.beams()];
        lidar.scan(&room, Pose2::default(), NO_NOISE, &mut out);
        assert!((out[270] as f64 - ahead).abs() < 1e-6, "{range_max}: {}", out[270]);
        assert!(out[..200].iter().all(|&r| r as f64 == range_max));
        let mut tally = Tally::default();
        assert!(agree(&room, &lidar, Pose2::new(0.0, 0.1, 0.0), &mut tally));
    }
}

#[test]
fn fast_atan2_is_within_its_error_bound() {
    let mut worst: f64 = 0.0;
    for k in 0..200_000 {
        let a = -PI + TAU * k as f64 / 200_000.0;
        for r in [1e-6, 1.0, 1e3] {
            let (y, x) = (r * a.sin(), r * a.cos());
            let d = (fast_atan2(y, x) - y.atan2(x)).abs();
            worst = worst.max(d.min(TAU - d));
        }
    }
    for (y, x) in [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0)] {
        let d = (fast_atan2(y, x) - f64::atan2(y, x)).abs();
        worst = worst.max(d.min(TAU - d));
    }
    assert!(worst < 2e-5 && 10.0 * worst <= CULL_SLACK, "worst error {worst}");
}

#[test]
fn a_box_silhouette_spans_all_its_corners() {
    let mut rng = Pcg64::seed_from_u64(21);
    for _ in 0..20_000 {
        let (x0, y0) = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
        let b = [x0, y0, x0 + rng.random_range(0.01..2.0), y0 + rng.random_range(0.01..2.0)];
        let p = [rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0)];
        if (b[0]..=b[2]).contains(&p[0]) && (b[1]..=b[3]).contains(&p[1]) {
            continue;
        }
        let (lo, hi) = silhouette(&b, p);
        let a_lo = lo[1].atan2(lo[0]);
        let width = (hi[1].atan2(hi[0]) - a_lo).rem_euclid(TAU);
        assert!(width < PI, "{b:?} from {p:?}");
        for c in [[b[0], b[1]], [b[2], b[1]], [b[0], b[3]], [b[2], b[3]]] {
            let a = (c[1] - p[1]).atan2(c[0] - p[0]);
            let u = (a - a_lo).rem_euclid(TAU);
            assert!(u <= width + 1e-12 || u >= TAU - 1e-12, "{b:?} from {p:?}: corner {c:?}");
        }
    }
}

/// A room of `n` shapes scattered over a `side` square: mostly small axis-aligned boxes (like
/// an occupancy-grid map's), some turned boxes, circles and polygons.
fn many_shape_room(rng: &mut Pcg64, side: f64, n: usize) -> Room {
    let mut spec = RoomSpec::empty("many", side);
    let h = side / 2.0;
    while spec.obstacles.len() < n {
        let o = if rng.random_range(0..4) == 0 {
            random_obstacle(rng, h)
        } else {
            let center = [rng.random_range(-h..h), rng.random_range(-h..h)];
            let half_extents = [rng.random_range(0.025..0.4), rng.random_range(0.025..0.1)];
            let half_extents = if rng.random_bool(0.5) {
                half_extents
            } else {
                [half_extents[1], half_extents[0]]
            };
            ObstacleSpec::Box { center, half_extents, angle: 0.0 }
        };
        if o.validate().is_ok() {
            spec.obstacles.push(o);
        }
    }
    Room::try_new(spec).unwrap()
}

#[test]
fn culling_changes_no_reading_in_a_room_of_many_shapes() {
    let mut rng = Pcg64::seed_from_u64(22);
    for (side, n) in [(6.0, 80), (12.0, 400), (25.0, 1500)] {
        let room = many_shape_room(&mut rng, side, n);
        let culled = room.caster();
        assert!(culled.has_grid());
        let all = culled.without_grid();
        for (fov, beams, max_range) in
            [(270.0f64, 540, 10.0), (360.0, 720, 10.0), (90.0, 31, 3.0), (359.0, 97, 1.5)]
        {
            let fov = fov.to_radians();
            let step = fov / beams as f64;
            let first = -fov / 2.0 + step / 2.0;
            let dirs: Vec<(f64, f64)> = (0..beams)
                .map(|i| (first + step * i as f64).sin_cos())
                .map(|(s, c)| (c, s))
                .collect();
            let b = Beams { first, step, dirs: &dirs };
            let (mut fast, mut slow) = (vec![0.0f32; beams], vec![0.0f32; beams]);
            for _ in 0..150 {
                // Some poses beyond the walls too.
                let h = side / 2.0 + 1.0;
                let p = [rng.random_range(-h..h), rng.random_range(-h..h)];
                let yaw = rng.random_range(-PI..PI);
                assert_eq!(culled.inside_any(p), all.inside_any(p), "{p:?}");
                culled.cast(p, yaw, b, max_range, &mut fast);
                all.cast(p, yaw, b, max_range, &mut slow);
                for i in 0..beams {
                    let (f, s) = (fast[i] as f64, slow[i] as f64);
                    assert!(
                        f == s || (f > max_range && s > max_range),
                        "side {side}, {p:?} yaw {yaw}, beam {i}: culled {f} vs all {s}"
                    );
                }
            }
        }
    }
}

#[test]
fn a_room_of_many_shapes_matches_rapier() {
    let mut rng = Pcg64::seed_from_u64(23);
    let room = many_shape_room(&mut rng, 12.0, 300);
    assert!(room.caster().has_grid());
    let lidar = Lidar::new(&LidarConfig::default());
    let mut tally = Tally::default();
    for _ in 0..200 {
        agree(&room, &lidar, random_pose(&mut rng, room.side()), &mut tally);
    }
    assert!(tally.poses >= 150 && tally.inside > 10, "{tally:?}");
    assert!(tally.returns > 100 * lidar.beams(), "{tally:?}");
    assert!(tally.grazing * 1000 < tally.beams, "{tally:?}");
}
