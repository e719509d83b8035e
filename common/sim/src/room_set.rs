//! [`RoomSet`]: one curriculum stage as a *set* of rooms, drawn from per episode.
//!
//! A stage string lists alternatives separated by `|` (spaces around them are ignored). Each
//! alternative is either
//!
//! - a room name or path as [`Room::load`](crate::Room::load) takes it (a built-in room, a room
//!   file, a generated room `generated:KIND:SEED[:PARAMS]`, an occupancy-grid map), or
//! - a range of generated rooms `generated:KIND:A..B[:KEY=VALUE,…]`: seeds `A` (included) to
//!   `B` (excluded) of one generator with the same parameters (see [`crate::generate`]).
//!
//! ```
//! use dvnav_sim::room_set::RoomSet;
//! use rand::SeedableRng;
//! let set = RoomSet::parse("env0|generated:clutter:0..2000:density=0.05").unwrap();
//! let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
//! let name = set.pick(&mut rng); // `env0`, or e.g. `generated:clutter:417:density=0.05`
//! assert!(name == "env0" || name.starts_with("generated:clutter:"));
//! let first = set.sample(3); // for evaluation: the first rooms, alternatives in turn
//! assert_eq!(first[..2], ["env0", "generated:clutter:0:density=0.05"]);
//! assert_eq!(first[2], "generated:clutter:1:density=0.05");
//! assert!(RoomSet::parse("env3").unwrap().is_single());
//! ```
//!
//! **Training and held-out seeds.** By convention, generated seeds 0..8999 are for training and
//! seeds 9000 and above are held out for evaluation: a policy trained on
//! `generated:clutter:0..2000` is measured on unseen rooms with `generated:clutter:9000` and
//! up. Nothing enforces it; keep training ranges below 9000.
//!
//! **Design.** [`RoomSet::pick`] returns a concrete room *name* rather than a room, so that
//! the caller decides how rooms are built and cached (a generated room takes tens of
//! milliseconds to build), and so that the name in episode logs is one [`Room::load`] takes.
//! A set of one room draws nothing from the random stream: a stage written as one name
//! behaves exactly like the single-room stages that came before sets.
//!
//! [`Room::load`]: crate::Room::load

use crate::generate::{self, Generated};
use anyhow::Context;
use rand::Rng;
use std::ops::Range;

/// One alternative of a stage.
#[derive(Clone, Debug, PartialEq)]
pub enum Alternative {
    /// One room, named as [`Room::load`](crate::Room::load) takes it (as written).
    Name(String),
    /// Generated rooms of one kind and parameters, seeds `seeds` (never empty).
    Generated {
        /// The kind and parameters (its `seed` is `seeds.start`).
        template: Generated,
        /// The seeds, `A..B`.
        seeds: Range<u64>,
    },
}

impl Alternative {
    /// Rooms in this alternative.
    pub fn len(&self) -> u64 {
        match self {
            Alternative::Name(_) => 1,
            Alternative::Generated { seeds, .. } => seeds.end - seeds.start,
        }
    }

    /// Never true: parsing refuses empty alternatives (for clippy's `len_without_is_empty`).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The name of room `i` (< [`Alternative::len`]).
    fn name(&self, i: u64) -> String {
        match self {
            Alternative::Name(n) => n.clone(),
            Alternative::Generated { template, seeds } => {
                Generated { seed: seeds.start + i, ..template.clone() }.name()
            }
        }
    }
}

/// A curriculum stage: the rooms its episodes are drawn from. See the [module docs](self).
#[derive(Clone, Debug, PartialEq)]
pub struct RoomSet {
    /// The stage string as written.
    stage: String,
    /// Never empty.
    alternatives: Vec<Alternative>,
}

