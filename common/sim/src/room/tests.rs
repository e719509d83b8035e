//! Tests of `room.rs`.

use super::*;
use crate::EnvConfig;
use crate::NavEnv;

fn assert_send_sync<T: Send + Sync>() {}

#[test]
fn room_is_shareable() {
    assert_send_sync::<Room>();
    assert_send_sync::<Arc<Room>>();
}

#[test]
fn builtin_names_resolve_and_unknown_lists_valid_names() {
    let names = Room::builtin_names();
    assert_eq!(names, ["env0", "env1", "env2", "env3", "sac_ri", "gate", "dynamic"]);
    for (name, side) in
        [("env0", 8.0), ("env1", 7.0), ("env2", 6.0), ("env3", 5.0), ("sac_ri", 12.0)]
    {
        let room = Room::builtin(name).unwrap();
        assert_eq!(room.name(), name);
        assert_eq!(room.side(), side);
        assert_eq!(room.spec().obstacles.len(), 8, "{name}: eight obstacle groups");
        assert_eq!(*room.spec(), RoomSpec::training(name, side));
    }
    let err = Room::builtin("env9").unwrap_err().to_string();
    assert!(err.contains("env0") && err.contains("gate") && err.contains("dynamic"), "{err}");
}

#[test]
fn queries_see_walls_and_obstacles() {
    let mut spec = RoomSpec::empty("t", 4.0);
    spec.obstacles.push(ObstacleSpec::Circle { center: [1.0, 1.0], radius: 0.25 });
    let room = Room::new(spec);
    // Wall at x = 2.
    let d = room.cast_ray([0.0, 0.0], [1.0, 0.0], 10.0).unwrap();
    assert!((d - 2.0).abs() < 1e-5, "{d}");
    assert_eq!(room.cast_ray([0.0, 0.0], [1.0, 0.0], 1.5), None);
    assert!(!room.circle_collides([0.0, 0.0], 0.5));
    assert!(room.circle_collides([1.0, 0.5], 0.26));
    assert!(!room.circle_collides([1.0, 0.5], 0.24));
    assert!(room.circle_collides([1.85, -1.0], 0.2), "overlaps the wall");
    assert!((room.clearance([1.0, 0.0], 5.0) - 0.75).abs() < 1e-5);
    assert_eq!(room.clearance([0.0, 0.0], 0.1), 0.1);
    assert_eq!(room.clearance([1.0, 1.0], 5.0), 0.0);
}

#[test]
fn compounds_and_footprints_collide_part_by_part() {
    // An L of two boxes: its concave corner is free, each arm is solid.
    let mut spec = RoomSpec::empty("l", 6.0);
    spec.obstacles.push(ObstacleSpec::Compound {
        at: [1.0, 1.0],
        parts: vec![
            ObstacleSpec::Box { center: [0.0, 0.0], half_extents: [1.0, 0.1], angle: 0.0 },
            ObstacleSpec::Box { center: [0.9, 0.9], half_extents: [0.1, 1.0], angle: 0.0 },
        ],
    });
    let room = Room::new(spec);
    assert!(room.circle_collides([0.5, 1.0], 0.05));
    assert!(room.circle_collides([1.9, 2.0], 0.05));
    assert!(!room.circle_collides([1.2, 1.5], 0.3), "inside the L's corner");
    assert!(room.cast_ray([1.2, 1.5], [0.0, -1.0], 5.0).unwrap() < 0.5);
    // A 1 m x 0.2 m rectangle in the corner: free along x, touching the arm when turned.
    let rect = Footprint::rectangle(1.0, 0.2);
    assert!(!room.footprint_collides(&rect, Pose2::new(1.0, 1.5, 0.0)));
    assert!(room.footprint_collides(&rect, Pose2::new(1.0, 1.5, std::f64::consts::FRAC_PI_2)));
    assert!(room.footprint_collides(&rect, Pose2::new(1.5, 1.5, 0.0)), "reaches x = 2");
    let cargo = Footprint::circle(0.1)
        .with_cargo([ObstacleSpec::Circle { center: [0.0, -0.45], radius: 0.1 }]);
    assert!(!room.footprint_collides(&cargo, Pose2::new(1.0, 1.7, 0.0)));
    assert!(room.footprint_collides(&cargo, Pose2::new(1.0, 1.5, 0.0)), "cargo hits the arm");
}

