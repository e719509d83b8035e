//! Where a robot of a given size can go in a room: a raster of the room's static shapes, its
//! distance transform, and from that the cells a disc of radius r can occupy, their connected
//! components and shortest paths between them.
//!
//! Episode sampling uses it so that every start and goal are reachable for the robot (a gate
//! too narrow for a big robot splits the room in two), and so that a task's path length can be
//! bounded relative to its straight line; the room generators use it to keep every generated
//! room connected.
//!
//! Conservative by construction, so a "reachable" answer is always true of the exact geometry:
//! - a cell is *occupied* when a shape comes within half a cell diagonal of its centre, so every
//!   point of every shape lies within half a diagonal of an occupied centre;
//! - a cell is *passable* for radius r when its centre lies at least `r + diagonal` from every
//!   occupied centre, so the disc of radius r is clear on the whole straight segment between
//!   two neighbouring passable centres (each point of it is within half a diagonal of one);
//! - a point joins the grid through a passable centre no farther than `slack` from it, where
//!   the caller knows the point has clearance `r + slack` (a sampled start has the spawn
//!   clearance on top of the robot's radius).
//!
//! It may call a narrow but passable gap blocked; it never calls a blocked gap passable.

use super::spec::{ObstacleSpec, Point, RoomSpec};
use std::collections::BinaryHeap;
use std::sync::OnceLock;

/// Cells per side at most along the room's square (the resolution grows for big rooms).
const MAX_CELLS_PER_SIDE: f64 = 400.0;
/// Cells per side at most of the path planner's raster ([`Raster::for_planning`]).
pub const PLAN_MAX_CELLS_PER_SIDE: f64 = 1600.0;
/// Finest resolution (m) of a room's [`ClearanceMap`].
const FINEST: f64 = 0.025;

/// A square raster over a room's square: cell (i, j) has its centre at
/// `origin + (i + ½, j + ½)·res`.
#[derive(Clone, Debug, PartialEq)]
pub struct Raster {
    /// Cell size (m).
    pub res: f64,
    /// Lower-left corner of cell (0, 0) (m).
    pub origin: Point,
    /// Cells per side.
    pub n: usize,
}

impl Raster {
    /// The raster of a room of side `side`: 2.5 cm cells, coarser for rooms over 10 m.
    pub fn for_side(side: f64) -> Raster {
        Raster::for_side_with(side, MAX_CELLS_PER_SIDE)
    }

    /// The path planner's raster of a room of side `side`: 2.5 cm cells up to 40 m, then
    /// [`PLAN_MAX_CELLS_PER_SIDE`] a side (3.6 cm for the 58 m Willow Garage map, whose own
    /// pixels are 5 cm).
    pub fn for_planning(side: f64) -> Raster {
        Raster::for_side_with(side, PLAN_MAX_CELLS_PER_SIDE)
    }

    /// The raster of a room of side `side` with at most about `max_cells` cells a side: 2.5 cm
    /// cells, coarser where the room needs more.
    pub fn for_side_with(side: f64, max_cells: f64) -> Raster {
        let res = FINEST.max(side / max_cells);
        let n = (side / res).ceil() as usize;
        let half = n as f64 * res / 2.0;
        Raster { res, origin: [-half, -half], n }
    }

    /// Centre of cell `(i, j)`.
    pub fn centre(&self, i: usize, j: usize) -> Point {
        [self.origin[0] + (i as f64 + 0.5) * self.res, self.origin[1] + (j as f64 + 0.5) * self.res]
    }

    /// Flat index of cell `(i, j)`.
    pub(crate) fn index(&self, i: usize, j: usize) -> usize {
        j * self.n + i
    }

    /// The cell whose square holds `p`, if `p` is on the raster.
    pub(crate) fn cell_of(&self, p: Point) -> Option<(usize, usize)> {
        let fi = ((p[0] - self.origin[0]) / self.res).floor();
        let fj = ((p[1] - self.origin[1]) / self.res).floor();
        let ok = |f: f64| f >= 0.0 && f < self.n as f64;
        (ok(fi) && ok(fj)).then_some((fi as usize, fj as usize))
    }

