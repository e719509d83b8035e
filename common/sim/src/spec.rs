//! Rooms as data: the walls, obstacles, spawn regions, goal routes and timed obstacles of a room,
//! in metres, world frame (x right, y up, origin at the room's centre). A [`RoomSpec`] is plain
//! serde data; [`super::room_file`] reads it from the TOML room files users write (and the
//! built-in rooms in `rooms/`), and [`super::Room`] turns one into geometry.

use serde::{Deserialize, Serialize};

/// A 2-D point or vector in metres.
pub type Point = [f64; 2];

/// One shape of a room (or of a robot's footprint, see [`super::Footprint`]).
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
    /// A union of boxes, circles and polygons placed relative to the anchor `at`: one obstacle
    /// made of several convex parts (an L, a U-shaped trap, a table and its legs). When a room
    /// layout is instanced at another side (see [`super::room_file`]) the anchor moves and the
    /// parts keep their size and their offsets. Parts may not be compounds themselves.
    Compound {
        /// Anchor (m); the parts' coordinates are relative to it.
        #[serde(default)]
        at: Point,
        /// The parts, relative to `at`.
        parts: Vec<ObstacleSpec>,
    },
}

/// A straight wall: a box `thickness` thick centred on the segment from `from` to `to`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallSegment {
    /// One end of the wall's centre line (m).
    pub from: Point,
    /// The other end (m).
    pub to: Point,
    /// Thickness (m); the room's `wall_thickness` when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness: Option<f64>,
}

/// An axis-aligned rectangle where episode starts and/or goals are drawn (the free part of it:
/// the sampler still keeps the robot's clearance from every shape).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpawnRegion {
    /// Name, unique in the room.
    pub name: String,
    /// Lower-left corner (m).
    pub min: Point,
    /// Upper-right corner (m).
    pub max: Point,
    /// Starts are drawn here (default true).
    #[serde(default = "yes")]
    pub starts: bool,
    /// Goals are drawn here (default true).
    #[serde(default = "yes")]
    pub goals: bool,
}

/// A fixed evaluation route: a start pose and goals visited in order (the next goal is set
/// when the previous one is reached).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Route {
    /// Name, unique in the room (`eval` for the evaluation route of design §4).
    pub name: String,
    /// Start position (m).
    pub start: Point,
    /// Start heading (degrees, counter-clockwise from +x).
    #[serde(default)]
    pub heading_deg: f64,
    /// Goals in the order they are visited (m).
    pub goals: Vec<Point>,
}

impl Route {
    /// The start pose (heading in radians).
    pub fn start_pose(&self) -> super::Pose2 {
        super::Pose2::new(self.start[0], self.start[1], self.heading_deg.to_radians())
    }
}

/// An obstacle that appears mid-episode (the dynamic scenario): absent before, present from
/// the moment `at_step` control steps have elapsed (simulation time `at_step · dt`) until the
/// episode ends. It is in the scan observed after step `at_step`, and it blocks motion from
/// then on; a robot it appears on collides with it at that step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimedObstacle {
    /// Control steps after the reset at which the obstacle appears (0: present from the start).
    pub at_step: u32,
    /// Its shape.
    pub obstacle: ObstacleSpec,
}

fn yes() -> bool {
    true
}

fn is_true(b: &bool) -> bool {
    *b
}

/// A room: walls, static obstacles, and what episodes in it use (spawn regions, routes, timed
/// obstacles). By default the walls are the four sides of a `side` x `side` square around the
/// origin; [`RoomSpec::square_walls`] `= false` with [`RoomSpec::wall_segments`] makes rooms of
/// any other outline (the square then only bounds the drawing and the sampling).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSpec {
    /// Name, e.g. `env0`.
    pub name: String,
    /// Inner side length of the square room (m); walls lie just outside ±side/2. With
    /// `square_walls = false`, the square everything must lie in.
    pub side: f64,
    /// Wall thickness (m).
    pub wall_thickness: f64,
    /// Static obstacles inside the room.
    pub obstacles: Vec<ObstacleSpec>,
    /// One line of what the room is for (shown by `dvnav rooms list`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    /// Whether the four walls of the square are there (default true).
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub square_walls: bool,
    /// Further walls, e.g. a wall with a gate across the room.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub wall_segments: Vec<WallSegment>,
    /// Where starts and goals are drawn; none: anywhere in the square.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub spawn_regions: Vec<SpawnRegion>,
    /// Named evaluation routes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub routes: Vec<Route>,
    /// Obstacles that appear during an episode.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub timed_obstacles: Vec<TimedObstacle>,
}

/// Side (m) of the room the training layout is defined for (Env_0).
pub const TRAINING_BASE_SIDE: f64 = 8.0;

/// Wall thickness (m) of the built-in rooms. Walls lie outside the room, so it only matters to
/// what a LiDAR beam could see through a wall, which it never can.
pub const DEFAULT_WALL_THICKNESS: f64 = 0.2;

