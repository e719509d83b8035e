//! The path planner: a route through a room for a robot of a given size, for the meta agent to
//! follow by subgoals ([`crate::subgoal`]).
//!
//! Nav2's split, on the room's own raster ([`crate::grid::ClearanceMap`]):
//! - the costmap is the clearance raster *inflated by the footprint*: a cell is passable when
//!   its centre lies at least the robot's bounding radius (plus a margin) and a cell diagonal
//!   from every occupied centre, the same conservative rule as [`crate::grid::Reach`], so the
//!   disc is clear along every step between two passable neighbours;
//! - A* over the 8-connected passable cells, each step's length weighted by an inflation cost
//!   that decays exponentially with the clearance beyond that need (Nav2's inflation layer),
//!   so a path keeps to the middle of a corridor where there is room and still squeezes through
//!   a door that just fits;
//! - string pulling: the grid path is cut to the farthest points in line of sight, where a
//!   shortcut may come no closer to the walls than the grid path did between the same points
//!   (up to `preferred_clearance_m`), so a lookahead point on the result is never behind a
//!   corner and the path loses the grid's 45° zig-zags without hugging walls.

use crate::dist;
use crate::grid::{ClearanceMap, Open, neighbours};
use crate::spec::Point;
use std::collections::BinaryHeap;

/// How paths are shaped (the defaults are measured: `dvnav bench plan`, docs/results.md).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlannerConfig {
    /// Clearance (m) kept beyond the robot's bounding radius, on top of the raster's own
    /// conservative cell diagonal.
    pub margin_m: f64,
    /// Weight of the inflation cost: a step next to the walls costs `1 + weight` times its
    /// length, one with plenty of room about 1.
    pub clearance_weight: f64,
    /// Distance (m) over which the inflation cost falls by e beyond the needed clearance.
    pub clearance_decay_m: f64,
    /// Clearance (m) beyond the need that a shortcut keeps where the grid path had it.
    pub preferred_clearance_m: f64,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            margin_m: 0.0,
            clearance_weight: 2.0,
            clearance_decay_m: 0.3,
            preferred_clearance_m: 0.25,
        }
    }
}

/// A planned route: a polyline from the start to the goal (room frame, m).
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedPath {
    /// Vertices, the start first and the goal last.
    pub points: Vec<Point>,
    /// Length of the polyline (m).
    pub length_m: f64,
}

impl PlannedPath {
    /// The polyline through `points` (at least one).
    pub fn new(points: Vec<Point>) -> PlannedPath {
        let length_m = points.windows(2).map(|w| dist(w[0], w[1])).sum();
        PlannedPath { points, length_m }
    }
}

/// Why no path was found; each names the point concerned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// The start or the goal is off the room's raster.
    #[error("the {which} ({:.2}, {:.2}) lies outside the map", point[0], point[1])]
    OffMap {
        /// `start` or `goal`.
        which: &'static str,
        /// The point (m).
        point: Point,
    },
    /// No passable cell for the robot near the start or the goal: it is inside an obstacle, or
    /// the robot does not fit there.
    #[error(
        "the {which} ({:.2}, {:.2}) has no room for a robot of radius {radius} m \
         (inside an obstacle or too close to one)",
        point[0],
        point[1]
    )]
    NoRoom {
        /// `start` or `goal`.
        which: &'static str,
        /// The point (m).
        point: Point,
        /// The robot's radius plus margin (m).
        radius: f64,
    },
    /// Start and goal lie in parts of the room that a robot of this size cannot drive between.
    #[error(
        "the goal ({:.2}, {:.2}) cannot be reached from the start by a robot of radius {radius} m",
        goal[0],
        goal[1]
    )]
    Unreachable {
        /// The goal (m).
        goal: Point,
        /// The robot's radius plus margin (m).
        radius: f64,
    },
}

/// Plans a path for a disc of `radius` (the robot's bounding radius) from `start` to `goal`.
pub fn plan(
    map: &ClearanceMap,
    radius: f64,
    start: Point,
    goal: Point,
    cfg: &PlannerConfig,
) -> Result<PlannedPath, PlanError> {
    let r = radius + cfg.margin_m;
    let need = map.passable_need(r);
    let dist_of = map.distances();
    let raster = map.raster();
    let from = entry(map, r, need, start, "start")?;
    let to = entry(map, r, need, goal, "goal")?;
    let cells =
        astar(map, need, from, to, cfg).ok_or(PlanError::Unreachable { goal, radius: r })?;
    // The grid path with the true start and goal at its ends; a vertex's clearance is its
    // cell's, the ends' left out (the robot is there whatever the grid says; a shortcut from a
    // tight start still has to clear its samples near it).
    let n = raster.n;
    let mut points = Vec::with_capacity(cells.len() + 2);
    let mut clear = Vec::with_capacity(cells.len() + 2);
    points.push(start);
    clear.push(f64::INFINITY);
    for &c in &cells {
        points.push(raster.centre(c % n, c / n));
        clear.push(dist_of[c]);
    }
    points.push(goal);
    clear.push(f64::INFINITY);
    Ok(PlannedPath::new(pull_string(map, &points, &clear, need, cfg.preferred_clearance_m)))
}

