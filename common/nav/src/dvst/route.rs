//! Routes for the controller (`dvnav serve`'s `SetRoute`): a robot with its own planner (Nav2's,
//! say) hands the controller its path, and each `Act` then carries the robot's pose in the
//! path's frame; the controller picks the subgoal with the one subgoal rule of the simulator
//! ([`dvnav_sim::subgoal`]), holds the robot in the rotation shim after a new path, and says when
//! the robot has strayed or stalled so that its planner should plan again.
//!
//! A robot without a planner of its own sends a goal instead (`SetGoal`), on a map the server
//! was given (`SetMap`, a [`PlanMap`]): the server plans for that robot's footprint (bounding
//! radius plus margin) with [`dvnav_sim::planner`], and replans itself when the robot strays or
//! stalls, reporting `blocked` when no path remains. Replans run on one planner thread, as
//! Nav2's planner server runs beside its controller server: the `Act` that finds the robot off
//! its path asks for one and returns at once, and the robot follows its old path until a later
//! `Act` finds the new one.

use dvnav_sim::Pose2;
use dvnav_sim::grid::{ClearanceMap, Raster};
use dvnav_sim::grid_map::{self, MapFrame};
use dvnav_sim::planner::{self, PlanError, PlannedPath, PlannerConfig};
use dvnav_sim::subgoal::{Replan, RouteGuide, SubgoalConfig};
use std::sync::{Arc, OnceLock, mpsc};

/// The largest map file text `SetMap` takes (bytes).
pub const MAX_MAP_YAML: usize = 64 * 1024;
/// The largest map image `SetMap` takes (bytes); its side is bounded too
/// ([`grid_map::MAX_SIDE_PX`]).
pub const MAX_MAP_IMAGE: usize = 32 * 1024 * 1024;

/// A map the controller plans on: the room raster of a map_server map and its frame.
#[derive(Debug)]
pub struct PlanMap {
    frame: MapFrame,
    clearance: ClearanceMap,
    /// Image size (px) and resolution (m/px).
    pub width: usize,
    /// See `width`.
    pub height: usize,
    /// See `width`.
    pub resolution: f64,
}

impl PlanMap {
    /// A map_server YAML and its image's bytes; refused naming `map_yaml` or `image`.
    pub fn from_bytes(map_yaml: &str, image: &[u8]) -> Result<PlanMap, RouteRefusal> {
        if map_yaml.len() > MAX_MAP_YAML {
            let why = format!("{} bytes; a map file has at most {MAX_MAP_YAML}", map_yaml.len());
            return Err(RouteRefusal { field: "map_yaml".into(), reason: why });
        }
        if image.len() > MAX_MAP_IMAGE {
            let why = format!("{} bytes; a map image has at most {MAX_MAP_IMAGE}", image.len());
            return Err(RouteRefusal { field: "image".into(), reason: why });
        }
        let map = grid_map::from_bytes("SetMap", map_yaml, image).map_err(|e| {
            let field = if e.key == "image" { "image" } else { "map_yaml" };
            let line = e.line.map(|l| format!("line {l}: ")).unwrap_or_default();
            let key = if e.key.is_empty() { String::new() } else { format!("`{}`: ", e.key) };
            RouteRefusal { field: field.into(), reason: format!("{line}{key}{}", e.reason) }
        })?;
        Ok(PlanMap {
            clearance: ClearanceMap::of_room_on(&map.spec, Raster::for_planning(map.spec.side)),
            width: map.grid.width,
            height: map.grid.height,
            resolution: map.meta.resolution,
            frame: map.frame,
        })
    }

    /// A path (map frame) from `start` to `goal` (map frame) for a disc of `radius`; refused
    /// naming `start` or `goal`.
    pub fn plan(
        &self,
        radius: f64,
        start: [f64; 2],
        goal: [f64; 2],
        cfg: &PlannerConfig,
    ) -> Result<Vec<[f64; 2]>, RouteRefusal> {
        self.plan_avoiding(radius, start, goal, cfg, &[])
    }

