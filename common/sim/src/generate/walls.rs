//! `walls`: a straight wall across a square room with a narrow gap in it and a wide opening
//! elsewhere along it: the gate test's trap (design §2) at random, for training. The gap
//! (0.25–0.7 m) admits the meta robot (0.4 m wide) only sometimes, and the scaled world DVST
//! shows a bigger robot narrows it further; the opening (1.0–1.8 m) is the way round. A goal
//! behind the wall then asks for what the gate test asks: judge the gap, and when it is too
//! narrow, leave the straight line for the detour.

use super::{Generated, aa_box, cm};
use crate::grid::FreeSpace;
use crate::spec::{ObstacleSpec, RoomSpec};
use rand::Rng;

/// Width of the wide opening, drawn from this range (m).
const OPENING: std::ops::Range<f64> = 1.0..1.8;
/// Least free wall between the gap and the opening (m): the two must not merge.
const APART: f64 = 1.0;

pub(super) fn generate(
    g: &Generated,
    rng: &mut impl Rng,
    for_radius: f64,
) -> anyhow::Result<RoomSpec> {
    let side = g.param_or_drawn("size", 4.0, 20.0, 5.0..=8.0, rng)?;
    let gap = g.param_or_drawn("gap", 0.0, 2.0, 0.25..=0.7, rng)?;
    let h = side / 2.0;
    // Wall coordinates: u along the wall, v across it; `vertical` swaps them into the room's
    // (x, y), `flip` mirrors u, so the opening lies left or right, below or above.
    let (vertical, flip) = (rng.random_bool(0.5), rng.random_bool(0.5));
    let at_v = cm(rng.random_range(-h / 3.0..=h / 3.0));
    let thick = cm(rng.random_range(0.1..=0.2));
    let opening = cm(rng.random_range(OPENING));
    // The opening at the wall's end (the gate test's left path) or inside it.
    let open_lo =
        if rng.random_bool(0.5) { -h } else { cm(rng.random_range(-h + 0.5..h - 0.5 - opening)) };
    let open = [open_lo, open_lo + opening];
    // The gap: somewhere at least APART from the opening, 0.3 m from the room's walls.
    let spots: Vec<[f64; 2]> = [[-h + 0.3, open[0] - APART], [open[1] + APART, h - 0.3]]
        .into_iter()
        .filter(|[lo, hi]| hi - lo >= gap)
        .collect();
    anyhow::ensure!(
        !spots.is_empty(),
        "room `{}`: no room for a {gap} m gap beside a {opening} m opening in a {side} m room",
        g.name()
    );
    let [lo, hi] = spots[rng.random_range(0..spots.len())];
    let gap_lo = cm(rng.random_range(lo..=hi - gap));
    let mut holes = [open, [gap_lo, gap_lo + gap]];
    holes.sort_by(|a, b| a[0].total_cmp(&b[0]));

    let mut spec = RoomSpec::empty("", side);
    spec.description = format!(
        "walls: a {side:.2} m room crossed by a wall with a {gap:.2} m gap and a {opening:.2} m \
         opening"
    );
    let place = |u: [f64; 2], v: [f64; 2]| -> Option<ObstacleSpec> {
        let u = if flip { [-u[1], -u[0]] } else { u };
        if vertical {
            aa_box([v[0], u[0]], [v[1], u[1]])
        } else {
            aa_box([u[0], v[0]], [u[1], v[1]])
        }
    };
    let v = [at_v - thick / 2.0, at_v + thick / 2.0];
    let mut free = FreeSpace::of_room(&spec, for_radius);
    let mut from = -h;
    for hole in holes.iter().chain(std::iter::once(&[h, h])) {
        if let Some(piece) = place([from, hole[0]], v) {
            anyhow::ensure!(
                free.try_add(&piece),
                "room `{}`: the wall would cut the room in two for a robot of radius {for_radius} \
                 m (its opening is {opening} m wide); use a smaller for_radius",
                g.name()
            );
            spec.obstacles.push(piece);
        }
        from = hole[1];
    }
    Ok(spec)
}
