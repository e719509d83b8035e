//! Rooms as data: the walls and obstacles of a room, in metres, world frame (x right, y up,
//! origin at the room's centre). A [`RoomSpec`] is plain serde data so rooms can be written in
//! files; [`super::Room`] turns one into rapier2d colliders.

use serde::{Deserialize, Serialize};

/// A 2-D point or vector in metres.
pub type Point = [f64; 2];

/// One static shape of a room.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case", deny_unknown_fields)]
pub enum ObstacleSpec {
    /// A rectangle centred at `center`, rotated by `angle` (rad), with half-sizes `half_extents`.
    Box {
        /// Centre (m).
        center: Point,
        /// Half width and half height (m).
        half_extents: Point,
        /// Rotation (rad, counter-clockwise).
        #[serde(default)]
        angle: f64,
    },
    /// A disc.
    Circle {
        /// Centre (m).
        center: Point,
        /// Radius (m).
        radius: f64,
    },
    /// A convex polygon, vertices in counter-clockwise order (m).
    Polygon {
        /// Vertices (m).
        points: Vec<Point>,
    },
}

/// A square room: four walls of side `side` (inner size) and the obstacles inside.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSpec {
    /// Name, e.g. `env0`.
    pub name: String,
    /// Inner side length of the square room (m); walls lie just outside ±side/2.
    pub side: f64,
    /// Wall thickness (m).
    pub wall_thickness: f64,
    /// Obstacles inside the room.
    pub obstacles: Vec<ObstacleSpec>,
}

/// Side (m) of the room the training layout is defined for (Env_0).
pub const TRAINING_BASE_SIDE: f64 = 8.0;

/// Wall thickness (m) of the built-in rooms. Walls lie outside the room, so it only matters to
/// what a LiDAR beam could see through a wall, which it never can.
pub const DEFAULT_WALL_THICKNESS: f64 = 0.2;

/// One obstacle group of the training layout: parts given relative to an anchor. When the room
/// shrinks, the anchor moves towards the centre (its coordinates scale by side/8) while the
/// parts keep their size and their offsets, so a U-shaped trap stays one U of the same size.
struct Group {
    /// Anchor in the 8 m room (m).
    anchor: Point,
    /// Parts, centred relative to the anchor (m).
    parts: Vec<ObstacleSpec>,
}