    /// [`PlanMap::plan`] with `obstacles` (map frame) marked occupied as well: a robot's scan
    /// returns after it stalled (a closed door, a person standing in the way), as the
    /// simulator's replans do ([`dvnav_sim::grid::ClearanceMap::with_points`]; on a building's
    /// map that redoes its distance transform, a tenth of a second, so only on the planner
    /// thread).
    pub fn plan_avoiding(
        &self,
        radius: f64,
        start: [f64; 2],
        goal: [f64; 2],
        cfg: &PlannerConfig,
        obstacles: &[[f64; 2]],
    ) -> Result<Vec<[f64; 2]>, RouteRefusal> {
        let (a, b) = (self.frame.map_to_room(start), self.frame.map_to_room(goal));
        let marked;
        let clearance = if obstacles.is_empty() {
            &self.clearance
        } else {
            let room: Vec<[f64; 2]> =
                obstacles.iter().map(|&p| self.frame.map_to_room(p)).collect();
            marked = self.clearance.with_points(&room, cfg.known_tolerance_m);
            &marked
        };
        let path = planner::plan(clearance, radius, a, b, cfg).map_err(|e| {
            let field = match &e {
                PlanError::OffMap { which, .. } | PlanError::NoRoom { which, .. } => *which,
                PlanError::Unreachable { .. } => "goal",
            };
            // The error's coordinates are the room's; name the map's.
            let reason = match e {
                PlanError::OffMap { which, .. } => {
                    let p = if which == "start" { start } else { goal };
                    format!("({:.2}, {:.2}) lies outside the map", p[0], p[1])
                }
                PlanError::NoRoom { which, radius, .. } => {
                    let p = if which == "start" { start } else { goal };
                    format!(
                        "({:.2}, {:.2}) has no room for a robot of radius {radius:.3} m (inside \
                         an obstacle, unknown space or too close to one)",
                        p[0], p[1]
                    )
                }
                PlanError::Unreachable { radius, .. } => format!(
                    "({:.2}, {:.2}) cannot be reached from the start by a robot of radius \
                     {radius:.3} m",
                    goal[0], goal[1]
                ),
            };
            RouteRefusal { field: field.into(), reason }
        })?;
        Ok(path.points.into_iter().map(|q| self.frame.room_to_map(q)).collect())
    }
}

/// Most poses a route may have.
pub const MAX_ROUTE_POSES: usize = 100_000;
/// Largest coordinate (m) of a route pose or of a robot pose: a building, not a continent.
pub const MAX_COORD_M: f64 = 1.0e5;

/// Why a route or a pose was refused: the field and the reason.
#[derive(Clone, Debug, PartialEq)]
pub struct RouteRefusal {
    /// The request field, e.g. `poses[3].x`.
    pub field: String,
    /// What is wrong with it.
    pub reason: String,
}

/// Checks a route's poses (room or odometry frame, m): 1 to [`MAX_ROUTE_POSES`] of them, each
/// coordinate finite and within ±[`MAX_COORD_M`].
pub fn check_route(points: &[[f64; 2]]) -> Result<(), RouteRefusal> {
    let refuse = |field: String, reason: String| Err(RouteRefusal { field, reason });
    if points.is_empty() {
        return refuse("poses".into(), "a route needs at least one pose (its goal)".into());
    }
    if points.len() > MAX_ROUTE_POSES {
        let why = format!("{} poses; a route has at most {MAX_ROUTE_POSES}", points.len());
        return refuse("poses".into(), why);
    }
    for (i, p) in points.iter().enumerate() {
        for (axis, x) in [("x", p[0]), ("y", p[1])] {
            if !(x.is_finite() && x.abs() <= MAX_COORD_M) {
                let why = format!("must be finite and within ±{MAX_COORD_M} m, got {x}");
                return refuse(format!("poses[{i}].{axis}"), why);
            }
        }
    }
    Ok(())
}

/// Checks a robot's pose in its route's frame (`pose.x`, `pose.y`, `pose.yaw`).
pub fn check_pose(pose: Pose2) -> Result<(), RouteRefusal> {
    for (axis, x, limit) in
        [("x", pose.x, MAX_COORD_M), ("y", pose.y, MAX_COORD_M), ("yaw", pose.yaw, 1.0e6)]
    {
        if !(x.is_finite() && x.abs() <= limit) {
            return Err(RouteRefusal {
                field: format!("pose.{axis}"),
                reason: format!("must be finite and within ±{limit}, got {x}"),
            });
        }
    }
    Ok(())
}