/// Corners of a box, counter-clockwise.
pub fn box_corners(center: Point, half_extents: Point, angle: f64) -> [Point; 4] {
    let (s, c) = angle.sin_cos();
    [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(sx, sy)| {
        let (lx, ly) = (sx * half_extents[0], sy * half_extents[1]);
        [center[0] + c * lx - s * ly, center[1] + s * lx + c * ly]
    })
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
            ObstacleSpec::Compound { at, parts } => {
                ObstacleSpec::Compound { at: add(at), parts: parts.clone() }
            }
        }
    }

    /// The point that moves when a layout is instanced at another side: a box's or circle's
    /// centre, a polygon's vertex mean, a compound's anchor.
    pub fn anchor(&self) -> Point {
        match self {
            ObstacleSpec::Box { center, .. } | ObstacleSpec::Circle { center, .. } => *center,
            ObstacleSpec::Polygon { points } => {
                let n = points.len().max(1) as f64;
                points.iter().fold([0.0, 0.0], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n])
            }
            ObstacleSpec::Compound { at, .. } => *at,
        }
    }

    /// Calls `f` with every convex part in room coordinates: the shape itself, or a compound's
    /// parts moved to its anchor.
    pub fn for_each_primitive(&self, f: &mut impl FnMut(&ObstacleSpec)) {
        match self {
            ObstacleSpec::Compound { at, parts } => {
                for p in parts {
                    p.translated(*at).for_each_primitive(f);
                }
            }
            other => f(other),
        }
    }

    /// The convex parts in room coordinates (see [`ObstacleSpec::for_each_primitive`]).
    pub fn primitives(&self) -> Vec<ObstacleSpec> {
        let mut out = Vec::new();
        self.for_each_primitive(&mut |p| out.push(p.clone()));
        out
    }

    /// Vertices of a box or polygon, counter-clockwise; `None` for a circle or a compound.
    pub fn vertices(&self) -> Option<Vec<Point>> {
        match self {
            ObstacleSpec::Box { center, half_extents, angle } => {
                Some(box_corners(*center, *half_extents, *angle).to_vec())
            }
            ObstacleSpec::Polygon { points } => Some(points.clone()),
            _ => None,
        }
    }

    /// Axis-aligned bounding box `[min, max]` (m).
    pub fn aabb(&self) -> [Point; 2] {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        self.for_each_primitive(&mut |p| {
            let (plo, phi) = match p {
                ObstacleSpec::Circle { center, radius } => (
                    [center[0] - radius, center[1] - radius],
                    [center[0] + radius, center[1] + radius],
                ),
                other => {
                    let v = other.vertices().unwrap_or_default();
                    let min = |k: usize| v.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
                    let max = |k: usize| v.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
                    ([min(0), min(1)], [max(0), max(1)])
                }
            };
            for k in 0..2 {
                lo[k] = lo[k].min(plo[k]);
                hi[k] = hi[k].max(phi[k]);
            }
        });
        [lo, hi]
    }

    /// Largest distance (m) of any point of the shape from `p`.
    pub fn max_distance_from(&self, p: Point) -> f64 {
        let mut d: f64 = 0.0;
        self.for_each_primitive(&mut |s| {
            let far = match s {
                ObstacleSpec::Circle { center, radius } => {
                    (center[0] - p[0]).hypot(center[1] - p[1]) + radius
                }
                other => other
                    .vertices()
                    .unwrap_or_default()
                    .iter()
                    .map(|v| (v[0] - p[0]).hypot(v[1] - p[1]))
                    .fold(0.0, f64::max),
            };
            d = d.max(far);
        });
        d
    }

    /// Short name of the shape kind, as written in files.
    pub fn kind(&self) -> &'static str {
        match self {
            ObstacleSpec::Box { .. } => "box",
            ObstacleSpec::Circle { .. } => "circle",
            ObstacleSpec::Polygon { .. } => "polygon",
            ObstacleSpec::Compound { .. } => "compound",
        }
    }

    /// Checks that the shape is finite and non-degenerate; polygons must be convex and
    /// counter-clockwise; compounds need at least one part and no compound parts.
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
                anyhow::ensure!(
                    points.len() >= 3,
                    "polygon: needs at least 3 points, got {}",
                    points.len()
                );
                anyhow::ensure!(points.iter().all(finite), "polygon: non-finite point");
                let n = points.len();
                let turns: Vec<f64> = (0..n)
                    .map(|i| {
                        let (a, b, c) = (points[i], points[(i + 1) % n], points[(i + 2) % n]);
                        (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
                    })
                    .collect();
                if let Some(i) = turns.iter().position(|&t| t <= 0.0) {
                    let clockwise = turns.iter().all(|&t| t < 0.0);
                    anyhow::ensure!(
                        !clockwise,
                        "polygon: the points run clockwise; list them counter-clockwise"
                    );
                    anyhow::bail!(
                        "polygon: points must form a convex polygon in counter-clockwise order \
                         (the turn at point {} is not to the left: non-convex, or a repeated or \
                         collinear point)",
                        (i + 1) % n
                    );
                }
                // Convex turns everywhere but winding more than once (a star) is not convex.
                let winding: f64 = (0..n)
                    .map(|i| {
                        let (a, b, c) = (points[i], points[(i + 1) % n], points[(i + 2) % n]);
                        let u = [b[0] - a[0], b[1] - a[1]];
                        let v = [c[0] - b[0], c[1] - b[1]];
                        (u[0] * v[1] - u[1] * v[0]).atan2(u[0] * v[0] + u[1] * v[1])
                    })
                    .sum();
                anyhow::ensure!(
                    (winding - std::f64::consts::TAU).abs() < 1e-6,
                    "polygon: the points wind around more than once (self-intersecting), \
                     so the polygon is not convex"
                );
            }
            ObstacleSpec::Compound { at, parts } => {
                anyhow::ensure!(finite(at), "compound: non-finite anchor");
                anyhow::ensure!(!parts.is_empty(), "compound: needs at least one part");
                for (i, p) in parts.iter().enumerate() {
                    anyhow::ensure!(
                        !matches!(p, ObstacleSpec::Compound { .. }),
                        "compound: part {i} is a compound; list its parts directly"
                    );
                    p.validate().map_err(|e| anyhow::anyhow!("compound part {i}: {e}"))?;
                }
            }
        }
        Ok(())
    }
}

