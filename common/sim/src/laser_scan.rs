//! Any LiDAR's scan, as ROS's `sensor_msgs/LaserScan` describes it, resampled to the meta
//! agent's beams: the robot's own sensor (a Hokuyo's 1,081 beams over 270°, an RPLidar's
//! varying count over 360°, mounted ahead of the axle, turned) stands in for the meta robot's.
//! `dvnav serve`, `dvnav replay`, the ROS 2 bridge, Python and `dvnav eval --sensor` (through
//! [`crate::sensor`]) all use this one function.
//!
//! **Readings** follow REP 117 and the common drivers: a finite range within `[range_min,
//! range_max]` is a return; `+inf` is "no return" (nothing within `range_max`), read as
//! `range_max`; exactly `0.0` is "no return" too, as the drivers of many low-cost LiDARs
//! (Neato's LDS, TurtleBot 3's LDS-01) report it; `-inf` is "too close to measure", read as
//! `range_min`; NaN and other values outside the range are invalid and ignored.
//!
//! **Conservative resampling.** Sensor beam `j` covers the angular interval of width
//! `|angle_increment|` centred on `angle_min + j·angle_increment`; meta beam `i` covers
//! `[-fov/2 + i·w, -fov/2 + (i+1)·w)` with `w = fov/beams`. Each meta beam takes the *nearest*
//! reading among the sensor beams whose interval overlaps its own, so a thin obstacle seen by
//! one fine sensor beam is never averaged away, and a coarse sensor beam speaks for every meta
//! beam it spans.
//!
//! **Mounting.** A sensor at `(x, y)` from the axle centre, turned by `yaw`, sees points
//! `p = (x, y) + r·(cos(yaw + θ), sin(yaw + θ))` of the robot frame; the meta agent's LiDAR sits
//! at the axle centre. Each reading's interval is carried over through its two edge points
//! (angles `atan2(p)`), and its range is the nearest of the edges and the centre, `|p|`.
//!
//! **Directions no reading covers** (outside a narrower sensor's field; beside a sensor ahead of
//! the axle, whose field seen from the axle leaves gaps near its edges; where every reading was
//! invalid) get, by default ([`Uncovered::Nearest`]), the nearer of the ranges at the two ends
//! of the gap, the way the nearest projected points in that neighbourhood bound it: a wall that
//! runs into the unseen sector is taken to go on at that distance. Filling them with 0 m, as this
//! module once did, put an obstacle inside the robot's own body that the agent turned away from
//! for ever (docs/results.md, "Real sensors"). [`Uncovered::Range`] fills them with a fixed
//! range instead; [`resample`] says how many beams were filled either way.

use serde::Serialize;
use std::f64::consts::{PI, TAU};

/// The most readings one scan may carry (a 0.1° LiDAR over 360° has 3,600).
pub const MAX_SCAN_RANGES: usize = 65_536;
/// The longest range (m) a scan, a mounting offset or a fill value may give.
pub const MAX_RANGE_M: f64 = 1.0e5;

/// Intervals closer than this (rad) only touch.
const TOUCH: f64 = 1e-9;

/// One scan in the sensor's own frame (REP 117 semantics; see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct LaserScan<'a> {
    /// Angle of the first reading (rad, sensor frame, left positive).
    pub angle_min: f64,
    /// Angle between readings (rad); negative for a sensor that turns clockwise.
    pub angle_increment: f64,
    /// Shortest and longest range the sensor measures (m).
    pub range_min: f64,
    /// See `range_min`.
    pub range_max: f64,
    /// The readings (m).
    pub ranges: &'a [f32],
}

/// Where the LiDAR sits on the robot and what unseen beams read: the `[lidar]` table of a
/// footprint file.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SensorSetup {
    /// The sensor's position ahead of the axle centre (m).
    pub x: f64,
    /// The sensor's position left of the axle centre (m).
    pub y: f64,
    /// The sensor's heading relative to the robot's (rad, left positive).
    pub yaw: f64,
    /// What a meta beam with no valid reading reads.
    pub uncovered: Uncovered,
}

/// What a meta beam that no valid reading reaches reads (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Uncovered {
    /// The nearer of the ranges at the two ends of the unseen run of beams (the default).
    #[default]
    Nearest,
    /// This range (m); 0 treats unseen space as blocked.
    Range(f64),
}

impl Uncovered {
    /// The fixed range, if that is the rule.
    pub fn range(self) -> Option<f64> {
        match self {
            Uncovered::Nearest => None,
            Uncovered::Range(r) => Some(r),
        }
    }
}

impl Default for SensorSetup {
    fn default() -> Self {
        SensorSetup { x: 0.0, y: 0.0, yaw: 0.0, uncovered: Uncovered::Nearest }
    }
}

