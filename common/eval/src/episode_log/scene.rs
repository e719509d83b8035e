//! The `/scene` message: a room, its goal and the robot's footprint as Foxglove scene entities.
//!
//! The room is 2-D; the scene extrudes it to a low 3-D model so Foxglove's 3D panel shows it from
//! any angle. World entities live in frame `world` (the room's frame, metres); the footprint lives
//! in frame `robot`, which `/tf` moves, so it follows the robot without per-step updates.
//!
//! One full scene goes out at the start of each episode and deletes everything before it. Because
//! it is complete, Foxglove's seek (which replays the latest message of each topic) always shows
//! the right room. The path so far is a separate topic (`/path`, one entity `path` that each
//! update replaces) for the same reason: path updates on `/scene` would become "the latest
//! message" and hide the room after a seek.

use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, LinePrimitive, Point3, Pose, Quaternion, SceneEntity,
    SceneEntityDeletion, SceneUpdate, SpherePrimitive, Timestamp, TriangleListPrimitive, Vector3,
    line_primitive, scene_entity_deletion,
};

use super::EpisodeStart;
use dvnav_sim::{ObstacleSpec, Point, RoomSpec};

/// Frame of the room (parent of `/tf`).
pub(crate) const WORLD_FRAME: &str = "world";
/// Frame of the robot's axle centre, x ahead (child of `/tf`, frame of `/scan`).
pub(crate) const ROBOT_FRAME: &str = "robot";

/// Drawn height of walls (m); display only.
const WALL_HEIGHT: f64 = 0.5;
/// Drawn height of obstacles (m); display only.
const OBSTACLE_HEIGHT: f64 = 0.4;
/// Drawn height of the robot's footprint (m); display only.
const ROBOT_HEIGHT: f64 = 0.15;
/// Diameter of the goal marker (m); a marker, not the goal tolerance.
const GOAL_MARKER_DIAMETER: f64 = 0.2;

const WALL_COLOR: Color = Color { r: 0.45, g: 0.45, b: 0.5, a: 1.0 };
const OBSTACLE_COLOR: Color = Color { r: 0.75, g: 0.45, b: 0.2, a: 0.85 };
const GOAL_COLOR: Color = Color { r: 0.1, g: 0.8, b: 0.25, a: 0.9 };
const ROBOT_COLOR: Color = Color { r: 0.2, g: 0.45, b: 0.95, a: 0.6 };
const HEADING_COLOR: Color = Color { r: 1.0, g: 1.0, b: 1.0, a: 1.0 };
const SCALED_COLOR: Color = Color { r: 0.95, g: 0.3, b: 0.85, a: 0.35 };
const PATH_COLOR: Color = Color { r: 0.2, g: 0.6, b: 1.0, a: 1.0 };
const PLAN_COLOR: Color = Color { r: 0.1, g: 0.85, b: 0.85, a: 0.8 };
const SUBGOAL_COLOR: Color = Color { r: 1.0, g: 0.85, b: 0.1, a: 0.9 };
/// Diameter of the subgoal marker (m).
const SUBGOAL_MARKER_DIAMETER: f64 = 0.12;
/// Drawn height of the path above the floor (m), so it shows on top of it.
const PATH_Z: f64 = 0.02;
/// Line width of the path (m).
const PATH_WIDTH: f64 = 0.03;

/// Rotation by `yaw` (rad) about +z.
pub(crate) fn yaw_quaternion(yaw: f64) -> Quaternion {
    let half = 0.5 * yaw;
    Quaternion { x: 0.0, y: 0.0, z: half.sin(), w: half.cos() }
}

/// A pose at (x, y, z) rotated by `yaw` about +z.
fn pose(x: f64, y: f64, z: f64, yaw: f64) -> Pose {
    Pose { position: Some(Vector3 { x, y, z }), orientation: Some(yaw_quaternion(yaw)) }
}

fn size(x: f64, y: f64, z: f64) -> Option<Vector3> {
    Some(Vector3 { x, y, z })
}

fn point(p: Point, z: f64) -> Point3 {
    Point3 { x: p[0], y: p[1], z }
}

fn entity(id: &str, frame: &str, timestamp: Timestamp) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp),
        frame_id: frame.to_string(),
        id: id.to_string(),
        ..Default::default()
    }
}

