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
use crate::grid::{BLOCK, ClearanceMap};
use crate::spec::Point;
use search::{Grid, Search};

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
    /// A replan after a stall marks the scan's returns as obstacles, except those within this
    /// distance (m) of the map's own obstacles: those are the walls already known, seen through
    /// range noise and localization error, and marking them narrows every door the robot
    /// stands in (under σ = 0.02 m noise, half the long tasks of a tuning room at R = 0.5
    /// ended `blocked` so; docs/results.md, "Replans after a stall"). 0 marks every return.
    pub known_tolerance_m: f64,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            margin_m: 0.0,
            clearance_weight: 2.0,
            clearance_decay_m: 0.3,
            preferred_clearance_m: 0.25,
            known_tolerance_m: 0.1,
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

/// Blocks of dilation round the block path that the cell search may use: the cheapest path
/// of the cells keeps within about a metre of the blocks' (measured on Willow Garage,
/// `dvnav bench plan`).
const CORRIDOR_BLOCKS: usize = 3;

/// Rasters with fewer cells a side are searched cell by cell at once.
const SEARCH_BLOCKS_FROM: usize = 480;

/// A* from cell `from` to cell `to` over cells with clearance ≥ `need`, each step's length
/// times `1 + w·exp(−(clearance − need)/decay)` of the cell stepped into; the cells of the
/// cheapest path, `from` first.
///
/// On a big raster (a building at its map's resolution) the search runs on the map's blocks
/// first ([`crate::grid::Blocks`], each with its best cell's clearance, so it never misses a
/// way and proves unreachability at a sixteenth of the cells), then on the cells of a
/// corridor round the block path; if the corridor holds no way (a door that fits somewhere in
/// its blocks but not along them), the cells of the whole map.
fn astar(
    map: &ClearanceMap,
    need: f64,
    from: usize,
    to: usize,
    cfg: &PlannerConfig,
) -> Option<Vec<usize>> {
    astar_by(map, need, from, to, cfg, map.raster().n >= SEARCH_BLOCKS_FROM)
}

/// [`astar`], by blocks first or not.
fn astar_by(
    map: &ClearanceMap,
    need: f64,
    from: usize,
    to: usize,
    cfg: &PlannerConfig,
    by_blocks: bool,
) -> Option<Vec<usize>> {
    let raster = map.raster();
    let n = raster.n;
    let dist_of = map.distances();
    let decay = cfg.clearance_decay_m.max(1e-9);
    let cost = |clear: f64| {
        (clear >= need).then(|| 1.0 + cfg.clearance_weight * (-(clear - need) / decay).exp())
    };
    let cells = |allowed: &dyn Fn(usize) -> bool| {
        let grid = Grid { n, unit: 1.0, cost: |c: usize| cost(dist_of[c]), allowed };
        CELLS.with_borrow_mut(|s| grid.astar(s, from, to))
    };
    if !by_blocks {
        return cells(&|_| true);
    }
    let blocks = map.blocks();
    let nb = blocks.n;
    let blocks_grid =
        Grid { n: nb, unit: BLOCK as f64, cost: |b: usize| cost(blocks.max[b]), allowed: |_| true };
    let (bf, bt) = (blocks.of_cell(from, n), blocks.of_cell(to, n));
    let way = BLOCKS.with_borrow_mut(|s| blocks_grid.astar(s, bf, bt))?;
    let mut corridor = vec![false; nb * nb];
    let k = CORRIDOR_BLOCKS as isize;
    for &b in &way {
        let (bi, bj) = ((b % nb) as isize, (b / nb) as isize);
        for j in (bj - k).max(0)..=(bj + k).min(nb as isize - 1) {
            for i in (bi - k).max(0)..=(bi + k).min(nb as isize - 1) {
                corridor[j as usize * nb + i as usize] = true;
            }
        }
    }
    cells(&|c| corridor[blocks.of_cell(c, n)]).or_else(|| cells(&|_| true))
}

thread_local! {
    /// Each thread's search arrays for the cells and for the blocks, reused from plan to plan.
    static CELLS: std::cell::RefCell<Search> = std::cell::RefCell::new(Search::default());
    static BLOCKS: std::cell::RefCell<Search> = std::cell::RefCell::new(Search::default());
}

