//! [`Footprint`]: the robot's shape in its own frame (x ahead, y to the left, origin at the
//! axle centre, where the LiDAR is), as plain data users can write in a small TOML file.
//!
//! A footprint is a union of convex parts (boxes, circles, convex polygons): the meta robot is
//! one circle, a rectangular robot one box, a robot carrying cargo its body plus the cargo's
//! parts (design §5: DVR = MR ∪ cargo). The simulator checks the union for contact with the
//! room; DVST (issue 6) works on the same parts.
//!
//! ```toml
//! # A 0.6 m x 0.4 m robot, axle 0.1 m behind its centre, with a 0.3 m disc of cargo behind.
//! name = "cart"
//! [[parts]]
//! shape = "box"
//! center = [0.1, 0.0]
//! half_extents = [0.3, 0.2]
//! [[parts]]
//! shape = "circle"
//! center = [-0.35, 0.0]
//! radius = 0.15
//! ```

use super::Pose2;
use super::room_file::{SpecFileError, line_of, parse_toml, read_spec_file};
use super::spec::{ObstacleSpec, Point};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A robot's footprint: the union of `parts`, in the robot frame (m).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Footprint {
    /// A label for logs and figures (optional).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
    /// Convex parts: boxes, circles, convex polygons (no compounds; the list is the union).
    pub parts: Vec<ObstacleSpec>,
}

impl Footprint {
    /// A disc of radius `r` centred on the axle (the meta robot).
    pub fn circle(r: f64) -> Footprint {
        Footprint {
            name: format!("circle r={r}"),
            parts: vec![ObstacleSpec::Circle { center: [0.0, 0.0], radius: r }],
        }
    }

    /// A `length` (along x) by `width` rectangle centred on the axle.
    pub fn rectangle(length: f64, width: f64) -> Footprint {
        Footprint {
            name: format!("rectangle {length}x{width}"),
            parts: vec![ObstacleSpec::Box {
                center: [0.0, 0.0],
                half_extents: [length / 2.0, width / 2.0],
                angle: 0.0,
            }],
        }
    }

    /// A convex polygon (counter-clockwise, robot frame).
    pub fn polygon(points: Vec<Point>) -> Footprint {
        Footprint { name: "polygon".into(), parts: vec![ObstacleSpec::Polygon { points }] }
    }

    /// This footprint with `cargo` added to the union.
    pub fn with_cargo(mut self, cargo: impl IntoIterator<Item = ObstacleSpec>) -> Footprint {
        self.parts.extend(cargo);
        self
    }

    /// The radius of a footprint that is one disc centred on the axle; `None` otherwise.
    pub fn as_circle(&self) -> Option<f64> {
        match self.parts.as_slice() {
            [ObstacleSpec::Circle { center: [x, y], radius }] if *x == 0.0 && *y == 0.0 => {
                Some(*radius)
            }
            _ => None,
        }
    }

    /// Largest distance (m) of any point of the footprint from the axle centre: the disc
    /// around the axle that covers the robot in every heading.
    pub fn bounding_radius(&self) -> f64 {
        self.parts.iter().map(|p| p.max_distance_from([0.0, 0.0])).fold(0.0, f64::max)
    }

    /// Largest distance (m) a point of the footprint moves per radian of turning in place:
    /// the bounding radius, except that discs centred on the axle do not move when turning.
    pub fn sweep_radius(&self) -> f64 {
        self.parts
            .iter()
            .map(|p| match p {
                ObstacleSpec::Circle { center: [x, y], .. } if *x == 0.0 && *y == 0.0 => 0.0,
                other => other.max_distance_from([0.0, 0.0]),
            })
            .fold(0.0, f64::max)
    }

    /// The parts placed at `pose` (room frame), for drawing.
    pub fn at(&self, pose: Pose2) -> Vec<ObstacleSpec> {
        let (s, c) = pose.yaw.sin_cos();
        let tf = |p: &Point| [pose.x + c * p[0] - s * p[1], pose.y + s * p[0] + c * p[1]];
        self.parts
            .iter()
            .map(|p| match p {
                ObstacleSpec::Box { center, half_extents, angle } => ObstacleSpec::Box {
                    center: tf(center),
                    half_extents: *half_extents,
                    angle: angle + pose.yaw,
                },
                ObstacleSpec::Circle { center, radius } => {
                    ObstacleSpec::Circle { center: tf(center), radius: *radius }
                }
                ObstacleSpec::Polygon { points } => {
                    ObstacleSpec::Polygon { points: points.iter().map(tf).collect() }
                }
                ObstacleSpec::Compound { .. } => p.clone(),
            })
            .collect()
    }

