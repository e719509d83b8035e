use super::*;
use crate::Room;
use crate::spec::{ObstacleSpec, RoomSpec, WallSegment};

/// A room of side 6 split at x = 0 by a wall with a gap of `gap` m centred at `y_gap`.
fn split_room(gap: f64, y_gap: f64) -> RoomSpec {
    let mut spec = RoomSpec::empty("split", 6.0);
    let t = Some(0.1);
    spec.wall_segments = vec![
        WallSegment { from: [0.0, 3.0], to: [0.0, y_gap + gap / 2.0], thickness: t },
        WallSegment { from: [0.0, y_gap - gap / 2.0], to: [0.0, -3.0], thickness: t },
    ];
    spec
}

/// Two walls make an S-bend: the robot goes up on the left, across the middle, down on the
/// right.
fn s_bend() -> RoomSpec {
    let mut spec = RoomSpec::empty("s-bend", 8.0);
    let t = Some(0.1);
    spec.wall_segments = vec![
        WallSegment { from: [-1.5, -4.0], to: [-1.5, 2.5], thickness: t },
        WallSegment { from: [1.5, 4.0], to: [1.5, -2.5], thickness: t },
    ];
    spec.obstacles.push(ObstacleSpec::Circle { center: [0.0, 0.0], radius: 0.4 });
    spec
}

/// Every point of `path`, every centimetre, keeps `radius` clear of the exact geometry.
fn assert_collision_free(room: &Room, path: &PlannedPath, radius: f64) {
    for w in path.points.windows(2) {
        let len = dist(w[0], w[1]);
        let steps = (len / 0.01).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let q = [w[0][0] + t * (w[1][0] - w[0][0]), w[0][1] + t * (w[1][1] - w[0][1])];
            let c = room.clearance(q, 2.0);
            assert!(c >= radius - 1e-6, "{q:?} is {c} m from a wall, radius {radius}");
        }
    }
}

/// The reference: the shortest 8-connected path of `crate::grid::Reach` (an exact shortest
/// grid path through the same passable cells, no clearance cost).
fn reference(room: &Room, r: f64, a: Point, b: Point) -> f64 {
    room.reach(r).path_length(a, b, 0.1).expect("reachable in the reference")
}

/// The clearance kept where there is room costs a few per cent of length round tight bends.
const EPS: f64 = 0.08;

#[test]
fn in_an_empty_room_the_path_is_the_straight_line() {
    let room = Room::new(RoomSpec::empty("e", 6.0));
    let (a, b) = ([-2.0, -1.0], [2.0, 1.5]);
    let p = plan(room.clearance_map(), 0.2, a, b, &PlannerConfig::default()).unwrap();
    assert_eq!(p.points, vec![a, b]);
    assert!((p.length_m - dist(a, b)).abs() < 1e-12);
}

#[test]
fn through_a_door_collision_free_and_near_the_shortest_grid_path() {
    for (gap, y_gap, r) in [(1.0, 0.0, 0.2), (1.2, 1.5, 0.3), (0.9, -2.0, 0.15)] {
        let room = Room::new(split_room(gap, y_gap));
        let (a, b) = ([-2.0, -1.0], [2.2, 2.0]);
        let p = plan(room.clearance_map(), r, a, b, &PlannerConfig::default()).unwrap();
        assert_eq!((p.points[0], *p.points.last().unwrap()), (a, b));
        assert_collision_free(&room, &p, r);
        let refl = reference(&room, r, a, b);
        assert!(p.length_m <= (1.0 + EPS) * refl, "gap {gap}: {} vs {refl}", p.length_m);
        assert!(p.length_m >= dist(a, [0.0, y_gap]) + dist([0.0, y_gap], b) - 0.3);
        // Pruned: a handful of vertices, not one per cell.
        assert!(p.points.len() <= 6, "{:?}", p.points);
    }
}

#[test]
fn an_s_bend_for_small_and_big_robots() {
    let room = Room::new(s_bend());
    let (a, b) = ([-3.0, -3.0], [3.0, 3.0]);
    for r in [0.2, 0.3, 0.4] {
        let p = plan(room.clearance_map(), r, a, b, &PlannerConfig::default()).unwrap();
        assert_collision_free(&room, &p, r);
        let refl = reference(&room, r, a, b);
        assert!(p.length_m <= (1.0 + EPS) * refl, "r {r}: {} vs {refl}", p.length_m);
    }
}

