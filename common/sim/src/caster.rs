//! [`Caster`]: exact, fast LiDAR scans against a room's static geometry, without rapier.
//!
//! A room is a handful of convex shapes, so a scan is cheaper done shape by shape than beam by
//! beam: every convex polygon (boxes included) is a closed chain of counter-clockwise edges and
//! every disc a centre and a radius, kept in flat arrays. For one sensor position each shape
//! covers an angular interval as seen from the sensor; as beam angles are uniform, the beams in
//! that interval are an index range computed directly, and only those beams are intersected
//! with the shape, keeping the nearest hit per beam.
//!
//! Exactness:
//! - The interval only culls: it is widened by [`ANGLE_SLACK`] and every beam in it is tested
//!   with the exact segment–ray or circle–ray intersection in `f64`, so a beam grazing a vertex
//!   is decided by the geometry, not by the interval's rounding.
//! - Only front faces (edges with the sensor strictly on their outer side) are intersected. From
//!   outside a closed convex shape a ray enters through a front face before it can reach a back
//!   face, so skipping back faces changes no first hit.
//! - A sensor inside (or on the boundary of) any shape reads 0 on every beam, as rapier's solid
//!   ray casts do ([`super::Room::cast_ray`] uses `solid = true`).

use super::spec::{ObstacleSpec, RoomSpec};
use std::f64::consts::TAU;

/// Widening (rad) of each shape's angular interval before it is turned into beam indices, so
/// rounding in `atan2`/`asin` can never drop a beam the exact test would hit.
const ANGLE_SLACK: f64 = 1e-7;

/// A room's shapes as flat arrays, built once per room.
#[derive(Clone, Debug, Default)]
pub(super) struct Caster {
    /// Vertices of every convex polygon (boxes included), counter-clockwise, polygon after
    /// polygon.
    verts: Vec<[f64; 2]>,
    /// `(first vertex, vertex count)` of each polygon in `verts`.
    polys: Vec<(usize, usize)>,
    /// Discs: `[cx, cy, r]`.
    circles: Vec<[f64; 3]>,
}

/// The beams of one scan: beam `i` points at `first + step·i` (rad) from the heading, with unit
/// direction `dirs[i]` relative to the heading.
#[derive(Clone, Copy, Debug)]
pub(super) struct Beams<'a> {
    /// Angle of beam 0 relative to the heading (rad).
    pub first: f64,
    /// Angle between neighbouring beams (rad), positive.
    pub step: f64,
    /// (cos, sin) of each beam angle relative to the heading.
    pub dirs: &'a [(f64, f64)],
}

/// Beam angles in the world frame for one scan: beam `i` at `base + step·i`.
struct Span {
    base: f64,
    step: f64,
    n: usize,
}

impl Span {
    /// Calls `f(i)` for every beam whose angle lies in the interval that starts at world angle
    /// `lo` and spans `width` rad counter-clockwise, widened by [`ANGLE_SLACK`] on both sides.
    /// A beam may be visited twice (when the interval wraps onto itself); never missed.
    #[inline]
    fn for_beams(&self, lo: f64, width: f64, mut f: impl FnMut(usize)) {
        let u0 = (lo - self.base).rem_euclid(TAU) - ANGLE_SLACK;
        let w = width + 2.0 * ANGLE_SLACK;
        let end = self.step * self.n as f64;
        let last_beam = (self.n - 1) as f64;
        // The interval repeats every 2π; beam offsets lie in [0, step·n) ⊆ [0, 2π).
        let mut u = u0 - TAU;
        while u <= end {
            let first = (u / self.step).ceil().max(0.0);
            let last = ((u + w) / self.step).floor().min(last_beam);
            if first <= last {
                for i in first as usize..=last as usize {
                    f(i);
                }
            }
            u += TAU;
        }
    }
}

#[inline]
fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

impl Caster {
    /// The walls and obstacles of `spec` (assumed valid); timed obstacles are left out.
    pub fn new(spec: &RoomSpec) -> Caster {
        Caster::from_shapes(spec.walls().iter().chain(&spec.obstacles))
    }