impl WallSegment {
    /// The wall as a box, `default_thickness` thick unless the segment sets its own.
    pub fn to_box(&self, default_thickness: f64) -> ObstacleSpec {
        let t = self.thickness.unwrap_or(default_thickness);
        let (dx, dy) = (self.to[0] - self.from[0], self.to[1] - self.from[1]);
        ObstacleSpec::Box {
            center: [0.5 * (self.from[0] + self.to[0]), 0.5 * (self.from[1] + self.to[1])],
            half_extents: [0.5 * dx.hypot(dy), 0.5 * t],
            angle: dy.atan2(dx),
        }
    }
}

impl RoomSpec {
    /// A square room with walls and no obstacles.
    pub fn empty(name: &str, side: f64) -> RoomSpec {
        RoomSpec {
            name: name.to_string(),
            side,
            wall_thickness: DEFAULT_WALL_THICKNESS,
            obstacles: Vec::new(),
            description: String::new(),
            square_walls: true,
            wall_segments: Vec::new(),
            spawn_regions: Vec::new(),
            routes: Vec::new(),
            timed_obstacles: Vec::new(),
        }
    }

    /// Checks the side, the wall thickness and every shape (not where they lie: see
    /// [`super::room_file`] for the checks against the room's free space).
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
        for (i, w) in self.wall_segments.iter().enumerate() {
            let ok = w.from.iter().chain(&w.to).all(|v| v.is_finite())
                && w.from != w.to
                && w.thickness.is_none_or(|t| t.is_finite() && t > 0.0);
            anyhow::ensure!(
                ok,
                "room `{}`: wall segment {i}: needs two distinct finite ends and a positive \
                 thickness",
                self.name
            );
        }
        for (i, t) in self.timed_obstacles.iter().enumerate() {
            t.obstacle
                .validate()
                .map_err(|e| anyhow::anyhow!("room `{}`: timed obstacle {i}: {e}", self.name))?;
        }
        anyhow::ensure!(
            self.square_walls || !self.spawn_regions.is_empty(),
            "room `{}`: a room without square walls needs spawn regions (the sampler cannot \
             tell inside from outside of other outlines)",
            self.name
        );
        Ok(())
    }

    /// Every wall as a shape: the four sides of the square (boxes just outside ±side/2, inner
    /// faces on the room's edge) unless `square_walls` is false, then the wall segments.
    pub fn walls(&self) -> Vec<ObstacleSpec> {
        let mut out = Vec::with_capacity(4 + self.wall_segments.len());
        if self.square_walls {
            let h = self.side / 2.0;
            let t = self.wall_thickness / 2.0;
            let long = [h + self.wall_thickness, t];
            let tall = [t, h + self.wall_thickness];
            let bx = |center: Point, half_extents: Point| ObstacleSpec::Box {
                center,
                half_extents,
                angle: 0.0,
            };
            out.extend([
                bx([0.0, h + t], long),
                bx([0.0, -h - t], long),
                bx([h + t, 0.0], tall),
                bx([-h - t, 0.0], tall),
            ]);
        }
        out.extend(self.wall_segments.iter().map(|w| w.to_box(self.wall_thickness)));
        out
    }

    /// A route by name.
    pub fn route(&self, name: &str) -> Option<&Route> {
        self.routes.iter().find(|r| r.name == name)
    }
}

impl ObstacleSpec {
    /// True when `p` lies inside or on the boundary of the shape (exact, `f64`).
    pub fn contains(&self, p: Point) -> bool {
        let mut hit = false;
        self.for_each_primitive(&mut |s| {
            hit |= match s {
                ObstacleSpec::Circle { center, radius } => {
                    (center[0] - p[0]).hypot(center[1] - p[1]) <= *radius
                }
                other => {
                    let v = other.vertices().unwrap_or_default();
                    let n = v.len();
                    n >= 3
                        && (0..n).all(|k| {
                            let (a, b) = (v[k], v[(k + 1) % n]);
                            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0.0
                        })
                }
            }
        });
        hit
    }
}