/// What the route says for one control cycle, as the reply reports it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RouteStatus {
    /// The subgoal the agent was given (route frame, m).
    pub subgoal: [f64; 2],
    /// Path left to the route's goal (m).
    pub remaining_m: f64,
    /// The robot strayed from the path or made no progress along it: its planner should send
    /// a new route (a route the server planned, `SetGoal`, it replans itself).
    pub replan_wanted: bool,
    /// Plans the server made after the first (`SetGoal` routes).
    pub replans: u32,
    /// The server is planning this robot a new path (off the request path); meanwhile the
    /// robot follows the one it has.
    pub replanning: bool,
    /// A replan found no path: the robot heads for the goal itself.
    pub blocked: bool,
}

/// What the server replans a `SetGoal` route with.
#[derive(Clone, Debug)]
struct Replanner {
    map: Arc<PlanMap>,
    /// The robot's bounding radius plus margin (m).
    radius: f64,
}

impl Replanner {
    /// Asks the planner thread for a path from `start` to `goal`; the answer lands in the
    /// slot returned. Replans run there, not in the `Act` that asked, so a robot's replan
    /// (milliseconds on a building's map) never holds up the calls of the others.
    fn request(
        &self,
        start: [f64; 2],
        goal: [f64; 2],
        cfg: PlannerConfig,
        obstacles: Vec<[f64; 2]>,
    ) -> Arc<PlanSlot> {
        let slot = Arc::new(PlanSlot::new());
        let job = PlanJob {
            map: self.map.clone(),
            radius: self.radius,
            start,
            goal,
            cfg,
            obstacles,
            slot: slot.clone(),
        };
        if let Err(mpsc::SendError(job)) = planner_thread().send(job) {
            // No planner thread (it could not be started): plan here.
            job.run();
        }
        slot
    }
}

/// Where a replan's answer lands: a path (map frame) or why none.
type PlanSlot = OnceLock<Result<Vec<[f64; 2]>, RouteRefusal>>;

/// One replan for the planner thread.
struct PlanJob {
    map: Arc<PlanMap>,
    radius: f64,
    start: [f64; 2],
    goal: [f64; 2],
    cfg: PlannerConfig,
    /// Points to plan round (map frame): the scan's returns after a stall.
    obstacles: Vec<[f64; 2]>,
    slot: Arc<PlanSlot>,
}

impl PlanJob {
    fn run(self) {
        let plan =
            self.map.plan_avoiding(self.radius, self.start, self.goal, &self.cfg, &self.obstacles);
        let _ = self.slot.set(plan);
    }
}

/// The server's planner thread (Nav2's planner server): one, started on the first replan,
/// taking replans in the order asked. One is plenty: a replan on Willow Garage takes 4 ms at
/// p50 (`dvnav bench plan`), and 100 robots at 10 Hz straying every 5 s ask for 20 a second.
fn planner_thread() -> &'static mpsc::Sender<PlanJob> {
    static SENDER: OnceLock<mpsc::Sender<PlanJob>> = OnceLock::new();
    SENDER.get_or_init(|| {
        let (tx, rx) = mpsc::channel::<PlanJob>();
        // If the thread cannot start, `rx` is dropped with it and each send fails: the caller
        // then plans itself.
        let _ = std::thread::Builder::new()
            .name("dvnav-planner".into())
            .spawn(move || rx.into_iter().for_each(PlanJob::run));
        tx
    })
}

/// One robot's route: the subgoal rule on the path it sent.
#[derive(Clone, Debug)]
pub struct RobotRoute {
    guide: RouteGuide,
    replanner: Option<Replanner>,
    /// The replan asked for and not yet applied.
    pending: Option<Arc<PlanSlot>>,
    replans: u32,
    blocked: bool,
}

