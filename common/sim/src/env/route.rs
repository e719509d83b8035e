//! A long task followed along a planned path inside [`super::NavEnv`] (`env.subgoals`): the
//! planner's path for the robot's size, the subgoal rule, and what the episode's route came to.

use crate::planner::{self, PlannedPath};
use crate::spec::Point;
use crate::subgoal::{Replan, RouteGuide, SubgoalConfig};
use crate::{Pose2, Room};

/// What an episode's route came to, for reports.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct RouteStats {
    /// The agent was fed the subgoals (`env.subgoals.follow`); otherwise the path was planned
    /// for the reports only and the agent saw the final goal.
    pub follow: bool,
    /// Length (m) of the first plan from the start; `None` when none was found.
    pub planned_length_m: Option<f64>,
    /// Plans after the first.
    pub replans: u32,
    /// A replan (or the first plan) found no path: the robot went on towards the final goal.
    pub blocked: bool,
}

/// The route of the current episode.
#[derive(Clone, Debug)]
pub(super) struct RouteState {
    guide: RouteGuide,
    /// Radius the paths are planned for (the footprint's bounding radius).
    radius: f64,
    stats: RouteStats,
    /// The subgoal rule's path left (m) at the current pose: the reward's d_t when following.
    remaining_m: f64,
}

impl RouteState {
    /// Plans from `start` to `goal` for a robot of bounding `radius` and DVST scale `scale`;
    /// `follow` says whether the agent is fed this episode's subgoals.
    pub(super) fn begin(
        cfg: &SubgoalConfig,
        follow: bool,
        room: &Room,
        radius: f64,
        scale: f64,
        start: Pose2,
        goal: Point,
    ) -> RouteState {
        let mut guide = RouteGuide::new(cfg.clone(), scale, goal);
        let first =
            planner::plan(room.planning_map(), radius, start.position(), goal, &cfg.planner);
        let stats = RouteStats {
            follow,
            planned_length_m: first.as_ref().ok().map(|p| p.length_m),
            replans: 0,
            blocked: first.is_err(),
        };
        if let Ok(path) = first {
            guide.set_path(path);
        }
        let remaining_m = guide.update_seeing(start, 0.0, &sight(room, radius)).remaining_m;
        RouteState { guide, radius, stats, remaining_m }
    }

    /// The robot is at `pose`, `dt` seconds on: follows the path, and replans when the rule
    /// asks (with `scan_points`, the current scan's returns, as obstacles after a stall).
    /// Returns the path left (m) before any replan, the reward's d_{t+1}.
    pub(super) fn step(
        &mut self,
        room: &Room,
        pose: Pose2,
        dt: f64,
        scan_points: impl FnOnce() -> Vec<Point>,
    ) -> f64 {
        let g = self.guide.update_seeing(pose, dt, &sight(room, self.radius));
        let reached = g.remaining_m;
        // Planned for the reports only, the first plan stands: the agent never sees a replan.
        let replan = if self.stats.follow { g.replan } else { None };
        if let Some(why) = replan {
            let cfg = self.guide.config().planner.clone();
            let goal = self.guide.goal();
            let found = match why {
                Replan::Drift => {
                    planner::plan(room.planning_map(), self.radius, pose.position(), goal, &cfg)
                }
                Replan::Stall => {
                    let map =
                        room.planning_map().with_points(&scan_points(), cfg.known_tolerance_m);
                    planner::plan(&map, self.radius, pose.position(), goal, &cfg)
                }
            };
            self.stats.replans += 1;
            match found {
                Ok(path) => self.guide.set_path(path),
                Err(_) => {
                    self.stats.blocked = true;
                    self.guide.clear_path();
                }
            }
            self.remaining_m =
                self.guide.update_seeing(pose, 0.0, &sight(room, self.radius)).remaining_m;
        } else {
            self.remaining_m = reached;
        }
        reached
    }

    /// The path left (m) from the current pose on the current plan.
    pub(super) fn remaining_m(&self) -> f64 {
        self.remaining_m
    }

    /// The point the agent heads for.
    pub(super) fn subgoal(&self) -> Point {
        self.guide.subgoal()
    }

    /// The rotation shim's command at `pose`, while it holds the robot.
    pub(super) fn shim_command(&self, pose: Pose2, omega_max: f64) -> Option<(f64, f64)> {
        self.guide.shim_command(pose, omega_max)
    }

    /// The current plan.
    pub(super) fn path(&self) -> Option<&PlannedPath> {
        self.guide.path()
    }

    /// What the route came to so far.
    pub(super) fn stats(&self) -> RouteStats {
        self.stats
    }

    /// The agent is fed the subgoals.
    pub(super) fn follow(&self) -> bool {
        self.stats.follow
    }
}

/// The subgoal rule's visibility test in `room` for a robot of `radius`.
fn sight(room: &Room, radius: f64) -> impl Fn(Point, Point) -> bool + '_ {
    move |a, b| planner::line_of_sight(room.planning_map(), a, b, radius)
}
