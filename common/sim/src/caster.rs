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
//!
//! Culling, for rooms of many shapes (an occupancy-grid map is thousands of boxes, see
//! [`super::grid_map`]): the shapes are binned by their bounding boxes into a uniform grid of
//! cells ([`ShapeGrid`]), and a scan visits the cells ring by ring outwards from the sensor's.
//! A cell, and then a shape, is skipped when every beam that could reach it already reads less
//! than its distance from the sensor (the occluded far side of a wall), or when it lies beyond
//! the range; the scan ends when the next ring is farther than every reading. That changes no
//! reading: a skipped shape could only offer hits at least as far as the hits already found
//! (hits beyond the range are free to be reported or not, as always). The angular intervals
//! used for culling come from a polynomial `atan2` and are widened by many times its error, and
//! the distance tests keep a margin far above rounding, so culling only ever errs towards
//! casting a shape; the exact casting above is untouched.

use super::spec::{ObstacleSpec, RoomSpec};
use std::cell::RefCell;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Widening (rad) of each shape's angular interval before it is turned into beam indices, so
/// rounding in `atan2`/`asin` can never drop a beam the exact test would hit.
const ANGLE_SLACK: f64 = 1e-7;

/// Rooms with at least this many convex shapes get a [`ShapeGrid`]; below it visiting every
/// shape costs less than the grid's bookkeeping (the built-in rooms have a few dozen).
const GRID_MIN_SHAPES: usize = 64;

/// Shapes per grid cell aimed at (on average over the grid's area): big cells cull coarsely,
/// small ones cost more cells per ring.
const SHAPES_PER_CELL: f64 = 4.0;

/// Most cells along either side of a [`ShapeGrid`].
const MAX_GRID_CELLS: usize = 512;

/// Widening (rad) of the culling intervals: 10x the largest error of [`fast_atan2`] (2e-5).
const CULL_SLACK: f64 = 2e-4;

/// Relative and absolute (m) margins of the culling distance tests: something is skipped only
/// when the readings it could lower are below its distance by more than these, far more than
/// the rounding of any computed distance or of the grid's cell boundaries.
const CULL_MARGIN: f64 = 1e-9;
const CULL_ABS: f64 = 1e-9;

/// Absolute padding (m) of the bounding boxes shapes are binned by.
const AABB_PAD: f64 = 1e-9;

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
    /// The shapes binned for culling; `None` for rooms of few shapes.
    grid: Option<ShapeGrid>,
}

/// A uniform grid of square cells over the shapes' bounding boxes, each cell listing the shapes
/// whose (padded) bounding box overlaps it. Shape `k` is polygon `k` for `k < polys.len()`,
/// otherwise circle `k − polys.len()`.
#[derive(Clone, Debug)]
struct ShapeGrid {
    /// Lower-left corner of cell (0, 0) (m).
    origin: [f64; 2],
    /// Side of a cell (m).
    cell: f64,
    nx: usize,
    ny: usize,
    /// Cell `(i, j)` (index `j·nx + i`) lists `shapes[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    shapes: Vec<u32>,
    /// Each shape's bounding box `[x0, y0, x1, y1]` (m), padded by [`AABB_PAD`].
    aabbs: Vec<[f64; 4]>,
}

thread_local! {
    /// Which shapes the current scan on this thread has dealt with: `marks[k] == generation`.
    /// A new generation per scan clears them all at once; kept per thread because rooms are
    /// shared, read-only, by every environment stepping in parallel.
    static MARKS: RefCell<(Vec<u32>, u32)> = const { RefCell::new((Vec::new(), 0)) };
}

/// `atan2(y, x)` to within 2e-5 rad (Abramowitz and Stegun 4.4.49 on the octant), for culling
/// only: several times cheaper than `f64::atan2`, and callers widen by [`CULL_SLACK`].
#[inline]
fn fast_atan2(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let (num, den) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if den == 0.0 {
        return 0.0;
    }
    let z = num / den;
    let z2 = z * z;
    let mut a = z
        * (0.999_866_0
            + z2 * (-0.330_299_5 + z2 * (0.180_141_0 + z2 * (-0.085_133_0 + z2 * 0.020_835_1))));
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 { -a } else { a }
}

