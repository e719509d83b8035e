//! `dvnav transfer --out`: the paper's illustration of the dimension-scaled robot. The meta
//! robot (dashed), the varied robot (its outline, body parts and cargo parts), the scaled robot
//! that covers it, and the axle centre, the centre of scaling.

use super::room::draw_shape;
use super::room_map::outline;
use super::{Canvas, INK, Rgba, WHITE, WorldView, text};
use dvnav_nav::dvst::{MetaRobot, VariedRobot, covering_scale};
use dvnav_sim::{Footprint, ObstacleSpec};

/// The meta robot's dashed outline.
pub const META: Rgba = Rgba::hex(0x404040);
/// The varied robot: its outline, and its body parts (translucent).
pub const VARIED: Rgba = Rgba::hex(0x1f77b4);
/// Cargo: parts of the varied robot outside the meta robot.
pub const CARGO: Rgba = Rgba::hex(0xc07a3a);
/// The dimension-scaled robot.
pub const SCALED: Rgba = Rgba::hex(0x2ca02c);
/// Light axes through the axle centre.
const AXES: Rgba = Rgba::hex(0xd0d0d0);

/// Pixels around the drawing.
const MARGIN: u32 = 16;
/// Title height (two lines).
const TITLE: u32 = 44;
/// Legend height.
const LEGEND: u32 = 30;
/// Width (px) of the varied robot's outline, half of it outside the parts.
const OUTLINE: f32 = 5.0;

/// Whether `part` lies within the meta robot (then it is body, else cargo).
fn within(meta: &MetaRobot, part: &ObstacleSpec) -> bool {
    let one = Footprint { name: String::new(), parts: vec![part.clone()] };
    covering_scale(meta, &one, 0.0) <= 1.0 + 1e-9
}

/// The world square shown on a `size`-pixel panel whose top-left corner is (`left`, `top`):
/// everything drawn, with some room around it.
pub fn view_of(robot: &VariedRobot, left: f32, top: f32, size: u32) -> WorldView {
    let reach = robot
        .scaled_robot()
        .bounding_radius()
        .max(robot.meta.bounding_radius())
        .max(robot.footprint.bounding_radius() + robot.margin);
    WorldView { left, top, size: size as f32, center: [0.0, 0.0], side: 2.6 * reach }
}

/// A closed outline cut into dashes of `dash` pixels with gaps as long.
fn dashes(ring: &[(f32, f32)], dash: f32) -> Vec<Vec<(f32, f32)>> {
    let mut out = Vec::new();
    let mut current: Vec<(f32, f32)> = Vec::new();
    let mut s = 0.0f32;
    let n = ring.len();
    for i in 0..n {
        let (a, b) = (ring[i], ring[(i + 1) % n]);
        let len = (b.0 - a.0).hypot(b.1 - a.1);
        let steps = (len / 1.0).ceil().max(1.0) as usize;
        for k in 0..steps {
            let t = k as f32 / steps as f32;
            let p = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
            if ((s / dash) as usize).is_multiple_of(2) {
                current.push(p);
            } else if !current.is_empty() {
                current.push(p);
                out.push(std::mem::take(&mut current));
            }
            s += len / steps as f32;
        }
    }
    if current.len() > 1 {
        out.push(current);
    }
    out
}

