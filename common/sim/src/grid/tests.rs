use super::*;
use crate::spec::{RoomSpec, WallSegment};

/// A room of side 6 split at x = 0 by a wall with a gap of `gap` m centred at y = 0.
fn split_room(gap: f64) -> RoomSpec {
    let mut spec = RoomSpec::empty("split", 6.0);
    let t = Some(0.1);
    spec.wall_segments = vec![
        WallSegment { from: [0.0, 3.0], to: [0.0, gap / 2.0], thickness: t },
        WallSegment { from: [0.0, -gap / 2.0], to: [0.0, -3.0], thickness: t },
    ];
    spec
}

#[test]
fn distance_transform_matches_brute_force() {
    let n = 23;
    let occupied: Vec<bool> = (0..n * n).map(|k| (k * 7919 + k / 3) % 31 == 0).collect();
    let fast = distance_transform(&occupied, n);
    for (c, &d) in fast.iter().enumerate() {
        let (i, j) = ((c % n) as f64, (c / n) as f64);
        let brute = (0..n * n)
            .filter(|&o| occupied[o])
            .map(|o| {
                let (a, b) = ((o % n) as f64, (o / n) as f64);
                (a - i).powi(2) + (b - j).powi(2)
            })
            .fold(f64::INFINITY, f64::min);
        assert_eq!(d, brute, "cell {c}");
    }
    assert!(distance_transform(&[false; 9], 3).iter().all(|d| d.is_infinite()));
}

#[test]
fn distance_to_convex_shapes() {
    let b = ObstacleSpec::Box { center: [0.0, 0.0], half_extents: [1.0, 0.5], angle: 0.0 };
    assert_eq!(distance_to_convex(&b, [0.2, 0.1]), 0.0);
    assert!((distance_to_convex(&b, [2.0, 0.0]) - 1.0).abs() < 1e-12);
    assert!((distance_to_convex(&b, [2.0, 1.5]) - 2f64.sqrt()).abs() < 1e-12);
    let c = ObstacleSpec::Circle { center: [1.0, 1.0], radius: 0.5 };
    assert!((distance_to_convex(&c, [1.0, 3.0]) - 1.5).abs() < 1e-12);
}

#[test]
fn an_empty_room_is_one_component_and_paths_are_near_straight() {
    let map = ClearanceMap::of_room(&RoomSpec::empty("e", 5.0));
    let reach = map.reach(0.2);
    assert_eq!(reach.component_count(), 1);
    let (a, b): ([f64; 2], [f64; 2]) = ([-1.5, -1.0], [1.5, 1.2]);
    let straight = (a[0] - b[0]).hypot(a[1] - b[1]);
    let path = reach.path_length(a, b, 0.1).unwrap();
    assert!(path >= straight - 1e-9 && path < straight * 1.09, "{path} vs {straight}");
}

#[test]
fn a_gap_connects_the_small_robot_and_splits_the_room_for_the_big_one() {
    let map = ClearanceMap::of_room(&split_room(1.0));
    let (left, right) = ([-1.5, 1.0], [1.5, 1.0]);
    let small = map.reach(0.2);
    assert_eq!(small.component_count(), 1);
    assert!(small.connected(left, right, 0.1));
    let path = small.path_length(left, right, 0.1).unwrap();
    // Through the gap at (0, 0): two legs of √(1.5² + 1²).
    assert!(
        path > 2.0 * f64::hypot(1.5, 1.0) - 0.05 && path < 2.0 * f64::hypot(1.5, 1.0) * 1.09,
        "{path}"
    );
    // The gap is 1.0 m minus the wall's rounded ends: a 0.5 m disc cannot pass.
    let big = map.reach(0.5);
    assert_eq!(big.component_count(), 2);
    assert!(!big.connected(left, right, 0.1));
    assert_eq!(big.path_length(left, right, 0.1), None);
    assert!(big.connected(left, [-1.0, -2.0], 0.1));
}

