//! Tests of room sets: parsing, drawing and evaluation samples.

use super::*;
use crate::Room;
use rand::SeedableRng;
use rand_pcg::Pcg64;
use std::collections::BTreeMap;

fn draws(set: &RoomSet, seed: u64, n: usize) -> Vec<String> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..n).map(|_| set.pick(&mut rng)).collect()
}

#[test]
fn a_single_name_is_a_single_room_and_draws_nothing() {
    for name in ["env3", "rooms/training.toml", "generated:rooms:3", "generated:paper:5..6"] {
        let set = RoomSet::parse(name).unwrap();
        assert!(set.is_single(), "{name}");
        let mut rng = Pcg64::seed_from_u64(1);
        let picked = set.pick(&mut rng);
        assert_eq!(rng, Pcg64::seed_from_u64(1), "{name}: the stream is untouched");
        assert_eq!(set.sample(4), [picked], "{name}");
    }
    assert_eq!(RoomSet::parse("env3").unwrap().pick(&mut Pcg64::seed_from_u64(0)), "env3");
    assert_eq!(
        RoomSet::parse("generated:paper:5..6").unwrap().pick(&mut Pcg64::seed_from_u64(0)),
        "generated:paper:5"
    );
    assert!(!RoomSet::parse("env0|env1").unwrap().is_single());
    assert!(!RoomSet::parse("generated:paper:5..7").unwrap().is_single());
}

#[test]
fn picks_are_deterministic_for_a_seed_and_stay_in_the_set() {
    let set = RoomSet::parse("env0 | generated:clutter:10..20:size=6,density=0.1").unwrap();
    let a = draws(&set, 7, 400);
    assert_eq!(a, draws(&set, 7, 400));
    assert_ne!(a, draws(&set, 8, 400));
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for name in &a {
        *counts.entry(name.clone()).or_default() += 1;
    }
    // Every room of the set and nothing else; the alternative is drawn first, so `env0`
    // gets about half the draws, each seed about a twentieth.
    let mut expected = vec!["env0".to_string()];
    expected.extend((10..20).map(|s| format!("generated:clutter:{s}:density=0.1,size=6")));
    expected.sort();
    assert_eq!(counts.keys().cloned().collect::<Vec<_>>(), expected);
    assert!((150..250).contains(&counts["env0"]), "{counts:?}");
    // Each name is one Room::load takes, and names itself.
    let g = a.iter().find(|n| n.starts_with("generated:")).unwrap();
    assert_eq!(Room::load(g).unwrap()[0].name(), g);
}

#[test]
fn a_range_draws_every_seed_in_it_and_none_outside() {
    let set = RoomSet::parse("generated:corridors:3..7").unwrap();
    let seen: std::collections::BTreeSet<String> = draws(&set, 1, 200).into_iter().collect();
    let want: std::collections::BTreeSet<String> =
        (3..7).map(|s| format!("generated:corridors:{s}")).collect();
    assert_eq!(seen, want);
    assert_eq!(set.alternatives()[0].len(), 4);
}

#[test]
fn samples_take_the_first_seeds_round_robin_without_repeats() {
    let set =
        RoomSet::parse("generated:paper:0..2000|generated:clutter:0..2000:density=0.05|env0|env0")
            .unwrap();
    assert_eq!(
        set.sample(5),
        [
            "generated:paper:0",
            "generated:clutter:0:density=0.05",
            "env0",
            "generated:paper:1",
            "generated:clutter:1:density=0.05",
        ]
    );
    assert_eq!(set.sample(5), set.sample(5));
    assert_eq!(set.sample(0), Vec::<String>::new());
    // A set smaller than k gives all of its rooms.
    let small = RoomSet::parse("env1|generated:rooms:4..6").unwrap();
    assert_eq!(small.sample(10), ["env1", "generated:rooms:4", "generated:rooms:5"]);
}

#[test]
fn bad_stage_strings_name_the_stage_and_the_problem() {
    let err = |s: &str| format!("{:#}", RoomSet::parse(s).unwrap_err());
    for (stage, words) in [
        ("", "is empty"),
        ("env0||env1", "alternative 2"),
        ("env0|", "an alternative is empty"),
        ("generated:clutter:5..5", "seed range `5..5` is empty"),
        ("generated:clutter:9..2", "A must be below B"),
        ("generated:clutter:x..9", "`x` is not a non-negative integer"),
        ("generated:clutter:1..", "`` is not a non-negative integer"),
        ("generated:mazes:0..10", "unknown generator kind `mazes`"),
        ("env0|generated:rooms:0..10:density=0.1", "no parameter `density`"),
        ("generated:rooms:x", "seed `x`"),
    ] {
        let e = err(stage);
        assert!(e.contains(&format!("room set `{stage}`")), "{stage}: {e}");
        assert!(e.contains(words), "{stage}: {e}");
    }
    assert!(err("env0|generated:mazes:0..10").contains("alternative 2 (`generated:mazes:0..10`)"));
}
