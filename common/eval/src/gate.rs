//! Which way a robot went in the gate room (design §2): through the **gate** straight ahead, by
//! the **left** path, or **other** (it never crossed the wall, or crossed elsewhere).
//!
//! The geometry comes from the room, not from constants: the wall across the room is its
//! horizontal wall segments (all at one height `y_w`); the openings are the stretches of
//! `y = y_w` inside the room's square that no segment covers. The gate is the opening the
//! straight line from the route's start to its goal passes through; openings left of it (lower
//! x) are the left path. A trajectory is classified by where it first crosses `y = y_w` from
//! the start's side to the goal's side.

use dvnav_sim::{RoomSpec, Route};
use serde::Serialize;

/// Which way a robot went.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GateRoute {
    /// Through the gate on the straight line from start to goal.
    Gate,
    /// Through an opening left of the gate.
    Left,
    /// Never crossed the wall, or crossed right of the gate.
    Other,
}

impl GateRoute {
    /// Lower-case name, as in JSON and tables.
    pub fn as_str(self) -> &'static str {
        match self {
            GateRoute::Gate => "gate",
            GateRoute::Left => "left",
            GateRoute::Other => "other",
        }
    }
}

/// The wall line, its gate and the openings left of it.
#[derive(Clone, Debug, PartialEq)]
pub struct GateGeometry {
    /// Height of the wall's centre line (m).
    pub wall_y: f64,
    /// The gate: x range of the opening on the start–goal line (m).
    pub gate: [f64; 2],
    /// Openings left of the gate, x ranges (m).
    pub left: Vec<[f64; 2]>,
    /// The start lies below the wall (y < wall_y).
    start_below: bool,
}

impl GateGeometry {
    /// Reads the geometry of `room` for `route` (its start and first goal must lie on opposite
    /// sides of the wall).
    pub fn from_room(room: &RoomSpec, route: &Route) -> anyhow::Result<GateGeometry> {
        let horizontal: Vec<_> =
            room.wall_segments.iter().filter(|s| (s.from[1] - s.to[1]).abs() < 1e-9).collect();
        anyhow::ensure!(
            !horizontal.is_empty(),
            "room `{}` has no horizontal wall segment to pass",
            room.name
        );
        let wall_y = horizontal[0].from[1];
        anyhow::ensure!(
            horizontal.iter().all(|s| (s.from[1] - wall_y).abs() < 1e-9),
            "room `{}`: the horizontal wall segments are not at one height",
            room.name
        );
        let goal = *route
            .goals
            .first()
            .ok_or_else(|| anyhow::anyhow!("route `{}` has no goal", route.name))?;
        let (s, g) = (route.start, goal);
        anyhow::ensure!(
            (s[1] - wall_y) * (g[1] - wall_y) < 0.0,
            "route `{}`: start and goal are on the same side of the wall",
            route.name
        );
        // Uncovered stretches of the wall line inside the square.
        let h = room.side / 2.0;
        let mut covered: Vec<[f64; 2]> =
            horizontal.iter().map(|s| [s.from[0].min(s.to[0]), s.from[0].max(s.to[0])]).collect();
        covered.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let mut openings = Vec::new();
        let mut x = -h;
        for c in covered {
            if c[0] > x {
                openings.push([x, c[0].min(h)]);
            }
            x = x.max(c[1]);
        }
        if x < h {
            openings.push([x, h]);
        }
        let t = (wall_y - s[1]) / (g[1] - s[1]);
        let cross = s[0] + t * (g[0] - s[0]);
        let gate = *openings.iter().find(|o| o[0] <= cross && cross <= o[1]).ok_or_else(|| {
            anyhow::anyhow!("route `{}`: the straight line to the goal meets the wall", route.name)
        })?;
        let left = openings.iter().filter(|o| o[1] <= gate[0]).copied().collect();
        Ok(GateGeometry { wall_y, gate, left, start_below: s[1] < wall_y })
    }

    /// Classifies a path (robot positions in order) by its first crossing of the wall line
    /// from the start's side.
    pub fn classify(&self, path: &[[f64; 2]]) -> GateRoute {
        let side =
            |p: &[f64; 2]| if self.start_below { p[1] - self.wall_y } else { self.wall_y - p[1] };
        for w in path.windows(2) {
            let (a, b) = (w[0], w[1]);
            let (da, db) = (side(&a), side(&b));
            if da < 0.0 && db >= 0.0 {
                let t = -da / (db - da);
                let x = a[0] + t * (b[0] - a[0]);
                return if self.gate[0] <= x && x <= self.gate[1] {
                    GateRoute::Gate
                } else if self.left.iter().any(|o| o[0] <= x && x <= o[1]) {
                    GateRoute::Left
                } else {
                    GateRoute::Other
                };
            }
        }
        GateRoute::Other
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_sim::Room;

    fn gate() -> GateGeometry {
        let room = Room::builtin("gate").unwrap();
        let route = room.spec().route("gate").unwrap().clone();
        GateGeometry::from_room(room.spec(), &route).unwrap()
    }

    #[test]
    fn reads_the_gate_rooms_geometry() {
        let g = gate();
        assert_eq!(g.wall_y, 0.0);
        assert_eq!(g.gate, [-0.275, 0.275]);
        assert_eq!(g.left, vec![[-3.0, -1.3]]);
    }

    #[test]
    fn classifies_synthetic_paths() {
        let g = gate();
        let line = |pts: &[[f64; 2]]| pts.to_vec();
        // Straight through the gate.
        let straight: Vec<[f64; 2]> = (0..=30).map(|k| [0.02, -1.5 + 0.1 * k as f64]).collect();
        assert_eq!(g.classify(&straight), GateRoute::Gate);
        // Around by the left path, crossing at x = −2.
        let left = line(&[[0.0, -1.5], [-2.0, -1.0], [-2.0, -0.05], [-2.0, 0.05], [0.0, 1.5]]);
        assert_eq!(g.classify(&left), GateRoute::Left);
        // Stuck below the wall (e.g. a collision at the gate).
        let stuck = line(&[[0.0, -1.5], [0.0, -0.6], [0.1, -0.45]]);
        assert_eq!(g.classify(&stuck), GateRoute::Other);
        // Crossing right of the gate can only happen through the wall: other.
        let right = line(&[[0.0, -1.5], [1.5, -0.5], [1.5, 0.5]]);
        assert_eq!(g.classify(&right), GateRoute::Other);
        // The first upward crossing decides: left, then back down and up through the gate.
        let both =
            line(&[[0.0, -1.5], [-2.0, -0.5], [-2.0, 0.5], [0.0, 0.5], [0.0, -0.5], [0.0, 1.5]]);
        assert_eq!(g.classify(&both), GateRoute::Left);
        assert_eq!(g.classify(&[]), GateRoute::Other);
        assert_eq!(g.classify(&[[0.0, 1.0]]), GateRoute::Other);
    }

    #[test]
    fn a_room_without_a_wall_across_is_refused() {
        let room = Room::builtin("env0").unwrap();
        let route = room.spec().route("eval").unwrap().clone();
        assert!(GateGeometry::from_room(room.spec(), &route).is_err());
    }
}