impl RoomSet {
    /// Parses a stage string (see the [module docs](self)). Errors name the stage string and
    /// what is wrong with it: an empty alternative, a range whose start is not below its end,
    /// an unknown generator kind or parameter.
    pub fn parse(stage: &str) -> anyhow::Result<RoomSet> {
        let alternatives = stage
            .split('|')
            .enumerate()
            .map(|(i, alt)| {
                parse_alternative(alt.trim()).with_context(|| {
                    format!("room set `{stage}`: alternative {} (`{}`)", i + 1, alt.trim())
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(RoomSet { stage: stage.to_string(), alternatives })
    }

    /// The stage string as written.
    pub fn as_str(&self) -> &str {
        &self.stage
    }

    /// The alternatives, in the order written.
    pub fn alternatives(&self) -> &[Alternative] {
        &self.alternatives
    }

    /// True when the set holds exactly one room (one name, or a range of one seed): then
    /// [`RoomSet::pick`] returns it without drawing from the random stream.
    pub fn is_single(&self) -> bool {
        self.alternatives.len() == 1 && self.alternatives[0].len() == 1
    }

    /// A room of the set: an alternative drawn uniformly, then a seed of it uniformly. Returns
    /// the room's name, canonical for generated rooms (`generated:clutter:417:density=0.1`).
    /// Draws from `rng` only where there is a choice: nothing for a single room, no
    /// alternative for a set of one, no seed for a name.
    pub fn pick<R: Rng>(&self, rng: &mut R) -> String {
        let n = self.alternatives.len();
        let alt =
            if n == 1 { &self.alternatives[0] } else { &self.alternatives[rng.random_range(0..n)] };
        let len = alt.len();
        let i = if len == 1 { 0 } else { rng.random_range(0..len) };
        alt.name(i)
    }

    /// `k` deterministic representatives of the set, for evaluation: round-robin over the
    /// alternatives, each giving its rooms in order (a range its first seeds), without
    /// repeats. Fewer than `k` when the set holds fewer rooms.
    pub fn sample(&self, k: usize) -> Vec<String> {
        let mut out: Vec<String> = Vec::with_capacity(k);
        let mut round = 0u64;
        while out.len() < k {
            let mut any = false;
            for alt in self.alternatives.iter().filter(|a| round < a.len()) {
                any = true;
                let name = alt.name(round);
                if out.len() < k && !out.contains(&name) {
                    out.push(name);
                }
            }
            if !any {
                break;
            }
            round += 1;
        }
        out
    }
}

impl std::fmt::Display for RoomSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.stage)
    }
}

fn parse_alternative(alt: &str) -> anyhow::Result<Alternative> {
    anyhow::ensure!(!alt.is_empty(), "an alternative is empty (check the `|` separators)");
    let Some(rest) = alt.strip_prefix(generate::PREFIX) else {
        return Ok(Alternative::Name(alt.to_string()));
    };
    let mut parts = rest.splitn(3, ':');
    let kind = parts.next().unwrap_or_default();
    let seeds = parts.next().unwrap_or_default();
    let params = parts.next();
    let Some((a, b)) = seeds.split_once("..") else {
        // One generated room: checked now, kept as written.
        Generated::parse(alt)?;
        return Ok(Alternative::Name(alt.to_string()));
    };
    let seed = |s: &str| {
        s.parse::<u64>().map_err(|_| {
            anyhow::anyhow!("the seed range `{seeds}`: `{s}` is not a non-negative integer")
        })
    };
    let (a, b) = (seed(a)?, seed(b)?);
    anyhow::ensure!(
        a < b,
        "the seed range `{seeds}` is empty: A..B takes seeds A (included) to B (excluded), so A \
         must be below B"
    );
    let one = match params {
        Some(p) => format!("{}{kind}:{a}:{p}", generate::PREFIX),
        None => format!("{}{kind}:{a}", generate::PREFIX),
    };
    let template = Generated::parse(&one)?;
    Ok(Alternative::Generated { template, seeds: a..b })
}

#[cfg(test)]
mod tests;
