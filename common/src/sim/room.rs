//! [`Room`]: the static geometry of one room behind rapier2d's collider set and query pipeline.
//!
//! A room never moves, so it is built once and shared read-only (`Arc<Room>`) by every
//! environment that runs in it. rapier works in `f32`; the room's public methods take and return
//! `f64` like the rest of the simulator and convert at the boundary, so rapier's types never
//! leave `sim`. LiDAR scans do not go through rapier: the room also keeps its shapes as flat
//! arrays (`caster.rs`) for a much faster exact scan, tested against rapier's ray casts.

use super::caster::Caster;
use super::spec::{ObstacleSpec, RoomSpec};
use anyhow::Context;
use rapier2d::parry::shape::Ball;
use rapier2d::prelude::*;
use std::sync::Arc;

/// Names of the built-in rooms and their sides (m): the training curriculum Env_0..Env_3.
const BUILTIN: [(&str, f64); 4] = [("env0", 8.0), ("env1", 7.0), ("env2", 6.0), ("env3", 5.0)];

/// Names accepted by [`Room::builtin`].
const BUILTIN_NAMES: [&str; 4] = ["env0", "env1", "env2", "env3"];

/// A room's walls and obstacles as rapier colliders, with the broad-phase BVH built, ready for
/// ray casts and overlap tests. Immutable after construction, `Send + Sync`.
pub struct Room {
    spec: RoomSpec,
    /// rapier's world, holding the colliders (standalone, no rigid bodies) and the broad phase
    /// the query pipeline reads. Nothing is ever stepped.
    world: PhysicsWorld,
    /// The same shapes as flat arrays for fast exact LiDAR scans.
    caster: Caster,
}

impl std::fmt::Debug for Room {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Room").field("spec", &self.spec).finish_non_exhaustive()
    }
}

/// The collider for one obstacle.
pub(super) fn collider_for(o: &ObstacleSpec) -> Option<Collider> {
    let v = |p: &[f64; 2]| Vector::new(p[0] as Real, p[1] as Real);
    let builder = match o {
        ObstacleSpec::Box { center, half_extents, angle } => {
            ColliderBuilder::cuboid(half_extents[0] as Real, half_extents[1] as Real)
                .position(Pose::new(v(center), *angle as Real))
        }
        ObstacleSpec::Circle { center, radius } => {
            ColliderBuilder::ball(*radius as Real).translation(v(center))
        }
        ObstacleSpec::Polygon { points } => {
            let pts: Vec<Vector> = points.iter().map(v).collect();
            ColliderBuilder::convex_polyline(pts)?
        }
    };
    Some(builder.build())
}

impl Room {
    /// Builds the colliders of `spec` (its obstacles and four walls).
    ///
    /// # Panics
    /// If the spec is invalid (see [`RoomSpec::validate`]); use [`Room::try_new`] for specs
    /// that come from users.
    pub fn new(spec: RoomSpec) -> Room {
        match Room::try_new(spec) {
            Ok(room) => room,
            Err(e) => panic!("invalid room: {e:#}"),
        }
    }

    /// Builds the colliders of `spec`, or says what is wrong with it.
    pub fn try_new(spec: RoomSpec) -> anyhow::Result<Room> {
        spec.validate()?;
        let mut world = PhysicsWorld::new();
        for (i, o) in spec.walls().iter().chain(&spec.obstacles).enumerate() {
            let collider = collider_for(o)
                .with_context(|| format!("room `{}`: shape {i} is degenerate", spec.name))?;
            world.insert_collider(collider, None);
        }
        // Builds the broad-phase BVH over the new colliders; no body moves, nothing else changes.
        world.detect_collisions(&(), &());
        let caster = Caster::new(&spec);
        Ok(Room { spec, world, caster })
    }

    /// A built-in room: `env0`..`env3` are the training layout at side 8, 7, 6, 5 m.
    pub fn builtin(name: &str) -> anyhow::Result<Arc<Room>> {
        let (name, side) = BUILTIN.iter().find(|(n, _)| *n == name).with_context(|| {
            format!("unknown room `{name}`; built-in rooms are: {}", BUILTIN_NAMES.join(", "))
        })?;
        Ok(Arc::new(Room::new(RoomSpec::training(name, *side))))
    }