#[test]
fn passable_cells_keep_their_radius_clear_of_the_exact_geometry() {
    let spec = split_room(0.9);
    let room = crate::Room::new(spec.clone());
    let map = ClearanceMap::of_room(&spec);
    let reach = map.reach(0.3);
    let r = reach.raster();
    let mut passable = 0;
    for j in 0..r.n {
        for i in 0..r.n {
            if reach.label[r.index(i, j)] != 0 {
                passable += 1;
                let c = r.centre(i, j);
                assert!(room.clearance(c, 1.0) >= 0.3 + r.half_diagonal() - 1e-6, "{c:?}");
            }
        }
    }
    assert!(passable > 1000);
}

#[test]
fn a_point_off_the_raster_or_in_a_wall_joins_nothing() {
    let reach = ClearanceMap::of_room(&split_room(1.0)).reach(0.2);
    assert_eq!(reach.component_at([10.0, 0.0], 0.1), None);
    assert_eq!(reach.component_at([0.0, 2.0], 0.1), None);
}

#[test]
fn points_added_to_a_map_close_a_gap() {
    let map = ClearanceMap::of_room(&split_room(1.0));
    let (left, right) = ([-1.5, 1.0], [1.5, 1.0]);
    assert!(map.reach(0.2).connected(left, right, 0.1));
    // A person standing in the gap, seen as a few returns.
    let person: Vec<Point> = (-4..=4).map(|k| [-0.05, k as f64 * 0.1]).collect();
    let closed = map.with_points(&person, 0.1);
    assert!(!closed.reach(0.2).connected(left, right, 0.1));
    assert_eq!(map.with_points(&[], 0.1).dist, map.dist);
}

#[test]
fn returns_near_the_maps_own_walls_mark_nothing_within_the_tolerance() {
    // The gap's jambs seen through range noise: returns up to 6 cm into the gap from each side.
    let map = ClearanceMap::of_room(&split_room(1.0));
    let (left, right) = ([-1.5, 1.0], [1.5, 1.0]);
    let jambs: Vec<Point> = (0..=12)
        .flat_map(|k| [[0.0, 0.5 - k as f64 * 0.005], [0.0, -0.5 + k as f64 * 0.005]])
        .collect();
    assert_eq!(map.with_points(&jambs, 0.1).dist, map.dist, "the walls already known");
    // Marked all the same, they narrow the gap below what a 0.42 m disc needs.
    assert!(map.reach(0.42).connected(left, right, 0.1));
    assert!(!map.with_points(&jambs, 0.0).reach(0.42).connected(left, right, 0.1));
    // A return farther from every wall than the tolerance is new and marked.
    let person = [[0.0, 0.0]];
    assert_ne!(map.with_points(&person, 0.1).dist, map.dist);
}

#[test]
fn connected_pairs_lie_in_one_component_and_far_enough_apart() {
    use rand::SeedableRng;
    let reach = ClearanceMap::of_room(&split_room(0.3)).reach(0.2);
    assert_eq!(reach.component_count(), 2, "the gap is too narrow for the disc");
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for (a, b) in reach.random_connected_pairs(&mut rng, 200, 1.5).unwrap() {
        assert!((a[0] - b[0]).hypot(a[1] - b[1]) >= 1.5);
        assert_eq!(a[0] < 0.0, b[0] < 0.0, "{a:?} and {b:?} are on either side of the wall");
        assert!(reach.connected(a, b, 0.0));
    }
    assert_eq!(reach.random_connected_pairs(&mut rng, 1, 100.0), None);
}

/// A room of side 6 with a wall down x = 0 from the top to y = −1.5, leaving a 1.5 m way round
/// at the bottom, and a gap of `gap` m in it centred at y = 1.
fn wall_with_a_way_round(gap: f64) -> RoomSpec {
    let mut spec = RoomSpec::empty("way-round", 6.0);
    let t = Some(0.1);
    spec.wall_segments = vec![
        WallSegment { from: [0.0, 3.0], to: [0.0, 1.0 + gap / 2.0], thickness: t },
        WallSegment { from: [0.0, 1.0 - gap / 2.0], to: [0.0, -1.5], thickness: t },
    ];
    spec
}

