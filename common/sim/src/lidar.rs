//! [`Lidar`]: a planar range finder at the robot's axle centre.

use super::caster::Beams;
use super::{Pose2, Room};
use crate::LidarConfig;
use rand_distr::{Distribution, Normal};
use rapier2d::prelude::*;

/// Beam geometry and range limits of one LiDAR; cheap to clone.
///
/// Beam `i` points at `-fov/2 + fov·(i + 0.5)/beams` from the heading (beam 0 on the right,
/// angles counter-clockwise), so 540 beams over 270° lie 0.5° apart, symmetric about straight
/// ahead. Sines and cosines of the beam angles are computed once here.
#[derive(Clone, Debug)]
pub struct Lidar {
    angles: Vec<f64>,
    /// (cos, sin) of each beam angle relative to the heading.
    dirs: Vec<(f64, f64)>,
    /// Angle of beam 0 relative to the heading (rad).
    first: f64,
    /// Angle between neighbouring beams (rad).
    step: f64,
    range_min: f64,
    range_max: f64,
    /// `None` when `noise_std` is 0.
    noise: Option<Normal<f64>>,
}

impl Lidar {
    /// The LiDAR described by `cfg`.
    ///
    /// # Panics
    /// If `noise_std` is negative or not finite (a validated config never is).
    pub fn new(cfg: &LidarConfig) -> Lidar {
        let fov = cfg.fov_deg.to_radians();
        let n = cfg.beams;
        let angles: Vec<f64> =
            (0..n).map(|i| -fov / 2.0 + fov * (i as f64 + 0.5) / n as f64).collect();
        let dirs = angles.iter().map(|a| (a.cos(), a.sin())).collect();
        let noise = (cfg.noise_std > 0.0)
            .then(|| Normal::new(0.0, cfg.noise_std).expect("lidar.noise_std must be finite"));
        let step = fov / n as f64;
        let first = -fov / 2.0 + step / 2.0;
        Lidar {
            angles,
            dirs,
            first,
            step,
            range_min: cfg.range_min,
            range_max: cfg.range_max,
            noise,
        }
    }

    /// Sets the range noise σ (m) of the scans from now on (0: exact).
    ///
    /// # Panics
    /// If `noise_std` is negative or not finite.
    pub(crate) fn set_noise_std(&mut self, noise_std: f64) {
        self.noise = (noise_std > 0.0)
            .then(|| Normal::new(0.0, noise_std).expect("lidar noise σ must be finite"));
    }

    /// Number of beams.
    pub fn beams(&self) -> usize {
        self.angles.len()
    }

    /// Beam angles relative to the heading (rad), right to left.
    pub fn beam_angles(&self) -> &[f64] {
        &self.angles
    }

    /// Shortest reported range (m).
    pub fn range_min(&self) -> f64 {
        self.range_min
    }

    /// Longest reported range (m); what a beam without a return reads.
    pub fn range_max(&self) -> f64 {
        self.range_max
    }

    /// Writes one range per beam (m) into `out` for a LiDAR at `pose` in `room`: the exact
    /// distance to the first wall or obstacle, plus Gaussian noise when the config has
    /// `noise_std > 0` and `noise` gives a generator, clamped to `[range_min, range_max]`. A beam
    /// with no return within `range_max` reads `range_max` (never noisy). A LiDAR inside a shape
    /// reads 0 (so `range_min`) on every beam.
    ///
    /// Computed shape by shape with the room's flat geometry (see `caster.rs`); agrees with
    /// rapier's ray casts ([`Lidar::scan_reference`]) to well below 1e-4 m.
    ///
    /// # Panics
    /// If `out` is not [`Lidar::beams`] long.
    pub fn scan(
        &self,
        room: &Room,
        pose: Pose2,
        noise: Option<&mut impl rand::Rng>,
        out: &mut [f32],
    ) {
        self.scan_active(room, pose, 0, noise, out);
    }

    /// [`Lidar::scan`] of the room with its first `active` timed obstacles present (see
    /// [`Room::timed_active`]).
    ///
    /// # Panics
    /// If `out` is not [`Lidar::beams`] long.
    pub fn scan_active(
        &self,
        room: &Room,
        pose: Pose2,
        active: usize,
        noise: Option<&mut impl rand::Rng>,
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), self.beams(), "scan buffer length");
        let beams = Beams { first: self.first, step: self.step, dirs: &self.dirs };
        room.cast_scan(pose.position(), pose.yaw, beams, self.range_max, active, out);
        self.finish(noise, out);
    }

    /// [`Lidar::scan`] done the slow way, one rapier ray cast per beam: the reference the fast
    /// scan is tested against.
    ///
    /// # Panics
    /// If `out` is not [`Lidar::beams`] long.
    pub fn scan_reference(
        &self,
        room: &Room,
        pose: Pose2,
        noise: Option<&mut impl rand::Rng>,
        out: &mut [f32],
    ) {
        self.scan_reference_active(room, pose, 0, noise, out);
    }

    /// [`Lidar::scan_active`] done with rapier's ray casts, the reference.
    ///
    /// # Panics
    /// If `out` is not [`Lidar::beams`] long.
    pub fn scan_reference_active(
        &self,
        room: &Room,
        pose: Pose2,
        active: usize,
        noise: Option<&mut impl rand::Rng>,
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), self.beams(), "scan buffer length");
        let query = room.query();
        let origin = Vector::new(pose.x as Real, pose.y as Real);
        let (s, c) = pose.yaw.sin_cos();
        let max = self.range_max as Real;
        for (r, &(cb, sb)) in out.iter_mut().zip(&self.dirs) {
            // Heading rotation applied to the fixed beam direction.
            let dir = Vector::new((c * cb - s * sb) as Real, (s * cb + c * sb) as Real);
            let ray = Ray::new(origin, dir);
            let hit = query.cast_ray(&ray, max, true).map(|(_, toi)| toi);
            let timed = if active > 0 { room.cast_ray_timed(&ray, max, active) } else { None };
            *r = match (hit, timed) {
                (Some(a), Some(b)) => a.min(b),
                (a, b) => a.or(b).unwrap_or(f32::INFINITY),
            };
        }
        self.finish(noise, out);
    }

    /// Turns first-hit distances (`out`, anything above `range_max` for no return) into ranges:
    /// noise on returns, `range_max` without one, clamped to `[range_min, range_max]`.
    fn finish(&self, mut noise: Option<&mut impl rand::Rng>, out: &mut [f32]) {
        for r in out.iter_mut() {
            let d = *r as f64;
            let range = if d <= self.range_max {
                match (self.noise.as_ref(), noise.as_deref_mut()) {
                    (Some(n), Some(rng)) => d + n.sample(rng),
                    _ => d,
                }
            } else {
                self.range_max
            };
            *r = range.clamp(self.range_min, self.range_max) as f32;
        }
    }
}

/// The returns of `scan` (beams at `angles` from `pose`, `max` or more for none, 0 for none
/// either) as points in `pose`'s frame: what a replan marks as obstacles after a stall.
pub fn scan_points(pose: Pose2, scan: &[f32], angles: &[f64], max: f32) -> Vec<[f64; 2]> {
    scan.iter()
        .zip(angles)
        .filter(|(r, _)| **r > 0.0 && **r < max)
        .map(|(&r, &a)| {
            let (s, c) = (pose.yaw + a).sin_cos();
            [pose.x + r as f64 * c, pose.y + r as f64 * s]
        })
        .collect()
}

#[cfg(test)]
mod tests;
