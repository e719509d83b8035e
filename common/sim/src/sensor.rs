//! A real robot's LiDAR in the simulator: [`SensorSpec`] describes one (its beams, field of
//! view, ranges, noise, how its driver reports "no return", and where it sits on the robot: a
//! sensor file, `sensors/*.toml`, or `[env.sensor]` in a run's config), and [`MountedSensor`]
//! produces the `LaserScan` that driver would publish and carries it over to the meta agent's
//! beams with [`crate::laser_scan::resample`], the function `dvnav serve` uses on a real robot.
//! An environment with a sensor (`EnvConfig::sensor`) observes through it, so `dvnav eval
//! --sensor FILE` drives the agent as the robot would see.
//!
//! ```toml
//! name = "Hokuyo UST-10LX, 0.1 m ahead of the axle"
//! beams = 1081          # readings per scan, evenly over the field of view
//! fov_deg = 270.0       # centred on the sensor's heading
//! range_min = 0.06      # m
//! range_max = 10.0      # m
//! noise_std = 0.01      # m, Gaussian range noise (default 0)
//! no_return = "inf"     # what the driver reports without a return: "inf" (REP 117) or "zero"
//! x = 0.1               # m ahead of the axle centre (default 0)
//! y = 0.0               # m to the left (default 0)
//! yaw = 0.0             # rad, left positive (default 0)
//! # uncovered_range = 0.0  # optional: a fixed range for meta beams the sensor does not see
//! ```

use crate::laser_scan::{BeamLayout, LaserScan, MAX_SCAN_RANGES, SensorSetup, Uncovered};
use crate::room_file::{line_of, parse_toml, read_spec_file};
use crate::{Lidar, LidarConfig, Pose2, Room, SpecFileError};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The farthest a sensor may sit from the axle centre (m): no robot is larger.
pub const MAX_MOUNT_OFFSET_M: f64 = 20.0;

/// What a driver publishes for a beam that saw nothing within its range.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoReturn {
    /// `+inf`, as REP 117 asks (urg_node, rplidar_ros).
    #[default]
    Inf,
    /// `0.0`, as the drivers of many low-cost LiDARs do (Neato's LDS, TurtleBot 3's LDS-01).
    Zero,
}

/// A LiDAR and its mounting (see the module docs for the file format).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SensorSpec {
    /// What it is, for reports.
    #[serde(default)]
    pub name: String,
    /// Readings per scan.
    pub beams: usize,
    /// Field of view (degrees), centred on the sensor's heading.
    pub fov_deg: f64,
    /// Shortest range measured (m).
    pub range_min: f64,
    /// Longest range measured (m).
    pub range_max: f64,
    /// Gaussian range noise σ (m).
    #[serde(default)]
    pub noise_std: f64,
    /// How "no return" is reported.
    #[serde(default)]
    pub no_return: NoReturn,
    /// Position ahead of the axle centre (m).
    #[serde(default)]
    pub x: f64,
    /// Position left of the axle centre (m).
    #[serde(default)]
    pub y: f64,
    /// Heading relative to the robot's (rad, left positive).
    #[serde(default)]
    pub yaw: f64,
    /// A fixed range for the meta beams the sensor does not see; absent: the nearest seen range
    /// ([`Uncovered::Nearest`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncovered_range: Option<f64>,
}

impl SensorSpec {
    /// The mounting and fill rule the resampling uses.
    pub fn setup(&self) -> SensorSetup {
        SensorSetup {
            x: self.x,
            y: self.y,
            yaw: self.yaw,
            uncovered: self.uncovered_range.map_or(Uncovered::Nearest, Uncovered::Range),
        }
    }

    /// The sensor's own beams as a [`LidarConfig`].
    pub fn lidar_config(&self) -> LidarConfig {
        LidarConfig {
            beams: self.beams,
            fov_deg: self.fov_deg,
            range_min: self.range_min,
            range_max: self.range_max,
            noise_std: self.noise_std,
        }
    }