#[test]
fn where_there_is_room_the_path_keeps_off_the_walls() {
    // A 2.4 m wide corridor bent by a pillar: the path keeps the preferred clearance.
    let room = Room::new(s_bend());
    let cfg = PlannerConfig::default();
    let r = 0.2;
    let p = plan(room.clearance_map(), r, [-3.0, -3.0], [3.0, 3.0], &cfg).unwrap();
    let least = p
        .points
        .windows(2)
        .flat_map(|w| {
            (0..=50).map(move |k| {
                let t = k as f64 / 50.0;
                [w[0][0] + t * (w[1][0] - w[0][0]), w[0][1] + t * (w[1][1] - w[0][1])]
            })
        })
        .filter(|q| dist(*q, [-3.0, -3.0]) > 0.5 && dist(*q, [3.0, 3.0]) > 0.5)
        .map(|q| room.clearance(q, 3.0))
        .fold(f64::INFINITY, f64::min);
    assert!(least >= r + cfg.preferred_clearance_m, "least clearance {least}");
    // Without the inflation cost and the preference, the same path hugs the wall ends.
    let tight = PlannerConfig { clearance_weight: 0.0, preferred_clearance_m: 0.0, ..cfg };
    let q = plan(room.clearance_map(), r, [-3.0, -3.0], [3.0, 3.0], &tight).unwrap();
    assert!(q.length_m < p.length_m);
}

#[test]
fn unreachable_and_blocked_points_are_named() {
    let room = Room::new(split_room(1.0, 0.0));
    let map = room.clearance_map();
    let cfg = PlannerConfig::default();
    let err = plan(map, 0.6, [-2.0, 0.0], [2.0, 0.0], &cfg).unwrap_err();
    assert_eq!(err, PlanError::Unreachable { goal: [2.0, 0.0], radius: 0.6 });
    assert!(err.to_string().contains("goal (2.00, 0.00)"), "{err}");
    let err = plan(map, 0.2, [-2.0, 0.0], [0.0, 2.0], &cfg).unwrap_err();
    assert!(matches!(err, PlanError::NoRoom { which: "goal", .. }), "{err}");
    let err = plan(map, 0.2, [-9.0, 0.0], [2.0, 0.0], &cfg).unwrap_err();
    assert!(matches!(err, PlanError::OffMap { which: "start", .. }), "{err}");
    // The margin counts: a 0.25 m robot passes a 1 m gap, with 0.3 m more it does not.
    assert!(plan(map, 0.25, [-2.0, 0.0], [2.0, 0.0], &cfg).is_ok());
    let wide = PlannerConfig { margin_m: 0.3, ..cfg };
    assert!(matches!(
        plan(map, 0.25, [-2.0, 0.0], [2.0, 0.0], &wide),
        Err(PlanError::Unreachable { .. })
    ));
}

#[test]
fn a_start_against_a_wall_joins_on_its_own_side() {
    // 0.25 m from the dividing wall's face, the nearest passable cells are on the left.
    let room = Room::new(split_room(1.0, 2.0));
    let p = plan(room.clearance_map(), 0.2, [-0.3, -1.0], [-2.0, -2.0], &PlannerConfig::default())
        .unwrap();
    assert!(p.points.iter().all(|q| q[0] < 0.0), "{:?}", p.points);
}

/// A building-sized room (50 m, so the task-sampling raster has 12.5 cm cells and the
/// planner's 3.1 cm) split at x = 0 by a wall with a door of `door` m centred at y = 5, and
/// furnished with seeded boxes on either side.
fn building(door: f64) -> RoomSpec {
    use rand::{Rng, SeedableRng};
    let mut spec = RoomSpec::empty("building", 50.0);
    let t = Some(0.1);
    spec.wall_segments = vec![
        WallSegment { from: [0.0, 25.0], to: [0.0, 5.0 + door / 2.0], thickness: t },
        WallSegment { from: [0.0, 5.0 - door / 2.0], to: [0.0, -25.0], thickness: t },
    ];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    while spec.obstacles.len() < 120 {
        let c: [f64; 2] = [rng.random_range(-23.0..23.0), rng.random_range(-23.0..23.0)];
        let h: [f64; 2] = [rng.random_range(0.2..1.5), rng.random_range(0.2..1.5)];
        // Keep the door's approaches open.
        if c[0].abs() - h[0] < 2.0 && (c[1] - 5.0).abs() - h[1] < 2.0 {
            continue;
        }
        spec.obstacles.push(ObstacleSpec::Box { center: c, half_extents: h, angle: 0.0 });
    }
    spec
}

/// What a cell path costs the planner's search (its steps' lengths in cells, each times the
/// inflation cost of the cell stepped into).
fn cell_path_cost(map: &ClearanceMap, need: f64, cfg: &PlannerConfig, cells: &[usize]) -> f64 {
    let n = map.raster().n;
    let d = map.distances();
    cells
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let len = if a % n != b % n && a / n != b / n { std::f64::consts::SQRT_2 } else { 1.0 };
            len * (1.0 + cfg.clearance_weight * (-(d[b] - need) / cfg.clearance_decay_m).exp())
        })
        .sum()
}

