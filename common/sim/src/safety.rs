//! A collision monitor on the policy's commands: Nav2's Collision Monitor in its "approach"
//! mode, for a disc robot and its own scan. The policy's ω is kept and its v scaled down just
//! enough that driving the command for a horizon would not bring the disc into a scan return,
//! so the robot approaches an obstacle ever slower instead of clipping it, and still turns as
//! the policy asks (a disc turning in place sweeps nothing).
//!
//! Why: a DVST robot of 0.6 m in dense clutter clips a small obstacle on the bend round it, or
//! creeps along it a few millimetres off until it touches (docs/results.md, "A collision
//! monitor"); with the monitor it stops short, turns, and the route replans.
//!
//! Everything is in one frame: the robot at the origin facing +x, ranges and radius in the same
//! metres, v in those metres per second (the meta robot's frame in evaluation and in `dvnav
//! serve`, where DVST has already scaled the robot's scan by 1/μ).

use crate::laser_scan::BeamLayout;
use crate::{Pose2, advance};

/// The longest step (m) between two checked poses along the predicted arc: thin obstacles
/// are not stepped over.
const CHECK_STEP_M: f64 = 0.02;

/// Bisection steps for the speed share: 1/256 of v.
const BISECTIONS: usize = 8;

/// The clearance kept beyond the radius, as a share of it (2 mm for the 0.2 m meta robot): a
/// robot creeping along an obstacle a millimetre off touches it with its next millimetre of
/// motion, so the disc checked is a little larger than the body. Measured on tuning rooms
/// (docs/results.md, "A collision monitor"): 5 % stalls big robots in gaps they pass, 0.2 %
/// leaves grazing collisions, 1 % neither.
pub const MARGIN_SHARE: f64 = 0.01;

/// The linear velocity (≤ `v`) at which driving `(v', ω)` for `horizon_s` seconds keeps the
/// disc of `radius` (and [`MARGIN_SHARE`] of it) clear of `scan`'s returns (one range per beam of `layout`; a range at or
/// beyond `range_max` is no return). A return already inside the disc (noise, a grazing
/// contact) blocks only motion that comes closer to it. `v` itself when the arc is clear; 0
/// when no forward motion is.
pub fn safe_speed(
    scan: &[f32],
    layout: BeamLayout,
    range_max: f64,
    radius: f64,
    (v, omega): (f64, f64),
    horizon_s: f64,
) -> f64 {
    if v <= 0.0 || horizon_s <= 0.0 {
        return v;
    }
    let radius = radius * (1.0 + MARGIN_SHARE);
    let reach = radius + v * horizon_s;
    let near: Vec<([f64; 2], f64)> = scan
        .iter()
        .enumerate()
        .filter_map(|(i, &r)| {
            let r = f64::from(r);
            (r.is_finite() && r < range_max - 1e-6 && r < reach).then(|| {
                let (sin, cos) = layout.angle(i).sin_cos();
                ([r * cos, r * sin], r)
            })
        })
        .collect();
    if near.is_empty() {
        return v;
    }
    let clear = |speed: f64| {
        let steps = ((speed * horizon_s / CHECK_STEP_M).ceil() as usize).clamp(1, 100);
        (1..=steps).all(|k| {
            let p = advance(Pose2::default(), speed, omega, horizon_s * k as f64 / steps as f64);
            near.iter().all(|&([x, y], d0)| {
                let d = (x - p.x).hypot(y - p.y);
                d >= radius || d >= d0
            })
        })
    };
    if clear(v) {
        return v;
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (lo + hi);
        if clear(mid * v) { lo = mid } else { hi = mid }
    }
    lo * v
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAYOUT: BeamLayout = BeamLayout { beams: 540, fov: 1.5 * std::f64::consts::PI };

    /// A straight wall across the way `ahead` m in front of the centre.
    fn wall_ahead(ahead: f64) -> Vec<f32> {
        LAYOUT
            .angles()
            .into_iter()
            .map(|a| if a.cos() > 1e-6 { (ahead / a.cos()).min(10.0) as f32 } else { 10.0 })
            .collect()
    }

    #[test]
    fn open_space_keeps_the_command() {
        let scan = vec![10.0f32; LAYOUT.beams];
        assert_eq!(safe_speed(&scan, LAYOUT, 10.0, 0.2, (0.5, 0.3), 1.0), 0.5);
    }

    #[test]
    fn a_wall_ahead_slows_the_robot_to_stop_at_its_surface_within_the_horizon() {
        // 0.2 m radius (0.202 m with the margin), wall 0.5 m ahead: 0.298 m of free travel in
        // 1 s allows 0.298 m/s.
        let v = safe_speed(&wall_ahead(0.5), LAYOUT, 10.0, 0.2, (0.5, 0.0), 1.0);
        assert!((v - 0.298).abs() < 0.005, "{v}");
        // Far enough: untouched; touching: stopped; turning in place is never limited.
        assert_eq!(safe_speed(&wall_ahead(1.0), LAYOUT, 10.0, 0.2, (0.5, 0.0), 1.0), 0.5);
        assert!(safe_speed(&wall_ahead(0.2), LAYOUT, 10.0, 0.2, (0.5, 0.0), 1.0) < 0.01);
        assert_eq!(safe_speed(&wall_ahead(0.2), LAYOUT, 10.0, 0.2, (0.0, 1.5), 1.0), 0.0);
    }

    #[test]
    fn turning_away_from_the_wall_is_limited_less_than_driving_into_it() {
        let straight = safe_speed(&wall_ahead(0.5), LAYOUT, 10.0, 0.2, (0.5, 0.0), 1.0);
        let turning = safe_speed(&wall_ahead(0.5), LAYOUT, 10.0, 0.2, (0.5, 1.5), 1.0);
        assert!(turning > straight + 0.05, "{turning} vs {straight}");
    }

    #[test]
    fn a_return_inside_the_disc_blocks_only_motion_towards_it() {
        // One return 0.15 m behind-left of the centre (inside a 0.2 m disc): driving ahead
        // moves away from it.
        let mut scan = vec![10.0f32; LAYOUT.beams];
        scan[0] = 0.15;
        assert_eq!(safe_speed(&scan, LAYOUT, 10.0, 0.2, (0.5, 0.0), 1.0), 0.5);
    }
}
