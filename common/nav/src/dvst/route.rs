//! Routes for the controller (`dvnav serve`'s `SetRoute`): a robot with its own planner (Nav2's,
//! say) hands the controller its path, and each `Act` then carries the robot's pose in the
//! path's frame; the controller picks the subgoal with the one subgoal rule of the simulator
//! ([`dvnav_sim::subgoal`]), holds the robot in the rotation shim after a new path, and says when
//! the robot has strayed or stalled so that its planner should plan again.

use dvnav_sim::Pose2;
use dvnav_sim::planner::PlannedPath;
use dvnav_sim::subgoal::{RouteGuide, SubgoalConfig};

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
    /// a new route.
    pub replan_wanted: bool,
}

/// One robot's route: the subgoal rule on the path it sent.
#[derive(Clone, Debug)]
pub struct RobotRoute {
    guide: RouteGuide,
}

impl RobotRoute {
    /// Follows `points` (checked with [`check_route`]) for a robot of DVST scale `mu`.
    pub fn new(cfg: SubgoalConfig, mu: f64, points: Vec<[f64; 2]>) -> RobotRoute {
        let goal = *points.last().expect("a checked route has a pose");
        let mut guide = RouteGuide::new(cfg, mu, goal);
        guide.set_path(PlannedPath::new(points));
        RobotRoute { guide }
    }

    /// The route's goal.
    pub fn goal(&self) -> [f64; 2] {
        self.guide.goal()
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
    /// shim's command while it holds the robot (within `omega_max`).
    pub fn step(
        &mut self,
        pose: Pose2,
        dt: f64,
        omega_max: f64,
    ) -> (RouteStatus, Option<(f64, f64)>) {
        let g = self.guide.update(pose, dt);
        let status = RouteStatus {
            subgoal: g.subgoal,
            remaining_m: g.remaining_m,
            replan_wanted: g.replan.is_some(),
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
        let (s, shim) = small.step(at, 0.2, 1.0);
        assert_eq!((s.subgoal, shim), ([2.5, 0.0], None));
        assert!((s.remaining_m - 9.0).abs() < 1e-12 && !s.replan_wanted);
        assert_eq!(big.step(at, 0.2, 1.0).0.subgoal, [4.0, 0.0]);
        // Facing away from a new route: the shim turns it first.
        let mut fresh =
            RobotRoute::new(SubgoalConfig::default(), 1.0, vec![[0.0, 0.0], [10.0, 0.0]]);
        let (_, shim) = fresh.step(Pose2::new(1.0, 0.0, 3.0), 0.2, 1.0);
        assert_eq!(shim, Some((0.0, -1.0)));
        assert_eq!(small.goal(), [10.0, 0.0]);
        assert_eq!(small.length_m(), 10.0);
    }
}
