//! `rooms`: a floor of rooms on a jittered grid, separated by thin walls. Doors (0.7–1.2 m)
//! join every room to the others: a random spanning tree of the rooms' adjacency plus some
//! extra doors. Furniture (shelves against walls, tables, round tables) goes into the rooms,
//! each piece kept only if the floor stays connected.

use super::{Generated, aa_box, inside_square};
use crate::grid::FreeSpace;
use crate::spec::{ObstacleSpec, RoomSpec};
use rand::Rng;
use rand::seq::SliceRandom;

/// Interior wall thickness (m).
const WALL: f64 = 0.1;
/// Share of the walls between rooms, beyond those of the spanning tree, with a door.
const EXTRA_DOORS: f64 = 0.25;
/// Attempts per piece of furniture.
const TRIES: usize = 12;

pub(super) fn generate(
    g: &Generated,
    rng: &mut impl Rng,
    for_radius: f64,
) -> anyhow::Result<RoomSpec> {
    let side = g.param("size", 10.0, 4.0, 40.0)?;
    let furniture = g.param("furniture", 3.0, 0.0, 8.0)? as usize;
    let h = side / 2.0;
    let cols = ((side / 3.5).round() as usize).clamp(2, 8);
    let rows = ((side / 3.5).round() as usize).clamp(2, 8);
    let splits = |n: usize, rng: &mut dyn rand::RngCore| -> Vec<f64> {
        let step = side / n as f64;
        (0..=n)
            .map(|k| {
                let base = -h + k as f64 * step;
                if k == 0 || k == n {
                    base
                } else {
                    base + rng.random_range(-0.2 * step..=0.2 * step)
                }
            })
            .collect()
    };
    let xs = splits(cols, rng);
    let ys = splits(rows, rng);
    let room = |c: usize, r: usize| r * cols + c;
    // Walls between neighbouring rooms: (room a, room b, vertical wall?, c, r).
    let mut walls: Vec<(usize, usize, bool, usize, usize)> = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            if c + 1 < cols {
                walls.push((room(c, r), room(c + 1, r), true, c, r));
            }
            if r + 1 < rows {
                walls.push((room(c, r), room(c, r + 1), false, c, r));
            }
        }
    }
    let doors = tree_plus_extra(rows * cols, &walls, rng);
    let mut spec = RoomSpec::empty("", side);
    spec.description =
        format!("rooms: {cols}x{rows} rooms on a {side} m floor, doors 0.7-1.2 m, furniture");
    let t = WALL / 2.0;
    for (k, &(_, _, vertical, c, r)) in walls.iter().enumerate() {
        // The wall's extent along its line, stopping at the crossing walls.
        let (lo, hi, at) =
            if vertical { (ys[r], ys[r + 1], xs[c + 1]) } else { (xs[c], xs[c + 1], ys[r + 1]) };
        let mut pieces = vec![(lo, hi)];
        if doors[k] {
            let w = rng.random_range(0.7..=1.2f64).min(hi - lo - 0.6);
            let d0 = rng.random_range(lo + 0.3..=hi - 0.3 - w);
            pieces = vec![(lo, d0), (d0 + w, hi)];
        }
        for (a, b) in pieces {
            let piece = if vertical {
                aa_box([at - t, a], [at + t, b])
            } else {
                aa_box([a, at - t], [b, at + t])
            };
            spec.obstacles.extend(piece);
        }
    }
    let mut free = FreeSpace::of_room(&spec, for_radius);
    for r in 0..rows {
        for c in 0..cols {
            let cell = ([xs[c] + t, ys[r] + t], [xs[c + 1] - t, ys[r + 1] - t]);
            let n = rng.random_range(0..=furniture);
            for _ in 0..n {
                for _ in 0..TRIES {
                    let piece = random_piece(rng, cell);
                    if !inside_square(&piece, h) {
                        continue;
                    }
                    if free.try_add(&piece) {
                        spec.obstacles.push(piece);
                        break;
                    }
                }
            }
        }
    }
    Ok(spec)
}

/// A shelf against one of the cell's walls, a table, or a round table, inside `cell`.
fn random_piece(rng: &mut impl Rng, (lo, hi): ([f64; 2], [f64; 2])) -> ObstacleSpec {
    let (w, hgt) = (hi[0] - lo[0], hi[1] - lo[1]);
    match rng.random_range(0..3) {
        0 => {
            let depth = rng.random_range(0.3..0.5);
            let len = rng.random_range(0.6..1.5f64).min(0.8 * w.min(hgt));
            let along = |a: f64, b: f64, rng: &mut dyn rand::RngCore| {
                rng.random_range(a..=(b - len).max(a))
            };
            let piece = match rng.random_range(0..4) {
                0 => {
                    let x = along(lo[0], hi[0], rng);
                    aa_box([x, lo[1]], [x + len, lo[1] + depth])
                }
                1 => {
                    let x = along(lo[0], hi[0], rng);
                    aa_box([x, hi[1] - depth], [x + len, hi[1]])
                }
                2 => {
                    let y = along(lo[1], hi[1], rng);
                    aa_box([lo[0], y], [lo[0] + depth, y + len])
                }
                _ => {
                    let y = along(lo[1], hi[1], rng);
                    aa_box([hi[0] - depth, y], [hi[0], y + len])
                }
            };
            piece.expect("a shelf has a positive size")
        }
        1 => {
            let half_extents = [rng.random_range(0.3..0.6), rng.random_range(0.25..0.4)];
            let center = [rng.random_range(lo[0]..hi[0]), rng.random_range(lo[1]..hi[1])];
            let angle = if rng.random_bool(0.5) { 0.0 } else { std::f64::consts::FRAC_PI_2 };
            ObstacleSpec::Box { center, half_extents, angle }
        }
        _ => ObstacleSpec::Circle {
            center: [rng.random_range(lo[0]..hi[0]), rng.random_range(lo[1]..hi[1])],
            radius: rng.random_range(0.25..0.5),
        },
    }
}

/// Which walls get a door: a random spanning tree of the rooms (every room reachable), then
/// [`EXTRA_DOORS`] of the other walls.
fn tree_plus_extra(
    n: usize,
    walls: &[(usize, usize, bool, usize, usize)],
    rng: &mut impl Rng,
) -> Vec<bool> {
    // Kruskal on a shuffled edge order with a union-find.
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    let mut order: Vec<usize> = (0..walls.len()).collect();
    order.shuffle(rng);
    let mut door = vec![false; walls.len()];
    for k in order {
        let (a, b) = (find(&mut parent, walls[k].0), find(&mut parent, walls[k].1));
        if a != b {
            parent[a] = b;
            door[k] = true;
        } else if rng.random_bool(EXTRA_DOORS) {
            door[k] = true;
        }
    }
    door
}