impl SensorSetup {
    /// Checks every value is finite and within bounds; the error names the key.
    pub fn validate(&self) -> Result<(), ScanError> {
        for (key, v) in [("x", self.x), ("y", self.y)] {
            if !(v.is_finite() && v.abs() <= MAX_RANGE_M) {
                return Err(ScanError::new(key, format!("must be a finite offset (m), got {v}")));
            }
        }
        if !(self.yaw.is_finite() && self.yaw.abs() <= 2.0 * TAU) {
            let why = format!("must be an angle (rad) within ±4π, got {}", self.yaw);
            return Err(ScanError::new("yaw", why));
        }
        if let Uncovered::Range(u) = self.uncovered
            && !(u.is_finite() && (0.0..=MAX_RANGE_M).contains(&u))
        {
            let why = format!("must be a range in [0, {MAX_RANGE_M}] m, got {u}");
            return Err(ScanError::new("uncovered_range", why));
        }
        Ok(())
    }

    fn centred(&self) -> bool {
        self.x == 0.0 && self.y == 0.0
    }
}

/// The meta agent's beams: `beams` over `fov` (rad), centred on the heading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamLayout {
    /// Number of beams.
    pub beams: usize,
    /// Field of view (rad), at most 2π.
    pub fov: f64,
}

impl BeamLayout {
    /// The layout of `beams` beams over `fov_deg` degrees.
    pub fn new(beams: usize, fov_deg: f64) -> BeamLayout {
        BeamLayout { beams, fov: fov_deg.to_radians() }
    }

    /// Each beam's centre angle relative to the heading (rad), right to left, as
    /// [`crate::Lidar`] casts them.
    pub fn angles(&self) -> Vec<f64> {
        (0..self.beams).map(|i| self.angle(i)).collect()
    }

    /// Beam `i`'s centre angle relative to the heading (rad), one of [`BeamLayout::angles`].
    pub fn angle(&self, i: usize) -> f64 {
        let (start, w) = self.grid();
        start + w * (i as f64 + 0.5)
    }

    /// Whether the beams go all the way round (the last one neighbours the first).
    pub(crate) fn wraps(&self) -> bool {
        self.fov >= TAU - 1e-9
    }

    /// Lowest angle and width of one beam's interval.
    fn grid(&self) -> (f64, f64) {
        (-self.fov / 2.0, self.fov / self.beams as f64)
    }

    /// The meta beams whose intervals overlap the open interval `(lo, hi)` (rad, hi − lo <
    /// 2π), wherever it lies around the circle. Intervals that merely touch, to within
    /// rounding ([`TOUCH`]), do not overlap: a sensor laid out as the meta agent's beams maps
    /// one reading to one beam.
    fn overlapping(&self, lo: f64, hi: f64, mut each: impl FnMut(usize)) {
        let (lo, hi) = (lo + TOUCH, hi - TOUCH);
        let (start, w) = self.grid();
        let end = start + self.fov;
        // `lo` into [−π, π); the interval may then reach past π, and the layout may reach
        // past ±π only by less than a turn: three shifts see every overlap.
        let shift0 = lo - (lo + PI).rem_euclid(TAU) + PI;
        for turn in [-TAU, 0.0, TAU] {
            let (l, h) = (lo - shift0 + turn, hi - shift0 + turn);
            if h <= start || l >= end {
                continue;
            }
            let first = ((l - start) / w).floor().max(0.0) as usize;
            let last = (((h - start) / w).ceil() as usize).min(self.beams);
            (first..last).for_each(&mut each);
        }
    }
}

/// Why a scan (or a sensor setup) was refused: the field and what is wrong with it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("`{field}`: {reason}")]
pub struct ScanError {
    /// e.g. `angle_increment`.
    pub field: String,
    /// What is wrong.
    pub reason: String,
}

impl ScanError {
    fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        ScanError { field: field.into(), reason: reason.into() }
    }
}

impl LaserScan<'_> {
    /// Checks the scan's description (not its readings: an invalid reading is ignored, as
    /// REP 117 says).
    pub fn validate(&self) -> Result<(), ScanError> {
        let n = self.ranges.len();
        if n == 0 || n > MAX_SCAN_RANGES {
            let why = format!("{n} readings; a scan has 1 to {MAX_SCAN_RANGES}");
            return Err(ScanError::new("ranges", why));
        }
        if !(self.angle_min.is_finite() && self.angle_min.abs() <= 2.0 * TAU) {
            let why = format!("must be an angle (rad) within ±4π, got {}", self.angle_min);
            return Err(ScanError::new("angle_min", why));
        }
        let inc = self.angle_increment;
        if !(inc.is_finite() && (1e-6..=PI / 2.0).contains(&inc.abs())) {
            let why = format!("must be an angle of 1e-6 to π/2 rad either way, got {inc}");
            return Err(ScanError::new("angle_increment", why));
        }
        // A full turn may be described with its last reading one increment short of 2π or on
        // it (as drivers do); more would read some directions twice.
        let span = inc.abs() * (n - 1) as f64;
        if span > TAU + 1e-3 {
            let why = format!(
                "{n} readings {inc} rad apart span {:.1}°, more than a turn",
                span.to_degrees()
            );
            return Err(ScanError::new("angle_increment", why));
        }
        let (lo, hi) = (self.range_min, self.range_max);
        if !(lo.is_finite() && lo >= 0.0) {
            return Err(ScanError::new("range_min", format!("must be ≥ 0 m, got {lo}")));
        }
        if !(hi.is_finite() && hi > lo && hi <= MAX_RANGE_M) {
            let why = format!("must be above range_min ({lo} m) and at most {MAX_RANGE_M} m");
            return Err(ScanError::new("range_max", format!("{why}, got {hi}")));
        }
        Ok(())
    }

    /// Reading `j` as a range (m), or `None` for an invalid one (see the module docs).
    fn reading(&self, j: usize) -> Option<f64> {
        let r = self.ranges[j];
        if r == f32::INFINITY || r == 0.0 {
            Some(self.range_max)
        } else if r == f32::NEG_INFINITY {
            Some(self.range_min)
        } else {
            let r = f64::from(r);
            (self.range_min..=self.range_max).contains(&r).then_some(r)
        }
    }
}