/// The polyline `points` cut, from each kept vertex, to a farther one in line of sight: a
/// shortcut's every cell keeps clearance `min(need + preferred, the least clearance of the
/// vertices it skips and joins)` (never below `need`), so it is never tighter than the grid
/// path was there. The farthest such vertex is found by galloping and then bisecting along the
/// path (a few segment tests, not one per vertex: a straight corridor of a building is
/// hundreds of cells), so where sight comes and goes along the path the cut may land past a
/// vertex that is not in sight, never on one.
fn pull_string(
    map: &ClearanceMap,
    points: &[Point],
    clear: &[f64],
    need: f64,
    preferred: f64,
) -> Vec<Point> {
    let last = points.len() - 1;
    let mut out = vec![points[0]];
    let mut a = 0;
    while a < last {
        let in_sight = |j: usize| {
            let least = clear[a..=j].iter().copied().fold(f64::INFINITY, f64::min);
            segment_clear(map, points[a], points[j], least.min(need + preferred).max(need))
        };
        // The next vertex is always taken: the grid path steps to it.
        let mut good = a + 1;
        let mut step = 1;
        let mut bad = None;
        while good < last {
            let j = (good + step).min(last);
            if in_sight(j) {
                good = j;
                step *= 2;
            } else {
                bad = Some(j);
                break;
            }
        }
        if let Some(mut bad) = bad {
            while bad - good > 1 {
                let mid = good + (bad - good) / 2;
                if in_sight(mid) {
                    good = mid;
                } else {
                    bad = mid;
                }
            }
        }
        out.push(points[good]);
        a = good;
    }
    out
}

/// True when a disc of about `radius` can slide from `a` to `b` on `map`: every cell on the way
/// has its centre at least `radius` from the nearest occupied centre (within a cell diagonal
/// of exact). The subgoal rule keeps its subgoal in sight with it.
pub fn line_of_sight(map: &ClearanceMap, a: Point, b: Point, radius: f64) -> bool {
    segment_clear(map, a, b, radius)
}

/// True when every cell the segment `a`–`b` passes through is on the raster and has
/// clearance at least `want` (the cells walked in order, Amanatides and Woo's traversal).
fn segment_clear(map: &ClearanceMap, a: Point, b: Point, want: f64) -> bool {
    let r = map.raster();
    let dist_of = map.distances();
    let to_grid = |p: Point| [(p[0] - r.origin[0]) / r.res, (p[1] - r.origin[1]) / r.res];
    let (ga, gb) = (to_grid(a), to_grid(b));
    let n = r.n as f64;
    let on = |g: [f64; 2]| g.iter().all(|&v| v >= 0.0 && v < n);
    if !on(ga) || !on(gb) {
        return false;
    }
    let (mut i, mut j) = (ga[0] as usize, ga[1] as usize);
    let (bi, bj) = (gb[0] as usize, gb[1] as usize);
    let (dx, dy) = (gb[0] - ga[0], gb[1] - ga[1]);
    // Per axis: the step, the parameter t (0 at a, 1 at b) of the next cell border and the
    // parameter a cell's width takes.
    let axis = |d: f64, g: f64, cell: usize| -> (isize, f64, f64) {
        if d > 0.0 {
            (1, (cell as f64 + 1.0 - g) / d, 1.0 / d)
        } else if d < 0.0 {
            (-1, (g - cell as f64) / -d, -1.0 / d)
        } else {
            (0, f64::INFINITY, f64::INFINITY)
        }
    };
    let (si, mut ti, di) = axis(dx, ga[0], i);
    let (sj, mut tj, dj) = axis(dy, ga[1], j);
    // Each step moves one cell towards b's: this many reach it (should rounding step past it,
    // b's cell is still tested).
    for _ in 0..=(i.abs_diff(bi) + j.abs_diff(bj)) {
        if dist_of[r.index(i, j)] < want {
            return false;
        }
        if (i, j) == (bi, bj) {
            return true;
        }
        if ti < tj {
            i = i.wrapping_add_signed(si);
            ti += di;
        } else {
            j = j.wrapping_add_signed(sj);
            tj += dj;
        }
        if i >= r.n || j >= r.n {
            return false;
        }
    }
    dist_of[r.index(bi, bj)] >= want
}

mod search;
#[cfg(test)]
mod tests;