/// The two corners of the box `[x0, y0, x1, y1]` that bound it as seen from `p` outside it:
/// `(clockwise-most, counter-clockwise-most)`, relative to `p`.
#[inline]
fn silhouette(b: &[f64; 4], p: [f64; 2]) -> ([f64; 2], [f64; 2]) {
    let [x0, y0, x1, y1] = *b;
    let (lo, hi) = if p[0] < x0 {
        if p[1] < y0 {
            ([x1, y0], [x0, y1])
        } else if p[1] > y1 {
            ([x0, y0], [x1, y1])
        } else {
            ([x0, y0], [x0, y1])
        }
    } else if p[0] > x1 {
        if p[1] < y0 {
            ([x1, y1], [x0, y0])
        } else if p[1] > y1 {
            ([x0, y1], [x1, y0])
        } else {
            ([x1, y1], [x1, y0])
        }
    } else if p[1] < y0 {
        ([x1, y0], [x0, y0])
    } else {
        ([x0, y1], [x1, y1])
    };
    ([lo[0] - p[0], lo[1] - p[1]], [hi[0] - p[0], hi[1] - p[1]])
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
    /// Calls `f(first..=last)` for the index ranges of the beams whose angle lies in the
    /// interval that starts at world angle `lo` and spans `width` rad counter-clockwise, widened
    /// by `slack` on both sides. A beam may be in two ranges (when the interval wraps onto
    /// itself); never missed.
    #[inline]
    fn for_ranges(
        &self,
        lo: f64,
        width: f64,
        slack: f64,
        mut f: impl FnMut(std::ops::RangeInclusive<usize>),
    ) {
        let u0 = wrap_tau(lo - self.base) - slack;
        let w = width + 2.0 * slack;
        let end = self.step * self.n as f64;
        let last_beam = (self.n - 1) as f64;
        // The interval repeats every 2π; beam offsets lie in [0, step·n) ⊆ [0, 2π).
        let mut u = u0 - TAU;
        while u <= end {
            let first = ceil(u / self.step).max(0.0);
            let last = floor((u + w) / self.step).min(last_beam);
            if first <= last {
                f(first as usize..=last as usize);
            }
            u += TAU;
        }
    }

    /// Calls `f(i)` for every beam whose angle lies in the interval that starts at world angle
    /// `lo` and spans `width` rad counter-clockwise, widened by [`ANGLE_SLACK`] on both sides.
    /// A beam may be visited twice (when the interval wraps onto itself); never missed.
    #[inline]
    fn for_beams(&self, lo: f64, width: f64, mut f: impl FnMut(usize)) {
        self.for_ranges(lo, width, ANGLE_SLACK, |r| r.for_each(&mut f));
    }

    /// True when every beam that could meet the box `b` (`[x0, y0, x1, y1]`, m) reads less
    /// than its distance from `p` in `out`, or when it is farther than `max_range`: nothing in
    /// it can lower a reading within range. False for a box `p` is in or on.
    #[inline]
    fn occluded(&self, b: &[f64; 4], p: [f64; 2], max_range: f64, out: &[f32]) -> bool {
        let dx = (b[0] - p[0]).max(p[0] - b[2]).max(0.0);
        let dy = (b[1] - p[1]).max(p[1] - b[3]).max(0.0);
        if dx == 0.0 && dy == 0.0 {
            return false;
        }
        let d = (dx * dx + dy * dy).sqrt();
        if d > max_range * (1.0 + CULL_MARGIN) + CULL_ABS {
            return true;
        }
        let (lo, hi) = silhouette(b, p);
        let a_lo = fast_atan2(lo[1], lo[0]);
        let width = wrap_tau(fast_atan2(hi[1], hi[0]) - a_lo);
        let bound = d * (1.0 - CULL_MARGIN) - CULL_ABS;
        let mut hidden = true;
        self.for_ranges(a_lo, width, CULL_SLACK, |r| {
            hidden &= out[r].iter().all(|&v| (v as f64) <= bound);
        });
        hidden
    }
}

/// `x.rem_euclid(TAU)`, bit for bit, without the `fmod` call for the usual |x| < 2π.
#[inline]
fn wrap_tau(x: f64) -> f64 {
    if x.abs() < TAU { if x < 0.0 { x + TAU } else { x } } else { x.rem_euclid(TAU) }
}

