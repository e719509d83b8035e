//! How far the goal is from anywhere in a room for a disc of one radius, the way the disc can
//! drive: the length of a shortest path through the cells of its [`Reach`] (16-connected:
//! neighbours and knight's moves), from every cell at once (one Dijkstra pass from the goal).
//!
//! The progress reward's distance when `env.reward.geodesic_progress` is on: Habitat's PointNav
//! pays the decrease of this distance (Savva et al., ICCV 2019) rather than of the straight
//! line, so that an agent that sees only its goal is paid for going round a wall and not for
//! pressing against it: the trap a reactive policy learns in front of a partition.

use super::{Open, Raster, Reach};
use crate::spec::Point;
use std::collections::BinaryHeap;

/// A step `(di, dj)` of `len` cells that crosses cells `a` and `b` (offsets from its start).
type Step = (isize, isize, f64, (isize, isize), (isize, isize));

/// The 16 steps of the search: the 8 neighbours and the 8 knight's moves, each with its length
/// in cells and the two cells it crosses (the step's own end for the 8 neighbours). An
/// 8-connected grid measures a way up to 8 % long, and by its heading: a step along an axis
/// would shorten a diagonal way as much as a step along it, and the reward would favour the
/// axes; with the knight's moves the error is under 3 %.
const STEPS: [Step; 16] = {
    const D: f64 = std::f64::consts::SQRT_2;
    const K: f64 = 2.236_067_977_499_79; // √5
    [
        (1, 0, 1.0, (1, 0), (1, 0)),
        (-1, 0, 1.0, (-1, 0), (-1, 0)),
        (0, 1, 1.0, (0, 1), (0, 1)),
        (0, -1, 1.0, (0, -1), (0, -1)),
        (1, 1, D, (1, 1), (1, 1)),
        (1, -1, D, (1, -1), (1, -1)),
        (-1, 1, D, (-1, 1), (-1, 1)),
        (-1, -1, D, (-1, -1), (-1, -1)),
        (1, 2, K, (0, 1), (1, 1)),
        (-1, 2, K, (0, 1), (-1, 1)),
        (1, -2, K, (0, -1), (1, -1)),
        (-1, -2, K, (0, -1), (-1, -1)),
        (2, 1, K, (1, 0), (1, 1)),
        (2, -1, K, (1, 0), (1, -1)),
        (-2, 1, K, (-1, 0), (-1, 1)),
        (-2, -1, K, (-1, 0), (-1, -1)),
    ]
};

/// The shortest-path distance (m) to one goal from every cell of the goal's component.
#[derive(Clone, Debug)]
pub struct GeodesicField {
    raster: Raster,
    /// Metres to the goal from each cell centre by flat index; infinite where the disc cannot
    /// reach the goal from.
    dist: Vec<f32>,
    /// Farthest a point looks for a cell of the field ([`GeodesicField::distance`]).
    reach_m: f64,
}

impl Reach {
    /// The [`GeodesicField`] of `goal`: the goal joins the grid through every passable cell
    /// within `slack` of it (each starting at its straight distance from the goal, so the field
    /// is the same near the goal from every side); `None` when it has none.
    pub fn field_to(&self, goal: Point, slack: f64) -> Option<GeodesicField> {
        let sources = self.entries(goal, slack);
        let label = self.label[sources.first()?.1];
        let n = self.raster.n;
        let res = self.raster.res;
        let mut dist = vec![f64::INFINITY; self.label.len()];
        let mut heap = BinaryHeap::new();
        for &(d, c) in &sources {
            if self.label[c] == label && d < dist[c] {
                dist[c] = d;
                heap.push(Open { f: d, c });
            }
        }
        let ni = n as isize;
        let free = |i: isize, j: isize| {
            i >= 0 && j >= 0 && i < ni && j < ni && self.label[(j * ni + i) as usize] == label
        };
        while let Some(Open { f, c }) = heap.pop() {
            if f > dist[c] {
                continue;
            }
            let (i, j) = ((c % n) as isize, (c / n) as isize);
            for &(di, dj, len, (ai, aj), (bi, bj)) in &STEPS {
                // A knight's step crosses two cells besides its ends; both must be free.
                if !free(i + di, j + dj) || !free(i + ai, j + aj) || !free(i + bi, j + bj) {
                    continue;
                }
                let nb = ((j + dj) * ni + i + di) as usize;
                let cand = f + len * res;
                if cand < dist[nb] {
                    dist[nb] = cand;
                    heap.push(Open { f: cand, c: nb });
                }
            }
        }
        Some(GeodesicField {
            raster: self.raster.clone(),
            dist: dist.into_iter().map(|d| d as f32).collect(),
            reach_m: 2.0 * self.radius + 4.0 * res,
        })
    }
}

impl GeodesicField {
    /// The way (m) from `p` to the goal: over the field's cells near `p`, the least of a cell's
    /// distance plus the straight join from `p` to its centre (so the value moves smoothly as
    /// `p` crosses cells). A disc touching a wall sits on cells too tight to be passable; the
    /// search widens ring by ring up to twice the radius plus four cells. `None` when no cell of
    /// the field lies that near (off the raster, or cut off from the goal).
    pub fn distance(&self, p: Point) -> Option<f64> {
        let r = &self.raster;
        let fi = ((p[0] - r.origin[0]) / r.res).floor();
        let fj = ((p[1] - r.origin[1]) / r.res).floor();
        if !(fi.is_finite() && fj.is_finite()) {
            return None;
        }
        let (ci, cj) = (fi as isize, fj as isize);
        let n = r.n as isize;
        let max_k = (self.reach_m / r.res).ceil() as isize;
        let mut best = f64::INFINITY;
        let mut k = 2;
        loop {
            for j in (cj - k).max(0)..=(cj + k).min(n - 1) {
                for i in (ci - k).max(0)..=(ci + k).min(n - 1) {
                    let d = self.dist[(j * n + i) as usize];
                    if d.is_finite() {
                        let c = r.centre(i as usize, j as usize);
                        best = best.min(d as f64 + (c[0] - p[0]).hypot(c[1] - p[1]));
                    }
                }
            }
            if best.is_finite() || k >= max_k {
                return best.is_finite().then_some(best);
            }
            k = (2 * k).min(max_k);
        }
    }
}