/// Every wall of the room ([`RoomSpec::walls`]: the square's four sides and any wall
/// segments) as a box.
fn walls(room: &RoomSpec, timestamp: Timestamp) -> SceneEntity {
    let h = WALL_HEIGHT;
    let mut cubes = Vec::new();
    for w in room.walls().iter() {
        w.for_each_primitive(&mut |p| {
            if let ObstacleSpec::Box { center, half_extents, angle } = p {
                cubes.push(CubePrimitive {
                    pose: Some(pose(center[0], center[1], 0.5 * h, *angle)),
                    size: size(2.0 * half_extents[0], 2.0 * half_extents[1], h),
                    color: Some(WALL_COLOR),
                });
            }
        });
    }
    SceneEntity { cubes, ..entity("walls", WORLD_FRAME, timestamp) }
}

/// A convex polygon (counter-clockwise) as a closed prism: a fan-triangulated top face and two
/// triangles per side. Fewer than three points draw nothing.
fn prism(points: &[Point], h: f64) -> TriangleListPrimitive {
    let n = points.len();
    let mut tri = Vec::new();
    if n >= 3 {
        tri.reserve(3 * (n - 2) + 6 * n);
        for i in 1..n - 1 {
            tri.extend([point(points[0], h), point(points[i], h), point(points[i + 1], h)]);
        }
        for i in 0..n {
            let (a, b) = (points[i], points[(i + 1) % n]);
            tri.extend([point(a, 0.0), point(b, 0.0), point(b, h)]);
            tri.extend([point(a, 0.0), point(b, h), point(a, h)]);
        }
    }
    TriangleListPrimitive {
        pose: Some(pose(0.0, 0.0, 0.0, 0.0)),
        points: tri,
        color: Some(OBSTACLE_COLOR),
        ..Default::default()
    }
}

/// Boxes as cubes, discs as cylinders, convex polygons as triangle-list prisms; a compound
/// obstacle as its parts.
fn obstacles(list: &[ObstacleSpec], timestamp: Timestamp) -> SceneEntity {
    let h = OBSTACLE_HEIGHT;
    let mut e = entity("obstacles", WORLD_FRAME, timestamp);
    let mut parts = Vec::new();
    for o in list {
        o.for_each_primitive(&mut |p| parts.push(p.clone()));
    }
    for o in &parts {
        match o {
            ObstacleSpec::Box { center, half_extents, angle } => e.cubes.push(CubePrimitive {
                pose: Some(pose(center[0], center[1], 0.5 * h, *angle)),
                size: size(2.0 * half_extents[0], 2.0 * half_extents[1], h),
                color: Some(OBSTACLE_COLOR),
            }),
            ObstacleSpec::Circle { center, radius } => {
                e.cylinders.push(disc(*center, *radius, h, OBSTACLE_COLOR))
            }
            ObstacleSpec::Polygon { points } => e.triangles.push(prism(points, h)),
            // Parts are never compounds (for_each_primitive flattens them).
            ObstacleSpec::Compound { .. } => {}
        }
    }
    e
}

/// The footprint (a disc of the robot's radius) and a heading line, locked to frame `robot`.
fn robot(radius: f64, timestamp: Timestamp) -> SceneEntity {
    let h = ROBOT_HEIGHT;
    SceneEntity {
        frame_locked: true,
        cylinders: vec![disc([0.0, 0.0], radius, h, ROBOT_COLOR)],
        lines: vec![LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: Some(pose(0.0, 0.0, h + 0.01, 0.0)),
            thickness: 0.03,
            scale_invariant: false,
            points: vec![Point3 { x: 0.0, y: 0.0, z: 0.0 }, Point3 { x: radius, y: 0.0, z: 0.0 }],
            color: Some(HEADING_COLOR),
            ..Default::default()
        }],
        ..entity("robot", ROBOT_FRAME, timestamp)
    }
}

/// The dimension-scaled robot (DVST): the meta robot's disc scaled by μ about the axle centre,
/// translucent and a little lower than the footprint, locked to frame `robot`.
fn scaled_footprint(radius: f64, timestamp: Timestamp) -> SceneEntity {
    let h = 0.5 * ROBOT_HEIGHT;
    SceneEntity {
        frame_locked: true,
        cylinders: vec![disc([0.0, 0.0], radius, h, SCALED_COLOR)],
        ..entity("scaled_footprint", ROBOT_FRAME, timestamp)
    }
}

/// An upright cylinder of `radius` and `height` standing on the floor at `center`.
fn disc(center: Point, radius: f64, height: f64, color: Color) -> CylinderPrimitive {
    CylinderPrimitive {
        pose: Some(pose(center[0], center[1], 0.5 * height, 0.0)),
        size: size(2.0 * radius, 2.0 * radius, height),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(color),
    }
}