/// The training layout (design §2), defined for the 8 m room.
///
/// Eight groups, eleven shapes, on a ring around a free centre (the evaluation start):
///
/// ```text
///   NW triangle      N  U-trap (opens south)   NE circle r 0.30
///   W  rotated box         (origin)            E  pentagon
///   SW diamond       S  circle r 0.35          SE L-corner trap (opens north-west)
/// ```
///
/// The anchors are chosen so that at side 5 (the most crowded room) every gap between two
/// groups, and between a group and a wall, is at least 0.6 m, and the origin has more than 1 m
/// of clearance; gaps only grow in the larger rooms. The U pocket is 0.8 m wide and 0.7 m deep,
/// so the 0.4 m robot can drive into it and has to back out: a local minimum for a goal behind
/// it. The L corner is a shallower trap of the same kind.
fn training_groups() -> Vec<Group> {
    use ObstacleSpec::{Box, Circle, Polygon};
    let regular = |n: usize, r: f64, phase: f64| -> ObstacleSpec {
        let points = (0..n)
            .map(|k| {
                let a = phase + std::f64::consts::TAU * k as f64 / n as f64;
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        Polygon { points }
    };
    let bx = |center: Point, half_extents: Point, angle: f64| Box { center, half_extents, angle };
    vec![
        // N: U-shaped pocket opening towards the centre (−y): back bar and two arms.
        Group {
            anchor: [0.0, 2.24],
            parts: vec![
                bx([0.0, 0.35], [0.5, 0.05], 0.0),
                bx([-0.45, 0.0], [0.05, 0.4], 0.0),
                bx([0.45, 0.0], [0.05, 0.4], 0.0),
            ],
        },
        // SE: L-shaped corner whose concave side faces the centre.
        Group {
            anchor: [2.4, -2.4],
            parts: vec![bx([0.0, -0.3], [0.35, 0.05], 0.0), bx([0.3, 0.0], [0.05, 0.35], 0.0)],
        },
        // S: circle.
        Group { anchor: [0.0, -2.4], parts: vec![Circle { center: [0.0, 0.0], radius: 0.35 }] },
        // NE: circle.
        Group { anchor: [2.4, 2.4], parts: vec![Circle { center: [0.0, 0.0], radius: 0.3 }] },
        // E: regular pentagon, circumradius 0.35.
        Group { anchor: [2.4, 0.0], parts: vec![regular(5, 0.35, 0.3)] },
        // NW: triangle, circumradius 0.35.
        Group { anchor: [-2.4, 2.4], parts: vec![regular(3, 0.35, std::f64::consts::FRAC_PI_2)] },
        // W: rotated rectangle 0.7 m x 0.4 m.
        Group { anchor: [-2.32, 0.0], parts: vec![bx([0.0, 0.0], [0.35, 0.2], 0.4)] },
        // SW: square turned 45° (a diamond).
        Group {
            anchor: [-2.4, -2.4],
            parts: vec![bx([0.0, 0.0], [0.25, 0.25], std::f64::consts::FRAC_PI_4)],
        },
    ]
}

impl ObstacleSpec {
    /// The same shape moved by `offset` (m).
    pub fn translated(&self, offset: Point) -> ObstacleSpec {
        let add = |p: &Point| [p[0] + offset[0], p[1] + offset[1]];
        match self {
            ObstacleSpec::Box { center, half_extents, angle } => ObstacleSpec::Box {
                center: add(center),
                half_extents: *half_extents,
                angle: *angle,
            },
            ObstacleSpec::Circle { center, radius } => {
                ObstacleSpec::Circle { center: add(center), radius: *radius }
            }
            ObstacleSpec::Polygon { points } => {
                ObstacleSpec::Polygon { points: points.iter().map(add).collect() }
            }
        }
    }

    /// Checks that the shape is finite and non-degenerate; polygons must be convex and
    /// counter-clockwise.
    pub fn validate(&self) -> anyhow::Result<()> {
        let finite = |p: &Point| p[0].is_finite() && p[1].is_finite();
        match self {
            ObstacleSpec::Box { center, half_extents, angle } => {
                anyhow::ensure!(finite(center) && angle.is_finite(), "box: non-finite pose");
                anyhow::ensure!(
                    half_extents[0] > 0.0 && half_extents[1] > 0.0 && finite(half_extents),
                    "box: half extents must be positive, got {half_extents:?}"
                );
            }
            ObstacleSpec::Circle { center, radius } => {
                anyhow::ensure!(finite(center), "circle: non-finite centre");
                anyhow::ensure!(
                    radius.is_finite() && *radius > 0.0,
                    "circle: radius must be positive, got {radius}"
                );
            }
            ObstacleSpec::Polygon { points } => {
                anyhow::ensure!(points.len() >= 3, "polygon: needs at least 3 points");
                anyhow::ensure!(points.iter().all(finite), "polygon: non-finite point");
                let n = points.len();
                for i in 0..n {
                    let (a, b, c) = (points[i], points[(i + 1) % n], points[(i + 2) % n]);
                    let cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
                    anyhow::ensure!(
                        cross > 0.0,
                        "polygon: points must form a convex polygon in counter-clockwise order \
                         (turn at point {} is not to the left)",
                        (i + 1) % n
                    );
                }
            }
        }
        Ok(())
    }
}

impl RoomSpec {
    /// A room with walls and no obstacles.
    pub fn empty(name: &str, side: f64) -> RoomSpec {
        RoomSpec {
            name: name.to_string(),
            side,
            wall_thickness: DEFAULT_WALL_THICKNESS,
            obstacles: Vec::new(),
        }
    }

    /// The training layout (see the `training_groups` docs in the source) instanced at `side`
    /// metres: obstacle positions scale by `side / 8`, obstacle sizes stay the same, so
    /// smaller rooms are more crowded. Env_0..Env_3 are sides 8, 7, 6 and 5; the layout is
    /// checked to leave ≥ 0.6 m gaps down to side 5.
    pub fn training(name: &str, side: f64) -> RoomSpec {
        let s = side / TRAINING_BASE_SIDE;
        let obstacles = training_groups()
            .into_iter()
            .flat_map(|g| {
                let anchor = [g.anchor[0] * s, g.anchor[1] * s];
                g.parts.into_iter().map(move |p| p.translated(anchor))
            })
            .collect();
        RoomSpec { obstacles, ..RoomSpec::empty(name, side) }
    }

    /// The training layout's obstacles at `side`, grouped (parts of one trap together).
    #[cfg(test)]
    pub(crate) fn training_grouped(side: f64) -> Vec<Vec<ObstacleSpec>> {
        let s = side / TRAINING_BASE_SIDE;
        training_groups()
            .into_iter()
            .map(|g| {
                let anchor = [g.anchor[0] * s, g.anchor[1] * s];
                g.parts.iter().map(|p| p.translated(anchor)).collect()
            })
            .collect()
    }

    /// Checks the side, the wall thickness and every obstacle.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.side.is_finite() && self.side > 0.0,
            "room `{}`: side must be positive, got {}",
            self.name,
            self.side
        );
        anyhow::ensure!(
            self.wall_thickness.is_finite() && self.wall_thickness > 0.0,
            "room `{}`: wall_thickness must be positive, got {}",
            self.name,
            self.wall_thickness
        );
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate().map_err(|e| anyhow::anyhow!("room `{}`: obstacle {i}: {e}", self.name))?;
        }
        Ok(())
    }

    /// The four walls as boxes just outside ±side/2 (the inner faces lie on the room's edge).
    pub fn walls(&self) -> [ObstacleSpec; 4] {
        let h = self.side / 2.0;
        let t = self.wall_thickness / 2.0;
        let long = [h + self.wall_thickness, t];
        let tall = [t, h + self.wall_thickness];
        let bx = |center: Point, half_extents: Point| ObstacleSpec::Box {
            center,
            half_extents,
            angle: 0.0,
        };
        [
            bx([0.0, h + t], long),
            bx([0.0, -h - t], long),
            bx([h + t, 0.0], tall),
            bx([-h - t, 0.0], tall),
        ]
    }
}
