//! Latency compensation: a scan and a goal observed `k` control cycles ago, carried forward to
//! where the robot is now by the commands it has sent since (a controller always knows those;
//! only its sensors lag). The classic answer to a known dead time (a Smith predictor's
//! forward model): the policy then acts on the world as it is, not as it was.
//!
//! - **Motion:** the commands since the observation, each driven for one nominal control
//!   period along the unicycle's exact arc, give the robot's pose now in the frame it had then.
//! - **Scan:** the old scan is the scan of a sensor that sits where the robot was, so it is
//!   resampled to the robot's beams with that pose as the sensor's mounting
//!   ([`crate::laser_scan::resample`], the code `dvnav serve` runs for a LiDAR mounted off the
//!   axle); directions it did not see take the nearer range at the ends of the gap.
//! - **Goal:** its old distance and bearing, as a point, seen from the pose now.
//!
//! The prediction uses the commands, not what the motors did (actuation noise, control-period
//! jitter), as a real controller must.

use crate::laser_scan::{self, BeamLayout, LaserScan, SensorSetup, Uncovered};
use crate::{Pose2, obs, wrap_angle};

/// The robot's pose now in the frame it had when the observation was taken, after driving each
/// `(v, ω)` of `commands` (oldest first) for `dt` seconds.
pub fn motion_since(commands: impl IntoIterator<Item = (f64, f64)>, dt: f64) -> Pose2 {
    let mut p = Pose2::default();
    for (v, omega) in commands {
        p = crate::advance(p, v, omega, dt);
    }
    p.yaw = wrap_angle(p.yaw);
    p
}

/// Writes into `out` the scan `old` (one range per beam of `layout`, m, within `range`, taken at
/// the robot's pose of then) as the robot's beams would read it after `moved`
/// ([`motion_since`]).
///
/// # Panics
/// If `old` or `out` is not `layout.beams` long.
pub fn predict_scan(
    old: &[f32],
    layout: BeamLayout,
    range: [f64; 2],
    moved: Pose2,
    out: &mut [f32],
) {
    assert_eq!(old.len(), layout.beams, "one range per beam");
    if moved == Pose2::default() {
        out.copy_from_slice(old);
        return;
    }
    // Where the robot was, seen from where it is: the old scan's "sensor mounting".
    let [x, y] = moved.to_local([0.0, 0.0]);
    let setup = SensorSetup { x, y, yaw: -moved.yaw, uncovered: Uncovered::Nearest };
    let scan = LaserScan {
        angle_min: layout.angle(0),
        angle_increment: layout.fov / layout.beams as f64,
        range_min: range[0],
        range_max: range[1],
        ranges: old,
    };
    // The scan's description is the robot's own beam layout, which is valid by construction.
    laser_scan::resample(&scan, &setup, layout, out).expect("the robot's own beam layout");
    for r in out.iter_mut() {
        *r = r.clamp(range[0] as f32, range[1] as f32);
    }
}

/// The goal observed at `distance` (m) and `bearing` (rad, left positive) from the robot's pose
/// of then, seen after `moved`: its distance and bearing now ((−π, π], as the observation has it).
pub fn predict_goal(distance: f64, bearing: f64, moved: Pose2) -> (f64, f64) {
    let g = [distance * bearing.cos(), distance * bearing.sin()];
    (crate::dist(moved.position(), g), moved.bearing_to(g))
}

/// Writes into `out` the observation `old` ([`crate::obs`]'s layout: `layout.beams` ranges,
/// then the goal's distance and bearing, v, ω, …) as the robot reads it after `moved`: its scan
/// by [`predict_scan`], its goal by [`predict_goal`]. The entries after the goal are left as
/// `out` has them (the last command is the controller's own, never delayed).
///
/// # Panics
/// If `old` or `out` is shorter than the scan and the goal.
pub fn carry_observation(
    old: &[f32],
    layout: BeamLayout,
    range: [f64; 2],
    moved: Pose2,
    out: &mut [f32],
) {
    let b = layout.beams;
    predict_scan(&old[..b], layout, range, moved, &mut out[..b]);
    let (d, bearing) = predict_goal(
        f64::from(old[b + obs::GOAL_DISTANCE]),
        f64::from(old[b + obs::GOAL_ANGLE]),
        moved,
    );
    out[b + obs::GOAL_DISTANCE] = d as f32;
    out[b + obs::GOAL_ANGLE] = bearing as f32;
}

/// The commands a controller sent one robot, with when it sent them: what
/// [`CommandLog::motion_over`] integrates for a scan that arrives `age` seconds old
/// (`dvnav serve`'s `scan_age_s`). Times are seconds on any clock that only goes forward; a
/// command holds from when it was sent until the next one. Before the first command the robot
/// stood still.
#[derive(Clone, Debug, Default)]
pub struct CommandLog {
    /// `(time, v, ω)`, oldest first.
    sent: std::collections::VecDeque<(f64, f64, f64)>,
}

/// How far back (s) a [`CommandLog`] keeps commands: the longest scan age it can carry over.
pub const MAX_SCAN_AGE_S: f64 = 2.0;

impl CommandLog {
    /// `(v, ω)` was sent at `t` (s). Commands that ended more than [`MAX_SCAN_AGE_S`] before
    /// `t` are forgotten.
    pub fn record(&mut self, t: f64, v: f64, omega: f64) {
        self.sent.push_back((t, v, omega));
        // The oldest entry is kept while the next one started within the horizon: it is what
        // was in force at its start.
        while self.sent.len() > 1 && self.sent[1].0 <= t - MAX_SCAN_AGE_S {
            self.sent.pop_front();
        }
    }

    /// The robot's pose at `to` in the frame it had at `from` (s, `from ≤ to`), driving each
    /// command for the part of `[from, to]` it was in force.
    pub fn motion_over(&self, from: f64, to: f64) -> Pose2 {
        let mut p = Pose2::default();
        for (k, &(t, v, omega)) in self.sent.iter().enumerate() {
            let end = self.sent.get(k + 1).map_or(to, |next| next.0).min(to);
            let held = end - t.max(from);
            if held > 0.0 {
                p = crate::advance(p, v, omega, held);
            }
        }
        p.yaw = wrap_angle(p.yaw);
        p
    }
}

#[cfg(test)]
mod tests;
