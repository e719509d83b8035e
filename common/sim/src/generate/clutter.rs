//! `clutter`: boxes, discs and convex polygons strewn over a square room until they cover a
//! share of its floor, each kept only if the room stays connected.

use super::{Generated, inside_square};
use crate::grid::FreeSpace;
use crate::spec::{ObstacleSpec, RoomSpec};
use rand::Rng;
use std::f64::consts::TAU;

/// Attempts per placed shape before the generator settles for a sparser room.
const TRIES: usize = 40;

pub(super) fn generate(
    g: &Generated,
    rng: &mut impl Rng,
    for_radius: f64,
) -> anyhow::Result<RoomSpec> {
    let side = g.param("size", 8.0, 3.0, 30.0)?;
    let density = g.param("density", 0.12, 0.0, 0.4)?;
    let mut spec = RoomSpec::empty("", side);
    spec.description =
        format!("clutter: {side} m square, {:.0} % of the floor covered", density * 100.0);
    let target = density * side * side;
    let mut covered = 0.0;
    let mut misses = 0;
    let h = side / 2.0;
    let mut free = FreeSpace::of_room(&spec, for_radius);
    while covered < target && misses < TRIES {
        let (shape, area) = random_shape(rng, h);
        if !inside_square(&shape, h) {
            misses += 1;
            continue;
        }
        if free.try_add(&shape) {
            spec.obstacles.push(shape);
            covered += area;
            misses = 0;
        } else {
            misses += 1;
        }
    }
    Ok(spec)
}

/// One shape somewhere in the square of half side `h`, and its area (m²).
fn random_shape(rng: &mut impl Rng, h: f64) -> (ObstacleSpec, f64) {
    let center = [rng.random_range(-h..h), rng.random_range(-h..h)];
    match rng.random_range(0..3) {
        0 => {
            let half_extents = [rng.random_range(0.1..0.5), rng.random_range(0.1..0.5)];
            let angle = rng.random_range(0.0..std::f64::consts::PI);
            (
                ObstacleSpec::Box { center, half_extents, angle },
                4.0 * half_extents[0] * half_extents[1],
            )
        }
        1 => {
            let radius = rng.random_range(0.1..0.4);
            (ObstacleSpec::Circle { center, radius }, std::f64::consts::PI * radius * radius)
        }
        _ => {
            // Vertices at sorted random angles on a circle: convex and counter-clockwise.
            let n = rng.random_range(3..=6);
            let r = rng.random_range(0.15..0.45);
            let mut angles: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..TAU)).collect();
            angles.sort_by(f64::total_cmp);
            let gap_ok = angles.windows(2).all(|w| w[1] - w[0] > 0.3)
                && angles[0] + TAU - angles[n - 1] > 0.3;
            if !gap_ok {
                // Evenly spaced with a random phase: still a convex polygon.
                let phase = angles[0];
                angles = (0..n).map(|k| phase + TAU * k as f64 / n as f64).collect();
            }
            let points: Vec<[f64; 2]> =
                angles.iter().map(|a| [center[0] + r * a.cos(), center[1] + r * a.sin()]).collect();
            let area = 0.5
                * (0..n)
                    .map(|k| {
                        let (a, b) = (points[k], points[(k + 1) % n]);
                        a[0] * b[1] - a[1] * b[0]
                    })
                    .sum::<f64>();
            (ObstacleSpec::Polygon { points }, area)
        }
    }
}
