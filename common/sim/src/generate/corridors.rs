//! `corridors`: a corridor network. Junctions lie on a jittered grid; a random spanning tree
//! of the grid's edges (randomized depth-first search, so long corridors and dead ends) plus a
//! few extra edges (loops) are the corridors; everything else is wall. Some corridors have a
//! door: two jambs narrowing them to 0.6–1.2 m.

use super::{Generated, aa_box};
use crate::spec::{ObstacleSpec, RoomSpec};
use rand::Rng;
use rand::seq::SliceRandom;

/// Share of the edges left out of the spanning tree that are added back as loops.
const LOOP_SHARE: f64 = 0.15;
/// Share of corridors with a door.
const DOOR_SHARE: f64 = 0.3;
/// Depth of a door jamb along the corridor (m).
const JAMB_DEPTH: f64 = 0.1;

pub(super) fn generate(g: &Generated, rng: &mut impl Rng) -> anyhow::Result<RoomSpec> {
    let side = g.param("size", 12.0, 5.0, 40.0)?;
    let width = match g.params.get("width") {
        Some(_) => g.param("width", 1.2, 0.6, 3.0)?,
        None => rng.random_range(1.4..2.4),
    };
    let spacing = rng.random_range(2.8..4.0f64).max(width + 1.0);
    let m = (((side - width) / spacing).floor() as usize + 1).max(2);
    let h = side / 2.0;
    // Junction coordinates: the outer corridors run along the walls; inner lines jittered.
    let line = |rng: &mut dyn rand::RngCore| -> Vec<f64> {
        let step = (side - width) / (m - 1) as f64;
        (0..m)
            .map(|a| {
                let base = -h + width / 2.0 + a as f64 * step;
                let jitter = if a == 0 || a == m - 1 { 0.0 } else { 0.15 * step };
                base + rng.random_range(-jitter..=jitter)
            })
            .collect()
    };
    let xs = line(rng);
    let ys = line(rng);
    let node = |a: usize, b: usize| b * m + a;
    // Edges: (from, to, horizontal).
    let mut edges: Vec<(usize, usize, bool)> = Vec::new();
    for b in 0..m {
        for a in 0..m {
            if a + 1 < m {
                edges.push((node(a, b), node(a + 1, b), true));
            }
            if b + 1 < m {
                edges.push((node(a, b), node(a, b + 1), false));
            }
        }
    }
    let open = spanning_tree_with_loops(m, &edges, rng);
    let half = width / 2.0;
    let mut obstacles: Vec<ObstacleSpec> = Vec::new();
    // Solid blocks between four junctions.
    for b in 0..m - 1 {
        for a in 0..m - 1 {
            obstacles
                .extend(aa_box([xs[a] + half, ys[b] + half], [xs[a + 1] - half, ys[b + 1] - half]));
        }
    }
    for (k, &(u, v, horizontal)) in edges.iter().enumerate() {
        let (a, b) = (u % m, u / m);
        let (a2, b2) = (v % m, v / m);
        if !open[k] {
            // Plug the corridor between the two junction squares.
            let plug = if horizontal {
                aa_box([xs[a] + half, ys[b] - half], [xs[a2] - half, ys[b] + half])
            } else {
                aa_box([xs[a] - half, ys[b] + half], [xs[a] + half, ys[b2] - half])
            };
            obstacles.extend(plug);
        } else if rng.random_bool(DOOR_SHARE) {
            let door = rng.random_range(0.6..=1.2f64);
            if door < width - 0.05 {
                let offset = rng.random_range(-(width - door) / 2.0..=(width - door) / 2.0);
                obstacles.extend(jambs(&xs, &ys, (a, b), (a2, b2), horizontal, half, door, offset));
            }
        }
    }
    let mut spec = RoomSpec::empty("", side);
    spec.description =
        format!("corridors: {m}x{m} junctions, corridors {width:.2} m wide, doors 0.6-1.2 m");
    spec.obstacles = obstacles;
    Ok(spec)
}

/// The two jambs of a door of width `door` (centre `offset` across the corridor) halfway along
/// the corridor from junction `p` to `q`.
#[allow(clippy::too_many_arguments)]
fn jambs(
    xs: &[f64],
    ys: &[f64],
    p: (usize, usize),
    q: (usize, usize),
    horizontal: bool,
    half: f64,
    door: f64,
    offset: f64,
) -> Vec<ObstacleSpec> {
    let d = JAMB_DEPTH / 2.0;
    let (lo, hi) = (offset - door / 2.0, offset + door / 2.0);
    if horizontal {
        let x = 0.5 * (xs[p.0] + xs[q.0]);
        let y = ys[p.1];
        [aa_box([x - d, y - half], [x + d, y + lo]), aa_box([x - d, y + hi], [x + d, y + half])]
            .into_iter()
            .flatten()
            .collect()
    } else {
        let y = 0.5 * (ys[p.1] + ys[q.1]);
        let x = xs[p.0];
        [aa_box([x - half, y - d], [x + lo, y + d]), aa_box([x + hi, y - d], [x + half, y + d])]
            .into_iter()
            .flatten()
            .collect()
    }
}

/// Which edges are corridors: a spanning tree by randomized depth-first search from a random
/// junction, plus [`LOOP_SHARE`] of the rest.
fn spanning_tree_with_loops(
    m: usize,
    edges: &[(usize, usize, bool)],
    rng: &mut impl Rng,
) -> Vec<bool> {
    let mut adjacent: Vec<Vec<usize>> = vec![Vec::new(); m * m];
    for (k, &(u, v, _)) in edges.iter().enumerate() {
        adjacent[u].push(k);
        adjacent[v].push(k);
    }
    let mut open = vec![false; edges.len()];
    let mut seen = vec![false; m * m];
    let start = rng.random_range(0..m * m);
    seen[start] = true;
    let mut stack = vec![start];
    while let Some(&u) = stack.last() {
        let mut next: Vec<usize> = adjacent[u]
            .iter()
            .copied()
            .filter(|&k| {
                let (a, b, _) = edges[k];
                !seen[if a == u { b } else { a }]
            })
            .collect();
        if next.is_empty() {
            stack.pop();
            continue;
        }
        next.shuffle(rng);
        let k = next[0];
        let (a, b, _) = edges[k];
        let v = if a == u { b } else { a };
        open[k] = true;
        seen[v] = true;
        stack.push(v);
    }
    for o in open.iter_mut() {
        if !*o && rng.random_bool(LOOP_SHARE) {
            *o = true;
        }
    }
    open
}
