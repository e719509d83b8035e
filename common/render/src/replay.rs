//! `dvnav replay --figure`: a replayed bag in the odometry frame: every scan's returns (light,
//! where the sensor saw them from the pose of the time), the robot's path coloured by the
//! commanded speed, where the controller's commands alone would have taken it (open loop from
//! the start), the start, the goal with its tolerance, where it arrived, a scale bar and the
//! frame's extent; below, the commanded and the recorded ω over time. A robot that followed
//! its planner's paths also shows each path (thin, the latest darker) and the subgoals.

use super::{Canvas, INK, Rgba, WHITE, WorldView, text};

/// What the figure shows, in the odometry frame (m).
#[derive(Clone, Debug, Default)]
pub struct ReplayFigure {
    /// The robot's position at each scan and the speed commanded there (m/s).
    pub path: Vec<([f64; 2], f64)>,
    /// Every scan's valid returns.
    pub returns: Vec<[f64; 2]>,
    pub goal: [f64; 2],
    /// The goal tolerance (m).
    pub tolerance: f64,
    /// When (s) and where the robot first arrived.
    pub arrived: Option<(f64, [f64; 2])>,
    /// The replay's length (s).
    pub duration_s: f64,
    /// Where the controller's commands would have taken the robot from the start (open loop).
    pub commanded_path: Vec<[f64; 2]>,
    /// At each scan: its time (s), the commanded ω and the recorded (odometry) ω (rad/s).
    pub omega: Vec<(f64, f64, f64)>,
    /// The planner's paths the robot followed, in order; empty without a route.
    pub plans: Vec<Vec<[f64; 2]>>,
    /// The subgoal the controller gave at each scan on a route.
    pub subgoals: Vec<[f64; 2]>,
}

const MARGIN: f32 = 16.0;
const TITLE: f32 = 28.0;
const RETURN: Rgba = Rgba::hex(0x9aa5b1);
const START: Rgba = Rgba::hex(0x2b6cb0);
const GOAL: Rgba = Rgba::hex(0x2f855a);
const COMMANDED: Rgba = Rgba::hex(0x6b46c1);
const RECORDED: Rgba = Rgba::hex(0xa0aec0);
const PLAN: Rgba = Rgba::hex(0x0987a0);
const SUBGOAL: Rgba = Rgba::hex(0xd69e2e);
/// Height (px) of the ω strip below the map, and of the lines of text under it.
const STRIP: f32 = 90.0;
const CAPTION: f32 = 22.0;

