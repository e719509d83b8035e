//! Room generators: seeded, deterministic rooms of several kinds, named like
//! `generated:corridors:17` or `generated:clutter:3:density=0.2,size=6`, accepted everywhere a
//! room name is ([`super::Room::load`]).
//!
//! | kind | what | parameters (default) |
//! |---|---|---|
//! | `clutter` | boxes, discs and convex polygons strewn over a square room | `size` (8 m), `density` (0.12: share of the floor the shapes cover) |
//! | `corridors` | a corridor network on a jittered grid: a random spanning tree (dead ends) plus a few loops, doors 0.6–1.2 m wide in some corridors | `size` (12 m), `width` (corridor width, drawn from 1.4–2.4 m: a robot of 0.6 m radius fits, not through every door) |
//! | `rooms` | a grid of rooms joined by doors 0.7–1.2 m wide (every room reachable), furniture inside | `size` (10 m), `furniture` (0–3 pieces per room: 3) |
//! | `paper` | the paper's training layout (its eight obstacle groups, traps included) placed at random in a room of 5–8 m | `size` (drawn from 5–8 m) |
//! | `walls` | the gate test's trap at random: a wall across a room of 5–8 m with a narrow gap (0.25–0.7 m) and a wide opening (1.0–1.8 m) elsewhere along it | `size` (drawn from 5–8 m), `gap` (drawn from 0.25–0.7 m) |
//!
//! Every kind takes `for_radius` (0.2 m, the meta robot): the generated free space is one
//! connected region for a disc of that radius (checked on the conservative grid of
//! [`super::grid`]; shapes that would cut it are not placed). Bigger robots may find parts of
//! a room closed to them; episode sampling only pairs points they can drive between.
//!
//! The same name gives the same room on every machine: the generator's random stream is
//! seeded from the kind and the seed, and no parameter depends on anything else.

mod clutter;
mod corridors;
mod paper;
mod rooms;
mod walls;

use super::grid::FreeSpace;
use super::spec::{ObstacleSpec, RoomSpec};
use rand::SeedableRng;
use rand_pcg::Pcg64;
use std::collections::BTreeMap;

/// The prefix of generated room names.
pub const PREFIX: &str = "generated:";

/// The generator kinds, in the order `dvnav rooms` lists them.
pub const KINDS: [&str; 5] = ["clutter", "corridors", "rooms", "paper", "walls"];

/// A parsed generated-room name: kind, seed and parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Generated {
    /// One of [`KINDS`].
    pub kind: String,
    /// The seed.
    pub seed: u64,
    /// Parameters given in the name (the generator's defaults fill the rest).
    pub params: BTreeMap<String, f64>,
}

impl Generated {
    /// Parses `generated:KIND:SEED[:KEY=VALUE,KEY=VALUE…]`.
    pub fn parse(name: &str) -> anyhow::Result<Generated> {
        let rest = name.strip_prefix(PREFIX).ok_or_else(|| {
            anyhow::anyhow!("`{name}` is not a generated room name (generated:KIND:SEED)")
        })?;
        let mut parts = rest.splitn(3, ':');
        let kind = parts.next().unwrap_or_default().to_string();
        anyhow::ensure!(
            KINDS.contains(&kind.as_str()),
            "room `{name}`: unknown generator kind `{kind}`; kinds are: {}",
            KINDS.join(", ")
        );
        let seed = parts.next().unwrap_or_default();
        let seed: u64 = seed.parse().map_err(|_| {
            anyhow::anyhow!("room `{name}`: the seed `{seed}` is not a non-negative integer")
        })?;
        let mut params = BTreeMap::new();
        if let Some(list) = parts.next() {
            for kv in list.split(',').filter(|s| !s.is_empty()) {
                let (k, v) = kv.split_once('=').ok_or_else(|| {
                    anyhow::anyhow!("room `{name}`: parameter `{kv}` is not KEY=VALUE")
                })?;
                let value: f64 =
                    v.parse().ok().filter(|v: &f64| v.is_finite()).ok_or_else(|| {
                        anyhow::anyhow!("room `{name}`: parameter `{k}`: `{v}` is not a number")
                    })?;
                params.insert(k.to_string(), value);
            }
        }
        let g = Generated { kind, seed, params };
        let known = g.known_params();
        if let Some(k) = g.params.keys().find(|k| !known.contains(&k.as_str())) {
            anyhow::bail!(
                "room `{name}`: the `{}` generator has no parameter `{k}`; it takes: {}",
                g.kind,
                known.join(", ")
            );
        }
        Ok(g)
    }

