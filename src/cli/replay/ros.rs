//! The ROS 2 messages `dvnav replay` reads, as their CDR encoding lays them out
//! (`sensor_msgs/msg/LaserScan`, `nav_msgs/msg/Odometry`, `nav_msgs/msg/Path`,
//! `geometry_msgs/msg/PoseStamped`, `tf2_msgs/msg/TFMessage`; field order and
//! types of the ROS 2 message definitions), decoded with the `cdr` crate.

use serde::Deserialize;

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// Seconds.
    pub fn seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `sensor_msgs/msg/LaserScan`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

/// `geometry_msgs/msg/Point` and `Vector3`: the same three doubles.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Quaternion {
    /// The rotation about z (rad): a ground robot's heading.
    pub fn yaw(&self) -> f64 {
        let Quaternion { x, y, z, w } = *self;
        (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
    }
}

/// A row-major 6x6 covariance (`float64[36]`): a fixed-size array, laid out in CDR with no
/// length. Two halves, since serde derives arrays of at most 32.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct Covariance([f64; 18], [f64; 18]);

/// `geometry_msgs/msg/PoseWithCovariance`, its `pose` (`position`, `orientation`) flattened:
/// a nested message adds no bytes in CDR.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct PoseWithCovariance {
    pub position: Vector3,
    pub orientation: Quaternion,
    pub covariance: Covariance,
}

/// `geometry_msgs/msg/TwistWithCovariance`, its `twist` (`linear`, `angular`) flattened.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
pub struct TwistWithCovariance {
    pub linear: Vector3,
    pub angular: Vector3,
    pub covariance: Covariance,
}

/// `nav_msgs/msg/Odometry`: the pose in `header.frame_id` (the odometry frame), the twist in
/// `child_frame_id` (the robot).
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/msg/PoseStamped`, its `pose` (`position`, `orientation`) flattened.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct PoseStamped {
    pub header: Header,
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `nav_msgs/msg/Path`: a planner's path (Nav2's `/plan`) in `header.frame_id`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct Path {
    pub header: Header,
    pub poses: Vec<PoseStamped>,
}

impl Path {
    /// The path's positions (m).
    pub fn points(&self) -> Vec<[f64; 2]> {
        self.poses.iter().map(|p| [p.position.x, p.position.y]).collect()
    }
}

/// `geometry_msgs/msg/TransformStamped`, its `transform` (`translation`, `rotation`)
/// flattened: `child_frame_id`'s pose in `header.frame_id`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `tf2_msgs/msg/TFMessage` (`/tf_static`: the robot's fixed frames, the sensor's mounting).
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

impl Odometry {
    /// A robot standing still at the odometry frame's origin, heading along x: what a bag
    /// without odometry (a fixed sensor) is replayed as.
    pub fn at_rest() -> Odometry {
        let zero = Vector3 { x: 0.0, y: 0.0, z: 0.0 };
        let covariance = Covariance([0.0; 18], [0.0; 18]);
        Odometry {
            header: Header { stamp: Time { sec: 0, nanosec: 0 }, frame_id: "odom".into() },
            child_frame_id: "base_link".into(),
            pose: PoseWithCovariance {
                position: zero,
                orientation: Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 },
                covariance,
            },
            twist: TwistWithCovariance { linear: zero, angular: zero, covariance },
        }
    }

    /// Why no robot could be where and how this message says (a non-finite pose, a speed
    /// beyond what the controller accepts), or `None`. Real drivers publish such messages: the
    /// first odometry of a public bag of a Neato says v = 1,975 m/s, ω = −610 rad/s, and every
    /// later one is plausible.
    pub fn implausible(&self, max_speed: f64) -> Option<String> {
        let (p, q) = (self.pose.position, self.pose.orientation);
        if ![p.x, p.y, q.x, q.y, q.z, q.w].iter().all(|x| x.is_finite()) {
            return Some(format!("pose ({}, {}) is not finite", p.x, p.y));
        }
        let (v, w) = (self.twist.linear.x, self.twist.angular.z);
        (!(v.is_finite() && w.is_finite() && v.abs() <= max_speed && w.abs() <= max_speed))
            .then(|| format!("v = {v:.1} m/s, ω = {w:.1} rad/s (bound ±{max_speed})"))
    }
}

/// A CDR message with its 4-byte encapsulation header (either byte order), as a ROS 2 bag
/// stores it.
pub fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> anyhow::Result<T> {
    cdr::deserialize::<T>(bytes).map_err(|e| anyhow::anyhow!("not a valid CDR message: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternions_give_the_heading() {
        let q =
            |yaw: f64| Quaternion { x: 0.0, y: 0.0, z: (yaw / 2.0).sin(), w: (yaw / 2.0).cos() };
        for yaw in [0.0, 0.5, -2.0, 3.0] {
            assert!((q(yaw).yaw() - yaw).abs() < 1e-12, "{yaw}");
        }
    }

    #[test]
    fn odometry_no_robot_could_have_is_named() {
        let mut o = Odometry::at_rest();
        assert_eq!(o.implausible(1e3), None);
        o.twist.linear.x = 1975.4;
        o.twist.angular.z = -609.7;
        let why = o.implausible(1e3).unwrap();
        assert!(why.contains("v = 1975.4 m/s") && why.contains("±1000"), "{why}");
        o.twist.linear.x = 0.3;
        assert_eq!(o.implausible(1e3), None, "ω = −609.7 rad/s is within the bound");
        o.twist.angular.z = 1e4;
        assert!(o.implausible(1e3).is_some(), "ω alone");
        o.twist.angular.z = f64::NAN;
        assert!(o.implausible(1e3).is_some());
        o.twist.angular.z = 0.0;
        assert_eq!(o.implausible(1e3), None);
        o.pose.position.y = f64::INFINITY;
        assert!(o.implausible(1e3).unwrap().contains("not finite"));
    }

    /// A LaserScan encoded by hand as CDR little-endian (XCDR1, the ROS 2 default): every
    /// primitive aligned to its size from the end of the 4-byte encapsulation header.
    #[test]
    fn a_hand_encoded_laser_scan_decodes() {
        let mut b: Vec<u8> = vec![0x00, 0x01, 0x00, 0x00];
        let pad = |b: &mut Vec<u8>, to: usize| {
            while !(b.len() - 4).is_multiple_of(to) {
                b.push(0);
            }
        };
        b.extend(7i32.to_le_bytes());
        b.extend(500_000_000u32.to_le_bytes());
        b.extend(6u32.to_le_bytes());
        b.extend(b"laser\0");
        pad(&mut b, 4);
        for x in [-1.0f32, 1.0, 0.5, 0.0, 0.1, 0.05, 12.0] {
            b.extend(x.to_le_bytes());
        }
        b.extend(3u32.to_le_bytes());
        for x in [1.0f32, f32::INFINITY, 2.5] {
            b.extend(x.to_le_bytes());
        }
        b.extend(0u32.to_le_bytes());
        let s: LaserScan = decode(&b).unwrap();
        assert_eq!(s.header.frame_id, "laser");
        assert_eq!(s.header.stamp.seconds(), 7.5);
        assert_eq!((s.angle_min, s.angle_increment, s.range_max), (-1.0, 0.5, 12.0));
        assert_eq!(s.ranges, [1.0, f32::INFINITY, 2.5]);
        assert!(s.intensities.is_empty());
        assert!(decode::<LaserScan>(&b[..20]).is_err(), "truncated");
    }
}