    /// Half a cell diagonal (m).
    pub(crate) fn half_diagonal(&self) -> f64 {
        self.res * std::f64::consts::FRAC_1_SQRT_2
    }
}

/// The room's static shapes rastered, and every cell centre's distance to the nearest occupied
/// centre.
#[derive(Clone, Debug)]
pub struct ClearanceMap {
    raster: Raster,
    /// Distance (m) from each cell centre to the nearest occupied cell centre (0 on occupied
    /// cells); `f64::INFINITY` when nothing is occupied.
    dist: Vec<f64>,
    /// Its blocks' greatest clearance, built when the planner first asks.
    blocks: OnceLock<Blocks>,
}

/// Cells per side of a [`Blocks`] block.
pub(crate) const BLOCK: usize = 4;

/// A [`ClearanceMap`] in blocks of [`BLOCK`]² cells, each with the greatest clearance of its
/// cells: where a disc fits *somewhere* in the block. Two cells a disc can drive between lie
/// in blocks joined by blocks where it fits, so a search here that finds no way proves there
/// is none, and the way it finds is a corridor for the search of the cells
/// ([`crate::planner`]).
#[derive(Clone, Debug)]
pub(crate) struct Blocks {
    /// Blocks per side (the last row and column may hold fewer cells).
    pub(crate) n: usize,
    /// Greatest clearance (m) of each block's cells, by flat block index.
    pub(crate) max: Vec<f64>,
}

impl Blocks {
    fn of(dist: &[f64], n: usize) -> Blocks {
        let nb = n.div_ceil(BLOCK);
        let mut max = vec![0.0f64; nb * nb];
        for j in 0..n {
            let row = &dist[j * n..(j + 1) * n];
            let out = &mut max[(j / BLOCK) * nb..(j / BLOCK + 1) * nb];
            for (i, &d) in row.iter().enumerate() {
                let m = &mut out[i / BLOCK];
                *m = m.max(d);
            }
        }
        Blocks { n: nb, max }
    }

    /// The block holding cell `c` of an `n`-cell raster.
    pub(crate) fn of_cell(&self, c: usize, n: usize) -> usize {
        (c / n / BLOCK) * self.n + (c % n) / BLOCK
    }
}

impl ClearanceMap {
    /// The walls and static obstacles of `spec` (timed obstacles are left out: they are not
    /// there when an episode starts).
    pub fn of_room(spec: &RoomSpec) -> ClearanceMap {
        ClearanceMap::of_room_on(spec, Raster::for_side(spec.side))
    }

    /// The same on a raster of the caller's (one covering the room's square).
    pub fn of_room_on(spec: &RoomSpec, raster: Raster) -> ClearanceMap {
        let mut occupied = vec![false; raster.n * raster.n];
        let inflate = raster.half_diagonal();
        for shape in spec.walls().iter().chain(&spec.obstacles) {
            shape.for_each_primitive(&mut |p| mark(&raster, p, inflate, &mut occupied));
        }
        let dist = distance_transform(&occupied, raster.n)
            .into_iter()
            .map(|d| d.sqrt() * raster.res)
            .collect();
        ClearanceMap { raster, dist, blocks: OnceLock::new() }
    }

    /// The raster.
    pub fn raster(&self) -> &Raster {
        &self.raster
    }

    /// This map with the cells holding `points` occupied as well: a scan's returns, so that a
    /// replan goes round a door that has closed or a person standing in the way. A point in a
    /// cell within `known_m` of an occupied one is the map's own obstacle seen with some error
    /// and marks nothing.
    pub fn with_points(&self, points: &[Point], known_m: f64) -> ClearanceMap {
        let r = &self.raster;
        let mut occupied: Vec<bool> = self.dist.iter().map(|&d| d == 0.0).collect();
        for &p in points {
            if let Some((i, j)) = r.cell_of(p) {
                let c = r.index(i, j);
                if self.dist[c] > known_m {
                    occupied[c] = true;
                }
            }
        }
        let dist =
            distance_transform(&occupied, r.n).into_iter().map(|d| d.sqrt() * r.res).collect();
        ClearanceMap { raster: r.clone(), dist, blocks: OnceLock::new() }
    }