#[test]
fn invalid_specs_are_refused() {
    let mut spec = RoomSpec::empty("bad", 4.0);
    spec.obstacles.push(ObstacleSpec::Polygon { points: vec![[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]] });
    let err = Room::try_new(spec).unwrap_err().to_string();
    assert!(err.contains("counter-clockwise"), "{err}");
    assert!(Room::try_new(RoomSpec::empty("bad", -1.0)).is_err());
}

/// Distance between two obstacle shapes (compounds: their nearest parts).
fn gap(a: &ObstacleSpec, b: &ObstacleSpec) -> f64 {
    let (ca, cb) = (colliders_for(a).unwrap(), colliders_for(b).unwrap());
    let mut d = f64::INFINITY;
    for x in &ca {
        for y in &cb {
            let q = query::distance(x.position(), x.shape(), y.position(), y.shape());
            d = d.min(q.unwrap().distance as f64);
        }
    }
    d
}

/// The layout promise: ≥ 0.6 m between groups (top-level obstacles) and from every group to
/// the walls, and a free origin, in every training room (the smallest is the binding one).
#[test]
fn training_layout_leaves_wide_gaps_and_a_free_origin() {
    for name in Room::training_names() {
        let room = Room::builtin(name).unwrap();
        let groups = &room.spec().obstacles;
        let walls = room.spec().walls();
        for (i, a) in groups.iter().enumerate() {
            for w in &walls {
                let d = gap(a, w);
                assert!(d >= 0.6 - 1e-6, "{name}: group {i} is {d:.3} m from a wall");
            }
            for (j, b) in groups.iter().enumerate().skip(i + 1) {
                let d = gap(a, b);
                assert!(d >= 0.6 - 1e-6, "{name}: groups {i}, {j} are {d:.3} m apart");
            }
        }
        let c = room.clearance([0.0, 0.0], 10.0);
        assert!(c >= 0.4 + 0.2, "{name}: origin clearance {c}");
        assert!(!room.circle_collides([0.0, 0.0], 0.2 + 0.4));
    }
}