/// `x.floor()` (but for the sign of a zero) without the libm call that baseline x86-64 makes
/// of it: below 4·10¹⁵ (< 2⁵²) truncating to `i64` and back is exact.
#[inline]
fn floor(x: f64) -> f64 {
    if x.is_nan() || x.abs() >= 4.0e15 {
        return x.floor();
    }
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// `x.ceil()` (but for the sign of a zero), as [`floor`].
#[inline]
fn ceil(x: f64) -> f64 {
    if x.is_nan() || x.abs() >= 4.0e15 {
        return x.ceil();
    }
    let t = x as i64 as f64;
    if t < x { t + 1.0 } else { t }
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
        if c.polys.len() + c.circles.len() >= GRID_MIN_SHAPES {
            c.grid = Some(ShapeGrid::new(&c));
        }
        c
    }

    /// The same shapes without the culling grid: every shape visited on every scan.
    #[cfg(test)]
    pub fn without_grid(&self) -> Caster {
        Caster { grid: None, ..self.clone() }
    }

    /// Whether scans are culled by a [`ShapeGrid`].
    #[cfg(test)]
    pub fn has_grid(&self) -> bool {
        self.grid.is_some()
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
        if let Some(g) = &self.grid {
            // Only the shapes binned in `p`'s cell can contain it.
            return g
                .cell_at(p)
                .is_some_and(|c| g.cell_shapes(c).iter().any(|&k| self.inside(k, p)));
        }
        (0..self.circles.len()).any(|k| self.inside_circle(k, p))
            || (0..self.polys.len()).any(|k| self.inside_poly(k, p))
    }

    /// True when `p` lies inside or on shape `k` (the numbering of [`ShapeGrid`]).
    #[inline]
    fn inside(&self, k: u32, p: [f64; 2]) -> bool {
        let k = k as usize;
        match k.checked_sub(self.polys.len()) {
            None => self.inside_poly(k, p),
            Some(c) => self.inside_circle(c, p),
        }
    }

    #[inline]
    fn inside_circle(&self, k: usize, p: [f64; 2]) -> bool {
        let [cx, cy, r] = self.circles[k];
        let (dx, dy) = (cx - p[0], cy - p[1]);
        dx * dx + dy * dy <= r * r
    }

    #[inline]
    fn inside_poly(&self, k: usize, p: [f64; 2]) -> bool {
        let (start, n) = self.polys[k];
        let v = &self.verts[start..start + n];
        (0..n).all(|k| {
            let a = [v[k][0] - p[0], v[k][1] - p[1]];
            let b = [v[(k + 1) % n][0] - p[0], v[(k + 1) % n][1] - p[1]];
            cross(a, b) >= 0.0
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
        let span = Span { base: yaw + beams.first, step: beams.step, n };
        let scan = Scan { origin, max_range, span, yaw_cs: (c, s), dirs: beams.dirs };
        match &self.grid {
            Some(g) => g.cast(self, &scan, out),
            None => {
                for k in 0..self.polys.len() {
                    self.cast_poly(k, &scan, out);
                }
                for k in 0..self.circles.len() {
                    self.cast_circle(k, &scan, out);
                }
            }
        }
    }

    /// Casts shape `k` (the numbering of [`ShapeGrid`]).
    #[inline]
    fn cast_shape(&self, k: u32, scan: &Scan<'_>, out: &mut [f32]) {
        let k = k as usize;
        match k.checked_sub(self.polys.len()) {
            None => self.cast_poly(k, scan, out),
            Some(c) => self.cast_circle(c, scan, out),
        }
    }

    /// Lowers `out` to the exact hits on polygon `k`'s front faces.
    #[inline]
    fn cast_poly(&self, k: usize, scan: &Scan<'_>, out: &mut [f32]) {
        let origin = scan.origin;
        let (start, len) = self.polys[k];
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
            if line_dist > scan.max_range {
                continue;
            }
            let ang_b = b[1].atan2(b[0]);
            let ang_a = a[1].atan2(a[0]);
            let width = wrap_tau(ang_a - ang_b);
            scan.span.for_beams(ang_b, width, |i| {
                let d = scan.dir(i);
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

    /// Lowers `out` to the exact hits on circle `k`.
    #[inline]
    fn cast_circle(&self, k: usize, scan: &Scan<'_>, out: &mut [f32]) {
        let origin = scan.origin;
        let [cx, cy, r] = self.circles[k];
        let cc = [cx - origin[0], cy - origin[1]];
        let dist2 = cc[0] * cc[0] + cc[1] * cc[1];
        let dist = dist2.sqrt();
        // Sensor outside: `dist2 − r²` > 0, the numerator of the cancellation-free root.
        let q = dist2 - r * r;
        if dist - r > scan.max_range {
            return;
        }
        let half = (r / dist).asin();
        let centre = cc[1].atan2(cc[0]);
        scan.span.for_beams(centre - half, 2.0 * half, |i| {
            let d = scan.dir(i);
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

/// One scan's sensor and beams.
struct Scan<'a> {
    origin: [f64; 2],
    max_range: f64,
    span: Span,
    /// (cos, sin) of the heading.
    yaw_cs: (f64, f64),
    /// (cos, sin) of each beam angle relative to the heading.
    dirs: &'a [(f64, f64)],
}

impl Scan<'_> {
    /// World direction of beam `i`, computed on demand: cheaper than a scratch buffer.
    #[inline]
    fn dir(&self, i: usize) -> [f64; 2] {
        let (c, s) = self.yaw_cs;
        let (cb, sb) = self.dirs[i];
        [c * cb - s * sb, s * cb + c * sb]
    }
}

impl ShapeGrid {
    /// Bins the shapes of `c` (at least one).
    fn new(c: &Caster) -> ShapeGrid {
        let mut aabbs: Vec<[f64; 4]> = c
            .polys
            .iter()
            .map(|&(start, n)| {
                c.verts[start..start + n].iter().fold(
                    [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY],
                    |b, v| [b[0].min(v[0]), b[1].min(v[1]), b[2].max(v[0]), b[3].max(v[1])],
                )
            })
            .collect();
        aabbs.extend(c.circles.iter().map(|&[x, y, r]| [x - r, y - r, x + r, y + r]));
        for b in &mut aabbs {
            *b = [b[0] - AABB_PAD, b[1] - AABB_PAD, b[2] + AABB_PAD, b[3] + AABB_PAD];
        }
        let lo = aabbs.iter().fold([f64::INFINITY; 2], |m, b| [m[0].min(b[0]), m[1].min(b[1])]);
        let hi = aabbs.iter().fold([f64::NEG_INFINITY; 2], |m, b| [m[0].max(b[2]), m[1].max(b[3])]);
        let (wx, wy) = (hi[0] - lo[0], hi[1] - lo[1]);
        let per_shape = wx * wy / aabbs.len() as f64;
        let cell =
            (per_shape * SHAPES_PER_CELL).sqrt().max(wx.max(wy) / MAX_GRID_CELLS as f64).max(1e-6);
        let cells = |w: f64| ((w / cell).ceil() as usize).clamp(1, MAX_GRID_CELLS);
        let mut g = ShapeGrid {
            origin: lo,
            cell,
            nx: cells(wx),
            ny: cells(wy),
            starts: Vec::new(),
            shapes: Vec::new(),
            aabbs,
        };
        // Counting sort of (cell, shape) pairs into the cells' lists.
        let mut counts = vec![0u32; g.nx * g.ny + 1];
        for b in &g.aabbs {
            g.for_cells(b, |c| counts[c + 1] += 1);
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let mut next = counts.clone();
        let mut shapes = vec![0; counts[g.nx * g.ny] as usize];
        for (k, b) in g.aabbs.iter().enumerate() {
            g.for_cells(b, |c| {
                shapes[next[c] as usize] = k as u32;
                next[c] += 1;
            });
        }
        g.shapes = shapes;
        g.starts = counts;
        g
    }

    /// Column (x) or row (y) index of coordinate `v` along `axis`, clamped to the grid.
    #[inline]
    fn index(&self, v: f64, axis: usize) -> usize {
        let n = if axis == 0 { self.nx } else { self.ny };
        (floor((v - self.origin[axis]) / self.cell).max(0.0) as usize).min(n - 1)
    }

    /// Calls `f(cell)` for every cell the box `b` overlaps.
    fn for_cells(&self, b: &[f64; 4], mut f: impl FnMut(usize)) {
        let (i0, i1) = (self.index(b[0], 0), self.index(b[2], 0));
        let (j0, j1) = (self.index(b[1], 1), self.index(b[3], 1));
        for j in j0..=j1 {
            for i in i0..=i1 {
                f(j * self.nx + i);
            }
        }
    }

    /// The cell holding `p`, or `None` outside the grid (where no shape is).
    #[inline]
    fn cell_at(&self, p: [f64; 2]) -> Option<usize> {
        let hi = [
            self.origin[0] + self.nx as f64 * self.cell,
            self.origin[1] + self.ny as f64 * self.cell,
        ];
        let outside = (0..2).any(|k| p[k] < self.origin[k] || p[k] > hi[k]);
        (!outside).then(|| self.index(p[1], 1) * self.nx + self.index(p[0], 0))
    }

    #[inline]
    fn cell_shapes(&self, c: usize) -> &[u32] {
        &self.shapes[self.starts[c] as usize..self.starts[c + 1] as usize]
    }

    /// The box of cells `i0..=i1` × `j0..=j1` (m).
    #[inline]
    fn block(&self, i0: usize, j0: usize, i1: usize, j1: usize) -> [f64; 4] {
        let [ox, oy] = self.origin;
        let c = self.cell;
        [ox + i0 as f64 * c, oy + j0 as f64 * c, ox + (i1 + 1) as f64 * c, oy + (j1 + 1) as f64 * c]
    }

    /// [`Caster::cast_add`] for the shapes of `caster`, culled: cells ring by ring outwards
    /// from the sensor's, skipping occluded cells and shapes, until the next ring lies beyond
    /// every reading (see the module docs).
    fn cast(&self, caster: &Caster, scan: &Scan<'_>, out: &mut [f32]) {
        let p = scan.origin;
        let (ci, cj) = (self.index(p[0], 0), self.index(p[1], 1));
        let rings = ci.max(self.nx - 1 - ci).max(cj).max(self.ny - 1 - cj);
        MARKS.with_borrow_mut(|(marks, generation)| {
            if marks.len() < self.aabbs.len() {
                marks.resize(self.aabbs.len(), 0);
            }
            if *generation == u32::MAX {
                marks.fill(0);
                *generation = 0;
            }
            *generation += 1;
            let generation = *generation;
            let mut visit_cell = |i: usize, j: usize, out: &mut [f32]| {
                let shapes = self.cell_shapes(j * self.nx + i);
                let mut cell_checked = false;
                for &k in shapes {
                    if marks[k as usize] == generation {
                        continue;
                    }
                    if !cell_checked {
                        cell_checked = true;
                        if scan.span.occluded(&self.block(i, j, i, j), p, scan.max_range, out) {
                            // The cell's shapes may still be cast from another cell.
                            return;
                        }
                    }
                    marks[k as usize] = generation;
                    // Occluded stays occluded: readings only fall during a scan.
                    if !scan.span.occluded(&self.aabbs[k as usize], p, scan.max_range, out) {
                        caster.cast_shape(k, scan, out);
                    }
                }
            };
            visit_cell(ci, cj, out);
            for k in 1..=rings {
                // Everything not yet visited lies outside the block of rings < k.
                let (i0, i1) = (ci.saturating_sub(k - 1), (ci + k - 1).min(self.nx - 1));
                let (j0, j1) = (cj.saturating_sub(k - 1), (cj + k - 1).min(self.ny - 1));
                let b = self.block(i0, j0, i1, j1);
                let mut clear = f64::INFINITY;
                if i0 > 0 {
                    clear = clear.min(p[0] - b[0]);
                }
                if j0 > 0 {
                    clear = clear.min(p[1] - b[1]);
                }
                if i1 + 1 < self.nx {
                    clear = clear.min(b[2] - p[0]);
                }
                if j1 + 1 < self.ny {
                    clear = clear.min(b[3] - p[1]);
                }
                if clear > scan.max_range * (1.0 + CULL_MARGIN) + CULL_ABS {
                    break;
                }
                let bound = clear * (1.0 - CULL_MARGIN) - CULL_ABS;
                if out.iter().all(|&v| (v as f64) <= bound) {
                    break;
                }
                // Ring k: rows cj ± k across, then columns ci ± k between them.
                let (ri0, ri1) = (ci.saturating_sub(k), (ci + k).min(self.nx - 1));
                for j in
                    [cj.checked_sub(k), Some(cj + k).filter(|&j| j < self.ny)].into_iter().flatten()
                {
                    for i in ri0..=ri1 {
                        visit_cell(i, j, out);
                    }
                }
                let (rj0, rj1) = ((cj + 1).saturating_sub(k), (cj + k - 1).min(self.ny - 1));
                for i in
                    [ci.checked_sub(k), Some(ci + k).filter(|&i| i < self.nx)].into_iter().flatten()
                {
                    for j in rj0..=rj1 {
                        visit_cell(i, j, out);
                    }
                }
            }
        });
    }
}

#[cfg(test)]
pub(crate) mod tests;