    /// Each cell centre's distance (m) to the nearest occupied centre, by flat index.
    pub(crate) fn distances(&self) -> &[f64] {
        &self.dist
    }

    /// The map in blocks ([`Blocks`]), built on first use.
    pub(crate) fn blocks(&self) -> &Blocks {
        self.blocks.get_or_init(|| Blocks::of(&self.dist, self.raster.n))
    }

    /// The clearance a disc centred on cell centres must have to be passable
    /// ([`ClearanceMap::reach`]): its radius plus a cell diagonal.
    pub(crate) fn passable_need(&self, radius: f64) -> f64 {
        radius + 2.0 * self.raster.half_diagonal()
    }

    /// The cells a disc of `radius` can be at, and their components.
    pub fn reach(&self, radius: f64) -> Reach {
        let r = &self.raster;
        let need = self.passable_need(radius);
        let passable: Vec<bool> = self.dist.iter().map(|&d| d >= need).collect();
        let (label, sizes) = components(&passable, r.n);
        Reach { raster: r.clone(), radius, label, sizes }
    }
}

/// Marks every cell whose centre lies within `inflate` of the convex shape `p`.
fn mark(r: &Raster, p: &ObstacleSpec, inflate: f64, occupied: &mut [bool]) {
    let [lo, hi] = p.aabb();
    let span = |lo: f64, hi: f64, o: f64| {
        let a = ((lo - inflate - o) / r.res - 0.5).ceil().max(0.0) as usize;
        let b = ((hi + inflate - o) / r.res - 0.5).floor();
        (a, if b < 0.0 { None } else { Some((b as usize).min(r.n - 1)) })
    };
    let (i0, i1) = span(lo[0], hi[0], r.origin[0]);
    let (j0, j1) = span(lo[1], hi[1], r.origin[1]);
    let (Some(i1), Some(j1)) = (i1, j1) else { return };
    for j in j0..=j1 {
        for i in i0..=i1 {
            if distance_to_convex(p, r.centre(i, j)) <= inflate {
                occupied[r.index(i, j)] = true;
            }
        }
    }
}

/// Distance (m) from `q` to the convex shape `p` (0 inside).
pub(crate) fn distance_to_convex(p: &ObstacleSpec, q: Point) -> f64 {
    match p {
        ObstacleSpec::Circle { center, radius } => {
            ((center[0] - q[0]).hypot(center[1] - q[1]) - radius).max(0.0)
        }
        other => {
            let v = other.vertices().unwrap_or_default();
            let n = v.len();
            let mut inside = n >= 3;
            let mut best = f64::INFINITY;
            for k in 0..n {
                let (a, b) = (v[k], v[(k + 1) % n]);
                let e = [b[0] - a[0], b[1] - a[1]];
                let w = [q[0] - a[0], q[1] - a[1]];
                if e[0] * w[1] - e[1] * w[0] < 0.0 {
                    inside = false;
                }
                let t = ((w[0] * e[0] + w[1] * e[1]) / (e[0] * e[0] + e[1] * e[1])).clamp(0.0, 1.0);
                best = best.min((w[0] - t * e[0]).hypot(w[1] - t * e[1]));
            }
            if inside { 0.0 } else { best }
        }
    }
}

/// Squared Euclidean distance transform (in m² once scaled) of an `n`×`n` raster: for every
/// cell, the squared distance in cells to the nearest `true` cell (Felzenszwalb and
/// Huttenlocher's two passes of lower envelopes of parabolas); infinite with nothing occupied.
fn distance_transform(occupied: &[bool], n: usize) -> Vec<f64> {
    // Far beyond any real squared distance (≤ 2·1600² cells² on the planner's raster), small
    // enough to stay exact.
    const FAR: f64 = 1e12;
    let mut grid: Vec<f64> = occupied.iter().map(|&o| if o { 0.0 } else { FAR }).collect();
    let mut line = vec![0.0; n];
    let mut out = vec![0.0; n];
    // Columns, then rows.
    for i in 0..n {
        for j in 0..n {
            line[j] = grid[j * n + i];
        }
        envelope(&line, &mut out);
        for j in 0..n {
            grid[j * n + i] = out[j];
        }
    }
    for j in 0..n {
        line.copy_from_slice(&grid[j * n..(j + 1) * n]);
        envelope(&line, &mut out);
        grid[j * n..(j + 1) * n].copy_from_slice(&out);
    }
    grid.into_iter().map(|d| if d >= FAR / 2.0 { f64::INFINITY } else { d }).collect()
}

