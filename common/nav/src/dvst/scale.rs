//! The meta robot and μ: the smallest scale of the meta robot about the axle centre that covers
//! the dimension-varied robot (design §5; the paper's "dimension-scaled robot").
//!
//! **The safety margin.** The paper inflates its real robots' radii by 3 cm before DVST (medium
//! robot 0.34 → 0.37 m, large 0.49 → 0.52 m). Here the margin `m` inflates the varied robot
//! itself: the scaled robot must cover every point within `m` of the varied robot (its
//! Minkowski sum with a disc of radius `m`), not only the robot. For a circular meta robot
//! that is exactly the paper's rule, R_s = R_DVR + m; for a rectangle every side keeps `m`
//! of clearance from the robot. It is a length in metres, so it means the same for a small and
//! a large robot, which a factor on μ would not.

use dvnav_sim::{EnvConfig, Footprint, ObstacleSpec, Point};
use serde::{Deserialize, Serialize};

/// Radius (m) of the default meta robot, the circle the shipped agent was trained with
/// (`env.robot_radius` in the default configuration).
pub const DEFAULT_META_RADIUS: f64 = 0.2;

/// The robot the meta agent was trained as (MR), in its own frame: x ahead, y to the left,
/// the axle centre (the scaling centre) at the origin.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case", deny_unknown_fields)]
pub enum MetaRobot {
    /// A disc centred on the axle.
    Circle {
        /// Radius R_m (m).
        radius: f64,
    },
    /// An axis-aligned rectangle that contains the axle centre: x ∈ [−back, front],
    /// y ∈ [−right, left]. All four are distances from the axle centre, positive.
    Rectangle {
        /// Reach ahead of the axle (m).
        front: f64,
        /// Reach behind the axle (m).
        back: f64,
        /// Reach to the left (m).
        left: f64,
        /// Reach to the right (m).
        right: f64,
    },
}

impl Default for MetaRobot {
    fn default() -> Self {
        MetaRobot::Circle { radius: DEFAULT_META_RADIUS }
    }
}

impl MetaRobot {
    /// Checks that every size is finite and positive (a rectangle must contain the axle
    /// centre strictly, or scaling about it could not cover anything on that side).
    pub fn validate(&self) -> anyhow::Result<()> {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        match *self {
            MetaRobot::Circle { radius } => {
                anyhow::ensure!(ok(radius), "circle: radius must be positive, got {radius}")
            }
            MetaRobot::Rectangle { front, back, left, right } => {
                for (name, x) in
                    [("front", front), ("back", back), ("left", left), ("right", right)]
                {
                    anyhow::ensure!(
                        ok(x),
                        "rectangle: `{name}` must be positive (the rectangle contains the axle \
                         centre), got {x}"
                    );
                }
            }
        }
        Ok(())
    }

    /// This shape scaled by `mu` about the axle centre (the dimension-scaled robot for μ).
    pub fn scaled(&self, mu: f64) -> MetaRobot {
        match *self {
            MetaRobot::Circle { radius } => MetaRobot::Circle { radius: mu * radius },
            MetaRobot::Rectangle { front, back, left, right } => MetaRobot::Rectangle {
                front: mu * front,
                back: mu * back,
                left: mu * left,
                right: mu * right,
            },
        }
    }

    /// The shape as a footprint part (a disc, or a box), for drawing and simulation.
    pub fn to_part(&self) -> ObstacleSpec {
        match *self {
            MetaRobot::Circle { radius } => ObstacleSpec::Circle { center: [0.0, 0.0], radius },
            MetaRobot::Rectangle { front, back, left, right } => ObstacleSpec::Box {
                center: [0.5 * (front - back), 0.5 * (left - right)],
                half_extents: [0.5 * (front + back), 0.5 * (left + right)],
                angle: 0.0,
            },
        }
    }

    /// The meta robot a footprint describes, if it is one: a single disc centred on the axle,
    /// or a single unrotated box that contains the axle centre.
    pub fn from_footprint(fp: &Footprint) -> Option<MetaRobot> {
        match fp.parts.as_slice() {
            [ObstacleSpec::Circle { center: [x, y], radius }] if *x == 0.0 && *y == 0.0 => {
                Some(MetaRobot::Circle { radius: *radius })
            }
            [ObstacleSpec::Box { center: [x, y], half_extents: [hx, hy], angle }]
                if *angle == 0.0 && x.abs() < *hx && y.abs() < *hy =>
            {
                Some(MetaRobot::Rectangle {
                    front: x + hx,
                    back: hx - x,
                    left: y + hy,
                    right: hy - y,
                })
            }
            _ => None,
        }
    }