impl RobotRoute {
    /// Follows `points` (checked with [`check_route`]) for a robot of DVST scale `mu`.
    pub fn new(cfg: SubgoalConfig, mu: f64, points: Vec<[f64; 2]>) -> RobotRoute {
        let goal = *points.last().expect("a checked route has a pose");
        let mut guide = RouteGuide::new(cfg, mu, goal);
        guide.set_path(PlannedPath::new(points));
        RobotRoute { guide, replanner: None, pending: None, replans: 0, blocked: false }
    }

    /// Plans on `map` from `start` to `goal` (map frame) for a robot of bounding `radius` (plus
    /// margin) and DVST scale `mu`, and follows the path, replanning on the map when the robot
    /// strays or stalls.
    pub fn planned(
        cfg: SubgoalConfig,
        mu: f64,
        map: Arc<PlanMap>,
        radius: f64,
        start: [f64; 2],
        goal: [f64; 2],
    ) -> Result<RobotRoute, RouteRefusal> {
        let points = map.plan(radius, start, goal, &cfg.planner)?;
        let mut route = RobotRoute::new(cfg, mu, points);
        route.replanner = Some(Replanner { map, radius });
        Ok(route)
    }

    /// The route's goal.
    pub fn goal(&self) -> [f64; 2] {
        self.guide.goal()
    }

    /// Vertices of its current path.
    pub fn pose_count(&self) -> usize {
        self.guide.path().map_or(0, |p| p.points.len())
    }

    /// Its length (m).
    pub fn length_m(&self) -> f64 {
        self.guide.path().map_or(0.0, |p| p.length_m)
    }

    /// The robot's lookahead (m).
    pub fn lookahead_m(&self) -> f64 {
        self.guide.lookahead_m()
    }