/// One dimension of the distance transform: `out[q] = min_p (q − p)² + f[p]`.
fn envelope(f: &[f64], out: &mut [f64]) {
    let n = f.len();
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let sq = |x: usize| (x * x) as f64;
    let cross = |q: usize, p: usize| ((f[q] + sq(q)) - (f[p] + sq(p))) / (2.0 * (q - p) as f64);
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        let mut s = cross(q, v[k]);
        // z[0] = −∞ stops the loop at k = 0.
        while s <= z[k] {
            k -= 1;
            s = cross(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let d = q as f64 - v[k] as f64;
        *o = d * d + f[v[k]];
    }
}

/// 8-connected components of the passable cells: a label per cell (0: not passable, else the
/// component's number from 1) and each component's size (index = label − 1).
fn components(passable: &[bool], n: usize) -> (Vec<u32>, Vec<usize>) {
    let mut label = vec![0u32; passable.len()];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..passable.len() {
        if !passable[start] || label[start] != 0 {
            continue;
        }
        let id = sizes.len() as u32 + 1;
        let mut size = 0;
        label[start] = id;
        stack.push(start);
        while let Some(c) = stack.pop() {
            size += 1;
            for nb in neighbours(c, n) {
                if passable[nb.0] && label[nb.0] == 0 {
                    label[nb.0] = id;
                    stack.push(nb.0);
                }
            }
        }
        sizes.push(size);
    }
    (label, sizes)
}

/// The 8 neighbours of flat cell `c` on an `n`×`n` raster, with the step length in cells.
pub(crate) fn neighbours(c: usize, n: usize) -> impl Iterator<Item = (usize, f64)> {
    let (i, j) = ((c % n) as isize, (c / n) as isize);
    const STEPS: [(isize, isize, f64); 8] = [
        (1, 0, 1.0),
        (-1, 0, 1.0),
        (0, 1, 1.0),
        (0, -1, 1.0),
        (1, 1, std::f64::consts::SQRT_2),
        (1, -1, std::f64::consts::SQRT_2),
        (-1, 1, std::f64::consts::SQRT_2),
        (-1, -1, std::f64::consts::SQRT_2),
    ];
    let n = n as isize;
    STEPS.into_iter().filter_map(move |(di, dj, len)| {
        let (a, b) = (i + di, j + dj);
        (a >= 0 && b >= 0 && a < n && b < n).then_some(((b * n + a) as usize, len))
    })
}

/// Where a disc of one radius can go: passable cells labelled by connected component.
#[derive(Clone, Debug)]
pub struct Reach {
    raster: Raster,
    radius: f64,
    label: Vec<u32>,
    sizes: Vec<usize>,
}

impl Reach {
    /// The disc's radius (m).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The raster.
    pub fn raster(&self) -> &Raster {
        &self.raster
    }

    /// Number of connected components of the free space.
    pub fn component_count(&self) -> usize {
        self.sizes.len()
    }

    /// Passable cells in all.
    pub fn passable_cells(&self) -> usize {
        self.sizes.iter().sum()
    }

    /// Area (m²) of the largest component's cells: where the disc's centre can go from there.
    pub fn largest_area_m2(&self) -> f64 {
        let cells = self.sizes.iter().max().copied().unwrap_or(0);
        cells as f64 * self.raster.res * self.raster.res
    }

    /// Share of the passable cells in the largest component (0 when none is passable).
    pub fn largest_share(&self) -> f64 {
        let total = self.passable_cells();
        if total == 0 { 0.0 } else { *self.sizes.iter().max().unwrap() as f64 / total as f64 }
    }

    /// `count` pairs of passable cell centres of one component each, drawn uniformly from the
    /// passable cells (so a big component is drawn more often) and at least `min_dist` (m)
    /// apart; `None` when a thousand draws in a row find no such pair.
    pub fn random_connected_pairs(
        &self,
        rng: &mut impl rand::Rng,
        count: usize,
        min_dist: f64,
    ) -> Option<Vec<(Point, Point)>> {
        let cells: Vec<usize> = (0..self.label.len()).filter(|&c| self.label[c] != 0).collect();
        if cells.is_empty() {
            return None;
        }
        let n = self.raster.n;
        let centre = |c: usize| self.raster.centre(c % n, c / n);
        let mut draw = || {
            (0..1000).find_map(|_| {
                let a = cells[rng.random_range(0..cells.len())];
                let b = cells[rng.random_range(0..cells.len())];
                let (pa, pb) = (centre(a), centre(b));
                let far = (pa[0] - pb[0]).hypot(pa[1] - pb[1]) >= min_dist;
                (self.label[a] == self.label[b] && far).then_some((pa, pb))
            })
        };
        (0..count).map(|_| draw()).collect()
    }

    /// The passable cells within `slack` (m) of `p`, nearest first: the cells `p` joins the
    /// grid through when it has clearance `radius + slack`. A slack under 1.5 cells (a point
    /// with little clearance to spare) searches 1.5 cells anyway: then the join is a good
    /// guess rather than a guarantee.
    fn entries(&self, p: Point, slack: f64) -> Vec<(f64, usize)> {
        let r = &self.raster;
        let slack = slack.max(1.5 * r.res);
        let k = (slack / r.res).ceil() as isize + 1;
        let Some((ci, cj)) = r.cell_of(p) else { return Vec::new() };
        let mut out = Vec::new();
        for dj in -k..=k {
            for di in -k..=k {
                let (i, j) = (ci as isize + di, cj as isize + dj);
                if i < 0 || j < 0 || i >= r.n as isize || j >= r.n as isize {
                    continue;
                }
                let (i, j) = (i as usize, j as usize);
                let c = r.centre(i, j);
                let d = (c[0] - p[0]).hypot(c[1] - p[1]);
                let idx = r.index(i, j);
                if d <= slack && self.label[idx] != 0 {
                    out.push((d, idx));
                }
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }

    /// The component `p` belongs to, for a point with clearance at least `radius + slack`;
    /// `None` when no passable cell is near enough to tell.
    pub fn component_at(&self, p: Point, slack: f64) -> Option<u32> {
        self.entries(p, slack).first().map(|&(_, c)| self.label[c])
    }

    /// True when the disc can drive from `a` to `b` (both with clearance `radius + slack`).
    pub fn connected(&self, a: Point, b: Point, slack: f64) -> bool {
        matches!((self.component_at(a, slack), self.component_at(b, slack)), (Some(x), Some(y)) if x == y)
    }

    /// Length (m) of a shortest 8-connected grid path from `a` to `b` through passable cells,
    /// including the two joins, or `None` when `b` is not reachable. An upper bound on the
    /// true shortest path of the disc, at most ~8 % above it in open space.
    pub fn path_length(&self, a: Point, b: Point, slack: f64) -> Option<f64> {
        let from = self.entries(a, slack);
        let to = self.entries(b, slack);
        let (&(da, ca), &(db, cb)) = (from.first()?, to.first()?);
        if self.label[ca] != self.label[cb] {
            return None;
        }
        let n = self.raster.n;
        let res = self.raster.res;
        let goal = self.raster.centre(cb % n, cb / n);
        let h = |c: usize| {
            let p = self.raster.centre(c % n, c / n);
            (p[0] - goal[0]).hypot(p[1] - goal[1]) / res
        };
        // A* in cells with the straight-line heuristic (admissible and consistent).
        let mut g = vec![f64::INFINITY; self.label.len()];
        let mut heap = BinaryHeap::new();
        g[ca] = 0.0;
        heap.push(Open { f: h(ca), c: ca });
        while let Some(Open { f, c }) = heap.pop() {
            if c == cb {
                return Some(g[c] * res + da + db);
            }
            if f > g[c] + h(c) + 1e-9 {
                continue;
            }
            for (nb, len) in neighbours(c, n) {
                if self.label[nb] == 0 {
                    continue;
                }
                let cand = g[c] + len;
                if cand < g[nb] {
                    g[nb] = cand;
                    heap.push(Open { f: cand + h(nb), c: nb });
                }
            }
        }
        None
    }
}

/// The free space of a room for one disc radius, built shape by shape: the room generators'
/// placement test. A cell is blocked when a shape comes closer to its centre than the radius
/// plus half a cell diagonal (so, as with [`Reach`], the disc is clear along the straight
/// segment between two neighbouring free centres). Cheaper than a [`ClearanceMap`] per test:
/// adding a shape touches only the cells near it; the connectivity count is one flood fill.
#[derive(Clone, Debug)]
pub struct FreeSpace {
    raster: Raster,
    radius: f64,
    blocked: Vec<bool>,
}

impl FreeSpace {
    /// Cell size (m) of the generators' test: fine enough for a 0.6 m door and the meta
    /// robot, coarse enough to test hundreds of placements per room quickly.
    pub const RES: f64 = 0.05;

    /// An empty square of side `side` for a disc of `radius`.
    pub fn new(side: f64, radius: f64) -> FreeSpace {
        let res = Self::RES.max(side / MAX_CELLS_PER_SIDE);
        let n = (side / res).ceil() as usize;
        let half = n as f64 * res / 2.0;
        let raster = Raster { res, origin: [-half, -half], n };
        FreeSpace { blocked: vec![false; n * n], raster, radius }
    }

    /// The walls and static obstacles of `spec`.
    pub fn of_room(spec: &RoomSpec, radius: f64) -> FreeSpace {
        let mut free = FreeSpace::new(spec.side, radius);
        for shape in spec.walls().iter().chain(&spec.obstacles) {
            free.block(shape);
        }
        free
    }

    /// Blocks the cells `shape` makes unusable; returns those newly blocked.
    pub fn block(&mut self, shape: &ObstacleSpec) -> Vec<usize> {
        let r = self.raster.clone();
        let reach = self.radius + r.half_diagonal();
        let mut newly = Vec::new();
        shape.for_each_primitive(&mut |p| {
            let [lo, hi] = p.aabb();
            let cells = |lo: f64, hi: f64, o: f64| {
                let a = ((lo - reach - o) / r.res - 0.5).ceil().max(0.0) as usize;
                let b = ((hi + reach - o) / r.res - 0.5).floor();
                (b >= 0.0).then(|| (a, (b as usize).min(r.n - 1)))
            };
            let (Some((i0, i1)), Some((j0, j1))) =
                (cells(lo[0], hi[0], r.origin[0]), cells(lo[1], hi[1], r.origin[1]))
            else {
                return;
            };
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let k = r.index(i, j);
                    if !self.blocked[k] && distance_to_convex(p, r.centre(i, j)) < reach {
                        self.blocked[k] = true;
                        newly.push(k);
                    }
                }
            }
        });
        newly
    }

    /// Adds `shape` if the free space stays one connected region; says whether it did.
    pub fn try_add(&mut self, shape: &ObstacleSpec) -> bool {
        let newly = self.block(shape);
        if self.components() <= 1 {
            return true;
        }
        for k in newly {
            self.blocked[k] = false;
        }
        false
    }

    /// Connected regions of free cells.
    pub fn components(&self) -> usize {
        let free: Vec<bool> = self.blocked.iter().map(|b| !b).collect();
        components(&free, self.raster.n).1.len()
    }

    /// Share of the square's cells that are free.
    pub fn free_share(&self) -> f64 {
        self.blocked.iter().filter(|b| !**b).count() as f64 / self.blocked.len() as f64
    }
}

/// An A* frontier entry, popped smallest `f` first.
pub(crate) struct Open {
    pub(crate) f: f64,
    pub(crate) c: usize,
}

impl PartialEq for Open {
    fn eq(&self, o: &Self) -> bool {
        self.f == o.f
    }
}
impl Eq for Open {}
impl PartialOrd for Open {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Open {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        o.f.total_cmp(&self.f)
    }
}

mod centres;
mod geodesic;
pub use geodesic::GeodesicField;

#[cfg(test)]
mod tests;