/// Draws `robot`'s DVST illustration on a `size`-pixel square panel with a title and a legend.
pub fn render_dvst(robot: &VariedRobot, size: u32) -> anyhow::Result<Canvas> {
    let mu = robot.mu();
    let dsr = robot.scaled_robot();
    let name = if robot.footprint.name.is_empty() { "varied robot" } else { &robot.footprint.name };
    let title = format!("{name}   mu = {mu:.3}");
    let sub = match dsr {
        MetaRobot::Circle { radius } => format!("scaled robot: r = {radius:.3} m"),
        MetaRobot::Rectangle { front, back, left, right } => format!(
            "scaled robot: front {front:.3}, back {back:.3}, left {left:.3}, right {right:.3} m"
        ),
    };
    let sub = format!("{sub}; margin {:.3} m", robot.margin);
    let legend = [
        (META, "meta robot (MR)"),
        (CARGO, "cargo"),
        (VARIED, "varied robot (DVR)"),
        (SCALED, "scaled robot (DSR)"),
        (INK, "axle centre"),
    ];
    let legend_px: f32 = legend.iter().map(|(_, l)| 30.0 + text::width(l, 1)).sum();
    // As wide as the panel, or as the title, subtitle and legend if they are wider.
    let text_px = legend_px.max(text::width(&title, 2)).max(text::width(&sub, 1)).ceil() as u32;
    let (w, h) = (size.max(text_px) + 2 * MARGIN, size + TITLE + LEGEND + 2 * MARGIN);
    let mut canvas = Canvas::new(w, h, WHITE)?;
    canvas.text(MARGIN as f32, MARGIN as f32, &title, 2, INK);
    canvas.text(MARGIN as f32, (MARGIN + 22) as f32, &sub, 1, INK);
    // The panel is centred when the text is wider.
    let left = 0.5 * (w - size) as f32;
    let view = view_of(robot, left, (MARGIN + TITLE) as f32, size);

    let half = 0.5 * view.side;
    canvas.stroke_polyline(&[view.px([-half, 0.0]), view.px([half, 0.0])], false, 1.0, AXES);
    canvas.stroke_polyline(&[view.px([0.0, -half]), view.px([0.0, half])], false, 1.0, AXES);
    let (ax, ay) = view.px([half, 0.0]);
    canvas.text(ax - text::width("x ahead", 1) - 4.0, ay - 12.0, "x ahead", 1, META);

    // The scaled robot: a light fill now, its outline last (on top).
    draw_shape(&mut canvas, &view, &dsr.to_part(), SCALED.alpha(40));

    // The varied robot: every part's outline stroked wide, then the parts filled over it, so
    // only the outer half of the outline shows: the outline of the union.
    for part in &robot.footprint.parts {
        for ring in outline(&view, part) {
            canvas.stroke_polyline(&ring, true, OUTLINE, VARIED);
        }
    }
    for part in &robot.footprint.parts {
        let fill = if within(&robot.meta, part) { VARIED.alpha(90) } else { CARGO };
        draw_shape(&mut canvas, &view, part, WHITE);
        draw_shape(&mut canvas, &view, part, fill);
    }

    for ring in outline(&view, &robot.meta.to_part()) {
        for dash in dashes(&ring, 6.0) {
            canvas.stroke_polyline(&dash, false, 2.0, META);
        }
    }
    for ring in outline(&view, &dsr.to_part()) {
        canvas.stroke_polyline(&ring, true, 2.5, SCALED);
    }
    let (x, y) = view.px([0.0, 0.0]);
    canvas.fill_circle(x, y, 4.5, INK);

    // Legend.
    let mut lx = MARGIN as f32;
    let ly = (MARGIN + TITLE + size + 10) as f32;
    for (color, label) in legend {
        canvas.fill_rect(lx, ly, 12.0, 12.0, color);
        lx += 16.0;
        lx += canvas.text(lx, ly + 2.0, label, 1, INK) + 14.0;
    }
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_robot_cargo_meta_robot_and_axle_land_where_they_are() {
        // The 0.2 m meta robot with a 0.2 m square of cargo behind it: μ = 2.5.
        let cargo = ObstacleSpec::Box { center: [-0.4, 0.0], half_extents: [0.1, 0.1], angle: 0.0 };
        let mut robot = VariedRobot::new(Footprint::circle(0.2).with_cargo([cargo]));
        robot.footprint.name = "test".into();
        let mu = robot.mu();
        assert!((mu - 0.5f64.hypot(0.1) / 0.2).abs() < 1e-12);
        let c = render_dvst(&robot, 400).unwrap();
        let left = 0.5 * (c.width() - 400) as f32;
        let view = view_of(&robot, left, (MARGIN + TITLE) as f32, 400);
        let at = |p: [f64; 2]| {
            let (x, y) = view.px(p);
            c.pixel(x as u32, y as u32).unwrap()
        };
        let r_s = 0.2 * mu;
        // Off the axes, up and to the right, where only the scaled robot reaches.
        let diag = |d: f64| [d * 0.6, d * 0.8];
        assert_eq!(at([0.0, 0.0]), INK, "axle centre");
        assert_eq!(at([-0.4, 0.0]), CARGO, "inside the cargo");
        assert_eq!(at([0.0, r_s]), SCALED, "on the scaled robot's outline");
        assert_ne!(at(diag(0.6 * r_s)), WHITE, "inside the scaled robot: tinted");
        assert_eq!(at(diag(1.15 * r_s)), WHITE, "outside the scaled robot");
        // The meta robot's outline is dashed: some points on it are its colour, some not.
        let on_meta: Vec<Rgba> = (0..72)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 72.0 + 0.3;
                at([0.2 * a.cos(), 0.2 * a.sin()])
            })
            .collect();
        let near = |a: Rgba, b: Rgba| {
            (a.0 as i32 - b.0 as i32).abs()
                + (a.1 as i32 - b.1 as i32).abs()
                + (a.2 as i32 - b.2 as i32).abs()
                < 60
        };
        let dark = on_meta.iter().filter(|&&p| near(p, META)).count();
        assert!((12..=60).contains(&dark), "dashes and gaps: {dark} of 72 samples dark");
        // The varied robot's outline, just outside the cargo's upper edge.
        let edge = at([-0.4, 0.1 + 1.0 / f64::from(view.scale())]);
        assert_eq!(edge, VARIED, "outline outside the cargo");
        assert!(c.encode_png().unwrap().starts_with(b"\x89PNG"));
        // A small drawing still has room for its legend.
        let small = render_dvst(&robot, 100).unwrap();
        assert!(small.width() >= 2 * MARGIN + 450, "{}", small.width());
    }
}
