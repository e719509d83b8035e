//! `dvnav rooms show`: one room as a map: walls, obstacles, obstacles that appear later (with
//! the step they appear at), spawn regions, evaluation routes with numbered goals, and a robot
//! footprint at the first route's start.

use super::room::{draw_room, draw_shape};
use super::{Canvas, INK, Rgba, WHITE, WorldView, text};
use dvnav_sim::{Footprint, ObstacleSpec, Pose2, RoomSpec};

/// Spawn-region fill and outline.
pub const SPAWN: Rgba = Rgba::hex(0x3b7dd8);
/// Timed obstacles (translucent until they appear).
pub const TIMED: Rgba = Rgba::hex(0xd62728);
/// Route lines and goal markers.
pub const ROUTE: Rgba = Rgba::hex(0x2ca02c);
/// The robot footprint.
pub const ROBOT: Rgba = Rgba::hex(0x1f3fbf);

/// Pixels around the map.
const MARGIN: u32 = 16;
/// Title height.
const TITLE: u32 = 40;
/// Legend height.
const LEGEND: u32 = 30;

/// Outline (`closed` polyline) of each convex part of a shape, as pixels; circles are
/// sampled.
pub fn outline(view: &WorldView, shape: &ObstacleSpec) -> Vec<Vec<(f32, f32)>> {
    let mut out = Vec::new();
    shape.for_each_primitive(&mut |p| {
        let pts = match p {
            ObstacleSpec::Circle { center, radius } => (0..48)
                .map(|k| {
                    let a = std::f64::consts::TAU * k as f64 / 48.0;
                    view.px([center[0] + radius * a.cos(), center[1] + radius * a.sin()])
                })
                .collect(),
            other => other.vertices().unwrap_or_default().iter().map(|&v| view.px(v)).collect(),
        };
        out.push(pts);
    });
    out
}

