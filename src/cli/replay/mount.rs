//! Where the LiDAR sits on the robot according to the bag's `/tf_static`: the chain of fixed
//! transforms from the scan's frame up to the robot's base frame, composed in the plane.

use super::ros::TransformStamped;

/// How many transforms a chain may have before it is taken for a loop.
const MAX_CHAIN: usize = 32;

/// A sensor's pose in the robot's base frame: `x` ahead, `y` left (m), `yaw` (rad).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mount {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

impl Mount {
    const IDENTITY: Mount = Mount { x: 0.0, y: 0.0, yaw: 0.0 };

    /// `self` (a frame's pose in its parent) after `child` (a pose in that frame).
    fn then(self, child: Mount) -> Mount {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let yaw = self.yaw + child.yaw;
        Mount {
            x: self.x + c * child.x - s * child.y,
            y: self.y + s * child.x + c * child.y,
            yaw: yaw.sin().atan2(yaw.cos()),
        }
    }

    /// Whether two mounts differ by more than a centimetre or a degree.
    pub fn differs_from(&self, other: &Mount) -> bool {
        let dyaw = (self.yaw - other.yaw).sin().atan2((self.yaw - other.yaw).cos());
        (self.x - other.x).hypot(self.y - other.y) > 0.01 || dyaw.abs() > 1f64.to_radians()
    }
}

/// Frame names as tf2 compares them: without a leading slash (ROS 1 habit).
fn frame(name: &str) -> &str {
    name.trim_start_matches('/')
}

/// The pose of frame `sensor` in frame `base` from `transforms` (the latest transform for
/// each child frame wins), walking from the sensor up its parents; `None` when the chain
/// does not reach `base`. With no `base` (a bag without odometry), the chain's top frame.
/// Returns the base frame's name with the pose.
pub fn sensor_mount(
    transforms: &[TransformStamped],
    sensor: &str,
    base: Option<&str>,
) -> Option<(String, Mount)> {
    let parent_of =
        |child: &str| transforms.iter().rev().find(|t| frame(&t.child_frame_id) == frame(child));
    let mut pose = Mount::IDENTITY;
    let mut at = frame(sensor).to_string();
    for _ in 0..MAX_CHAIN {
        if base.is_some_and(|b| frame(b) == at) {
            return Some((at, pose));
        }
        let Some(t) = parent_of(&at) else {
            // The top of the chain: the base when none was named and the sensor has a parent.
            return (base.is_none() && at != frame(sensor)).then_some((at, pose));
        };
        let step = Mount { x: t.translation.x, y: t.translation.y, yaw: t.rotation.yaw() };
        pose = step.then(pose);
        at = frame(&t.header.frame_id).to_string();
    }
    None
}

#[cfg(test)]
mod tests {
    use super::super::ros::{Header, Quaternion, Time, Vector3};
    use super::*;

    fn tf(parent: &str, child: &str, x: f64, y: f64, yaw: f64) -> TransformStamped {
        TransformStamped {
            header: Header { stamp: Time { sec: 0, nanosec: 0 }, frame_id: parent.into() },
            child_frame_id: child.into(),
            translation: Vector3 { x, y, z: 0.3 },
            rotation: Quaternion { x: 0.0, y: 0.0, z: (yaw / 2.0).sin(), w: (yaw / 2.0).cos() },
        }
    }

    fn close(a: Mount, b: Mount) -> bool {
        !a.differs_from(&b) && (a.x - b.x).abs() < 1e-12 && (a.y - b.y).abs() < 1e-12
    }

    #[test]
    fn a_chain_of_fixed_frames_composes_in_the_plane() {
        let pi = std::f64::consts::PI;
        // base_link -> base_scan (0.1 m back, turned around) -> laser (0.05 m ahead of that).
        let tfs = [
            tf("base_footprint", "base_link", 0.0, 0.0, 0.0),
            tf("base_link", "base_scan", -0.1, 0.0, pi),
            tf("/base_scan", "laser", 0.05, 0.02, 0.0),
        ];
        let (base, m) = sensor_mount(&tfs, "laser", Some("base_link")).unwrap();
        assert_eq!(base, "base_link");
        // 0.05 m ahead of a frame facing backwards is 0.05 m further back; left is right.
        assert!(close(m, Mount { x: -0.15, y: -0.02, yaw: pi }), "{m:?}");
        // Without odometry to name the base: the top of the chain.
        let (top, m2) = sensor_mount(&tfs, "laser", None).unwrap();
        assert_eq!(top, "base_footprint");
        assert!(close(m, m2));
        // A chain that does not reach the base, and a sensor with no transform at all.
        assert!(sensor_mount(&tfs, "laser", Some("odom")).is_none());
        assert!(sensor_mount(&tfs, "camera", None).is_none());
        // The sensor frame is the base frame: the identity.
        assert_eq!(sensor_mount(&tfs, "base_link", Some("base_link")).unwrap().1, Mount::IDENTITY);
    }

    #[test]
    fn the_latest_transform_wins_and_loops_end() {
        let tfs =
            [tf("base_link", "laser", 0.3, 0.0, 0.0), tf("base_link", "laser", 0.1, 0.0, 0.0)];
        let (_, m) = sensor_mount(&tfs, "laser", Some("base_link")).unwrap();
        assert_eq!(m.x, 0.1);
        let looped = [tf("a", "b", 0.0, 0.0, 0.0), tf("b", "a", 0.0, 0.0, 0.0)];
        assert!(sensor_mount(&looped, "a", Some("base_link")).is_none());
    }
}
