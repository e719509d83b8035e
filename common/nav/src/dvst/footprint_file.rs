//! [`VariedRobot`]: the dimension-varied robot as a user describes it in a small TOML file:
//! its footprint (the same `name` and `[[parts]]` as a [`Footprint`] file, so every footprint
//! file is also a DVST file), optionally its own velocity bounds, a safety margin, and the meta
//! robot the agent was trained as, and where its LiDAR sits ([`SensorSetup`], used when the
//! robot sends its scan as a `LaserScan`).
//!
//! ```toml
//! name = "cart with cargo"
//! margin = 0.03            # m, optional (default 0): clearance the scaled robot keeps
//! v_max = 0.4              # m/s, optional: this robot's own bounds (default: the meta agent's)
//! omega_max = 1.2          # rad/s, optional
//!
//! [lidar]                  # optional: where the LiDAR sits (default: on the axle centre)
//! x = 0.12                 # m ahead of the axle centre
//! y = 0.0                  # m to the left
//! yaw = 0.0                # rad, left positive
//! # uncovered_range = 0.0  # optional: m for unseen meta beams (default: nearest seen range)
//!
//! [meta]                   # optional; default: the circle of radius 0.2 m
//! shape = "rectangle"      # or: shape = "circle", radius = 0.2
//! front = 0.25
//! back = 0.15
//! left = 0.2
//! right = 0.2
//!
//! [[parts]]                # the whole varied robot: its body and its cargo
//! shape = "box"
//! center = [0.05, 0.0]
//! half_extents = [0.2, 0.2]
//! [[parts]]
//! shape = "box"
//! center = [-0.4, 0.0]
//! half_extents = [0.25, 0.22]
//! ```
//!
//! The parts are the whole varied robot (design §5: DVR = MR ∪ cargo), body included: a
//! robot smaller than the meta robot is a file with only its own, smaller body (μ < 1).

use super::laser_scan::{SensorSetup, Uncovered};
use super::scale::{MetaRobot, covering_scale};
use super::transfer::VelocityBounds;
use dvnav_sim::room_file::{line_of, parse_toml, read_spec_file};
use dvnav_sim::{Footprint, MAX_ROBOT_EXTENT_M, ObstacleSpec, SpecFileError, checked_parts};
use serde::Deserialize;
use std::path::Path;
use toml::Spanned;

/// A dimension-varied robot: footprint, meta robot, safety margin and optional own bounds.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VariedRobot {
    /// The varied robot (DVR): every part of it, robot frame, axle centre at the origin.
    pub footprint: Footprint,
    /// The robot the meta agent was trained as (MR).
    pub meta: MetaRobot,
    /// Clearance (m, ≥ 0) the scaled robot keeps around the varied robot (see
    /// [`super::scale`]).
    pub margin: f64,
    /// This robot's linear speed bound (m/s); `None`: the meta agent's.
    pub v_max: Option<f64>,
    /// This robot's angular speed bound (rad/s); `None`: the meta agent's.
    pub omega_max: Option<f64>,
    /// Its LiDAR's mounting and what unseen beams read.
    pub lidar: SensorSetup,
}

impl VariedRobot {
    /// A varied robot with the default meta robot, no margin and the meta agent's bounds.
    pub fn new(footprint: Footprint) -> VariedRobot {
        VariedRobot {
            footprint,
            meta: MetaRobot::default(),
            margin: 0.0,
            v_max: None,
            omega_max: None,
            lidar: SensorSetup::default(),
        }
    }

    /// μ: the scale of the meta robot that covers this robot with its margin.
    pub fn mu(&self) -> f64 {
        covering_scale(&self.meta, &self.footprint, self.margin)
    }

    /// The dimension-scaled robot (DSR): the meta robot scaled by μ.
    pub fn scaled_robot(&self) -> MetaRobot {
        self.meta.scaled(self.mu())
    }

    /// The bounds this robot moves within: its own where it has them, else `meta`'s.
    pub fn velocity_bounds(&self, meta: VelocityBounds) -> VelocityBounds {
        VelocityBounds {
            v_max: self.v_max.unwrap_or(meta.v_max),
            omega_max: self.omega_max.unwrap_or(meta.omega_max),
        }
    }

