//! The flat observation vector: `[scan[0..beams], goal_distance, goal_angle, v, omega]`.
//!
//! Distances are in metres, angles in radians in the robot frame (x ahead, y left), velocities
//! are the robot's current (last commanded) ones. DVST relies on the split between the
//! distance-like parts (scan, goal distance, v) and the angle-like parts (goal angle, ω).

/// Offsets of the scalar parts after the scan, relative to `beams`.
pub const GOAL_DISTANCE: usize = 0;
/// Goal bearing in the robot frame (rad, left positive).
pub const GOAL_ANGLE: usize = 1;
/// Current linear velocity (m/s).
pub const LINEAR_VELOCITY: usize = 2;
/// Current angular velocity (rad/s).
pub const ANGULAR_VELOCITY: usize = 3;
/// Scalars after the scan.
pub const EXTRA: usize = 4;
/// Dimension of the action (normalized linear, normalized angular).
pub const ACTION_DIM: usize = 2;

/// Length of an observation for a scan of `beams` ranges.
pub const fn obs_dim(beams: usize) -> usize {
    beams + EXTRA
}

/// A read-only view of one flat observation.
#[derive(Clone, Copy, Debug)]
pub struct ObsView<'a> {
    data: &'a [f32],
    beams: usize,
}

impl<'a> ObsView<'a> {
    /// Wraps `data`, which must be `obs_dim(beams)` long.
    pub fn new(data: &'a [f32], beams: usize) -> Self {
        assert_eq!(data.len(), obs_dim(beams), "observation length");
        Self { data, beams }
    }
    /// LiDAR ranges (m).
    pub fn scan(&self) -> &'a [f32] {
        &self.data[..self.beams]
    }
    /// Distance to the goal (m).
    pub fn goal_distance(&self) -> f32 {
        self.data[self.beams + GOAL_DISTANCE]
    }
    /// Bearing of the goal (rad).
    pub fn goal_angle(&self) -> f32 {
        self.data[self.beams + GOAL_ANGLE]
    }
    /// Current linear velocity (m/s).
    pub fn v(&self) -> f32 {
        self.data[self.beams + LINEAR_VELOCITY]
    }
    /// Current angular velocity (rad/s).
    pub fn omega(&self) -> f32 {
        self.data[self.beams + ANGULAR_VELOCITY]
    }
}