/// The figure, `size` pixels square for the map.
pub fn render(fig: &ReplayFigure, size: u32) -> anyhow::Result<Canvas> {
    anyhow::ensure!(!fig.path.is_empty(), "nothing to draw");
    // Frame the path and the goal, with 3 m around them: scans reach far, the path matters.
    let (mut lo, mut hi) = (fig.goal, fig.goal);
    for (p, _) in &fig.path {
        for i in 0..2 {
            lo[i] = lo[i].min(p[i]);
            hi[i] = hi[i].max(p[i]);
        }
    }
    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]) + 6.0;
    let center = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let view = WorldView { left: MARGIN, top: TITLE + MARGIN, size: size as f32, center, side };
    let extra = if fig.omega.is_empty() { CAPTION } else { CAPTION + STRIP + CAPTION };
    let (w, h) = (size + 2 * MARGIN as u32, size + (TITLE + 2.0 * MARGIN + extra) as u32);
    let mut canvas = Canvas::new(w, h, WHITE)?;
    let inside = |(x, y): (f32, f32)| {
        (view.left..view.left + view.size).contains(&x)
            && (view.top..view.top + view.size).contains(&y)
    };
    for p in fig.returns.iter().map(|&p| view.px(p)).filter(|&p| inside(p)) {
        canvas.fill_rect(p.0 - 0.5, p.1 - 0.5, 1.5, 1.5, RETURN.alpha(90));
    }
    for (i, plan) in fig.plans.iter().enumerate().filter(|(_, p)| p.len() > 1) {
        let pts: Vec<(f32, f32)> = plan.iter().map(|&p| view.px(p)).collect();
        let latest = i + 1 == fig.plans.len();
        canvas.stroke_polyline(&pts, false, 1.5, PLAN.alpha(if latest { 230 } else { 90 }));
    }
    for p in fig.subgoals.iter().map(|&p| view.px(p)).filter(|&p| inside(p)) {
        canvas.fill_circle(p.0, p.1, 2.5, SUBGOAL.alpha(200));
    }
    // The path, each step coloured by the commanded speed: red stopped, green at the fastest.
    let v_max = fig.path.iter().map(|(_, v)| v.abs()).fold(1e-9, f64::max);
    for w in fig.path.windows(2) {
        let t = (w[1].1.abs() / v_max) as f32;
        let color = Rgba((220.0 * (1.0 - t)) as u8, (160.0 * t) as u8, 60, 255);
        canvas.stroke_polyline(&[view.px(w[0].0), view.px(w[1].0)], false, 3.0, color);
    }
    if fig.commanded_path.len() > 1 {
        let pts: Vec<(f32, f32)> = fig.commanded_path.iter().map(|&p| view.px(p)).collect();
        canvas.stroke_polyline(&pts, false, 1.5, COMMANDED.alpha(200));
    }
    let (sx, sy) = view.px(fig.path[0].0);
    canvas.fill_circle(sx, sy, 6.0, START);
    let (gx, gy) = view.px(fig.goal);
    canvas.stroke_circle(gx, gy, (fig.tolerance as f32 * view.scale()).max(6.0), 2.0, GOAL);
    canvas.fill_circle(gx, gy, 4.0, GOAL);
    if let Some((_, p)) = fig.arrived {
        let (ax, ay) = view.px(p);
        canvas.stroke_circle(ax, ay, 8.0, 2.0, INK);
    }
    let title = format!(
        "{} scans, {:.1} s; start blue, goal green; {}",
        fig.path.len(),
        fig.duration_s,
        match fig.arrived {
            Some((t, _)) => format!("arrived at {t:.1} s"),
            None => "not arrived".into(),
        }
    );
    text::draw(&mut canvas, MARGIN, MARGIN, &title, 2, INK);
    draw_frame(&mut canvas, &view);
    let below = view.top + view.size + 6.0;
    let caption = format!(
        "x {:.1} .. {:.1} m, y {:.1} .. {:.1} m (odometry frame); purple: the commands, open \
         loop{}",
        center[0] - side / 2.0,
        center[0] + side / 2.0,
        center[1] - side / 2.0,
        center[1] + side / 2.0,
        if fig.plans.is_empty() { "" } else { "; teal: the planner's paths; yellow: subgoals" }
    );
    text::draw(&mut canvas, MARGIN, below, &caption, 1, INK);
    if !fig.omega.is_empty() {
        draw_omega(&mut canvas, &fig.omega, fig.duration_s, MARGIN, below + CAPTION, size as f32);
    }
    Ok(canvas)
}

/// A border round the map and a scale bar (a round length near a quarter of the view) in its
/// lower-left corner.
fn draw_frame(canvas: &mut Canvas, view: &WorldView) {
    let (l, t, s) = (view.left, view.top, view.size);
    canvas.stroke_polyline(&[(l, t), (l + s, t), (l + s, t + s), (l, t + s)], true, 1.0, INK);
    let bar = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
        .into_iter()
        .rfind(|&m| m <= view.side / 4.0)
        .unwrap_or(0.5);
    let px = bar as f32 * view.scale();
    let (x0, y0) = (l + 10.0, t + s - 12.0);
    canvas.stroke_polyline(&[(x0, y0), (x0 + px, y0)], false, 2.0, INK);
    canvas.stroke_polyline(&[(x0, y0 - 4.0), (x0, y0 + 4.0)], false, 2.0, INK);
    canvas.stroke_polyline(&[(x0 + px, y0 - 4.0), (x0 + px, y0 + 4.0)], false, 2.0, INK);
    text::draw(canvas, x0, y0 - 14.0, &format!("{bar} m"), 1, INK);
}

