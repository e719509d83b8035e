//! The flat observation vector: `[scan[0..beams], goal_distance, goal_angle, v, omega]`, and,
//! in a run with `env.radius_input = true` (the SAC_RI baseline), the robot's radius after ω.
//!
//! Distances are in metres, angles in radians in the robot frame (x ahead, y left), velocities
//! are the robot's current (last commanded) ones. DVST relies on the split between the
//! distance-like parts (scan, goal distance, v) and the angle-like parts (goal angle, ω); it
//! transfers the standard layout ([`obs_dim`]) only.
//!
//! [`ObsLayout`] is a run's layout: the scan length and whether the radius follows. The
//! standard layout (the meta agent's) is `beams + 4` long, 544 by default; the radius input
//! makes it one longer, and the networks' first fully-connected layers one wider.

/// Offsets of the scalar parts after the scan, relative to `beams`.
pub const GOAL_DISTANCE: usize = 0;
/// Goal bearing in the robot frame (rad, left positive).
pub const GOAL_ANGLE: usize = 1;
/// Current linear velocity (m/s).
pub const LINEAR_VELOCITY: usize = 2;
/// Current angular velocity (rad/s).
pub const ANGULAR_VELOCITY: usize = 3;
/// Scalars after the scan in the standard layout.
pub const EXTRA: usize = 4;
/// Offset of the robot's radius (m) after the scan, in a layout with the radius input.
pub const RADIUS: usize = 4;
/// Dimension of the action (normalized linear, normalized angular).
pub const ACTION_DIM: usize = 2;

/// Length of an observation in the standard layout for a scan of `beams` ranges.
pub const fn obs_dim(beams: usize) -> usize {
    beams + EXTRA
}

/// The layout of a run's observations (`EnvConfig::obs_layout`): what the environments write,
/// the replay buffer stores and the networks take.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ObsLayout {
    /// Scan length.
    pub beams: usize,
    /// The robot's radius (m) follows ω ([`RADIUS`]).
    pub radius_input: bool,
}

impl ObsLayout {
    /// The standard layout, without the radius.
    pub const fn standard(beams: usize) -> Self {
        Self { beams, radius_input: false }
    }

    /// Scalars after the scan: 4, or 5 with the radius.
    pub const fn extra(self) -> usize {
        EXTRA + self.radius_input as usize
    }

    /// Length of an observation.
    pub const fn dim(self) -> usize {
        self.beams + self.extra()
    }
}

/// A read-only view of one flat observation.
#[derive(Clone, Copy, Debug)]
pub struct ObsView<'a> {
    data: &'a [f32],
    layout: ObsLayout,
}

impl<'a> ObsView<'a> {
    /// Wraps `data` in the standard layout, which must be `obs_dim(beams)` long.
    pub fn new(data: &'a [f32], beams: usize) -> Self {
        Self::with_layout(data, ObsLayout::standard(beams))
    }

    /// Wraps `data`, which must be `layout.dim()` long.
    pub fn with_layout(data: &'a [f32], layout: ObsLayout) -> Self {
        assert_eq!(data.len(), layout.dim(), "observation length");
        Self { data, layout }
    }
    /// LiDAR ranges (m).
    pub fn scan(&self) -> &'a [f32] {
        &self.data[..self.layout.beams]
    }
    /// Distance to the goal (m).
    pub fn goal_distance(&self) -> f32 {
        self.data[self.layout.beams + GOAL_DISTANCE]
    }
    /// Bearing of the goal (rad).
    pub fn goal_angle(&self) -> f32 {
        self.data[self.layout.beams + GOAL_ANGLE]
    }
    /// Current linear velocity (m/s).
    pub fn v(&self) -> f32 {
        self.data[self.layout.beams + LINEAR_VELOCITY]
    }
    /// Current angular velocity (rad/s).
    pub fn omega(&self) -> f32 {
        self.data[self.layout.beams + ANGULAR_VELOCITY]
    }

    /// The robot's radius (m), in a layout with the radius input.
    pub fn radius(&self) -> Option<f32> {
        self.layout.radius_input.then(|| self.data[self.layout.beams + RADIUS])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_radius_input_adds_one_scalar_after_omega() {
        let standard = ObsLayout::standard(540);
        assert_eq!((standard.extra(), standard.dim()), (4, 544));
        assert_eq!(standard.dim(), obs_dim(540));
        let ri = ObsLayout { beams: 540, radius_input: true };
        assert_eq!((ri.extra(), ri.dim()), (5, 545));
        let data = [9.0, 8.0, 1.5, -0.25, 0.4, 0.1, 0.35];
        let o = ObsView::with_layout(&data, ObsLayout { beams: 2, radius_input: true });
        assert_eq!(o.scan(), &[9.0, 8.0]);
        assert_eq!((o.goal_distance(), o.goal_angle(), o.v(), o.omega()), (1.5, -0.25, 0.4, 0.1));
        assert_eq!(o.radius(), Some(0.35));
        assert_eq!(ObsView::new(&data[..6], 2).radius(), None);
    }

    #[test]
    #[should_panic(expected = "observation length")]
    fn a_standard_view_refuses_an_observation_with_the_radius() {
        ObsView::new(&[9.0, 8.0, 1.5, -0.25, 0.4, 0.1, 0.35], 2);
    }
}