    /// The given shapes (assumed valid), compounds split into their parts.
    pub fn from_shapes<'a>(shapes: impl IntoIterator<Item = &'a ObstacleSpec>) -> Caster {
        let mut c = Caster::default();
        for o in shapes {
            o.for_each_primitive(&mut |p| c.push(p));
        }
        c
    }

    fn push(&mut self, o: &ObstacleSpec) {
        match o {
            ObstacleSpec::Box { center, half_extents, angle } => {
                let (s, co) = angle.sin_cos();
                let start = self.verts.len();
                for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let (lx, ly) = (sx * half_extents[0], sy * half_extents[1]);
                    self.verts.push([center[0] + co * lx - s * ly, center[1] + s * lx + co * ly]);
                }
                self.polys.push((start, 4));
            }
            ObstacleSpec::Circle { center, radius } => {
                self.circles.push([center[0], center[1], *radius]);
            }
            ObstacleSpec::Polygon { points } => {
                self.polys.push((self.verts.len(), points.len()));
                self.verts.extend_from_slice(points);
            }
            ObstacleSpec::Compound { .. } => o.for_each_primitive(&mut |p| self.push(p)),
        }
    }

    /// True when `p` lies inside or on the boundary of any shape.
    pub fn inside_any(&self, p: [f64; 2]) -> bool {
        let in_circle = self.circles.iter().any(|&[cx, cy, r]| {
            let (dx, dy) = (cx - p[0], cy - p[1]);
            dx * dx + dy * dy <= r * r
        });
        in_circle
            || self.polys.iter().any(|&(start, n)| {
                let v = &self.verts[start..start + n];
                (0..n).all(|k| {
                    let a = [v[k][0] - p[0], v[k][1] - p[1]];
                    let b = [v[(k + 1) % n][0] - p[0], v[(k + 1) % n][1] - p[1]];
                    cross(a, b) >= 0.0
                })
            })
    }

    /// Writes into `out[i]` the exact distance (m) from `origin` along beam `i` of a sensor with
    /// heading `yaw` to the first shape, or `f32::INFINITY` where the beam hits nothing closer
    /// than `max_range` (hits beyond it may or may not be reported; callers compare with their
    /// range limit). Every beam reads 0 when `origin` is inside a shape.
    ///
    /// # Panics
    /// If `out` and `beams.dirs` differ in length.
    pub fn cast(
        &self,
        origin: [f64; 2],
        yaw: f64,
        beams: Beams<'_>,
        max_range: f64,
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), beams.dirs.len(), "scan buffer length");
        if self.inside_any(origin) {
            out.fill(0.0);
            return;
        }
        out.fill(f32::INFINITY);
        self.cast_add(origin, yaw, beams, max_range, out);
    }

    /// Lowers `out[i]` to the exact distance along beam `i` to the first of these shapes where
    /// that is nearer (see [`Caster::cast`]); a sensor inside one of them is the caller's to
    /// detect ([`Caster::inside_any`]). Lets several casters (static room, obstacles that
    /// appeared) fill one scan.
    ///
    /// # Panics
    /// If `out` and `beams.dirs` differ in length.
    pub fn cast_add(
        &self,
        origin: [f64; 2],
        yaw: f64,
        beams: Beams<'_>,
        max_range: f64,
        out: &mut [f32],
    ) {
        let n = beams.dirs.len();
        assert_eq!(out.len(), n, "scan buffer length");
        if n == 0 {
            return;
        }
        let (s, c) = yaw.sin_cos();
        // World beam directions are computed per beam on demand: cheaper than a scratch buffer.
        let dir = |i: usize| {
            let (cb, sb) = beams.dirs[i];
            [c * cb - s * sb, s * cb + c * sb]
        };
        let span = Span { base: yaw + beams.first, step: beams.step, n };

        for &(start, len) in &self.polys {
            let v = &self.verts[start..start + len];
            for k in 0..len {
                let a = [v[k][0] - origin[0], v[k][1] - origin[1]];
                let bv = v[if k + 1 == len { 0 } else { k + 1 }];
                let b = [bv[0] - origin[0], bv[1] - origin[1]];
                let ab = cross(a, b);
                // Front face iff the sensor is strictly outside the edge's line: then `b` is
                // clockwise from `a` by less than π.
                if ab >= 0.0 {
                    continue;
                }
                // Cheap range cull: the edge's distance to the sensor.
                let e = [b[0] - a[0], b[1] - a[1]];
                let ee = e[0] * e[0] + e[1] * e[1];
                let line_dist = -ab / ee.sqrt();
                if line_dist > max_range {
                    continue;
                }
                let ang_b = b[1].atan2(b[0]);
                let ang_a = a[1].atan2(a[0]);
                let width = (ang_a - ang_b).rem_euclid(TAU);
                span.for_beams(ang_b, width, |i| {
                    let d = dir(i);
                    let den = cross(d, e);
                    if den == 0.0 {
                        return;
                    }
                    let t = ab / den;
                    let sp = cross(a, d) / den;
                    if t >= 0.0 && (0.0..=1.0).contains(&sp) && (t as f32) < out[i] {
                        out[i] = t as f32;
                    }
                });
            }
        }

        for &[cx, cy, r] in &self.circles {
            let cc = [cx - origin[0], cy - origin[1]];
            let dist2 = cc[0] * cc[0] + cc[1] * cc[1];
            let dist = dist2.sqrt();
            // Sensor outside: `dist2 − r²` > 0, the numerator of the cancellation-free root.
            let q = dist2 - r * r;
            if dist - r > max_range {
                continue;
            }
            let half = (r / dist).asin();
            let centre = cc[1].atan2(cc[0]);
            span.for_beams(centre - half, 2.0 * half, |i| {
                let d = dir(i);
                let along = d[0] * cc[0] + d[1] * cc[1];
                let off = cross(d, cc);
                let disc = r * r - off * off;
                if along > 0.0 && disc >= 0.0 {
                    // = along − √disc, without cancellation when the sensor is near the circle.
                    let t = q / (along + disc.sqrt());
                    if (t as f32) < out[i] {
                        out[i] = t as f32;
                    }
                }
            });
        }
    }
}

#[cfg(test)]
mod tests;