#[test]
fn a_door_the_robot_fits_through_in_a_building_is_planned_through() {
    // 0.85 m of door for a 0.3 m robot: 25 cm to spare, which the task-sampling raster's
    // conservative cells do not see; the planner's raster does.
    let r = 0.3;
    let room = Room::new(building(2.0 * r + 0.25));
    let (a, b) = ([-6.0, 5.0], [6.0, 5.5]);
    assert!(!room.reach(r).connected(a, b, 0.0), "the sampling raster calls the door shut");
    let map = room.planning_map();
    assert!(map.raster().res < 0.04, "{}", map.raster().res);
    let p = plan(map, r, a, b, &PlannerConfig::default()).unwrap();
    assert_collision_free(&room, &p, r);
    assert!(p.length_m < 13.0, "{} m: round the door?", p.length_m);
    // 10 cm narrower, and it is shut for this robot.
    let shut = Room::new(building(2.0 * r + 0.05));
    let err = plan(shut.planning_map(), r, a, b, &PlannerConfig::default()).unwrap_err();
    assert_eq!(err, PlanError::Unreachable { goal: b, radius: r });
}

#[test]
fn the_block_corridor_keeps_the_cheapest_path_of_the_cells() {
    use rand::SeedableRng;
    let room = Room::new(building(1.0));
    let map = room.planning_map();
    assert!(map.raster().n >= SEARCH_BLOCKS_FROM, "the blocks are searched first here");
    let cfg = PlannerConfig::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    for r in [0.2, 0.4] {
        let need = map.passable_need(r);
        let reach = map.reach(r);
        for (a, b) in reach.random_connected_pairs(&mut rng, 6, 10.0).unwrap() {
            let cell = |p: Point| {
                let (i, j) = map.raster().cell_of(p).unwrap();
                map.raster().index(i, j)
            };
            let by_blocks = astar_by(map, need, cell(a), cell(b), &cfg, true).unwrap();
            let whole = astar_by(map, need, cell(a), cell(b), &cfg, false).unwrap();
            let (cb, cw) = (
                cell_path_cost(map, need, &cfg, &by_blocks),
                cell_path_cost(map, need, &cfg, &whole),
            );
            assert!(cb <= cw * 1.01 && cw <= cb * 1.0001, "r {r} {a:?} -> {b:?}: {cb} vs {cw}");
            let p = plan(map, r, a, b, &cfg).unwrap();
            assert_collision_free(&room, &p, r);
        }
    }
}

#[test]
fn segments_are_tested_on_every_cell_they_cross() {
    use rand::{Rng, SeedableRng};
    let room = Room::new(s_bend());
    let map = room.clearance_map();
    let r = map.raster();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let (mut clear, mut blocked) = (0, 0);
    for _ in 0..400 {
        let mut p = || [rng.random_range(-3.9..3.9), rng.random_range(-3.9..3.9)];
        let (a, b) = (p(), p());
        let want = 0.3;
        // Every cell a dense sampling of the segment lands in (a thousandth of a cell apart).
        let steps = (dist(a, b) / (1e-3 * r.res)).ceil() as usize;
        let dense = (0..=steps).all(|k| {
            let t = k as f64 / steps as f64;
            let q = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
            let (i, j) = r.cell_of(q).unwrap();
            map.distances()[r.index(i, j)] >= want
        });
        assert_eq!(segment_clear(map, a, b, want), dense, "{a:?} -> {b:?}");
        if dense { clear += 1 } else { blocked += 1 }
    }
    assert!(clear > 40 && blocked > 40, "{clear} clear, {blocked} blocked");
    // Off the raster is never clear.
    assert!(!segment_clear(map, [0.0, 0.0], [9.0, 0.0], 0.0));
}

#[test]
fn plans_in_rooms_of_other_sizes_between_do_not_disturb_each_other() {
    let small = Room::new(s_bend());
    let big = Room::new(building(1.0));
    let cfg = PlannerConfig::default();
    let first = plan(small.clearance_map(), 0.3, [-3.0, -3.0], [3.0, 3.0], &cfg).unwrap();
    plan(big.planning_map(), 0.3, [-6.0, 5.0], [6.0, 5.5], &cfg).unwrap();
    let again = plan(small.clearance_map(), 0.3, [-3.0, -3.0], [3.0, 3.0], &cfg).unwrap();
    assert_eq!(first, again);
}