    /// The canonical name (parameters sorted): the generated room's name.
    pub fn name(&self) -> String {
        let mut s = format!("{PREFIX}{}:{}", self.kind, self.seed);
        if !self.params.is_empty() {
            let kv: Vec<String> = self.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
            s.push(':');
            s.push_str(&kv.join(","));
        }
        s
    }

    fn known_params(&self) -> &'static [&'static str] {
        match self.kind.as_str() {
            "clutter" => &["size", "density", "for_radius"],
            "corridors" => &["size", "width", "for_radius"],
            "rooms" => &["size", "furniture", "for_radius"],
            "walls" => &["size", "gap", "for_radius"],
            _ => &["size", "for_radius"],
        }
    }

    /// A parameter, or `default`, checked to lie in `[lo, hi]`.
    fn param(&self, key: &str, default: f64, lo: f64, hi: f64) -> anyhow::Result<f64> {
        let v = self.params.get(key).copied().unwrap_or(default);
        anyhow::ensure!(
            (lo..=hi).contains(&v),
            "room `{}`: parameter `{key}` = {v} is outside [{lo}, {hi}]",
            self.name()
        );
        Ok(v)
    }

    /// A parameter given in the name, checked to lie in `[lo, hi]`, or else one drawn from
    /// `drawn` and rounded to whole centimetres (so the room's description reads well).
    fn param_or_drawn(
        &self,
        key: &str,
        lo: f64,
        hi: f64,
        drawn: std::ops::RangeInclusive<f64>,
        rng: &mut impl rand::Rng,
    ) -> anyhow::Result<f64> {
        if self.params.contains_key(key) {
            // Given, so the default is never read.
            self.param(key, lo, lo, hi)
        } else {
            Ok(cm(rng.random_range(drawn)))
        }
    }

    /// The room.
    pub fn generate(&self) -> anyhow::Result<RoomSpec> {
        let mut rng = Pcg64::seed_from_u64(stream_seed(&self.kind, self.seed));
        let for_radius = self.param("for_radius", 0.2, 0.05, 1.0)?;
        let mut spec = match self.kind.as_str() {
            "clutter" => clutter::generate(self, &mut rng, for_radius)?,
            "corridors" => corridors::generate(self, &mut rng)?,
            "rooms" => rooms::generate(self, &mut rng, for_radius)?,
            "paper" => paper::generate(self, &mut rng, for_radius)?,
            "walls" => walls::generate(self, &mut rng, for_radius)?,
            other => unreachable!("kind `{other}` was checked by parse"),
        };
        spec.name = self.name();
        spec.validate()?;
        let free = FreeSpace::of_room(&spec, for_radius);
        anyhow::ensure!(
            free.components() == 1,
            "room `{}`: the generated free space is not connected for a robot of radius \
             {for_radius} m ({} parts); this is a generator bug, please report it",
            spec.name,
            free.components()
        );
        Ok(spec)
    }
}

/// The seed of a kind's random stream: the kind's name folded into the seed, so `clutter:3`
/// and `rooms:3` share nothing.
fn stream_seed(kind: &str, seed: u64) -> u64 {
    kind.bytes().fold(seed ^ 0x9e37_79b9_7f4a_7c15, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3).rotate_left(17)
    })
}

/// `x` in whole centimetres: generated sizes that read well in names and descriptions.
fn cm(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// An axis-aligned box from its corners (m), or `None` when it is empty.
fn aa_box(lo: [f64; 2], hi: [f64; 2]) -> Option<ObstacleSpec> {
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
    (w > 1e-6 && h > 1e-6).then(|| ObstacleSpec::Box {
        center: [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])],
        half_extents: [0.5 * w, 0.5 * h],
        angle: 0.0,
    })
}

/// True when `o`'s bounding box lies inside the square of half side `h`.
fn inside_square(o: &ObstacleSpec, h: f64) -> bool {
    let [lo, hi] = o.aabb();
    lo[0] >= -h && lo[1] >= -h && hi[0] <= h && hi[1] <= h
}

#[cfg(test)]
mod tests;
