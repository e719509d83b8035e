//! [`Route`]: a path to follow by subgoals, for a policy driven from Python — the subgoal rule
//! of `dvnav serve`'s `SetRoute` ([`dvnav_nav::dvst::route::RobotRoute`]), without a server.

use dvnav_nav::dvst::route::{RobotRoute, RouteRefusal, check_pose, check_route};
use dvnav_sim::Pose2;
use dvnav_sim::subgoal::SubgoalConfig;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn refused(r: RouteRefusal) -> PyErr {
    PyValueError::new_err(format!("{}: {}", r.field, r.reason))
}

/// A route (a robot's own planner's path, in the frame its poses are in) followed by pure
/// pursuit: each `step` gives the subgoal `lookahead_m` (times μ) along it, the rotation
/// shim's command after a new route, and whether the robot strayed or stalled.
#[pyclass(module = "dvnav._core")]
pub struct Route {
    route: RobotRoute,
}

#[pymethods]
impl Route {
    /// `poses`: (x, y) points, the goal last; `mu`: the robot's DVST scale (the lookahead and
    /// the stray distance scale with it).
    #[new]
    #[pyo3(signature = (poses, mu=1.0, lookahead_m=None, rotation_shim=None, replan_distance_m=None, stall_s=None))]
    fn new(
        poses: Vec<(f64, f64)>,
        mu: f64,
        lookahead_m: Option<f64>,
        rotation_shim: Option<bool>,
        replan_distance_m: Option<f64>,
        stall_s: Option<f64>,
    ) -> PyResult<Route> {
        let points: Vec<[f64; 2]> = poses.into_iter().map(|(x, y)| [x, y]).collect();
        check_route(&points).map_err(refused)?;
        if !(mu.is_finite() && mu > 0.0) {
            return Err(PyValueError::new_err(format!("mu: must be above 0, not {mu}")));
        }
        let d = SubgoalConfig::default();
        let cfg = SubgoalConfig {
            lookahead_m: lookahead_m.unwrap_or(d.lookahead_m),
            rotation_shim: rotation_shim.unwrap_or(d.rotation_shim),
            replan_distance_m: replan_distance_m.unwrap_or(d.replan_distance_m),
            stall_s: stall_s.unwrap_or(d.stall_s),
            ..d
        };
        cfg.check().map_err(|(key, why)| {
            PyValueError::new_err(format!("{}: {why}", key.trim_start_matches("env.subgoals.")))
        })?;
        Ok(Route { route: RobotRoute::new(cfg, mu, points) })
    }

    /// The robot at `pose` (x, y, yaw), `dt` s after the last step, turning at most
    /// `omega_max` rad/s: a dict of `subgoal` (x, y), `goal_distance` and `goal_angle` (the
    /// subgoal from the robot: the observation's goal fields), `remaining_m`, `replan_wanted`,
    /// `arrived` (within `goal_tolerance` of the route's goal) and `shim` ((v, ω) while the
    /// rotation shim holds the robot, else None).
    #[pyo3(signature = (pose, dt, omega_max, goal_tolerance))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        pose: (f64, f64, f64),
        dt: f64,
        omega_max: f64,
        goal_tolerance: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let pose = Pose2::new(pose.0, pose.1, pose.2);
        check_pose(pose).map_err(refused)?;
        for (name, x) in [("dt", dt), ("omega_max", omega_max), ("goal_tolerance", goal_tolerance)]
        {
            if !(x.is_finite() && x >= 0.0) {
                return Err(PyValueError::new_err(format!("{name}: must be ≥ 0, not {x}")));
            }
        }
        // No server planned this route: nothing replans it here, so the scan is never asked.
        let (status, shim) = self.route.step(pose, dt, omega_max, Vec::new);
        let goal = self.route.goal();
        let arrived = (pose.x - goal[0]).hypot(pose.y - goal[1]) <= goal_tolerance;
        let [x, y] = pose.to_local(status.subgoal);
        let out = PyDict::new(py);
        out.set_item("subgoal", (status.subgoal[0], status.subgoal[1]))?;
        out.set_item("goal_distance", x.hypot(y))?;
        out.set_item("goal_angle", y.atan2(x))?;
        out.set_item("remaining_m", status.remaining_m)?;
        out.set_item("replan_wanted", status.replan_wanted)?;
        out.set_item("arrived", arrived)?;
        out.set_item("shim", if arrived { None } else { shim })?;
        Ok(out)
    }

    /// The route's goal (x, y).
    #[getter]
    fn goal(&self) -> (f64, f64) {
        let g = self.route.goal();
        (g[0], g[1])
    }

    /// Length of the path (m).
    #[getter]
    fn length_m(&self) -> f64 {
        self.route.length_m()
    }

    /// The lookahead (m, times μ).
    #[getter]
    fn lookahead_m(&self) -> f64 {
        self.route.lookahead_m()
    }
}
