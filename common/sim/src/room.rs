//! [`Room`]: the geometry of one room behind rapier2d's collider set and query pipeline.
//!
//! A room never changes after it is built, so it is built once and shared read-only
//! (`Arc<Room>`) by every environment that runs in it. rapier works in `f32`; the room's public
//! methods take and return `f64` like the rest of the simulator and convert at the boundary, so
//! rapier's types never leave `sim`. LiDAR scans do not go through rapier: the room also keeps
//! its shapes as flat arrays (`caster.rs`) for a much faster exact scan, tested against rapier's
//! ray casts.
//!
//! Timed obstacles (the dynamic scenario) are kept apart from the static geometry, each with
//! its own shapes and its own small caster, sorted by the step they appear at: an environment
//! only says how many of them are present (`active`, a prefix of that order), and collision
//! checks and scans add those to the static room. The room itself stays immutable.

use super::Pose2;
use super::caster::{Beams, Caster};
use super::footprint::Footprint;
use super::grid::{ClearanceMap, Raster, Reach};
use super::room_file::{self, SpecFileError};
use super::spec::{ObstacleSpec, RoomSpec};
use anyhow::Context;
use rapier2d::parry::query;
use rapier2d::parry::shape::Ball;
use rapier2d::prelude::*;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock};

/// A room's walls and obstacles as rapier colliders, with the broad-phase BVH built, ready for
/// ray casts and overlap tests. Immutable after construction, `Send + Sync`.
pub struct Room {
    spec: RoomSpec,
    /// rapier's world, holding the static colliders (standalone, no rigid bodies) and the
    /// broad phase the query pipeline reads. Nothing is ever stepped.
    world: PhysicsWorld,
    /// The same shapes as flat arrays for fast exact LiDAR scans.
    caster: Caster,
    /// Timed obstacles, sorted by `at_step` (stable).
    timed: Vec<TimedShape>,
    /// The static shapes rastered, built on first use (only rooms that sample tasks need it).
    clearance_map: OnceLock<ClearanceMap>,
    /// The planner's raster where it is finer than `clearance_map`'s (big rooms and maps).
    planning_map: OnceLock<ClearanceMap>,
    /// Where discs of the radii asked so far can go, by radius (bits of the `f64`).
    reach: Mutex<Vec<(u64, Arc<Reach>)>>,
    /// The same on the planner's raster, where it is finer.
    planning_reach: Mutex<Vec<(u64, Arc<Reach>)>>,
    /// Where discs' centres fit exactly, on the planner's raster ([`Room::centre_reach`]).
    centre_reach: Mutex<Vec<(u64, Arc<Reach>)>>,
}

/// One timed obstacle, ready for queries.
struct TimedShape {
    at_step: u32,
    /// Its convex parts: pose and shape (room frame).
    parts: Vec<(Pose, SharedShape)>,
    caster: Caster,
}

impl std::fmt::Debug for Room {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Room").field("spec", &self.spec).finish_non_exhaustive()
    }
}

/// The rapier shape and its pose for one convex shape (compounds: `None`; split them first).
pub(super) fn shape_for(o: &ObstacleSpec) -> Option<(Pose, SharedShape)> {
    let v = |p: &[f64; 2]| Vector::new(p[0] as Real, p[1] as Real);
    match o {
        ObstacleSpec::Box { center, half_extents, angle } => Some((
            Pose::new(v(center), *angle as Real),
            SharedShape::cuboid(half_extents[0] as Real, half_extents[1] as Real),
        )),
        ObstacleSpec::Circle { center, radius } => Some((
            Pose::translation(center[0] as Real, center[1] as Real),
            SharedShape::ball(*radius as Real),
        )),
        ObstacleSpec::Polygon { points } => {
            let pts: Vec<Vector> = points.iter().map(v).collect();
            Some((Pose::IDENTITY, SharedShape::convex_polyline(pts)?))
        }
        ObstacleSpec::Compound { .. } => None,
    }
}

/// The colliders of one shape (one per convex part).
pub(super) fn colliders_for(o: &ObstacleSpec) -> Option<Vec<Collider>> {
    let mut out = Vec::new();
    let mut ok = true;
    o.for_each_primitive(&mut |p| match shape_for(p) {
        Some((pose, shape)) => out.push(ColliderBuilder::new(shape).position(pose).build()),
        None => ok = false,
    });
    ok.then_some(out)
}

/// A footprint ready for collision checks: its parts as rapier shapes in the robot frame.
#[derive(Clone)]
pub(super) struct Body {
    /// `Some(r)` for one disc on the axle: the fast path, one ball query.
    circle: Option<f64>,
    parts: Vec<(Pose, SharedShape)>,
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Body")
            .field("circle", &self.circle)
            .field("parts", &self.parts.len())
            .finish()
    }
}

