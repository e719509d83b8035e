//! Where a disc's centre may sit, measured exactly at each cell centre: the cells the progress
//! reward's way ([`super::GeodesicField`]) runs through.
//!
//! [`ClearanceMap::reach`] is conservative so that a path on it is always drivable: a cell is
//! passable when its centre is the radius *plus a cell diagonal* from every occupied centre,
//! which shuts a gap up to 3.5 cm wider than the disc (the gate's 0.55 m gap for a 0.25 m
//! robot). A reward needs the way the robot can actually take, not a guarantee: a way round
//! a wall when the gap fits pays the robot for avoiding the gap it should drive through. Here a
//! cell is passable when its centre is at least the radius from every static shape, the
//! distance measured to the shapes themselves near the boundary (the raster's distance decides
//! everywhere else: it is within half a cell diagonal of the exact one).

use super::{ClearanceMap, Reach, components, distance_to_convex};
use crate::spec::{ObstacleSpec, Point, RoomSpec};

impl ClearanceMap {
    /// The cells whose centre lies at least `radius` from every wall and static obstacle of
    /// `spec` (the room this map was rastered from), and their components.
    ///
    /// Unlike [`ClearanceMap::reach`], a path through these cells may graze a corner by up to
    /// half a cell: use it to measure ways, not to plan them.
    pub fn reach_of_centres(&self, spec: &RoomSpec, radius: f64) -> Reach {
        let r = &self.raster;
        let half = r.half_diagonal();
        let mut shapes: Vec<(ObstacleSpec, [Point; 2])> = Vec::new();
        for shape in spec.walls().iter().chain(&spec.obstacles) {
            shape.for_each_primitive(&mut |p| shapes.push((p.clone(), p.aabb())));
        }
        // Every point of a shape is within half a diagonal of an occupied centre and every
        // occupied centre within half a diagonal of a shape, so the exact clearance of a centre
        // is its raster distance ± half a diagonal: only the band in between is measured.
        let clear = |c: Point| {
            shapes.iter().all(|(p, [lo, hi])| {
                let outside = c[0] < lo[0] - radius
                    || c[0] > hi[0] + radius
                    || c[1] < lo[1] - radius
                    || c[1] > hi[1] + radius;
                outside || distance_to_convex(p, c) >= radius
            })
        };
        let passable: Vec<bool> = self
            .dist
            .iter()
            .enumerate()
            .map(|(k, &d)| {
                d >= radius + half || (d >= radius - half && clear(r.centre(k % r.n, k / r.n)))
            })
            .collect();
        let (label, sizes) = components(&passable, r.n);
        Reach { raster: r.clone(), radius, label, sizes }
    }
}