/// `/path`: the robot's positions so far as one line strip in frame `world`; replaces the
/// previous `path` entity.
pub(crate) fn path_update(points: &[Point], timestamp: Timestamp) -> SceneUpdate {
    SceneUpdate {
        deletions: vec![],
        entities: vec![SceneEntity {
            lines: vec![LinePrimitive {
                r#type: line_primitive::Type::LineStrip as i32,
                pose: Some(pose(0.0, 0.0, 0.0, 0.0)),
                thickness: PATH_WIDTH,
                scale_invariant: false,
                points: points.iter().map(|&p| point(p, PATH_Z)).collect(),
                color: Some(PATH_COLOR),
                ..Default::default()
            }],
            ..entity("path", WORLD_FRAME, timestamp)
        }],
    }
}

/// `/plan`: the planned path (`env.subgoals`) as one line strip in frame `world`, thinner and
/// a little lower than the driven path; replaces the previous `plan` entity. An empty plan
/// deletes it (a mapless episode after a planned one, or a route left blocked).
pub(crate) fn plan_update(points: &[Point], timestamp: Timestamp) -> SceneUpdate {
    if points.is_empty() {
        return delete_entity("plan", timestamp);
    }
    SceneUpdate {
        deletions: vec![],
        entities: vec![SceneEntity {
            lines: vec![LinePrimitive {
                r#type: line_primitive::Type::LineStrip as i32,
                pose: Some(pose(0.0, 0.0, 0.0, 0.0)),
                thickness: 0.5 * PATH_WIDTH,
                scale_invariant: false,
                points: points.iter().map(|&p| point(p, 0.5 * PATH_Z)).collect(),
                color: Some(PLAN_COLOR),
                ..Default::default()
            }],
            ..entity("plan", WORLD_FRAME, timestamp)
        }],
    }
}

/// `/subgoal`: the point the agent heads for, a small sphere in frame `world` replacing the
/// previous `subgoal` entity; `None` deletes it.
pub(crate) fn subgoal_update(subgoal: Option<Point>, timestamp: Timestamp) -> SceneUpdate {
    let Some(p) = subgoal else {
        return delete_entity("subgoal", timestamp);
    };
    let d = SUBGOAL_MARKER_DIAMETER;
    SceneUpdate {
        deletions: vec![],
        entities: vec![SceneEntity {
            spheres: vec![SpherePrimitive {
                pose: Some(pose(p[0], p[1], 0.5 * d, 0.0)),
                size: size(d, d, d),
                color: Some(SUBGOAL_COLOR),
            }],
            ..entity("subgoal", WORLD_FRAME, timestamp)
        }],
    }
}

/// Deletes the entity `id` of a topic.
fn delete_entity(id: &str, timestamp: Timestamp) -> SceneUpdate {
    SceneUpdate {
        deletions: vec![SceneEntityDeletion {
            timestamp: Some(timestamp),
            r#type: scene_entity_deletion::Type::MatchingId as i32,
            id: id.to_string(),
        }],
        entities: vec![],
    }
}

fn goal(goal: Point, timestamp: Timestamp) -> SceneEntity {
    let d = GOAL_MARKER_DIAMETER;
    SceneEntity {
        spheres: vec![SpherePrimitive {
            pose: Some(pose(goal[0], goal[1], 0.5 * d, 0.0)),
            size: size(d, d, d),
            color: Some(GOAL_COLOR),
        }],
        ..entity("goal", WORLD_FRAME, timestamp)
    }
}

/// The full scene of one episode: deletes every earlier entity, then adds walls, obstacles, goal
/// and robot (and the scaled robot when μ ≠ 1).
pub(crate) fn episode_scene(ep: &EpisodeStart<'_>, timestamp: Timestamp) -> SceneUpdate {
    let mut entities = vec![
        walls(ep.room, timestamp),
        obstacles(&ep.room.obstacles, timestamp),
        goal(ep.goal, timestamp),
        robot(ep.robot_radius, timestamp),
    ];
    if ep.mu != 1.0 {
        entities.push(scaled_footprint(ep.mu * ep.robot_radius, timestamp));
    }
    SceneUpdate {
        deletions: vec![SceneEntityDeletion {
            timestamp: Some(timestamp),
            r#type: scene_entity_deletion::Type::All as i32,
            id: String::new(),
        }],
        entities,
    }
}