impl Body {
    /// The footprint's shapes (assumed valid).
    pub fn new(fp: &Footprint) -> Body {
        let parts = fp.parts.iter().filter_map(shape_for).collect();
        Body { circle: fp.as_circle(), parts }
    }
}

/// `map`'s reach for `radius` from `cache`, computed and kept there on first use.
fn reach_of(cache: &Mutex<Vec<(u64, Arc<Reach>)>>, map: &ClearanceMap, radius: f64) -> Arc<Reach> {
    cached(cache, radius, || map.reach(radius))
}

/// The entry of `cache` for `radius`, built by `build` on first use.
fn cached(
    cache: &Mutex<Vec<(u64, Arc<Reach>)>>,
    radius: f64,
    build: impl FnOnce() -> Reach,
) -> Arc<Reach> {
    let key = radius.to_bits();
    let mut cache = cache.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, r)) = cache.iter().find(|(k, _)| *k == key) {
        return r.clone();
    }
    let r = Arc::new(build());
    cache.push((key, r.clone()));
    r
}

fn pose_of(p: Pose2) -> Pose {
    Pose::new(Vector::new(p.x as Real, p.y as Real), p.yaw as Real)
}

impl Room {
    /// Builds the colliders of `spec` (its obstacles and walls).
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
            let colliders = colliders_for(o)
                .with_context(|| format!("room `{}`: shape {i} is degenerate", spec.name))?;
            for c in colliders {
                world.insert_collider(c, None);
            }
        }
        // Builds the broad-phase BVH over the new colliders; no body moves, nothing else changes.
        world.detect_collisions(&(), &());
        let caster = Caster::new(&spec);
        let mut timed = Vec::with_capacity(spec.timed_obstacles.len());
        for (i, t) in spec.timed_obstacles.iter().enumerate() {
            let mut parts = Vec::new();
            let mut ok = true;
            t.obstacle.for_each_primitive(&mut |p| match shape_for(p) {
                Some(s) => parts.push(s),
                None => ok = false,
            });
            anyhow::ensure!(ok, "room `{}`: timed obstacle {i} is degenerate", spec.name);
            let caster = Caster::from_shapes([&t.obstacle]);
            timed.push(TimedShape { at_step: t.at_step, parts, caster });
        }
        timed.sort_by_key(|t| t.at_step);
        Ok(Room {
            spec,
            world,
            caster,
            timed,
            clearance_map: OnceLock::new(),
            planning_map: OnceLock::new(),
            reach: Mutex::new(Vec::new()),
            planning_reach: Mutex::new(Vec::new()),
            centre_reach: Mutex::new(Vec::new()),
        })
    }

    /// A built-in room (the files in `rooms/`, embedded in the binary): `env0`..`env3` (the
    /// training layout at side 8, 7, 6, 5 m), `sac_ri` (that layout at 12 m), `gate`, `dynamic`.
    pub fn builtin(name: &str) -> anyhow::Result<Arc<Room>> {
        let spec =
            room_file::builtin_specs().into_iter().find(|s| s.name == name).with_context(|| {
                format!(
                    "unknown room `{name}`; built-in rooms are: {}",
                    Room::builtin_names().join(", ")
                )
            })?;
        Ok(Arc::new(Room::try_new(spec)?))
    }

    /// The built-in rooms `names`, in order (a curriculum's rooms).
    pub fn builtins(names: &[String]) -> anyhow::Result<Vec<Arc<Room>>> {
        names.iter().map(|n| Room::builtin(n)).collect()
    }

    /// Names accepted by [`Room::builtin`]: the curriculum rooms easiest (largest) first, then
    /// the baseline and scenario rooms.
    pub fn builtin_names() -> Vec<String> {
        room_file::builtin_specs().into_iter().map(|s| s.name).collect()
    }

    /// The training curriculum's rooms, Env_0..Env_3.
    pub fn training_names() -> [&'static str; 4] {
        ["env0", "env1", "env2", "env3"]
    }

    /// The room of an occupancy-grid map ([`crate::grid_map`]), with errors that name the file
    /// and the key.
    pub fn from_map(name: &str) -> Result<Room, SpecFileError> {
        let map = crate::grid_map::load(name)?;
        let source = map.meta.image.display().to_string();
        let room_name = map.spec.name.clone();
        Room::try_new(map.spec).map_err(|e| SpecFileError {
            source,
            line: None,
            key: String::new(),
            reason: format!("room `{room_name}`: {e:#}"),
        })
    }

    /// Every room in a room file (one, or one per instance), checked and built.
    pub fn from_file(path: &Path) -> Result<Vec<Arc<Room>>, SpecFileError> {
        let specs = room_file::load_room_file(path)?;
        specs
            .into_iter()
            .map(|s| {
                let name = s.name.clone();
                Room::try_new(s).map(Arc::new).map_err(|e| SpecFileError {
                    source: path.display().to_string(),
                    line: None,
                    key: String::new(),
                    reason: format!("room `{name}`: {e:#}"),
                })
            })
            .collect()
    }

    /// A built-in room by name, a generated room (`generated:KIND:SEED[:PARAMS]`, see
    /// [`crate::generate`]), an occupancy-grid map (`.yaml`/`.yml`/`.png`/`.pgm`, or
    /// `IMAGE.png:resolution=M`; see [`crate::grid_map`]), or the rooms of a room file when
    /// `name_or_path` ends in `.toml` or names an existing file.
    pub fn load(name_or_path: &str) -> anyhow::Result<Vec<Arc<Room>>> {
        if crate::grid_map::is_map_name(name_or_path) {
            return Ok(vec![Arc::new(Room::from_map(name_or_path)?)]);
        }
        if name_or_path.starts_with(crate::generate::PREFIX) {
            let spec = crate::generate::Generated::parse(name_or_path)?.generate()?;
            return Ok(vec![Arc::new(Room::try_new(spec)?)]);
        }
        let path = Path::new(name_or_path);
        if name_or_path.ends_with(".toml") || path.is_file() {
            return Ok(Room::from_file(path)?);
        }
        Ok(vec![Room::builtin(name_or_path)?])
    }

    /// Where a disc of `radius` can go in this room ([`crate::grid`]): computed on first use
    /// for each radius and kept.
    pub fn reach(&self, radius: f64) -> Arc<Reach> {
        reach_of(&self.reach, self.clearance_map(), radius)
    }

    /// [`Room::reach`] on the planner's raster ([`Room::planning_map`]): where the planner
    /// can take a disc of `radius`. Computed on first use for each radius and kept.
    pub fn planning_reach(&self, radius: f64) -> Arc<Reach> {
        if !self.plans_on_own_raster() {
            return self.reach(radius);
        }
        reach_of(&self.planning_reach, self.planning_map(), radius)
    }

    /// Where the centre of a disc of `radius` fits, measured exactly at the cell centres of the
    /// planner's raster ([`ClearanceMap::reach_of_centres`]): the cells the progress reward's
    /// way runs through, which take every gap the disc fits (the planner's reach shuts gaps up
    /// to a cell diagonal wider than the disc). Computed on first use for each radius and kept.
    pub fn centre_reach(&self, radius: f64) -> Arc<Reach> {
        cached(&self.centre_reach, radius, || {
            self.planning_map().reach_of_centres(&self.spec, radius)
        })
    }

    /// Whether the planner's raster is finer than the task-sampling one (a room over 10 m).
    fn plans_on_own_raster(&self) -> bool {
        Raster::for_planning(self.spec.side) != Raster::for_side(self.spec.side)
    }

    /// The room's static shapes rastered with each cell's clearance ([`crate::grid`]): computed
    /// on first use and kept. Tasks are drawn on it; the planner searches
    /// [`Room::planning_map`].
    pub fn clearance_map(&self) -> &ClearanceMap {
        self.clearance_map.get_or_init(|| ClearanceMap::of_room(&self.spec))
    }

    /// The raster the path planner ([`crate::planner`]) and the subgoal rule's line of sight
    /// search: [`Raster::for_planning`], as fine as 2.5 cm up to 40 m rooms, so a door a robot
    /// fits through is one the planner takes (on the task-sampling raster of
    /// [`Room::clearance_map`] a 58 m building is 14 cm cells, and each conservative cell
    /// diagonal narrows every gap). The same map as `clearance_map` where the rasters agree.
    pub fn planning_map(&self) -> &ClearanceMap {
        if !self.plans_on_own_raster() {
            return self.clearance_map();
        }
        self.planning_map.get_or_init(|| {
            ClearanceMap::of_room_on(&self.spec, Raster::for_planning(self.spec.side))
        })
    }

    /// The data this room was built from.
    pub fn spec(&self) -> &RoomSpec {
        &self.spec
    }

    /// The room's name.
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// Side of the room's square (m); the free area is `[-side/2, side/2]²` minus the shapes.
    pub fn side(&self) -> f64 {
        self.spec.side
    }

    /// rapier's scene queries over this room's static shapes.
    pub(super) fn query(&self) -> QueryPipeline<'_> {
        self.world.query_pipeline()
    }

    /// The room's static shapes for fast exact scans.
    #[cfg(test)]
    pub(super) fn caster(&self) -> &Caster {
        &self.caster
    }

    /// How many timed obstacles are present once `steps` control steps have elapsed.
    pub fn timed_active(&self, steps: u32) -> usize {
        self.timed.partition_point(|t| t.at_step <= steps)
    }

    /// Number of timed obstacles.
    pub fn timed_len(&self) -> usize {
        self.timed.len()
    }

    /// Writes the exact first-hit distance of each beam into `out` (see `Caster::cast`): the
    /// static room plus the first `active` timed obstacles.
    pub(super) fn cast_scan(
        &self,
        origin: [f64; 2],
        yaw: f64,
        beams: Beams<'_>,
        max_range: f64,
        active: usize,
        out: &mut [f32],
    ) {
        let timed = &self.timed[..active.min(self.timed.len())];
        if timed.is_empty() {
            self.caster.cast(origin, yaw, beams, max_range, out);
            return;
        }
        if self.caster.inside_any(origin) || timed.iter().any(|t| t.caster.inside_any(origin)) {
            out.fill(0.0);
            return;
        }
        out.fill(f32::INFINITY);
        self.caster.cast_add(origin, yaw, beams, max_range, out);
        for t in timed {
            t.caster.cast_add(origin, yaw, beams, max_range, out);
        }
    }

    /// rapier's first hit along a ray among the first `active` timed obstacles.
    pub(super) fn cast_ray_timed(&self, ray: &Ray, max: Real, active: usize) -> Option<Real> {
        self.timed[..active.min(self.timed.len())]
            .iter()
            .flat_map(|t| &t.parts)
            .filter_map(|(pose, shape)| shape.cast_ray(pose, ray, max, true))
            .reduce(Real::min)
    }

    /// Distance (m) along the unit direction `dir` from `origin` to the first wall or static
    /// obstacle, or `None` when nothing lies within `max_range`. A ray starting inside a shape
    /// hits at 0.
    pub fn cast_ray(&self, origin: [f64; 2], dir: [f64; 2], max_range: f64) -> Option<f64> {
        let ray = Ray::new(
            Vector::new(origin[0] as Real, origin[1] as Real),
            Vector::new(dir[0] as Real, dir[1] as Real),
        );
        self.query().cast_ray(&ray, max_range as Real, true).map(|(_, toi)| toi as f64)
    }

    /// True when a disc of `radius` at `center` touches or overlaps any wall or static
    /// obstacle.
    pub fn circle_collides(&self, center: [f64; 2], radius: f64) -> bool {
        let ball = Ball::new(radius as Real);
        let pose = Pose::translation(center[0] as Real, center[1] as Real);
        self.query().intersect_shape(pose, &ball).next().is_some()
    }

    /// Like [`Room::circle_collides`], also counting every timed obstacle (present or not): the
    /// test for sampled starts and goals, which must stay clear of what will appear.
    pub fn circle_collides_any_time(&self, center: [f64; 2], radius: f64) -> bool {
        if self.circle_collides(center, radius) {
            return true;
        }
        let ball = Ball::new(radius as Real);
        let pose = Pose::translation(center[0] as Real, center[1] as Real);
        self.timed_hits(&pose, &ball, self.timed.len())
    }

    fn timed_hits(&self, pose: &Pose, shape: &dyn Shape, active: usize) -> bool {
        self.timed[..active.min(self.timed.len())].iter().flat_map(|t| &t.parts).any(|(p, s)| {
            query::intersection_test(pose, shape, p, s.as_ref()).is_ok_and(|h| h.intersecting)
        })
    }

    /// True when `body` at `pose` touches or overlaps a wall, a static obstacle, or one of the
    /// first `active` timed obstacles.
    pub(super) fn body_collides(&self, body: &Body, pose: Pose2, active: usize) -> bool {
        let active = active.min(self.timed.len());
        if let Some(r) = body.circle {
            if self.circle_collides(pose.position(), r) {
                return true;
            }
            if active == 0 {
                return false;
            }
            let ball = Ball::new(r as Real);
            return self.timed_hits(
                &Pose::translation(pose.x as Real, pose.y as Real),
                &ball,
                active,
            );
        }
        let at = pose_of(pose);
        body.parts.iter().any(|(local, shape)| {
            let p = at * *local;
            self.query().intersect_shape(p, shape.as_ref()).next().is_some()
                || (active > 0 && self.timed_hits(&p, shape.as_ref(), active))
        })
    }

    /// True when `footprint` at `pose` touches any wall or static obstacle.
    pub fn footprint_collides(&self, footprint: &Footprint, pose: Pose2) -> bool {
        self.body_collides(&Body::new(footprint), pose, 0)
    }

    /// Distance (m) from `p` to the nearest wall or static obstacle, capped at `max`; 0 inside
    /// one.
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
mod tests;