    /// The robot is at `pose`, `dt` s after the last cycle: the subgoal, and the rotation
    /// shim's command while it holds the robot (within `omega_max`). `scan_points` gives the
    /// returns of its current scan (route frame), asked for only when a server-planned route
    /// replans after a stall, to plan round what stopped it.
    pub fn step(
        &mut self,
        pose: Pose2,
        dt: f64,
        omega_max: f64,
        scan_points: impl FnOnce() -> Vec<[f64; 2]>,
    ) -> (RouteStatus, Option<(f64, f64)>) {
        let mut g = self.guide.update(pose, dt);
        let arrived = self.pending.as_ref().and_then(|slot| slot.get().cloned());
        if let Some(plan) = arrived {
            // A replan asked for in an earlier cycle: the robot has moved on a little since,
            // and the rule projects it onto the new path from where it is now.
            self.pending = None;
            match plan {
                Ok(points) => self.guide.set_path(PlannedPath::new(points)),
                Err(_) => {
                    self.blocked = true;
                    self.guide.clear_path();
                }
            }
            self.replans += 1;
            g = self.guide.update(pose, 0.0);
        } else if let (Some(why), Some(r), None) = (g.replan, &self.replanner, &self.pending) {
            let cfg = self.guide.config().planner.clone();
            let obstacles = if why == Replan::Stall { scan_points() } else { Vec::new() };
            self.pending = Some(r.request(pose.position(), self.guide.goal(), cfg, obstacles));
        }
        let status = RouteStatus {
            subgoal: g.subgoal,
            remaining_m: g.remaining_m,
            replan_wanted: g.replan.is_some() && self.replanner.is_none(),
            replans: self.replans,
            replanning: self.pending.is_some(),
            blocked: self.blocked,
        };
        (status, self.guide.shim_command(pose, omega_max))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_routes_and_poses_name_the_field() {
        assert_eq!(check_route(&[]).unwrap_err().field, "poses");
        assert_eq!(check_route(&[[0.0, 0.0], [f64::NAN, 1.0]]).unwrap_err().field, "poses[1].x");
        assert_eq!(check_route(&[[0.0, 2e5]]).unwrap_err().field, "poses[0].y");
        assert!(check_route(&[[1.0, 2.0]]).is_ok());
        let e = check_pose(Pose2::new(0.0, 0.0, f64::INFINITY)).unwrap_err();
        assert_eq!(e.field, "pose.yaw");
    }

    #[test]
    fn a_route_gives_lookahead_subgoals_scaled_by_mu() {
        let pts = vec![[0.0, 0.0], [10.0, 0.0]];
        let mut small = RobotRoute::new(SubgoalConfig::default(), 1.0, pts.clone());
        let mut big = RobotRoute::new(SubgoalConfig::default(), 2.0, pts);
        let at = Pose2::new(1.0, 0.0, 0.0);
        let (s, shim) = small.step(at, 0.2, 1.0, Vec::new);
        assert_eq!((s.subgoal, shim), ([2.5, 0.0], None));
        assert!((s.remaining_m - 9.0).abs() < 1e-12 && !s.replan_wanted);
        assert_eq!(big.step(at, 0.2, 1.0, Vec::new).0.subgoal, [4.0, 0.0]);
        // Facing away from a new route: the shim turns it first.
        let mut fresh =
            RobotRoute::new(SubgoalConfig::default(), 1.0, vec![[0.0, 0.0], [10.0, 0.0]]);
        let (_, shim) = fresh.step(Pose2::new(1.0, 0.0, 3.0), 0.2, 1.0, Vec::new);
        assert_eq!(shim, Some((0.0, -1.0)));
        assert_eq!(small.goal(), [10.0, 0.0]);
        assert_eq!(small.length_m(), 10.0);
    }

    /// A 5 × 3 m map_server map (5 cm pixels) split at x = 2.5 m by a wall with a 1 m door at
    /// y = 1.8-2.8 m.
    fn door_map() -> PlanMap {
        let (w, h) = (100usize, 60usize);
        let mut px = vec![254u8; w * h];
        for row in 0..h {
            for col in 0..w {
                let y = (h - row) as f64 * 0.05 - 0.025;
                let border = row < 2 || row >= h - 2 || col < 2 || col >= w - 2;
                let wall = (49..=51).contains(&col) && !(1.8..2.8).contains(&y);
                if border || wall {
                    px[row * w + col] = 0;
                }
            }
        }
        let mut pgm = format!("P5\n{w} {h}\n255\n").into_bytes();
        pgm.extend(px);
        PlanMap::from_bytes("resolution: 0.05\norigin: [0.0, 0.0, 0.0]\n", &pgm).unwrap()
    }

    /// Holds the robot still at `at` until its route has replanned (on the planner thread),
    /// with `returns` as its scan's returns; the status then, and how often the scan was read.
    fn stall_until_replanned(route: &mut RobotRoute, returns: &[[f64; 2]]) -> (RouteStatus, usize) {
        let at = Pose2::new(1.0, 1.0, 0.0);
        let read = std::cell::Cell::new(0);
        for _ in 0..1000 {
            let (s, _) = route.step(at, 0.5, 1.0, || {
                read.set(read.get() + 1);
                returns.to_vec()
            });
            if s.replans > 0 {
                return (s, read.get());
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        panic!("no replan came back");
    }

    #[test]
    fn a_stalled_robot_is_replanned_round_its_scans_returns_off_the_call() {
        let map = Arc::new(door_map());
        let cfg = SubgoalConfig { rotation_shim: false, ..SubgoalConfig::default() };
        let plan =
            || RobotRoute::planned(cfg.clone(), 1.0, map.clone(), 0.2, [1.0, 1.0], [4.0, 1.0]);
        // Something in the doorway: the replan finds no way, and says so.
        let doorway: Vec<[f64; 2]> = (0..=20).map(|k| [2.5, 1.8 + 0.05 * k as f64]).collect();
        let mut route = plan().unwrap();
        let (s, read) = stall_until_replanned(&mut route, &doorway);
        assert!(s.blocked && s.replans == 1 && !s.replanning, "{s:?}");
        assert_eq!(read, 1, "the scan is read once, when the stall asks for the replan");
        // Something elsewhere: the same way is planned again.
        let mut route = plan().unwrap();
        let (s, _) = stall_until_replanned(&mut route, &[[4.5, 2.5]]);
        assert!(!s.blocked && s.replans == 1, "{s:?}");
        assert!(s.subgoal[1] > 1.0, "heads for the door again: {s:?}");
    }
}
