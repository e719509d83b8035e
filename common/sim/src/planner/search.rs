//! A* on a square 8-connected grid, for the planner's two levels (blocks, then cells).
//!
//! Built for maps at their own resolution (a building is a few million cells): the octile
//! distance is the heuristic (the exact grid length with no walls, so admissible and
//! consistent where every step costs at least its length, and far tighter than the straight
//! line on an 8-connected grid); the arrays are reused from search to search (a search touches
//! only the cells it reaches instead of clearing megabytes); the frontier is a heap of
//! `(f, cell)` packed in one `u64`.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// One grid search's problem: an `n`×`n` grid whose axis steps are `unit` long.
pub(super) struct Grid<C, A> {
    /// Cells per side.
    pub n: usize,
    /// Length of an axis step (a diagonal one is √2 times it).
    pub unit: f64,
    /// A cell's cost per unit of length stepped into it (≥ 1), `None` where it is impassable.
    pub cost: C,
    /// Whether the search may enter a cell at all (a corridor).
    pub allowed: A,
}

impl<C: Fn(usize) -> Option<f64>, A: Fn(usize) -> bool> Grid<C, A> {
    /// The cells of a cheapest path from `from` to `to`, `from` first; `None` when there is
    /// none within the allowed cells.
    pub fn astar(&self, s: &mut Search, from: usize, to: usize) -> Option<Vec<usize>> {
        let n = self.n;
        let (ti, tj) = ((to % n) as f64, (to / n) as f64);
        let h = |c: usize| {
            let (dx, dy) = (((c % n) as f64 - ti).abs(), ((c / n) as f64 - tj).abs());
            self.unit * (dx.max(dy) + (std::f64::consts::SQRT_2 - 1.0) * dx.min(dy))
        };
        s.begin(n * n);
        s.set_g(from, 0.0, u32::MAX);
        s.push(h(from), from);
        let ni = n as isize;
        let (a, d) = (self.unit, self.unit * std::f64::consts::SQRT_2);
        let steps: [(isize, isize, f64); 8] = [
            (1, 0, a),
            (-1, 0, a),
            (0, 1, a),
            (0, -1, a),
            (1, 1, d),
            (-1, 1, d),
            (1, -1, d),
            (-1, -1, d),
        ];
        while let Some(c) = s.pop() {
            if c == to {
                let mut cells = vec![to];
                let mut at = to;
                while at != from {
                    at = s.parent[at] as usize;
                    cells.push(at);
                }
                cells.reverse();
                return Some(cells);
            }
            if !s.close(c) {
                continue;
            }
            let gc = s.g[c];
            let (i, j) = (c % n, c / n);
            let inside = i > 0 && j > 0 && i + 1 < n && j + 1 < n;
            for &(di, dj, len) in &steps {
                let nb = if inside {
                    (c as isize + dj * ni + di) as usize
                } else {
                    let (a, b) = (i as isize + di, j as isize + dj);
                    if a < 0 || b < 0 || a >= ni || b >= ni {
                        continue;
                    }
                    (b * ni + a) as usize
                };
                if s.is_closed(nb) || !(self.allowed)(nb) {
                    continue;
                }
                let Some(cost) = (self.cost)(nb) else { continue };
                let cand = gc + len * cost;
                if cand < s.g_of(nb) {
                    s.set_g(nb, cand, c as u32);
                    s.push(cand + h(nb), nb);
                }
            }
        }
        None
    }
}

/// A* arrays for one grid size, valid for the current search where `stamp` says so: a new
/// search bumps the generation instead of clearing them.
#[derive(Default)]
pub(super) struct Search {
    /// `2·generation` where the cell's `g` belongs to this search, `+ 1` once it is closed.
    stamp: Vec<u32>,
    g: Vec<f64>,
    parent: Vec<u32>,
    generation: u32,
    /// Min-heap on `f` (its `f32` bits, which order as the value for non-negative floats) and
    /// the cell, packed high and low.
    heap: BinaryHeap<Reverse<u64>>,
}

impl Search {
    fn begin(&mut self, cells: usize) {
        if self.stamp.len() != cells || self.generation >= u32::MAX / 2 - 1 {
            *self = Search {
                stamp: vec![0; cells],
                g: vec![f64::INFINITY; cells],
                parent: vec![u32::MAX; cells],
                ..Search::default()
            };
        }
        self.generation += 1;
        self.heap.clear();
    }

    fn g_of(&self, c: usize) -> f64 {
        if self.stamp[c] >> 1 == self.generation { self.g[c] } else { f64::INFINITY }
    }

    fn set_g(&mut self, c: usize, g: f64, parent: u32) {
        self.stamp[c] = self.generation << 1;
        self.g[c] = g;
        self.parent[c] = parent;
    }

    fn is_closed(&self, c: usize) -> bool {
        self.stamp[c] == (self.generation << 1) | 1
    }

    /// Closes `c`; false when it was closed already (a stale heap entry).
    fn close(&mut self, c: usize) -> bool {
        let open = self.stamp[c] == self.generation << 1;
        self.stamp[c] |= 1;
        open
    }

    fn push(&mut self, f: f64, c: usize) {
        let key = (f as f32).to_bits() as u64;
        self.heap.push(Reverse((key << 32) | c as u64));
    }

    fn pop(&mut self) -> Option<usize> {
        self.heap.pop().map(|Reverse(k)| (k & 0xffff_ffff) as usize)
    }
}