    /// Checks every value; the error is `(key, reason)`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, why: String| Err((k.to_string(), why));
        if !(1..=MAX_SCAN_RANGES).contains(&self.beams) {
            return bad("beams", format!("must be 1 to {MAX_SCAN_RANGES}, got {}", self.beams));
        }
        if !(self.fov_deg.is_finite() && self.fov_deg > 0.0 && self.fov_deg <= 360.0) {
            return bad("fov_deg", format!("must be in (0, 360] degrees, got {}", self.fov_deg));
        }
        if !(self.range_min.is_finite() && self.range_min >= 0.0) {
            return bad("range_min", format!("must be ≥ 0 m, got {}", self.range_min));
        }
        let max = crate::laser_scan::MAX_RANGE_M;
        if !(self.range_max.is_finite() && self.range_max > self.range_min && self.range_max <= max)
        {
            let why = format!(
                "must be above range_min ({} m) and at most {max} m, got {}",
                self.range_min, self.range_max
            );
            return bad("range_max", why);
        }
        if !(self.noise_std.is_finite() && self.noise_std >= 0.0) {
            return bad("noise_std", format!("must be a σ ≥ 0 m, got {}", self.noise_std));
        }
        for (k, v) in [("x", self.x), ("y", self.y)] {
            if !(v.is_finite() && v.abs() <= MAX_MOUNT_OFFSET_M) {
                let why = format!("must be an offset within ±{MAX_MOUNT_OFFSET_M} m, got {v}");
                return bad(k, why);
            }
        }
        self.setup().validate().map_err(|e| (e.field, e.reason))
    }

    /// Parses and checks a sensor file; `source` names it in errors, which give the line and
    /// the key.
    pub fn from_toml_str(text: &str, source: &str) -> Result<SensorSpec, SpecFileError> {
        let spec: SensorSpec = parse_toml(text, source)?;
        spec.validate().map_err(|(key, reason)| {
            // The line of the key, when it is written out (a default has none).
            let line = text
                .lines()
                .position(|l| {
                    l.trim_start().starts_with(&format!("{key} "))
                        || l.trim_start().starts_with(&format!("{key}="))
                })
                .map(|i| i + 1)
                .or_else(|| text.find(&key).map(|at| line_of(text, at)));
            SpecFileError { source: source.to_string(), line, key, reason }
        })?;
        Ok(spec)
    }

    /// Reads a sensor file.
    pub fn load(path: &Path) -> Result<SensorSpec, SpecFileError> {
        let (text, source) = read_spec_file(path, "sensor file")?;
        SensorSpec::from_toml_str(&text, &source)
    }
}

/// A [`SensorSpec`] ready to scan: its beams, and a buffer for one scan.
#[derive(Clone, Debug)]
pub struct MountedSensor {
    spec: SensorSpec,
    lidar: Lidar,
    setup: SensorSetup,
    ranges: Vec<f32>,
}

impl MountedSensor {
    /// The sensor `spec` describes.
    ///
    /// # Panics
    /// If the spec is invalid ([`SensorSpec::validate`]).
    pub fn new(spec: &SensorSpec) -> MountedSensor {
        if let Err((k, why)) = spec.validate() {
            panic!("invalid sensor: {k}: {why}");
        }
        MountedSensor {
            spec: spec.clone(),
            lidar: Lidar::new(&spec.lidar_config()),
            setup: spec.setup(),
            ranges: vec![0.0; spec.beams],
        }
    }

    /// The sensor it simulates.
    pub fn spec(&self) -> &SensorSpec {
        &self.spec
    }

    /// The sensor's pose in the room for a robot at `robot`.
    pub fn pose(&self, robot: Pose2) -> Pose2 {
        let (s, c) = robot.yaw.sin_cos();
        Pose2::new(
            robot.x + c * self.spec.x - s * self.spec.y,
            robot.y + s * self.spec.x + c * self.spec.y,
            robot.yaw + self.spec.yaw,
        )
    }

    /// The scan the sensor's driver publishes with the robot at `robot` in `room` (its first
    /// `active` timed obstacles present): noisy when the spec has noise and `noise` gives a
    /// generator, and "no return" written as the driver writes it.
    pub fn laser_scan(
        &mut self,
        room: &Room,
        robot: Pose2,
        active: usize,
        noise: Option<&mut impl rand::Rng>,
    ) -> LaserScan<'_> {
        let pose = self.pose(robot);
        self.lidar.scan_active(room, pose, active, noise, &mut self.ranges);
        let max = self.spec.range_max as f32;
        let none = match self.spec.no_return {
            NoReturn::Inf => f32::INFINITY,
            NoReturn::Zero => 0.0,
        };
        for r in &mut self.ranges {
            if *r >= max {
                *r = none;
            }
        }
        let step = self.spec.fov_deg.to_radians() / self.spec.beams as f64;
        LaserScan {
            angle_min: -self.spec.fov_deg.to_radians() / 2.0 + step / 2.0,
            angle_increment: step,
            range_min: self.spec.range_min,
            range_max: self.spec.range_max,
            ranges: &self.ranges,
        }
    }

    /// The meta agent's scan (`meta`'s beams, ranges from the axle centre, at most its range) as
    /// the controller would compute it from this sensor's scan ([`Self::laser_scan`]) into
    /// `out`; returns how many meta beams the sensor did not see.
    pub fn meta_scan(
        &mut self,
        room: &Room,
        robot: Pose2,
        active: usize,
        noise: Option<&mut impl rand::Rng>,
        meta: &LidarConfig,
        out: &mut [f32],
    ) -> usize {
        let setup = self.setup;
        let (layout, range_max) = (BeamLayout::new(meta.beams, meta.fov_deg), meta.range_max);
        let scan = self.laser_scan(room, robot, active, noise);
        let filled = crate::laser_scan::resample(&scan, &setup, layout, out)
            .expect("a simulated scan is well formed");
        let max = range_max as f32;
        for r in out.iter_mut() {
            *r = r.min(max);
        }
        filled
    }
}

#[cfg(test)]
mod tests;