/// The layout as it was built in code before it moved to `rooms/training.toml`: the file
/// must give the same shapes bit for bit, so training behaves as before.
#[test]
fn training_file_is_the_former_code_layout_bit_for_bit() {
    use ObstacleSpec::{Box, Circle, Polygon};
    let regular = |n: usize, r: f64, phase: f64| -> ObstacleSpec {
        let points = (0..n)
            .map(|k| {
                let a = phase + std::f64::consts::TAU * k as f64 / n as f64;
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        Polygon { points }
    };
    let bx =
        |center: [f64; 2], half_extents: [f64; 2], angle: f64| Box { center, half_extents, angle };
    let groups: Vec<([f64; 2], Vec<ObstacleSpec>)> = vec![
        (
            [0.0, 2.24],
            vec![
                bx([0.0, 0.35], [0.5, 0.05], 0.0),
                bx([-0.45, 0.0], [0.05, 0.4], 0.0),
                bx([0.45, 0.0], [0.05, 0.4], 0.0),
            ],
        ),
        ([2.4, -2.4], vec![bx([0.0, -0.3], [0.35, 0.05], 0.0), bx([0.3, 0.0], [0.05, 0.35], 0.0)]),
        ([0.0, -2.4], vec![Circle { center: [0.0, 0.0], radius: 0.35 }]),
        ([2.4, 2.4], vec![Circle { center: [0.0, 0.0], radius: 0.3 }]),
        ([2.4, 0.0], vec![regular(5, 0.35, 0.3)]),
        ([-2.4, 2.4], vec![regular(3, 0.35, std::f64::consts::FRAC_PI_2)]),
        ([-2.32, 0.0], vec![bx([0.0, 0.0], [0.35, 0.2], 0.4)]),
        ([-2.4, -2.4], vec![bx([0.0, 0.0], [0.25, 0.25], std::f64::consts::FRAC_PI_4)]),
    ];
    for (name, side) in [("env0", 8.0), ("env1", 7.0), ("env2", 6.0), ("env3", 5.0)] {
        let s = side / 8.0;
        let old: Vec<ObstacleSpec> = groups
            .iter()
            .flat_map(|(a, parts)| parts.iter().map(move |p| p.translated([a[0] * s, a[1] * s])))
            .collect();
        let new: Vec<ObstacleSpec> = Room::builtin(name)
            .unwrap()
            .spec()
            .obstacles
            .iter()
            .flat_map(|o| o.primitives())
            .collect();
        assert_eq!(new, old, "{name}");
    }
}

#[test]
fn the_u_trap_pocket_fits_the_robot() {
    // Inside the U of env3 (anchor (0, 1.4)): free for the 0.2 m robot, closed on three sides.
    let room = Room::builtin("env3").unwrap();
    let inside = [0.0, 1.45];
    assert!(!room.circle_collides(inside, 0.2));
    for dir in [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]] {
        let d = room.cast_ray(inside, dir, 10.0).unwrap();
        assert!(d < 0.5, "pocket closed towards {dir:?}: {d}");
    }
    assert!(room.cast_ray(inside, [0.0, -1.0], 10.0).unwrap() > 2.0, "pocket opens south");
}

/// Every built-in room loads, the meta robot finds starts and goals in it, and its routes
/// start and end in free space with room for it.
#[test]
fn every_builtin_room_admits_the_meta_robot() {
    let cfg = EnvConfig::default();
    for name in Room::builtin_names() {
        let room = Room::builtin(&name).unwrap();
        let mut env = NavEnv::new(room.clone(), &cfg, 3);
        for _ in 0..20 {
            env.reset();
            assert!(!room.circle_collides_any_time(env.start().position(), cfg.robot_radius));
            assert!(!room.circle_collides_any_time(env.goal(), cfg.robot_radius));
        }
        assert!(!room.spec().routes.is_empty(), "{name}: no route");
        for r in &room.spec().routes {
            for p in std::iter::once(r.start).chain(r.goals.iter().copied()) {
                let c = room.clearance(p, 5.0);
                assert!(c >= 0.3, "{name}: route `{}` point {p:?} has {c:.3} m", r.name);
                assert!(!room.circle_collides_any_time(p, 0.3), "{name}: {p:?}");
            }
        }
    }
}

/// Design §4: in every training room (and the SAC_RI room) the evaluation route starts at
/// the origin and visits four goals, each ≥ 0.3 m from every shape.
#[test]
fn evaluation_routes_start_at_the_origin_with_four_clear_goals() {
    for name in ["env0", "env1", "env2", "env3", "sac_ri"] {
        let room = Room::builtin(name).unwrap();
        let r = room.spec().route("eval").unwrap();
        assert_eq!(r.start, [0.0, 0.0]);
        assert_eq!(r.goals.len(), 4);
        for g in &r.goals {
            assert!(room.clearance(*g, 5.0) >= 0.3, "{name}: goal {g:?}");
        }
    }
}

/// Cells of a grid over the room (pitch `h`) whose disc of radius `r` is free and that are
/// connected to `from` through free cells with `keep(x, y)`; whether `to` is among them.
fn reachable(
    room: &Room,
    r: f64,
    from: [f64; 2],
    to: [f64; 2],
    keep: impl Fn(f64, f64) -> bool,
) -> bool {
    let h = 0.025;
    let n = (room.side() / h).round() as i64;
    let cell = |p: [f64; 2]| {
        (
            ((p[0] + room.side() / 2.0) / h).round() as i64,
            ((p[1] + room.side() / 2.0) / h).round() as i64,
        )
    };
    let pos =
        |(i, j): (i64, i64)| [i as f64 * h - room.side() / 2.0, j as f64 * h - room.side() / 2.0];
    let free = |c: (i64, i64)| {
        let p = pos(c);
        (0..=n).contains(&c.0)
            && (0..=n).contains(&c.1)
            && keep(p[0], p[1])
            && !room.circle_collides(p, r)
    };
    let (start, goal) = (cell(from), cell(to));
    assert!(free(start) && free(goal), "start and goal must be free for r = {r}");
    let mut seen = std::collections::HashSet::from([start]);
    let mut todo = vec![start];
    while let Some((i, j)) = todo.pop() {
        if (i, j) == goal {
            return true;
        }
        for c in [(i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)] {
            if !seen.contains(&c) && free(c) {
                seen.insert(c);
                todo.push(c);
            }
        }
    }
    false
}

/// Design §2's gate: robots of radius ≤ 0.25 m pass the gate, ≥ 0.30 m do not; the path to
/// the left admits the 0.75 m robot. Checked on the geometry: the gap between the gate's
/// posts, discs placed in the gate, and reachability of the goal over a 2.5 cm grid of disc
/// positions, with and without the left path.
#[test]
fn gate_admits_025_blocks_030_and_the_left_path_admits_075() {
    let room = Room::builtin("gate").unwrap();
    let spec = room.spec();
    let route = spec.route("gate").unwrap();
    assert_eq!((route.start, route.goals.as_slice()), ([0.0, -1.5], &[[0.0, 1.5]][..]));
    // The gate's posts: the two wall segments either side of x = 0.
    let walls = spec.walls();
    let posts: Vec<&ObstacleSpec> = walls[4..].iter().collect();
    let width = gap(posts[0], posts[1]);
    assert!((width - 0.55).abs() < 1e-6, "gate width {width}");
    // A disc of 0.25 m drives straight through; one of 0.30 m touches at the gate.
    for k in 0..=60 {
        let y = -1.5 + 3.0 * k as f64 / 60.0;
        assert!(!room.circle_collides([0.0, y], 0.25), "R 0.25 at y = {y}");
    }
    assert!(room.circle_collides([0.0, 0.0], 0.30));
    // Without the left path (x > −1.2 only): 0.25 reaches the goal, 0.30 does not.
    let no_left = |x: f64, _y: f64| x > -1.2;
    assert!(reachable(&room, 0.25, route.start, route.goals[0], no_left));
    assert!(!reachable(&room, 0.30, route.start, route.goals[0], no_left));
    // With it: every robot up to 0.75 m reaches the goal (the left path is ≥ 1.5 m wide).
    for r in [0.30, 0.5, 0.75] {
        assert!(reachable(&room, r, route.start, route.goals[0], |_, _| true), "R {r}");
    }
    // The path is 1.7 m wide: 0.85 m is the largest radius through it.
    assert!(!reachable(&room, 0.86, route.start, route.goals[0], |_, _| true), "0.86 m");
    // The progress reward's way (the exact centre reach) is the gate's paper route for 0.25
    // (3 m straight through the 0.55 m gap) and the left path for 0.30.
    let way = |r: f64| {
        let field = room.centre_reach(r).field_to(route.goals[0], 0.0).unwrap();
        field.distance(route.start).unwrap()
    };
    assert!((way(0.25) - 3.0).abs() < 0.1, "R 0.25: {}", way(0.25));
    assert!(way(0.30) > 4.0, "R 0.30: {}", way(0.30));
    // Every robot of design §2's twelve (0.20 … 0.75 m) starts and ends in free space.
    for k in 0..12 {
        let r = 0.20 + 0.05 * k as f64;
        assert!(!room.circle_collides(route.start, r) && !room.circle_collides(route.goals[0], r));
    }
}

/// The dynamic room's obstacles appear on the route, ahead of any robot of radius ≤ 0.6 m
/// that left the start at most 0.5 m/s: where it could be, nothing appears.
#[test]
fn dynamic_obstacles_appear_on_the_route_ahead_of_the_robot() {
    let room = Room::builtin("dynamic").unwrap();
    let spec = room.spec();
    let route = spec.route("dynamic").unwrap();
    assert_eq!(room.timed_len(), 3);
    let (v_max, dt) = (0.5, 0.2);
    let start = route.start;
    let goal = route.goals[0];
    for t in &spec.timed_obstacles {
        let reach = v_max * dt * t.at_step as f64 + 0.6;
        // Nearest point of the obstacle to the start is farther than the robot can reach.
        let c = Room::new(RoomSpec {
            obstacles: vec![t.obstacle.clone()],
            ..RoomSpec::empty("one", spec.side)
        });
        let near = (0..=400)
            .map(|k| k as f64 / 400.0)
            .map(|f| [start[0] + f * (goal[0] - start[0]), start[1] + f * (goal[1] - start[1])])
            .find(|&p| c.spec().obstacles[0].contains(p) || c.circle_collides(p, 0.0));
        let p = near.unwrap_or_else(|| panic!("{t:?} is not on the straight route"));
        let d = (p[0] - start[0]).hypot(p[1] - start[1]);
        assert!(d > reach, "{t:?}: {d:.2} m from the start, a robot may be {reach:.2} m out");
        assert!(!c.circle_collides(goal, 0.3), "{t:?} leaves the goal clear");
    }
    assert_eq!((room.timed_active(0), room.timed_active(8), room.timed_active(39)), (0, 1, 2));
    assert_eq!(room.timed_active(40), 3);
}