/// The passable cell `p` joins the grid through: the nearest one within reach whose straight
/// join does not pass through an obstacle.
fn entry(
    map: &ClearanceMap,
    r: f64,
    need: f64,
    p: Point,
    which: &'static str,
) -> Result<usize, PlanError> {
    let raster = map.raster();
    let Some((ci, cj)) = raster.cell_of(p) else {
        return Err(PlanError::OffMap { which, point: p });
    };
    let dist_of = map.distances();
    // A point with the robot's clearance is at most a cell diagonal (plus rounding) from a
    // passable centre; look a little farther for one that starts in a tight spot.
    let reach = (2.0 * r).max(4.0 * raster.res);
    let k = (reach / raster.res).ceil() as isize;
    let mut cands: Vec<(f64, usize)> = Vec::new();
    for dj in -k..=k {
        for di in -k..=k {
            let (i, j) = (ci as isize + di, cj as isize + dj);
            if i < 0 || j < 0 || i >= raster.n as isize || j >= raster.n as isize {
                continue;
            }
            let idx = raster.index(i as usize, j as usize);
            let d = dist(p, raster.centre(i as usize, j as usize));
            if dist_of[idx] >= need && d <= reach {
                cands.push((d, idx));
            }
        }
    }
    // Nearest first (stable: ties in scan order) among those whose join stays out of the walls
    // (half the radius clear): the nearest passable cell may be behind a thin wall.
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));
    cands
        .into_iter()
        .find(|&(_, idx)| {
            segment_clear(map, p, raster.centre(idx % raster.n, idx / raster.n), 0.5 * r)
        })
        .map(|(_, idx)| idx)
        .ok_or(PlanError::NoRoom { which, point: p, radius: r })
}

/// A* from cell `from` to cell `to` over cells with clearance ≥ `need`, each step's length
/// times `1 + w·exp(−(clearance − need)/decay)` of the cell stepped into; the cells of the
/// cheapest path, `from` first.
fn astar(
    map: &ClearanceMap,
    need: f64,
    from: usize,
    to: usize,
    cfg: &PlannerConfig,
) -> Option<Vec<usize>> {
    let raster = map.raster();
    let n = raster.n;
    let dist_of = map.distances();
    let (ti, tj) = ((to % n) as f64, (to / n) as f64);
    // In cells; every step costs at least its length, so the straight line is admissible.
    let h = |c: usize| ((c % n) as f64 - ti).hypot((c / n) as f64 - tj);
    let decay_cells = (cfg.clearance_decay_m / raster.res).max(1e-9);
    let cost = |c: usize| {
        let extra = (dist_of[c] - need) / raster.res;
        1.0 + cfg.clearance_weight * (-extra / decay_cells).exp()
    };
    let mut g = vec![f64::INFINITY; n * n];
    let mut parent = vec![u32::MAX; n * n];
    let mut heap = BinaryHeap::new();
    g[from] = 0.0;
    heap.push(Open { f: h(from), c: from });
    while let Some(Open { f, c }) = heap.pop() {
        if c == to {
            let mut cells = vec![to];
            let mut at = to;
            while at != from {
                at = parent[at] as usize;
                cells.push(at);
            }
            cells.reverse();
            return Some(cells);
        }
        if f > g[c] + h(c) + 1e-9 {
            continue;
        }
        for (nb, len) in neighbours(c, n) {
            if dist_of[nb] < need {
                continue;
            }
            let cand = g[c] + len * cost(nb);
            if cand < g[nb] {
                g[nb] = cand;
                parent[nb] = c as u32;
                heap.push(Open { f: cand + h(nb), c: nb });
            }
        }
    }
    None
}

/// The polyline `points` cut to the farthest vertex in line of sight from each kept one: a
/// shortcut's every sample keeps clearance `min(need + preferred, the least clearance of the
/// vertices it skips and joins)` (never below `need`), so it is never tighter than the grid
/// path was there.
fn pull_string(
    map: &ClearanceMap,
    points: &[Point],
    clear: &[f64],
    need: f64,
    preferred: f64,
) -> Vec<Point> {
    let mut out = vec![points[0]];
    let mut a = 0;
    while a + 1 < points.len() {
        let mut best = a + 1;
        let mut least = clear[a].min(clear[a + 1]);
        for j in a + 2..points.len() {
            least = least.min(clear[j]);
            let want = least.min(need + preferred).max(need);
            if segment_clear(map, points[a], points[j], want) {
                best = j;
            } else {
                break;
            }
        }
        out.push(points[best]);
        a = best;
    }
    out
}

/// True when a disc of about `radius` can slide from `a` to `b` on `map`: every cell on the way
/// has its centre at least `radius` from the nearest occupied centre (within a cell diagonal
/// of exact). The subgoal rule keeps its subgoal in sight with it.
pub fn line_of_sight(map: &ClearanceMap, a: Point, b: Point, radius: f64) -> bool {
    segment_clear(map, a, b, radius)
}

/// True when every point of the segment `a`–`b`, sampled every quarter cell, lies in a cell
/// with clearance at least `want`.
fn segment_clear(map: &ClearanceMap, a: Point, b: Point, want: f64) -> bool {
    let raster = map.raster();
    let dist_of = map.distances();
    let len = dist(a, b);
    let steps = ((len / (0.25 * raster.res)).ceil() as usize).max(1);
    (0..=steps).all(|k| {
        let t = k as f64 / steps as f64;
        let q = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
        raster.cell_of(q).is_some_and(|(i, j)| dist_of[raster.index(i, j)] >= want)
    })
}

#[cfg(test)]
mod tests;