    /// Checks the footprint, the meta robot, the margin and the bounds.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.footprint.validate()?;
        self.meta.validate().map_err(|e| anyhow::anyhow!("meta: {e}"))?;
        self.lidar.validate().map_err(|e| anyhow::anyhow!("lidar.{e}"))?;
        anyhow::ensure!(
            self.margin.is_finite() && (0.0..=MAX_ROBOT_EXTENT_M).contains(&self.margin),
            "margin must be a length of 0 to {MAX_ROBOT_EXTENT_M} m, got {}",
            self.margin
        );
        let mu = self.mu();
        anyhow::ensure!(
            mu.is_finite() && mu > 0.0,
            "mu: the scale that covers this robot is {mu}, not a finite positive number"
        );
        for (name, x) in [("v_max", self.v_max), ("omega_max", self.omega_max)] {
            if let Some(x) = x {
                anyhow::ensure!(x.is_finite() && x > 0.0, "{name} must be positive, got {x}");
            }
        }
        Ok(())
    }

    /// Parses and checks a varied-robot file; `source` names it in errors, which give the
    /// line and the key.
    pub fn from_toml_str(text: &str, source: &str) -> Result<VariedRobot, SpecFileError> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            #[serde(default)]
            name: String,
            parts: Vec<Spanned<ObstacleSpec>>,
            margin: Option<Spanned<f64>>,
            v_max: Option<Spanned<f64>>,
            omega_max: Option<Spanned<f64>>,
            /// Read as a value first, so that a bad meta robot is reported under `meta`.
            meta: Option<Spanned<toml::Value>>,
            lidar: Option<Spanned<Lidar>>,
        }
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Lidar {
            #[serde(default)]
            x: f64,
            #[serde(default)]
            y: f64,
            #[serde(default)]
            yaw: f64,
            uncovered_range: Option<f64>,
        }
        let file: File = parse_toml(text, source)?;
        let err = |span: std::ops::Range<usize>, key: &str, reason: String| SpecFileError {
            source: source.to_string(),
            line: Some(line_of(text, span.start)),
            key: key.to_string(),
            reason,
        };
        let parts = checked_parts(file.parts, text, source)?;
        let meta = match file.meta {
            Some(m) => {
                let span = m.span();
                let meta = MetaRobot::deserialize(m.into_inner())
                    .map_err(|e| err(span.clone(), "meta", e.message().trim_end().to_string()))?;
                meta.validate().map_err(|e| err(span, "meta", e.to_string()))?;
                meta
            }
            None => MetaRobot::default(),
        };
        let margin = match file.margin {
            Some(m)
                if !(m.get_ref().is_finite()
                    && (0.0..=MAX_ROBOT_EXTENT_M).contains(m.get_ref())) =>
            {
                let why =
                    format!("must be a length of 0 to {MAX_ROBOT_EXTENT_M} m, got {}", m.get_ref());
                return Err(err(m.span(), "margin", why));
            }
            Some(m) => m.into_inner(),
            None => 0.0,
        };
        let bound = |b: Option<Spanned<f64>>, key: &str| match b {
            Some(b) if !(b.get_ref().is_finite() && *b.get_ref() > 0.0) => {
                Err(err(b.span(), key, format!("must be positive, got {}", b.get_ref())))
            }
            b => Ok(b.map(Spanned::into_inner)),
        };
        let lidar = match file.lidar {
            Some(l) => {
                let span = l.span();
                let Lidar { x, y, yaw, uncovered_range } = l.into_inner();
                let uncovered = uncovered_range.map_or(Uncovered::Nearest, Uncovered::Range);
                let setup = SensorSetup { x, y, yaw, uncovered };
                setup.validate().map_err(|e| err(span, &format!("lidar.{}", e.field), e.reason))?;
                setup
            }
            None => SensorSetup::default(),
        };
        Ok(VariedRobot {
            lidar,
            footprint: Footprint { name: file.name, parts },
            meta,
            margin,
            v_max: bound(file.v_max, "v_max")?,
            omega_max: bound(file.omega_max, "omega_max")?,
        })
    }

    /// Reads a varied-robot file.
    pub fn load(path: &Path) -> Result<VariedRobot, SpecFileError> {
        let (text, source) = read_spec_file(path, "footprint file")?;
        VariedRobot::from_toml_str(&text, &source)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example in the module docs.
    fn doc_example() -> &'static str {
        let doc = include_str!("footprint_file.rs");
        let start = doc.find("//! ```toml\n").unwrap() + "//! ```toml\n".len();
        let end = start + doc[start..].find("//! ```").unwrap();
        Box::leak(
            doc[start..end]
                .lines()
                .map(|l| l.strip_prefix("//!").unwrap().strip_prefix(' ').unwrap_or(""))
                .collect::<Vec<_>>()
                .join("\n")
                .into_boxed_str(),
        )
    }

    #[test]
    fn the_documented_file_parses() {
        let r = VariedRobot::from_toml_str(doc_example(), "doc.toml").unwrap();
        assert_eq!(r.footprint.name, "cart with cargo");
        assert_eq!(r.footprint.parts.len(), 2);
        assert_eq!((r.margin, r.v_max, r.omega_max), (0.03, Some(0.4), Some(1.2)));
        let lidar = SensorSetup { x: 0.12, ..SensorSetup::default() };
        assert_eq!(r.lidar, lidar);
        assert_eq!(r.meta, MetaRobot::Rectangle { front: 0.25, back: 0.15, left: 0.2, right: 0.2 });
        // The cargo reaches 0.65 m behind the axle: (0.65 + 0.03) / 0.15.
        assert!((r.mu() - 0.68 / 0.15).abs() < 1e-12, "{}", r.mu());
        r.validate().unwrap();
    }

    #[test]
    fn a_plain_footprint_file_is_a_varied_robot_with_defaults() {
        let r = VariedRobot::from_toml_str(
            "[[parts]]\nshape = \"circle\"\ncenter = [0.0, 0.0]\nradius = 0.5\n",
            "c.toml",
        )
        .unwrap();
        assert_eq!((r.meta, r.margin, r.v_max), (MetaRobot::default(), 0.0, None));
        assert!((r.mu() - 2.5).abs() < 1e-12);
        assert_eq!(r.scaled_robot(), MetaRobot::Circle { radius: 0.5 });
        let b = r.velocity_bounds(VelocityBounds { v_max: 0.5, omega_max: 1.0 });
        assert_eq!((b.v_max, b.omega_max), (0.5, 1.0));
    }

    #[test]
    fn bad_files_name_the_line_the_key_and_the_reason() {
        let base = doc_example();
        let check = |text: String, line: Option<usize>, key: &str, reason: &str| {
            let e = VariedRobot::from_toml_str(&text, "r.toml").unwrap_err();
            assert_eq!((e.line, e.key.as_str()), (line, key), "{e}");
            assert!(e.reason.contains(reason), "{e}");
            assert!(e.to_string().starts_with("r.toml:"), "{e}");
        };
        check(base.replace("margin = 0.03", "margin = -0.03"), Some(2), "margin", "0 to 20 m");
        check(base.replace("margin = 0.03", "margin = 1e300"), Some(2), "margin", "0 to 20 m");
        check(base.replace("v_max = 0.4", "v_max = 0.0"), Some(3), "v_max", "positive");
        check(base.replace("back = 0.15", "back = -0.15"), Some(12), "meta", "`back`");
        check(
            base.replace("half_extents = [0.25", "half_extents = [-0.25"),
            Some(23),
            "parts[1]",
            "half extents",
        );
        check(
            base.replace("shape = \"rectangle\"", "shape = \"hexagon\""),
            Some(12),
            "meta",
            "hexagon",
        );
        check(base.replace("margin", "margn"), Some(2), "", "unknown field `margn`");
        check(base.replace("front = 0.25", "front = \"far\""), Some(12), "meta", "expected f64");
        check(
            base.replace("front = 0.25", "radius = 0.25"),
            Some(12),
            "meta",
            "unknown field `radius`",
        );
        check(base.replace("yaw = 0.0", "yaw = 1e9"), Some(6), "lidar.yaw", "±4π");
        check(
            base.replace("# uncovered_range = 0.0", "uncovered_range = -2.0"),
            Some(6),
            "lidar.uncovered_range",
            "range",
        );
        check(base.replace("x = 0.12", "z = 0.12"), Some(7), "", "unknown field `z`");
        let e = VariedRobot::load(Path::new("/nonexistent/robot.toml")).unwrap_err();
        assert!(e.to_string().starts_with("/nonexistent/robot.toml: cannot read"), "{e}");
    }
}
