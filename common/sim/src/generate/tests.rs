//! Tests of the room generators.

use super::*;
use crate::Room;
use crate::grid::{ClearanceMap, FreeSpace};

#[test]
fn names_parse_and_print_canonically() {
    let g = Generated::parse("generated:clutter:17:size=6,density=0.2").unwrap();
    assert_eq!(g.kind, "clutter");
    assert_eq!(g.seed, 17);
    assert_eq!(g.params["size"], 6.0);
    assert_eq!(g.name(), "generated:clutter:17:density=0.2,size=6");
    assert_eq!(Generated::parse("generated:rooms:3").unwrap().name(), "generated:rooms:3");
}

#[test]
fn bad_names_say_what_is_wrong() {
    let err = |n: &str| Generated::parse(n).unwrap_err().to_string();
    assert!(err("generated:mazes:1").contains("unknown generator kind `mazes`"));
    assert!(err("generated:mazes:1").contains("clutter, corridors, rooms, paper, walls"));
    assert!(err("generated:rooms:x").contains("seed `x`"));
    assert!(err("generated:rooms:-1").contains("seed `-1`"));
    assert!(err("generated:rooms:1:size").contains("not KEY=VALUE"));
    assert!(err("generated:rooms:1:size=big").contains("`big` is not a number"));
    let e = err("generated:rooms:1:density=0.1");
    assert!(e.contains("no parameter `density`") && e.contains("size, furniture"), "{e}");
    let e = Generated::parse("generated:clutter:1:density=0.9").unwrap().generate().unwrap_err();
    assert!(e.to_string().contains("`density` = 0.9 is outside [0, 0.4]"), "{e}");
}

#[test]
fn every_kind_is_deterministic_and_seeds_differ() {
    for kind in KINDS {
        let name = format!("generated:{kind}:5");
        let a = Generated::parse(&name).unwrap().generate().unwrap();
        let b = Generated::parse(&name).unwrap().generate().unwrap();
        assert_eq!(a, b, "{kind}");
        assert_eq!(a.name, name);
        let c = Generated::parse(&format!("generated:{kind}:6")).unwrap().generate().unwrap();
        assert_ne!(a.obstacles, c.obstacles, "{kind}");
        assert!(!a.obstacles.is_empty(), "{kind}");
    }
}

#[test]
fn every_generated_room_is_connected_for_the_meta_robot() {
    for kind in KINDS {
        for seed in 0..4 {
            let spec =
                Generated::parse(&format!("generated:{kind}:{seed}")).unwrap().generate().unwrap();
            // Connected on the generators' grid, ...
            assert_eq!(FreeSpace::of_room(&spec, 0.2).components(), 1, "{}", spec.name);
            // ... and on the episodes' finer one up to pockets the coarse grid counts as
            // blocked (sampling pairs no start and goal across them).
            let reach = ClearanceMap::of_room(&spec).reach(0.2);
            assert!(reach.largest_share() > 0.98, "{}: {}", spec.name, reach.largest_share());
            // Enough floor to drive on: a tenth of the square at least.
            let share = reach.passable_cells() as f64 * reach.raster().res.powi(2)
                / (spec.side * spec.side);
            assert!(share > 0.1, "{}: {share}", spec.name);
            Room::try_new(spec).unwrap();
        }
    }
}

#[test]
fn clutter_density_sets_how_much_is_strewn() {
    let count = |d: f64| {
        Generated::parse(&format!("generated:clutter:1:density={d}"))
            .unwrap()
            .generate()
            .unwrap()
            .obstacles
            .len()
    };
    assert_eq!(count(0.0), 0);
    assert!(count(0.05) < count(0.2));
}

#[test]
fn corridor_doors_narrow_some_corridors_for_big_robots() {
    // Doors of 0.6-1.2 m in corridors of 1.4-2.4 m: a 0.2 m robot reaches everything, a robot
    // of 0.6 m radius (1.2 m wide) finds the network cut at the doors.
    let mut split = 0;
    for seed in 0..6 {
        let spec =
            Generated::parse(&format!("generated:corridors:{seed}")).unwrap().generate().unwrap();
        let map = ClearanceMap::of_room(&spec);
        assert_eq!(map.reach(0.2).component_count(), 1);
        if map.reach(0.6).component_count() > 1 {
            split += 1;
        }
    }
    assert!(split >= 3, "only {split} of 6 corridor networks are cut for a 0.6 m robot");
}

#[test]
fn generated_names_load_as_rooms() {
    let rooms = Room::load("generated:rooms:3").unwrap();
    assert_eq!(rooms.len(), 1);
    assert_eq!(rooms[0].name(), "generated:rooms:3");
    let err = Room::load("generated:rooms").unwrap_err().to_string();
    assert!(err.contains("seed"), "{err}");
}

#[test]
fn walls_cross_the_room_with_a_gap_and_a_way_round() {
    // The gap closes the wall for robots wider than it, the opening never does: a goal behind
    // the wall is reachable for the meta robot and for a 0.6 m one, by the opening at least.
    let mut narrow = 0;
    for seed in 0..8 {
        let g = Generated::parse(&format!("generated:walls:{seed}")).unwrap();
        let spec = g.generate().unwrap();
        assert!((2..=3).contains(&spec.obstacles.len()), "{}", spec.name);
        let map = ClearanceMap::of_room(&spec);
        assert_eq!(map.reach(0.2).component_count(), 1, "{}", spec.name);
        assert_eq!(map.reach(0.5).component_count(), 1, "{}", spec.name);
        // Pieces of one wall: boxes on one line across the room, their lengths plus the two
        // holes spanning the side.
        let boxes: Vec<_> = spec.obstacles.iter().map(|o| o.aabb()).collect();
        let across = |k: usize| boxes.iter().map(|[lo, hi]| hi[k] - lo[k]).sum::<f64>();
        let (along, _) = if across(0) > across(1) { (0, 1) } else { (1, 0) };
        let holes = spec.side - across(along);
        assert!((1.25..=2.5).contains(&holes), "{}: {holes} m of holes", spec.name);
        if spec.description.contains(" 0.2") || spec.description.contains(" 0.3") {
            narrow += 1;
        }
    }
    assert!(narrow >= 1, "no gap narrower than the meta robot in 8 rooms");
    // A given gap.
    let spec = Generated::parse("generated:walls:3:gap=0.3,size=6").unwrap().generate().unwrap();
    assert_eq!(spec.side, 6.0);
    assert!(spec.description.contains("0.30 m gap"), "{}", spec.description);
    let e = Generated::parse("generated:walls:1:gap=3").unwrap().generate().unwrap_err();
    assert!(e.to_string().contains("`gap` = 3 is outside [0, 2]"), "{e}");
    let e = Generated::parse("generated:walls:1:for_radius=0.95").unwrap().generate().unwrap_err();
    assert!(e.to_string().contains("cut the room in two for a robot of radius 0.95"), "{e}");
}