/// ω over time: the commanded (purple) and the recorded (grey), with the zero line and the
/// extent written beside.
fn draw_omega(
    canvas: &mut Canvas,
    omega: &[(f64, f64, f64)],
    duration_s: f64,
    left: f32,
    top: f32,
    width: f32,
) {
    let max = omega.iter().map(|&(_, c, r)| c.abs().max(r.abs())).fold(1e-6, f64::max);
    let t_max = duration_s.max(1e-6);
    let at = |t: f64, w: f64| {
        (left + (t / t_max) as f32 * width, top + STRIP / 2.0 - (w / max) as f32 * STRIP / 2.0)
    };
    let frame =
        [(left, top), (left + width, top), (left + width, top + STRIP), (left, top + STRIP)];
    canvas.stroke_polyline(&frame, true, 1.0, INK);
    canvas.stroke_polyline(&[at(0.0, 0.0), at(t_max, 0.0)], false, 1.0, RECORDED);
    let recorded: Vec<(f32, f32)> = omega.iter().map(|&(t, _, r)| at(t, r)).collect();
    canvas.stroke_polyline(&recorded, false, 1.5, RECORDED);
    let commanded: Vec<(f32, f32)> = omega.iter().map(|&(t, c, _)| at(t, c)).collect();
    canvas.stroke_polyline(&commanded, false, 1.5, COMMANDED);
    let label = format!(
        "omega (rad/s), +-{max:.2}, over {duration_s:.1} s: purple commanded, grey recorded"
    );
    text::draw(canvas, left, top + STRIP + 6.0, &label, 1, INK);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_path_returns_and_goal_land_where_they_are() {
        let fig = ReplayFigure {
            path: vec![([0.0, 0.0], 0.5), ([1.0, 0.0], 0.5), ([2.0, 0.0], 0.0)],
            returns: vec![[1.0, 1.0], [1.0, -1.0]],
            goal: [2.0, 0.0],
            tolerance: 0.2,
            arrived: Some((2.0, [2.0, 0.0])),
            duration_s: 2.0,
            commanded_path: vec![[0.0, 0.0], [0.0, 1.5]],
            omega: vec![(0.0, 0.5, 0.0), (1.0, -0.5, 0.1), (2.0, 0.0, 0.0)],
            plans: vec![vec![[1.0, -1.0], [2.0, -1.0]]],
            subgoals: vec![[0.5, -2.0]],
        };
        let c = render(&fig, 200).unwrap();
        let view = WorldView {
            left: MARGIN,
            top: TITLE + MARGIN,
            size: 200.0,
            center: [1.0, 0.0],
            side: 8.0,
        };
        let at = |p: [f64; 2]| {
            let (x, y) = view.px(p);
            c.pixel(x as u32, y as u32).unwrap()
        };
        assert_eq!(at([0.0, 0.0]), START);
        assert_ne!(at([0.5, 0.0]), WHITE, "the path");
        assert_ne!(at([1.5, -1.0]), WHITE, "the plan");
        assert_ne!(at([0.5, -2.0]), WHITE, "the subgoal");
        assert_eq!(at([1.0, -2.0]), WHITE, "nothing else there");
        assert_ne!(at([1.0, 1.0]), WHITE, "a return");
        assert_eq!(at([0.5, 2.0]), WHITE, "nothing there");
        assert_eq!(at([2.0, 0.0]), GOAL);
        assert_ne!(at([0.0, 1.0]), WHITE, "the commanded path");
        // The ω strip and its caption below the map.
        assert!(c.height() as f32 >= TITLE + MARGIN + 200.0 + CAPTION + STRIP);
        assert!(render(&ReplayFigure::default(), 200).is_err());
    }
}