/// Resamples `scan`, from a sensor mounted as `setup` says, to the meta agent's `layout`,
/// writing one range (m, robot frame, from the axle centre) per meta beam into `out`. Returns
/// how many meta beams no valid reading reached (they read what `setup.uncovered` says).
///
/// # Panics
/// If `out` is not `layout.beams` long.
pub fn resample(
    scan: &LaserScan,
    setup: &SensorSetup,
    layout: BeamLayout,
    out: &mut [f32],
) -> Result<usize, ScanError> {
    assert_eq!(out.len(), layout.beams, "one output per meta beam");
    scan.validate()?;
    let mut nearest = vec![f64::INFINITY; layout.beams];
    let half = scan.angle_increment.abs() / 2.0;
    for j in 0..scan.ranges.len() {
        let Some(r) = scan.reading(j) else { continue };
        let theta = setup.yaw + scan.angle_min + j as f64 * scan.angle_increment;
        let (lo, hi, range) = if setup.centred() {
            (theta - half, theta + half, r)
        } else {
            mounted_interval(setup, theta, half, r)
        };
        layout.overlapping(lo, hi, |i| nearest[i] = nearest[i].min(range));
    }
    let filled = nearest.iter().filter(|r| !r.is_finite()).count();
    match setup.uncovered {
        Uncovered::Range(u) => nearest.iter_mut().filter(|r| !r.is_finite()).for_each(|r| *r = u),
        Uncovered::Nearest => fill_from_neighbours(&mut nearest, layout.wraps()),
    }
    for (o, &r) in out.iter_mut().zip(&nearest) {
        *o = r as f32;
    }
    Ok(filled)
}

/// Gives every run of unseen (infinite) beams the nearer of the seen ranges at its two ends (one
/// end at the edge of a field that does not wrap; `wraps`: the last beam neighbours the first).
/// With no beam seen at all, every beam reads 0 (blocked): a scan that says nothing is no
/// licence to drive.
pub(crate) fn fill_from_neighbours(ranges: &mut [f64], wraps: bool) {
    let n = ranges.len();
    let Some(seen) = ranges.iter().position(|r| r.is_finite()) else {
        ranges.iter_mut().for_each(|r| *r = 0.0);
        return;
    };
    // Walk once around (or across) from a seen beam, so that every run has a known start.
    let order: Vec<usize> =
        if wraps { (0..n).map(|k| (seen + k) % n).collect() } else { (0..n).collect() };
    let mut k = 0;
    while k < n {
        if ranges[order[k]].is_finite() {
            k += 1;
            continue;
        }
        let end = (k..n).find(|&e| ranges[order[e]].is_finite());
        let before = (k > 0).then(|| ranges[order[k - 1]]);
        let after = match end {
            Some(e) => Some(ranges[order[e]]),
            None if wraps => Some(ranges[order[0]]),
            None => None,
        };
        let value = match (before, after) {
            (Some(a), Some(b)) => a.min(b),
            (Some(a), None) | (None, Some(a)) => a,
            (None, None) => unreachable!("a seen beam exists"),
        };
        let stop = end.unwrap_or(n);
        for &i in &order[k..stop] {
            ranges[i] = value;
        }
        k = stop;
    }
}

/// A reading `r` along `theta ± half` (sensor at `setup`) seen from the axle centre: the
/// interval between its edge points' bearings and the nearest of its edges and centre.
fn mounted_interval(setup: &SensorSetup, theta: f64, half: f64, r: f64) -> (f64, f64, f64) {
    let point = |a: f64| (setup.x + r * a.cos(), setup.y + r * a.sin());
    let (p0, pc, p1) = (point(theta - half), point(theta), point(theta + half));
    let norm = |p: (f64, f64)| p.0.hypot(p.1);
    let range = norm(p0).min(norm(pc)).min(norm(p1));
    let a0 = p0.1.atan2(p0.0);
    // The short way round from a0 to a1 (a reading's interval is well under half a turn).
    let d = (p1.1.atan2(p1.0) - a0 + PI).rem_euclid(TAU) - PI;
    if d >= 0.0 { (a0, a0 + d, range) } else { (a0 + d, a0, range) }
}

#[cfg(test)]
mod tests;