/// Draws `spec` on a `size`-pixel square map with a title and a legend; `footprint` is drawn
/// at the start of the room's first route (at the origin without routes).
pub fn render_room(
    spec: &RoomSpec,
    footprint: Option<&Footprint>,
    size: u32,
) -> anyhow::Result<Canvas> {
    let (w, h) = (size + 2 * MARGIN, size + TITLE + LEGEND + 2 * MARGIN);
    let mut canvas = Canvas::new(w, h, WHITE)?;
    let title = format!("{}  {} x {} m", spec.name, spec.side, spec.side);
    canvas.text(MARGIN as f32, MARGIN as f32, &title, 2, INK);
    if !spec.description.is_empty() {
        canvas.text(MARGIN as f32, (MARGIN + 20) as f32, &spec.description, 1, INK);
    }
    let view = WorldView {
        left: MARGIN as f32,
        top: (MARGIN + TITLE) as f32,
        size: size as f32,
        center: [0.0, 0.0],
        side: spec.side + 2.0 * spec.wall_thickness + 0.3,
    };
    draw_room(&mut canvas, &view, spec);

    for r in &spec.spawn_regions {
        let pts: Vec<_> = [r.min, [r.max[0], r.min[1]], r.max, [r.min[0], r.max[1]]]
            .iter()
            .map(|&p| view.px(p))
            .collect();
        canvas.fill_polygon(&pts, SPAWN.alpha(40));
        canvas.stroke_polyline(&pts, true, 1.5, SPAWN);
        let role = match (r.starts, r.goals) {
            (true, true) => "",
            (true, false) => " (starts)",
            _ => " (goals)",
        };
        canvas.text(pts[3].0 + 3.0, pts[3].1 + 3.0, &format!("{}{role}", r.name), 1, SPAWN);
    }

    for t in &spec.timed_obstacles {
        draw_shape(&mut canvas, &view, &t.obstacle, TIMED.alpha(70));
        for ring in outline(&view, &t.obstacle) {
            canvas.stroke_polyline(&ring, true, 1.5, TIMED);
        }
        let (x, y) = view.px(t.obstacle.anchor());
        let label = format!("t{}", t.at_step);
        canvas.text(x - text::width(&label, 1) / 2.0, y - 4.0, &label, 1, TIMED);
    }

    let scale = view.scale();
    for route in &spec.routes {
        let mut pts = vec![view.px(route.start)];
        pts.extend(route.goals.iter().map(|&g| view.px(g)));
        canvas.stroke_polyline(&pts, false, 2.0, ROUTE.alpha(170));
        // Start: a disc with a heading tick.
        let (sx, sy) = pts[0];
        let yaw = route.heading_deg.to_radians();
        canvas.fill_circle(sx, sy, 5.0, ROUTE);
        let tip = view.px([route.start[0] + 0.35 * yaw.cos(), route.start[1] + 0.35 * yaw.sin()]);
        canvas.stroke_polyline(&[(sx, sy), tip], false, 2.5, ROUTE);
        for (k, &(gx, gy)) in pts[1..].iter().enumerate() {
            let r = (0.2 * scale).max(8.0);
            canvas.fill_circle(gx, gy, r, ROUTE);
            let n = (k + 1).to_string();
            let s = if r >= 12.0 { 2 } else { 1 };
            let tw = text::width(&n, s);
            canvas.text(gx - tw / 2.0, gy - 4.0 * s as f32, &n, s, WHITE);
        }
        canvas.text(sx + 8.0, sy + 6.0, &route.name, 1, ROUTE);
    }

    if let Some(fp) = footprint {
        let pose = spec.routes.first().map_or(Pose2::default(), |r| r.start_pose());
        for part in fp.at(pose) {
            draw_shape(&mut canvas, &view, &part, ROBOT.alpha(110));
            for ring in outline(&view, &part) {
                canvas.stroke_polyline(&ring, true, 1.5, ROBOT);
            }
        }
        let (x, y) = view.px(pose.position());
        canvas.fill_circle(x, y, 2.5, INK);
    }

    // Legend.
    let mut x = MARGIN as f32;
    let y = (MARGIN + TITLE + size + 10) as f32;
    let items: Vec<(Rgba, &str)> = vec![
        (super::room::OBSTACLE, "obstacle"),
        (super::room::WALL, "wall"),
        (TIMED, "appears at step tN"),
        (SPAWN, "spawn region"),
        (ROUTE, "route: start, goals 1..n"),
        (ROBOT, "footprint"),
    ];
    for (color, label) in items {
        canvas.fill_rect(x, y, 12.0, 12.0, color);
        x += 16.0;
        x += canvas.text(x, y + 2.0, label, 1, INK) + 14.0;
    }
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::room::FLOOR;
    use dvnav_sim::{Route, SpawnRegion, TimedObstacle};

    #[test]
    fn regions_routes_timed_obstacles_and_footprint_land_where_they_are() {
        let spec = RoomSpec {
            spawn_regions: vec![SpawnRegion {
                name: "s".into(),
                min: [-3.0, -3.0],
                max: [-2.0, -2.0],
                starts: true,
                goals: true,
            }],
            routes: vec![Route {
                name: "r".into(),
                start: [0.0, -2.0],
                heading_deg: 90.0,
                goals: vec![[2.5, 2.5]],
            }],
            timed_obstacles: vec![TimedObstacle {
                at_step: 3,
                obstacle: ObstacleSpec::Circle { center: [-2.0, 2.0], radius: 0.6 },
            }],
            ..RoomSpec::empty("t", 8.0)
        };
        let fp = Footprint::rectangle(1.0, 0.6);
        let c = render_room(&spec, Some(&fp), 400).unwrap();
        let view = WorldView {
            left: MARGIN as f32,
            top: (MARGIN + TITLE) as f32,
            size: 400.0,
            center: [0.0, 0.0],
            side: 8.0 + 0.4 + 0.3,
        };
        let at = |p: [f64; 2]| {
            let (x, y) = view.px(p);
            c.pixel(x as u32, y as u32).unwrap()
        };
        let near = |a: Rgba, b: Rgba| {
            (a.0 as i32 - b.0 as i32).abs()
                + (a.1 as i32 - b.1 as i32).abs()
                + (a.2 as i32 - b.2 as i32).abs()
                < 90
        };
        assert_eq!(at([1.0, 1.0]), FLOOR);
        assert!(near(at([2.5, 2.5 + 0.15]), ROUTE), "goal marker: {:?}", at([2.5, 2.65]));
        assert!(at([-2.6, -2.6]) != FLOOR, "spawn region tinted");
        assert!(at([-2.3, 2.3]) != FLOOR, "timed obstacle drawn");
        // The 1 m x 0.6 m robot at (0, −2) facing +y: its long side is vertical.
        assert!(at([0.0, -1.6]) != FLOOR && at([0.25, -2.2]) != FLOOR);
        assert_eq!(at([0.45, -2.0]), FLOOR, "beyond the robot's half width");
        assert!(c.encode_png().unwrap().starts_with(b"\x89PNG"));
    }
}
