//! The subgoal rule: how the meta agent follows a planned path ([`crate::planner`]). One
//! implementation for training, evaluation, the controller (`dvnav serve`) and Python.
//!
//! - **Pure pursuit:** the agent's goal is the point a lookahead `L` further along the path
//!   than the robot's projection on it (DRL-VO's pure pursuit; Arena-Rosnav's spatial horizon);
//!   the final goal itself once it is within `L` (straight line or along the path).
//! - **Replans** are asked for when the robot is farther than a threshold from the path (it
//!   went round an obstacle the other way), and when it has made no progress along the path for
//!   a while (a door closed, a person standing: the caller plans again with the current scan's
//!   returns as obstacles, and reports `blocked` when no path remains).
//! - **A rotation shim** (Nav2's RotationShimController): after each plan the robot turns in
//!   place until the subgoal is within a set angle of its heading, then the agent drives. A
//!   mapless agent trained on goals ahead of it and walls around it creeps instead of turning
//!   when the goal is far behind it next to a wall (issue 28's measurement).
//!
//! Lengths are the meta robot's; a robot of DVST scale μ uses them times μ, as DVST scales
//! everything else.

use crate::planner::{PlannedPath, PlannerConfig};
use crate::spec::Point;
use crate::{Pose2, dist};
use serde::{Deserialize, Serialize};

/// `[env.subgoals]`: long tasks followed along a planned path.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SubgoalConfig {
    /// Feed the lookahead point to the agent as its goal. `false` plans for the reports
    /// (path length, path ratio) while the agent sees only the final goal: mapless.
    pub follow: bool,
    /// With `follow`, the share of episodes (drawn per episode) that are followed along the
    /// path; the others are the paper's mapless task (the agent sees the final goal, the reward
    /// is the straight-line progress), so one run learns both. 1 follows every episode.
    pub follow_share: f64,
    /// Lookahead L (m, meta robot; times μ for another size).
    pub lookahead_m: f64,
    /// Replan when the robot is farther than this from the path (m, meta robot).
    pub replan_distance_m: f64,
    /// Replan when the robot has made no progress along the path for this long (s).
    pub stall_s: f64,
    /// Turn in place towards the subgoal after each plan until it is within `shim_angle_deg`.
    pub rotation_shim: bool,
    /// The rotation shim hands over to the agent within this angle (degrees).
    pub shim_angle_deg: f64,
    /// Above 0, an episode's step limit is at least this many times the steps its planned path
    /// takes at `v_max` (`env.max_steps` stays the floor): a long route through a building may
    /// be 30 m, more than the 80 s of the paper's 400 steps allow at 0.5 m/s. 0 (the default)
    /// keeps `env.max_steps` for every episode; `dvnav eval --tasks long` uses 4, the slack
    /// the paper's limit leaves a 10 m path in its rooms (40 m of driving).
    pub time_limit_factor: f64,
    /// How paths are planned.
    pub planner: PlannerConfig,
}

impl Default for SubgoalConfig {
    fn default() -> Self {
        Self {
            follow: true,
            follow_share: 1.0,
            lookahead_m: 1.5,
            replan_distance_m: 1.0,
            stall_s: 10.0,
            rotation_shim: true,
            shim_angle_deg: 45.0,
            time_limit_factor: 0.0,
            planner: PlannerConfig::default(),
        }
    }
}

impl SubgoalConfig {
    /// Checks every value, naming the key (`env.subgoals.…`) of the first bad one.
    pub fn check(&self) -> Result<(), (String, String)> {
        let positive = |k: &str, x: f64| {
            if x.is_finite() && x > 0.0 {
                Ok(())
            } else {
                Err((format!("env.subgoals.{k}"), format!("must be above 0, not {x}")))
            }
        };
        if !(0.0..=1.0).contains(&self.follow_share) {
            return Err((
                "env.subgoals.follow_share".into(),
                format!("must lie in [0, 1], not {}", self.follow_share),
            ));
        }
        positive("lookahead_m", self.lookahead_m)?;
        positive("replan_distance_m", self.replan_distance_m)?;
        positive("stall_s", self.stall_s)?;
        if !(self.shim_angle_deg > 0.0 && self.shim_angle_deg < 180.0) {
            return Err((
                "env.subgoals.shim_angle_deg".into(),
                format!("must lie in (0, 180), not {}", self.shim_angle_deg),
            ));
        }
        if !(self.time_limit_factor.is_finite() && self.time_limit_factor >= 0.0) {
            return Err((
                "env.subgoals.time_limit_factor".into(),
                format!("must be ≥ 0, not {}", self.time_limit_factor),
            ));
        }
        let p = &self.planner;
        for (k, x) in [
            ("margin_m", p.margin_m),
            ("clearance_weight", p.clearance_weight),
            ("preferred_clearance_m", p.preferred_clearance_m),
            ("known_tolerance_m", p.known_tolerance_m),
        ] {
            if !(x.is_finite() && x >= 0.0) {
                return Err((format!("env.subgoals.planner.{k}"), format!("must be ≥ 0, not {x}")));
            }
        }
        positive("planner.clearance_decay_m", p.clearance_decay_m)
    }
}