#[test]
fn the_geodesic_field_goes_round_the_wall_and_through_a_gap_only_where_the_disc_fits() {
    let map = ClearanceMap::of_room(&wall_with_a_way_round(0.45));
    let (start, goal) = ([-1.5, 1.0], [1.5, 1.0]);
    // The 0.2 m disc does not fit the 0.45 m gap: its way is round the bottom of the wall.
    let big = map.reach(0.2);
    let field = big.field_to(goal, 0.0).expect("the goal has room");
    let round = field.distance(start).unwrap();
    let reference = big.path_length(start, goal, 0.0).unwrap();
    // Round the wall's end: 2·hypot(1.5, 2.75) = 6.27 m for the exact disc, ~6.45 m with the
    // raster's clearance (the radius plus a cell diagonal from occupied centres).
    assert!((6.2..6.6).contains(&round), "round the wall: {round}");
    // No longer than the 8-connected A* through the same cells (up to 8 % over).
    assert!(round <= reference + 1e-6, "field {round} against A* {reference}");
    // The 0.1 m disc takes the gap: the straight line, give or take the grid.
    let small = map.reach(0.1).field_to(goal, 0.0).unwrap();
    let through = small.distance(start).unwrap();
    assert!((through - 3.0).abs() < 0.1, "{through}");
    // Near the goal the field is the straight join, and it falls along the way round.
    assert!(field.distance([1.4, 1.0]).unwrap() < 0.15);
    let below = field.distance([-1.0, -2.2]).unwrap();
    assert!(below < round - 2.0, "{below} should be well under {round} once round the end");
    // Against the wall (0.25 m from its centre line, touching it), the way is still round:
    // the cells the search finds are on the robot's own side, not through the wall.
    let beside = field.distance([-0.25, 0.0]).unwrap();
    assert!(beside > 4.0, "{beside}: round the end from beside the wall is ~4.9 m");
    // A point cut off from the goal (walled in) has no value.
    let mut spec = wall_with_a_way_round(0.45);
    spec.wall_segments.push(WallSegment {
        from: [0.0, -1.5],
        to: [0.0, -3.0],
        thickness: Some(0.1),
    });
    let shut = ClearanceMap::of_room(&spec).reach(0.2).field_to(goal, 0.0).unwrap();
    assert_eq!(shut.distance(start), None);
    assert!(shut.distance([2.0, -2.0]).is_some());
}

#[test]
fn the_centre_reach_takes_every_gap_the_disc_fits_and_no_other() {
    let spec = wall_with_a_way_round(0.45);
    let map = ClearanceMap::of_room(&spec);
    let (start, goal) = ([-1.5, 1.0], [1.5, 1.0]);
    let way = |radius: f64| {
        let field = map.reach_of_centres(&spec, radius).field_to(goal, 0.0).unwrap();
        field.distance(start).unwrap()
    };
    // The 0.2 m disc fits the 0.45 m gap with 2.5 cm to spare, which the conservative reach
    // (the radius plus a 3.5 cm cell diagonal) shuts: the exact cells take the gap.
    assert!((way(0.2) - 3.0).abs() < 0.1, "through the gap: {}", way(0.2));
    let conservative = map.reach(0.2).field_to(goal, 0.0).unwrap().distance(start).unwrap();
    assert!(conservative > 6.0, "the conservative reach goes round: {conservative}");
    // A 0.23 m disc (0.46 m across) does not fit: round the wall's end (6.27 m exactly).
    assert!((6.1..6.5).contains(&way(0.23)), "round the wall: {}", way(0.23));
    // Every passable centre is clear of the shapes by the radius, on the whole raster.
    let reach = map.reach_of_centres(&spec, 0.2);
    let r = reach.raster().clone();
    let walls = spec.walls();
    for j in 0..r.n {
        for i in 0..r.n {
            if reach.label[r.index(i, j)] != 0 {
                let c = r.centre(i, j);
                let near = walls.iter().map(|w| distance_to_convex(w, c)).fold(f64::MAX, f64::min);
                assert!(near >= 0.2 - 1e-9, "{c:?} is {near} from a wall");
            }
        }
    }
}
