//! `paper`: the paper's training layout (design §2: the eight obstacle groups of Env_0..Env_3,
//! the U-shaped pocket and the L corner among them) placed at random, each group turned by a
//! random quarter turn, in a room of 5–8 m: the sizes the curriculum runs through. Groups keep
//! their sizes and stay at least 0.6 m apart, as in the built-in rooms.

use super::{Generated, inside_square};
use crate::grid::FreeSpace;
use crate::room_file::builtin_specs;
use crate::spec::{ObstacleSpec, Point, RoomSpec};
use rand::Rng;

/// Free gap kept between two groups' bounding boxes, and between a group and a wall (m).
const GAP: f64 = 0.6;
/// Placement attempts per group.
const TRIES: usize = 200;

pub(super) fn generate(
    g: &Generated,
    rng: &mut impl Rng,
    for_radius: f64,
) -> anyhow::Result<RoomSpec> {
    let side = g.param_or_drawn("size", 4.0, 20.0, 5.0..=8.0, rng)?;
    let layout = builtin_specs()
        .into_iter()
        .find(|s| s.name == "env0")
        .expect("the training layout is built in")
        .obstacles;
    let h = side / 2.0;
    let mut spec = RoomSpec::empty("", side);
    spec.description =
        format!("paper: the training layout's eight groups at random in a {side:.2} m room");
    let mut free = FreeSpace::of_room(&spec, for_radius);
    for group in &layout {
        for _ in 0..TRIES {
            let turned = quarter_turns(group, rng.random_range(0..4));
            let at = [rng.random_range(-h..h), rng.random_range(-h..h)];
            let anchor = turned.anchor();
            let placed = turned.translated([at[0] - anchor[0], at[1] - anchor[1]]);
            if !inside_square(&placed, h - GAP) || spec.obstacles.iter().any(|o| near(o, &placed)) {
                continue;
            }
            if free.try_add(&placed) {
                spec.obstacles.push(placed);
                break;
            }
        }
    }
    Ok(spec)
}

/// True when the bounding boxes of `a` and `b` come closer than [`GAP`].
fn near(a: &ObstacleSpec, b: &ObstacleSpec) -> bool {
    let ([alo, ahi], [blo, bhi]) = (a.aabb(), b.aabb());
    let gap = |k: usize| (blo[k] - ahi[k]).max(alo[k] - bhi[k]);
    gap(0) < GAP && gap(1) < GAP
}

/// `o` turned by `k` quarter turns counter-clockwise about its anchor.
fn quarter_turns(o: &ObstacleSpec, k: u32) -> ObstacleSpec {
    rotate_about(o, o.anchor(), k)
}

/// `o` turned by `k` quarter turns counter-clockwise about `c`. A compound's anchor turns
/// about `c` and its parts turn with their frame, about the anchor.
fn rotate_about(o: &ObstacleSpec, c: Point, k: u32) -> ObstacleSpec {
    let turn = |p: &Point| {
        let (mut x, mut y) = (p[0] - c[0], p[1] - c[1]);
        for _ in 0..k {
            (x, y) = (-y, x);
        }
        [c[0] + x, c[1] + y]
    };
    match o {
        ObstacleSpec::Box { center, half_extents, angle } => ObstacleSpec::Box {
            center: turn(center),
            half_extents: *half_extents,
            angle: angle + k as f64 * std::f64::consts::FRAC_PI_2,
        },
        ObstacleSpec::Circle { center, radius } => {
            ObstacleSpec::Circle { center: turn(center), radius: *radius }
        }
        ObstacleSpec::Polygon { points } => {
            ObstacleSpec::Polygon { points: points.iter().map(turn).collect() }
        }
        ObstacleSpec::Compound { at, parts } => ObstacleSpec::Compound {
            at: turn(at),
            parts: parts.iter().map(|p| rotate_about(p, [0.0, 0.0], k)).collect(),
        },
    }
}