    /// The meta robot a run trained (its `env.footprint`, else the disc of `env.robot_radius`),
    /// or an error naming it when it is neither a centred disc nor an unrotated box.
    pub fn trained(env: &EnvConfig) -> anyhow::Result<MetaRobot> {
        let trained = env.footprint.clone().unwrap_or_else(|| Footprint::circle(env.robot_radius));
        MetaRobot::from_footprint(&trained).ok_or_else(|| {
            anyhow::anyhow!(
                "DVST needs a circular or rectangular meta robot; the model was trained as `{}`",
                trained.name
            )
        })
    }

    /// Whether `p` (robot frame, m) lies in the shape, boundary included, up to `tol` (m).
    pub fn contains(&self, p: Point, tol: f64) -> bool {
        match *self {
            MetaRobot::Circle { radius } => p[0].hypot(p[1]) <= radius + tol,
            MetaRobot::Rectangle { front, back, left, right } => {
                p[0] <= front + tol
                    && -p[0] <= back + tol
                    && p[1] <= left + tol
                    && -p[1] <= right + tol
            }
        }
    }

    /// Largest distance (m) of the shape from the axle centre.
    pub fn bounding_radius(&self) -> f64 {
        match *self {
            MetaRobot::Circle { radius } => radius,
            MetaRobot::Rectangle { front, back, left, right } => {
                front.max(back).hypot(left.max(right))
            }
        }
    }

    /// One line for people: `circle r = 0.530 m` or
    /// `rectangle 0.800 x 0.600 m (front 0.500, back 0.300, left 0.300, right 0.300 m)`.
    pub fn describe(&self) -> String {
        match *self {
            MetaRobot::Circle { radius } => format!("circle r = {radius:.3} m"),
            MetaRobot::Rectangle { front, back, left, right } => format!(
                "rectangle {:.3} x {:.3} m (front {front:.3}, back {back:.3}, left {left:.3}, \
                 right {right:.3} m)",
                front + back,
                left + right
            ),
        }
    }
}

/// Support function of one convex part: max over its points p of p·u (m, for a unit `u`).
fn support(part: &ObstacleSpec, u: Point) -> f64 {
    let dot = |p: &Point| p[0] * u[0] + p[1] * u[1];
    match part {
        ObstacleSpec::Circle { center, radius } => dot(center) + radius * u[0].hypot(u[1]),
        other => {
            other.vertices().unwrap_or_default().iter().map(dot).fold(f64::NEG_INFINITY, f64::max)
        }
    }
}

/// How far the varied robot reaches from the axle centre along each axis (m): the largest x
/// (front), −x (back), y (left) and −y (right) over its points. Negative when the robot lies
/// entirely on the other side.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Reach {
    /// Largest x (m).
    pub front: f64,
    /// Largest −x (m).
    pub back: f64,
    /// Largest y (m).
    pub left: f64,
    /// Largest −y (m).
    pub right: f64,
}

impl Reach {
    /// The reach of the union of `parts` (circles contribute c ± r per axis, boxes and polygons
    /// their extreme vertices).
    pub fn of(footprint: &Footprint) -> Reach {
        let max = |u: Point| {
            footprint.parts.iter().map(|p| support(p, u)).fold(f64::NEG_INFINITY, f64::max)
        };
        Reach {
            front: max([1.0, 0.0]),
            back: max([-1.0, 0.0]),
            left: max([0.0, 1.0]),
            right: max([0.0, -1.0]),
        }
    }
}