    /// Names accepted by [`Room::builtin`], easiest (largest) first.
    pub fn builtin_names() -> &'static [&'static str] {
        &BUILTIN_NAMES
    }

    /// The data this room was built from.
    pub fn spec(&self) -> &RoomSpec {
        &self.spec
    }

    /// The room's name.
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// Inner side length (m); the free area is `[-side/2, side/2]²` minus the obstacles.
    pub fn side(&self) -> f64 {
        self.spec.side
    }

    /// rapier's scene queries over this room.
    pub(super) fn query(&self) -> QueryPipeline<'_> {
        self.world.query_pipeline()
    }

    /// The room's shapes for fast exact scans.
    pub(super) fn caster(&self) -> &Caster {
        &self.caster
    }

    /// Distance (m) along the unit direction `dir` from `origin` to the first wall or obstacle,
    /// or `None` when nothing lies within `max_range`. A ray starting inside a shape hits at 0.
    pub fn cast_ray(&self, origin: [f64; 2], dir: [f64; 2], max_range: f64) -> Option<f64> {
        let ray = Ray::new(
            Vector::new(origin[0] as Real, origin[1] as Real),
            Vector::new(dir[0] as Real, dir[1] as Real),
        );
        self.query().cast_ray(&ray, max_range as Real, true).map(|(_, toi)| toi as f64)
    }

    /// True when a disc of `radius` at `center` touches or overlaps any wall or obstacle.
    pub fn circle_collides(&self, center: [f64; 2], radius: f64) -> bool {
        let ball = Ball::new(radius as Real);
        let pose = Pose::translation(center[0] as Real, center[1] as Real);
        self.query().intersect_shape(pose, &ball).next().is_some()
    }

    /// Distance (m) from `p` to the nearest wall or obstacle, capped at `max`; 0 inside one.
    pub fn clearance(&self, p: [f64; 2], max: f64) -> f64 {
        let point = Vector::new(p[0] as Real, p[1] as Real);
        match self.query().project_point(point, max as Real, true) {
            Some((_, proj)) if proj.is_inside => 0.0,
            Some((_, proj)) => ((point - proj.point).length() as f64).min(max),
            None => max,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rapier2d::parry::query;

    fn assert_send_sync<T: Send + Sync>() {}

    #[test]
    fn room_is_shareable() {
        assert_send_sync::<Room>();
        assert_send_sync::<Arc<Room>>();
    }

    #[test]
    fn builtin_names_resolve_and_unknown_lists_valid_names() {
        for (name, side) in BUILTIN {
            let room = Room::builtin(name).unwrap();
            assert_eq!(room.name(), name);
            assert_eq!(room.side(), side);
            assert!((8..=12).contains(&room.spec().obstacles.len()));
        }
        let err = Room::builtin("env9").unwrap_err().to_string();
        assert!(err.contains("env0") && err.contains("env3"), "{err}");
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
    fn invalid_specs_are_refused() {
        let mut spec = RoomSpec::empty("bad", 4.0);
        spec.obstacles
            .push(ObstacleSpec::Polygon { points: vec![[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]] });
        let err = Room::try_new(spec).unwrap_err().to_string();
        assert!(err.contains("counter-clockwise"), "{err}");
        assert!(Room::try_new(RoomSpec::empty("bad", -1.0)).is_err());
    }

    /// Distance between two obstacle shapes.
    fn gap(a: &ObstacleSpec, b: &ObstacleSpec) -> f64 {
        let (ca, cb) = (collider_for(a).unwrap(), collider_for(b).unwrap());
        query::distance(ca.position(), ca.shape(), cb.position(), cb.shape()).unwrap().distance
            as f64
    }

    /// The layout promise: ≥ 0.6 m between groups and from every group to the walls, and a
    /// free origin, in every built-in room (the smallest is the binding one).
    #[test]
    fn training_layout_leaves_wide_gaps_and_a_free_origin() {
        for (name, side) in BUILTIN {
            let groups = RoomSpec::training_grouped(side);
            let walls = RoomSpec::empty("w", side).walls();
            for (i, gi) in groups.iter().enumerate() {
                for a in gi {
                    for w in &walls {
                        let d = gap(a, w);
                        assert!(d >= 0.6 - 1e-6, "{name}: group {i} is {d:.3} m from a wall");
                    }
                    for (j, gj) in groups.iter().enumerate().skip(i + 1) {
                        for b in gj {
                            let d = gap(a, b);
                            assert!(d >= 0.6 - 1e-6, "{name}: groups {i}, {j} are {d:.3} m apart");
                        }
                    }
                }
            }
            let room = Room::builtin(name).unwrap();
            let c = room.clearance([0.0, 0.0], 10.0);
            assert!(c >= 0.4 + 0.2, "{name}: origin clearance {c}");
            assert!(!room.circle_collides([0.0, 0.0], 0.2 + 0.4));
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
}