/// Where the robot is on a path, and the point it should head for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lookahead {
    /// The subgoal (m): `L` along the path from the robot's projection, or the final goal.
    pub subgoal: Point,
    /// Arc length (m) of the robot's projection on the path.
    pub progress_m: f64,
    /// Path length (m) left from the projection, plus the distance to it.
    pub remaining_m: f64,
    /// Distance (m) from the robot to the path.
    pub off_path_m: f64,
    /// The subgoal is the final goal.
    pub final_goal: bool,
}

/// Pure pursuit on one path.
#[derive(Clone, Debug)]
pub struct PathFollower {
    path: PlannedPath,
    /// Arc length at each vertex.
    cum: Vec<f64>,
    /// The projection's arc length at the last update.
    s: f64,
}

impl PathFollower {
    /// Follows `path` from its start.
    pub fn new(path: PlannedPath) -> PathFollower {
        let mut cum = vec![0.0];
        for w in path.points.windows(2) {
            cum.push(cum.last().unwrap() + dist(w[0], w[1]));
        }
        PathFollower { path, cum, s: 0.0 }
    }

    /// The path.
    pub fn path(&self) -> &PlannedPath {
        &self.path
    }

    /// The point at arc length `s` (clamped to the path).
    pub fn point_at(&self, s: f64) -> Point {
        let pts = &self.path.points;
        if pts.len() == 1 || s <= 0.0 {
            return pts[0];
        }
        let k = self.cum.partition_point(|&c| c <= s).min(pts.len() - 1);
        if k == 0 {
            return pts[0];
        }
        let (a, b) = (pts[k - 1], pts[k]);
        let seg = self.cum[k] - self.cum[k - 1];
        let t = if seg > 0.0 { ((s - self.cum[k - 1]) / seg).min(1.0) } else { 1.0 };
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
    }

    /// The robot at `p`: its projection on the path near the last one (from 1 m behind to
    /// `2L + 1` m ahead, so a path that folds back past a wall is not jumped), and the subgoal
    /// `lookahead` further on.
    pub fn update(&mut self, p: Point, lookahead: f64) -> Lookahead {
        self.update_seeing(p, lookahead, &|_, _| true)
    }

    /// [`PathFollower::update`], with the subgoal drawn back along the path until `visible`
    /// says the straight line from the robot to it is clear: round a corner the lookahead point
    /// is past, the robot heads for the corner rather than cutting it.
    pub fn update_seeing(
        &mut self,
        p: Point,
        lookahead: f64,
        visible: &dyn Fn(Point, Point) -> bool,
    ) -> Lookahead {
        let pts = &self.path.points;
        let total = *self.cum.last().unwrap();
        let (lo, hi) = (self.s - 1.0, self.s + 2.0 * lookahead + 1.0);
        let mut best = (f64::INFINITY, self.s);
        for k in 1..pts.len() {
            if self.cum[k] < lo || self.cum[k - 1] > hi {
                continue;
            }
            let (a, b) = (pts[k - 1], pts[k]);
            let e = [b[0] - a[0], b[1] - a[1]];
            let len2 = e[0] * e[0] + e[1] * e[1];
            let t = if len2 > 0.0 {
                (((p[0] - a[0]) * e[0] + (p[1] - a[1]) * e[1]) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let q = [a[0] + t * e[0], a[1] + t * e[1]];
            let d = dist(p, q);
            if d < best.0 {
                best = (d, self.cum[k - 1] + t * len2.sqrt());
            }
        }
        if pts.len() == 1 {
            best = (dist(p, pts[0]), 0.0);
        }
        let (off, s) = best;
        self.s = s;
        let goal = *pts.last().unwrap();
        let left = total - s;
        let mut final_goal = left <= lookahead || dist(p, goal) <= lookahead;
        let mut subgoal = if final_goal { goal } else { self.point_at(s + lookahead) };
        if !visible(p, subgoal) {
            // Bisect for the farthest visible point between the projection and the subgoal.
            let (mut lo, mut hi) = (s, if final_goal { total } else { s + lookahead });
            for _ in 0..8 {
                let mid = 0.5 * (lo + hi);
                if visible(p, self.point_at(mid)) { lo = mid } else { hi = mid }
            }
            subgoal = self.point_at(lo);
            final_goal = false;
        }
        Lookahead { subgoal, progress_m: s, remaining_m: left + off, off_path_m: off, final_goal }
    }
}

/// Why a new plan is asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Replan {
    /// The robot is farther from the path than `replan_distance_m`.
    Drift,
    /// No progress along the path for `stall_s`.
    Stall,
}

/// What the guide says at one control cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guidance {
    /// The goal to give the agent (m).
    pub subgoal: Point,
    /// Path length left to the final goal (m): along the path, or the straight line without
    /// one.
    pub remaining_m: f64,
    /// A new plan is wanted.
    pub replan: Option<Replan>,
}