    /// Checks that there is at least one part and every part is a valid box, circle or convex
    /// polygon.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(!self.parts.is_empty(), "a footprint needs at least one part");
        for (i, p) in self.parts.iter().enumerate() {
            anyhow::ensure!(
                !matches!(p, ObstacleSpec::Compound { .. }),
                "parts[{i}]: a footprint is already a union; list the parts directly"
            );
            p.validate().map_err(|e| anyhow::anyhow!("parts[{i}]: {e}"))?;
            within_reach(p).map_err(|e| anyhow::anyhow!("parts[{i}]: {e}"))?;
        }
        Ok(())
    }

    /// Parses and checks a footprint file; `source` names it in errors.
    pub fn from_toml_str(text: &str, source: &str) -> Result<Footprint, SpecFileError> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            #[serde(default)]
            name: String,
            parts: Vec<toml::Spanned<ObstacleSpec>>,
        }
        let file: File = parse_toml(text, source)?;
        Ok(Footprint { name: file.name, parts: checked_parts(file.parts, text, source)? })
    }

    /// Reads a footprint file.
    pub fn load(path: &Path) -> Result<Footprint, SpecFileError> {
        let (text, source) = read_spec_file(path, "footprint file")?;
        Footprint::from_toml_str(&text, &source)
    }
}

/// How far (m) any part of a robot may reach from its axle centre: no robot is larger, and a
/// footprint beyond it (a part centred at 1e308 m) would make every size derived from it
/// overflow.
pub const MAX_ROBOT_EXTENT_M: f64 = 20.0;

/// A part of a footprint lies within [`MAX_ROBOT_EXTENT_M`] of the axle centre.
fn within_reach(p: &ObstacleSpec) -> Result<(), String> {
    let reach = p.max_distance_from([0.0, 0.0]);
    if reach.is_finite() && reach <= MAX_ROBOT_EXTENT_M {
        Ok(())
    } else {
        Err(format!(
            "reaches {reach:e} m from the axle centre; a robot's footprint lies within \
             {MAX_ROBOT_EXTENT_M} m of it"
        ))
    }
}

/// The `parts` of a footprint file, checked: at least one, each a valid box, circle or convex
/// polygon (no compounds). Errors name the part's line in `text`. Shared with the DVST
/// footprint file (`dvnav_nav::dvst`), which has the same `parts` and a few keys more.
pub fn checked_parts(
    parts: Vec<toml::Spanned<ObstacleSpec>>,
    text: &str,
    source: &str,
) -> Result<Vec<ObstacleSpec>, SpecFileError> {
    let err = |line, key: String, reason: String| SpecFileError {
        source: source.to_string(),
        line,
        key,
        reason,
    };
    if parts.is_empty() {
        return Err(err(None, "parts".into(), "a footprint needs at least one part".into()));
    }
    for (i, p) in parts.iter().enumerate() {
        let line = Some(line_of(text, p.span().start));
        if matches!(p.get_ref(), ObstacleSpec::Compound { .. }) {
            let why = "a footprint is already a union; list the parts directly".to_string();
            return Err(err(line, format!("parts[{i}]"), why));
        }
        p.get_ref().validate().map_err(|e| err(line, format!("parts[{i}]"), e.to_string()))?;
        within_reach(p.get_ref()).map_err(|e| err(line, format!("parts[{i}]"), e))?;
    }
    Ok(parts.into_iter().map(|p| p.into_inner()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radii_of_simple_and_compound_footprints() {
        assert_eq!(Footprint::circle(0.2).bounding_radius(), 0.2);
        assert_eq!(Footprint::circle(0.2).sweep_radius(), 0.0);
        assert_eq!(Footprint::circle(0.2).as_circle(), Some(0.2));
        let r = Footprint::rectangle(0.6, 0.8);
        assert!((r.bounding_radius() - 0.5).abs() < 1e-12);
        assert!((r.sweep_radius() - 0.5).abs() < 1e-12);
        assert_eq!(r.as_circle(), None);
        let cargo = r.with_cargo([ObstacleSpec::Circle { center: [-0.6, 0.0], radius: 0.2 }]);
        assert!((cargo.bounding_radius() - 0.8).abs() < 1e-12);
        let p = Footprint::polygon(vec![[0.3, 0.0], [0.0, 0.4], [-0.2, -0.1]]);
        assert!((p.bounding_radius() - 0.4).abs() < 1e-12);
    }

    #[test]
    fn footprint_files_parse_and_bad_ones_name_the_line() {
        let text = "name = \"cart\"\n[[parts]]\nshape = \"box\"\ncenter = [0.1, 0.0]\n\
                    half_extents = [0.3, 0.2]\n[[parts]]\nshape = \"circle\"\n\
                    center = [-0.35, 0.0]\nradius = 0.15\n";
        let f = Footprint::from_toml_str(text, "cart.toml").unwrap();
        assert_eq!(f.parts.len(), 2);
        assert!((f.bounding_radius() - 0.5).abs() < 1e-12);
        // The module doc's example is the same file.
        let bad = text.replace("radius = 0.15", "radius = -0.15");
        let e = Footprint::from_toml_str(&bad, "cart.toml").unwrap_err();
        assert_eq!((e.line, e.key.as_str()), (Some(6), "parts[1]"), "{e}");
        assert!(e.reason.contains("radius must be positive"), "{e}");
        let e = Footprint::from_toml_str("[[parts]]\nshape = \"blob\"\n", "x.toml").unwrap_err();
        assert!(e.to_string().starts_with("x.toml:") && e.reason.contains("blob"), "{e}");
        let e = Footprint::from_toml_str("parts = []\n", "x.toml").unwrap_err();
        assert!(e.reason.contains("at least one part"), "{e}");
    }
}