/// μ: the smallest factor by which the meta robot, scaled about the axle centre, covers the
/// varied robot `dvr` inflated by `margin` (m, see the module docs).
///
/// - Circle: μ = (max distance of the DVR from the axle centre + margin) / R_m; a circle part
///   reaches |c| + r, a box or polygon its farthest vertex.
/// - Rectangle: μ = the largest ratio of the DVR's reach on a side (+ margin) to the
///   rectangle's bound on that side.
///
/// μ < 1 for a robot smaller than the meta robot. The footprint and the meta robot must be
/// valid ([`Footprint::validate`], [`MetaRobot::validate`]) and `margin` ≥ 0.
pub fn covering_scale(meta: &MetaRobot, dvr: &Footprint, margin: f64) -> f64 {
    match *meta {
        MetaRobot::Circle { radius } => (dvr.bounding_radius() + margin) / radius,
        MetaRobot::Rectangle { front, back, left, right } => {
            let r = Reach::of(dvr);
            [(r.front, front), (r.back, back), (r.left, left), (r.right, right)]
                .iter()
                .map(|(reach, bound)| (reach + margin) / bound)
                .fold(f64::NEG_INFINITY, f64::max)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn paper_robots_and_simple_cases() {
        let mr = MetaRobot::default();
        // The paper's medium and large robots with the 3 cm margin: DSR radii 0.37 and 0.52 m.
        assert!(close(covering_scale(&mr, &Footprint::circle(0.34), 0.03), 0.37 / 0.2));
        assert!(close(covering_scale(&mr, &Footprint::circle(0.49), 0.03), 0.52 / 0.2));
        // Smaller than the meta robot: μ < 1.
        assert!(close(covering_scale(&mr, &Footprint::circle(0.15), 0.0), 0.75));
        // A 0.6 x 0.8 rectangle centred on the axle reaches 0.5 m at its corners.
        assert!(close(covering_scale(&mr, &Footprint::rectangle(0.6, 0.8), 0.0), 2.5));
        // A rectangle meta robot carrying a box behind it: the back side decides.
        let rect = MetaRobot::Rectangle { front: 0.3, back: 0.1, left: 0.2, right: 0.2 };
        let body = Footprint::polygon(vec![[-0.1, -0.2], [0.3, -0.2], [0.3, 0.2], [-0.1, 0.2]]);
        assert!(close(covering_scale(&rect, &body, 0.0), 1.0));
        let cargo = body.clone().with_cargo([ObstacleSpec::Box {
            center: [-0.3, 0.0],
            half_extents: [0.2, 0.15],
            angle: 0.0,
        }]);
        assert!(close(covering_scale(&rect, &cargo, 0.0), 5.0), "reach 0.5 behind / 0.1");
        assert!(close(covering_scale(&rect, &cargo, 0.02), 5.2));
        // A disc off to the left: c ± r per axis.
        let disc = Footprint::circle(0.1)
            .with_cargo([ObstacleSpec::Circle { center: [0.0, 0.5], radius: 0.1 }]);
        assert!(close(covering_scale(&rect, &disc, 0.0), 3.0), "left reach 0.6 / 0.2");
        assert_eq!(MetaRobot::from_footprint(&Footprint::circle(0.2)), Some(mr));
        // Exact binary fractions, so the round trip through a box is exact.
        let rect = MetaRobot::Rectangle { front: 0.375, back: 0.125, left: 0.25, right: 0.5 };
        let back = MetaRobot::from_footprint(&Footprint {
            name: String::new(),
            parts: vec![rect.to_part()],
        });
        assert_eq!(back, Some(rect));
        let off_axle = Footprint {
            name: String::new(),
            parts: vec![ObstacleSpec::Box {
                center: [0.5, 0.0],
                half_extents: [0.2, 0.2],
                angle: 0.0,
            }],
        };
        assert_eq!(MetaRobot::from_footprint(&off_axle), None, "does not contain the axle");
    }

    #[test]
    fn invalid_meta_robots_are_refused() {
        assert!(MetaRobot::Circle { radius: 0.0 }.validate().is_err());
        let e = MetaRobot::Rectangle { front: 0.3, back: -0.1, left: 0.2, right: 0.2 }
            .validate()
            .unwrap_err();
        assert!(e.to_string().contains("`back`"), "{e}");
        assert!(
            MetaRobot::Rectangle { front: 0.3, back: 0.1, left: f64::NAN, right: 0.2 }
                .validate()
                .is_err()
        );
    }

    /// A random convex part: a disc, a rotated box, or a polygon with vertices on a rotated
    /// ellipse at increasing angles (so it is convex and counter-clockwise).
    fn random_part(rng: &mut Pcg64) -> ObstacleSpec {
        let c = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
        match rng.random_range(0..3) {
            0 => ObstacleSpec::Circle { center: c, radius: rng.random_range(0.02..0.6) },
            1 => ObstacleSpec::Box {
                center: c,
                half_extents: [rng.random_range(0.02..0.5), rng.random_range(0.02..0.5)],
                angle: rng.random_range(-3.2..3.2),
            },
            _ => {
                let n = rng.random_range(3..8);
                let (a, b) = (rng.random_range(0.05..0.6), rng.random_range(0.05..0.6));
                let rot: f64 = rng.random_range(-3.2..3.2);
                let step = std::f64::consts::TAU / n as f64;
                let points = (0..n)
                    .map(|k| {
                        let t = step * (k as f64 + rng.random_range(0.1..0.9));
                        let (x, y) = (a * t.cos(), b * t.sin());
                        let (s, co) = rot.sin_cos();
                        [c[0] + co * x - s * y, c[1] + s * x + co * y]
                    })
                    .collect();
                ObstacleSpec::Polygon { points }
            }
        }
    }

    fn random_meta(rng: &mut Pcg64) -> MetaRobot {
        if rng.random_bool(0.5) {
            MetaRobot::Circle { radius: rng.random_range(0.1..0.5) }
        } else {
            MetaRobot::Rectangle {
                front: rng.random_range(0.05..0.6),
                back: rng.random_range(0.05..0.6),
                left: rng.random_range(0.05..0.6),
                right: rng.random_range(0.05..0.6),
            }
        }
    }

    /// Points on the boundary of `part` inflated by `margin`: the support point in each of
    /// `n` directions, pushed `margin` outwards (the Minkowski sum with a disc), plus every
    /// vertex pushed along its own direction from the axle (where a circle meta robot's
    /// farthest point lies).
    fn inflated_boundary(part: &ObstacleSpec, margin: f64, n: usize) -> Vec<Point> {
        let mut out = Vec::new();
        let verts = part.vertices();
        for k in 0..n {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            let u = [a.cos(), a.sin()];
            let p = match (part, &verts) {
                (ObstacleSpec::Circle { center, radius }, _) => {
                    [center[0] + radius * u[0], center[1] + radius * u[1]]
                }
                (_, Some(v)) => *v
                    .iter()
                    .max_by(|a, b| {
                        (a[0] * u[0] + a[1] * u[1]).total_cmp(&(b[0] * u[0] + b[1] * u[1]))
                    })
                    .unwrap(),
                _ => unreachable!("footprint parts are convex primitives"),
            };
            out.push([p[0] + margin * u[0], p[1] + margin * u[1]]);
        }
        let radial = |p: Point, extra: f64| {
            let d = p[0].hypot(p[1]).max(1e-300);
            [p[0] + extra * p[0] / d, p[1] + extra * p[1] / d]
        };
        match part {
            ObstacleSpec::Circle { center, radius } => out.push(radial(*center, radius + margin)),
            _ => out.extend(verts.unwrap_or_default().into_iter().map(|v| radial(v, margin))),
        }
        out
    }

    /// Property: at μ every point of the (inflated) varied robot is inside the scaled meta
    /// robot, and at 0.99·μ some point is outside, so μ is the smallest covering scale.
    #[test]
    fn mu_covers_the_varied_robot_and_is_minimal() {
        let mut rng = Pcg64::seed_from_u64(6);
        for case in 0..3000 {
            let meta = random_meta(&mut rng);
            let parts: Vec<ObstacleSpec> =
                (0..rng.random_range(1..5)).map(|_| random_part(&mut rng)).collect();
            let dvr = Footprint { name: String::new(), parts };
            dvr.validate().unwrap();
            let margin = if rng.random_bool(0.3) { 0.0 } else { rng.random_range(0.0..0.1) };
            let mu = covering_scale(&meta, &dvr, margin);
            assert!(mu.is_finite() && mu > 0.0, "case {case}: mu = {mu}");
            let points: Vec<Point> =
                dvr.parts.iter().flat_map(|p| inflated_boundary(p, margin, 720)).collect();
            let dsr = meta.scaled(mu);
            if let Some(p) = points.iter().find(|&&p| !dsr.contains(p, 1e-9)) {
                panic!("case {case}: {p:?} outside the scaled robot {dsr:?} (mu {mu}, {dvr:?})");
            }
            let smaller = meta.scaled(0.99 * mu);
            assert!(
                points.iter().any(|&p| !smaller.contains(p, 0.0)),
                "case {case}: 0.99 mu = {} still covers {dvr:?} with margin {margin}",
                0.99 * mu
            );
        }
    }
}