/// The subgoal rule for one robot and one goal: a [`PathFollower`] on the current plan, the
/// progress watch and the rotation shim. Planning itself is the caller's (it owns the map).
#[derive(Clone, Debug)]
pub struct RouteGuide {
    cfg: SubgoalConfig,
    /// DVST scale μ of the robot: lengths are the meta robot's times μ.
    scale: f64,
    goal: Point,
    follower: Option<PathFollower>,
    /// Turning in place towards the subgoal.
    shim: bool,
    /// The last subgoal given.
    subgoal: Point,
    best_progress: f64,
    since_progress_s: f64,
}

impl RouteGuide {
    /// A guide to `goal` for a robot of DVST scale `scale`, with no path yet (the subgoal is
    /// the goal itself until [`RouteGuide::set_path`]).
    pub fn new(cfg: SubgoalConfig, scale: f64, goal: Point) -> RouteGuide {
        RouteGuide {
            cfg,
            scale,
            goal,
            follower: None,
            shim: false,
            subgoal: goal,
            best_progress: 0.0,
            since_progress_s: 0.0,
        }
    }

    /// The rule's constants.
    pub fn config(&self) -> &SubgoalConfig {
        &self.cfg
    }

    /// The lookahead for this robot (m).
    pub fn lookahead_m(&self) -> f64 {
        self.cfg.lookahead_m * self.scale
    }

    /// The final goal.
    pub fn goal(&self) -> Point {
        self.goal
    }

    /// The current plan, if any.
    pub fn path(&self) -> Option<&PlannedPath> {
        self.follower.as_ref().map(PathFollower::path)
    }

    /// Follows a new plan (from the robot's current position): progress starts over and the
    /// rotation shim, when on, turns the robot towards its first subgoal.
    pub fn set_path(&mut self, path: PlannedPath) {
        self.follower = Some(PathFollower::new(path));
        self.shim = self.cfg.rotation_shim;
        self.best_progress = 0.0;
        self.since_progress_s = 0.0;
    }

    /// No path remains: head for the final goal directly (the agent's mapless behaviour).
    pub fn clear_path(&mut self) {
        self.follower = None;
        self.shim = false;
    }

    /// The robot is at `pose` after `dt` seconds more: the subgoal, the path left, and
    /// whether to replan. Progress counts when the projection moves on by a tenth of the
    /// robot's lookahead (so creeping in place is no progress).
    pub fn update(&mut self, pose: Pose2, dt: f64) -> Guidance {
        self.update_seeing(pose, dt, &|_, _| true)
    }

    /// [`RouteGuide::update`] with the subgoal kept in sight ([`PathFollower::update_seeing`]).
    pub fn update_seeing(
        &mut self,
        pose: Pose2,
        dt: f64,
        visible: &dyn Fn(Point, Point) -> bool,
    ) -> Guidance {
        let p = pose.position();
        let l = self.lookahead_m();
        let Some(f) = self.follower.as_mut() else {
            self.subgoal = self.goal;
            return Guidance { subgoal: self.goal, remaining_m: dist(p, self.goal), replan: None };
        };
        let la = f.update_seeing(p, l, visible);
        self.subgoal = la.subgoal;
        if la.progress_m > self.best_progress + 0.1 * l {
            self.best_progress = la.progress_m;
            self.since_progress_s = 0.0;
        } else {
            self.since_progress_s += dt;
        }
        let replan = if la.off_path_m > self.cfg.replan_distance_m * self.scale {
            Some(Replan::Drift)
        } else if self.since_progress_s >= self.cfg.stall_s - 1e-9 && !la.final_goal {
            Some(Replan::Stall)
        } else {
            None
        };
        if self.shim && self.bearing(pose).abs() <= self.cfg.shim_angle_deg.to_radians() {
            self.shim = false;
        }
        Guidance { subgoal: la.subgoal, remaining_m: la.remaining_m, replan }
    }

    /// The rotation shim's command at `pose`, while it holds the robot: turn in place at
    /// `omega_max` towards the subgoal. `None` once the agent drives.
    pub fn shim_command(&self, pose: Pose2, omega_max: f64) -> Option<(f64, f64)> {
        let b = self.bearing(pose);
        (self.shim && b.abs() > self.cfg.shim_angle_deg.to_radians())
            .then(|| (0.0, omega_max.copysign(b)))
    }

    /// The last subgoal given.
    pub fn subgoal(&self) -> Point {
        self.subgoal
    }

    /// Bearing (rad) of the last subgoal from `pose`, left positive.
    fn bearing(&self, pose: Pose2) -> f64 {
        pose.bearing_to(self.subgoal)
    }
}

#[cfg(test)]
mod tests;
