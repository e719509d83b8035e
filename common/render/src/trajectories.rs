//! `dvnav plot trajectories`: the selected episodes' paths over their rooms, one panel per
//! room, coloured by outcome.

use super::room::draw_room;
use super::{Canvas, INK, Rgba, WHITE, WorldView, text};
use dvnav_sim::Outcome;
use dvnav_sim::RoomSpec;

/// Path colour of successful episodes.
pub const SUCCESS: Rgba = Rgba::hex(0x2ca02c);
/// Path colour of episodes that ended in a collision.
pub const COLLISION: Rgba = Rgba::hex(0xd62728);
/// Path colour of episodes that timed out.
pub const TIMEOUT: Rgba = Rgba::hex(0xff7f0e);
/// Path colour of episodes without an outcome.
pub const UNKNOWN: Rgba = Rgba::hex(0x7f7f7f);

/// Pixels between panels and around the figure.
const MARGIN: u32 = 16;
/// Height of a panel's title line.
const TITLE: u32 = 28;
/// Height of the legend under the panels (two lines).
const LEGEND: u32 = 52;
/// Panels per row.
const COLUMNS: usize = 2;
/// Path width (px).
const PATH_WIDTH: f32 = 2.0;
/// Planned paths: a thin blue-grey line.
const PLAN: Rgba = Rgba::hex(0x5b7fa6);

/// The colour of an outcome's paths.
pub fn outcome_color(o: Option<Outcome>) -> Rgba {
    match o {
        Some(Outcome::Success) => SUCCESS,
        Some(Outcome::Collision) => COLLISION,
        Some(Outcome::Timeout) => TIMEOUT,
        None => UNKNOWN,
    }
}

/// One episode's path.
#[derive(Clone, Debug)]
pub struct Trajectory {
    /// Robot positions, step by step (m, world frame).
    pub points: Vec<[f64; 2]>,
    /// How it ended.
    pub outcome: Option<Outcome>,
    /// Its goal (m, world frame).
    pub goal: [f64; 2],
    /// Radius of the robot's footprint (m), drawn at the end of a collision.
    pub radius: Option<f64>,
    /// The path planned for it (m, world frame), drawn thin beneath the driven path; empty
    /// for a mapless episode.
    pub plan: Vec<[f64; 2]>,
}

/// The episodes of one room.
#[derive(Clone, Debug)]
pub struct RoomPanel {
    /// Room name as logged.
    pub name: String,
    /// The room's walls and obstacles, when the name is a known room.
    pub room: Option<RoomSpec>,
    /// Its episodes' paths.
    pub trajectories: Vec<Trajectory>,
}

impl RoomPanel {
    /// The world square the panel shows: the room with its walls, or the paths' bounding box.
    fn view(&self, left: f32, top: f32, size: f32) -> WorldView {
        let (center, side) = match &self.room {
            Some(r) => ([0.0, 0.0], r.side + 2.0 * r.wall_thickness + 0.2),
            None => {
                let pts = self.trajectories.iter().flat_map(|t| t.points.iter().chain([&t.goal]));
                let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
                for p in pts {
                    for i in 0..2 {
                        lo[i] = lo[i].min(p[i]);
                        hi[i] = hi[i].max(p[i]);
                    }
                }
                if lo[0] > hi[0] {
                    ([0.0, 0.0], 1.0)
                } else {
                    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(0.5) * 1.1;
                    ([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0], side)
                }
            }
        };
        WorldView { left, top, size, center, side }
    }

    fn count(&self, o: Option<Outcome>) -> usize {
        self.trajectories.iter().filter(|t| t.outcome == o).count()
    }
}

/// Draws `panels` (each `panel_px` square, two per row) with titles and a legend.
pub fn render(panels: &[RoomPanel], panel_px: u32) -> anyhow::Result<Canvas> {
    anyhow::ensure!(!panels.is_empty(), "no episodes to draw");
    anyhow::ensure!(
        (64..=4096).contains(&panel_px),
        "panel size {panel_px} px is not in 64..=4096"
    );
    let cols = panels.len().min(COLUMNS) as u32;
    let rows = panels.len().div_ceil(COLUMNS) as u32;
    let cell_w = panel_px + MARGIN;
    let cell_h = TITLE + panel_px + MARGIN;
    let width = MARGIN + cols * cell_w;
    let height = MARGIN + rows * cell_h + LEGEND;
    let mut canvas = Canvas::new(width, height, WHITE)?;
    for (i, panel) in panels.iter().enumerate() {
        let (col, row) = ((i % COLUMNS) as u32, (i / COLUMNS) as u32);
        let left = (MARGIN + col * cell_w) as f32;
        let top = (MARGIN + row * cell_h) as f32;
        draw_panel(&mut canvas, panel, left, top, panel_px as f32);
    }
    draw_legend(&mut canvas, panels, (height - LEGEND + 8) as f32);
    Ok(canvas)
}

fn draw_panel(canvas: &mut Canvas, panel: &RoomPanel, left: f32, top: f32, size: f32) {
    let side =
        panel.room.as_ref().map_or(String::new(), |r| format!(" {:.0}x{:.0} m", r.side, r.side));
    let title = format!(
        "{}{side}: {} episodes ({} ok, {} hit, {} timeout)",
        panel.name,
        panel.trajectories.len(),
        panel.count(Some(Outcome::Success)),
        panel.count(Some(Outcome::Collision)),
        panel.count(Some(Outcome::Timeout)),
    );
    // Shrink the title to the panel's width.
    let scale = if text::width(&title, 2) <= size { 2 } else { 1 };
    canvas.text(left, top + 4.0, &title, scale, INK);
    let top = top + TITLE as f32;
    let view = panel.view(left, top, size);
    match &panel.room {
        Some(room) => draw_room(canvas, &view, room),
        None => {
            let frame =
                [(left, top), (left + size, top), (left + size, top + size), (left, top + size)];
            canvas.stroke_polyline(&frame, true, 1.0, INK);
            canvas.text(left + 6.0, top + 6.0, "room unknown", 1, INK);
        }
    }
    // Planned paths beneath everything driven.
    for t in panel.trajectories.iter().filter(|t| t.plan.len() > 1) {
        let pts: Vec<(f32, f32)> = t.plan.iter().map(|&p| view.px(p)).collect();
        canvas.stroke_polyline(&pts, false, 1.0, PLAN);
    }
    // Timeouts first, successes last: the outcome that matters most stays on top.
    let order = [None, Some(Outcome::Timeout), Some(Outcome::Collision), Some(Outcome::Success)];
    for outcome in order {
        let color = outcome_color(outcome);
        for t in panel.trajectories.iter().filter(|t| t.outcome == outcome) {
            let pts: Vec<(f32, f32)> = t.points.iter().map(|&p| view.px(p)).collect();
            canvas.stroke_polyline(&pts, false, PATH_WIDTH, color.alpha(210));
            let (gx, gy) = view.px(t.goal);
            canvas.stroke_polyline(
                &[(gx - 5.0, gy - 5.0), (gx + 5.0, gy + 5.0)],
                false,
                2.0,
                color,
            );
            canvas.stroke_polyline(
                &[(gx - 5.0, gy + 5.0), (gx + 5.0, gy - 5.0)],
                false,
                2.0,
                color,
            );
            if let (Some(&(sx, sy)), Some(&(ex, ey))) = (pts.first(), pts.last()) {
                canvas.stroke_circle(sx, sy, 4.0, 1.5, INK);
                canvas.fill_circle(ex, ey, 3.5, color);
                // Where it touched: the footprint at the last pose.
                if let (Some(Outcome::Collision), Some(r)) = (outcome, t.radius) {
                    canvas.stroke_circle(ex, ey, r as f32 * view.scale(), 1.0, color);
                }
            }
        }
    }
}

fn draw_legend(canvas: &mut Canvas, panels: &[RoomPanel], y: f32) {
    let total = |o| panels.iter().map(|p| p.count(o)).sum::<usize>();
    let entries = [
        (Some(Outcome::Success), format!("success ({})", total(Some(Outcome::Success)))),
        (Some(Outcome::Collision), format!("collision ({})", total(Some(Outcome::Collision)))),
        (Some(Outcome::Timeout), format!("timeout ({})", total(Some(Outcome::Timeout)))),
    ];
    let markers = ["start", "goal", "end", "footprint at a collision"];
    // Two lines (outcomes, then markers); text at scale 2 when both fit, else at scale 1.
    let line1 = |scale| entries.iter().map(|(_, t)| 50.0 + text::width(t, scale)).sum::<f32>();
    let line2 = |scale| markers.iter().map(|t| 36.0 + text::width(t, scale)).sum::<f32>();
    let avail = canvas.width() as f32 - 2.0 * MARGIN as f32;
    let scale = if line1(2).max(line2(2)) <= avail { 2 } else { 1 };
    let line_h = 8.0 * scale as f32 + 6.0;
    let mut x = MARGIN as f32;
    let mid = y + 4.0 * scale as f32;
    for (o, label) in &entries {
        let color = outcome_color(*o);
        canvas.stroke_polyline(&[(x, mid), (x + 24.0, mid)], false, 3.0, color);
        x += 30.0;
        x += canvas.text(x, y, label, scale, INK) + 20.0;
    }
    let (y, mid) = (y + line_h, mid + line_h);
    let mut x = MARGIN as f32;
    for (i, label) in markers.iter().enumerate() {
        let cx = x + 8.0;
        match i {
            0 => canvas.stroke_circle(cx, mid, 4.0, 1.5, INK),
            1 => {
                canvas.stroke_polyline(
                    &[(cx - 5.0, mid - 5.0), (cx + 5.0, mid + 5.0)],
                    false,
                    2.0,
                    INK,
                );
                canvas.stroke_polyline(
                    &[(cx - 5.0, mid + 5.0), (cx + 5.0, mid - 5.0)],
                    false,
                    2.0,
                    INK,
                );
            }
            2 => canvas.fill_circle(cx, mid, 3.5, INK),
            _ => canvas.stroke_circle(cx, mid, 7.0, 1.0, COLLISION),
        }
        x += 20.0;
        x += canvas.text(x, y, label, scale, INK) + 16.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::room::FLOOR;

    fn room() -> RoomSpec {
        RoomSpec::empty("t", 8.0)
    }

    fn panel(trajectories: Vec<Trajectory>) -> RoomPanel {
        RoomPanel { name: "t".into(), room: Some(room()), trajectories }
    }

    fn straight(y: f64, outcome: Option<Outcome>) -> Trajectory {
        Trajectory {
            points: (0..=30).map(|k| [-3.0 + 0.2 * f64::from(k), y]).collect(),
            outcome,
            goal: [3.5, y],
            radius: Some(0.2),
            plan: Vec::new(),
        }
    }

    /// The pixel at world point `p` of the first panel.
    fn at(c: &Canvas, panels: &[RoomPanel], p: [f64; 2]) -> Rgba {
        near(c, panels, p)[4]
    }

    /// The 3x3 pixels around world point `p` of the first panel (a 2 px anti-aliased line
    /// can fall between pixel centres).
    fn near(c: &Canvas, panels: &[RoomPanel], p: [f64; 2]) -> Vec<Rgba> {
        let view = panels[0].view(MARGIN as f32, (MARGIN + TITLE) as f32, 200.0);
        let (x, y) = view.px(p);
        let (x, y) = (x.round() as u32, y.round() as u32);
        (y - 1..=y + 1)
            .flat_map(|y| (x - 1..=x + 1).map(move |x| (x, y)))
            .map(|(x, y)| c.pixel(x, y).unwrap())
            .collect()
    }

    #[test]
    fn a_path_colours_the_pixels_along_it_by_outcome() {
        let empty = [panel(vec![])];
        let paths = [panel(vec![
            straight(2.0, Some(Outcome::Success)),
            straight(-2.0, Some(Outcome::Collision)),
            straight(0.0, Some(Outcome::Timeout)),
        ])];
        let before = render(&empty, 200).unwrap();
        let after = render(&paths, 200).unwrap();
        assert_eq!((before.width(), before.height()), (after.width(), after.height()));
        for (y, color) in [(2.0, SUCCESS), (-2.0, COLLISION), (0.0, TIMEOUT)] {
            assert_eq!(at(&before, &empty, [0.0, y]), FLOOR);
            // Drawn with alpha over the floor: close to the outcome colour, far from the floor.
            let dist = |a: Rgba, b: Rgba| {
                (i32::from(a.0) - i32::from(b.0)).abs()
                    + (i32::from(a.1) - i32::from(b.1)).abs()
                    + (i32::from(a.2) - i32::from(b.2)).abs()
            };
            let got =
                near(&after, &paths, [0.0, y]).into_iter().min_by_key(|&c| dist(c, color)).unwrap();
            assert!(dist(got, color) < 90, "at y = {y}: {got:?} vs {color:?}");
            assert!(dist(got, FLOOR) > 150, "at y = {y}: {got:?}");
        }
        // Away from the paths the floor is untouched.
        assert_eq!(at(&after, &paths, [0.0, 1.0]), FLOOR);
    }

    #[test]
    fn panels_are_laid_out_two_per_row() {
        let one = render(&[panel(vec![])], 100).unwrap();
        let three = render(&[panel(vec![]), panel(vec![]), panel(vec![])], 100).unwrap();
        assert_eq!(three.width(), 2 * one.width() - MARGIN);
        assert_eq!(three.height(), one.height() + TITLE + 100 + MARGIN);
        assert!(render(&[], 100).is_err());
    }

    #[test]
    fn unknown_rooms_frame_the_paths() {
        let p = RoomPanel {
            name: "custom".into(),
            room: None,
            trajectories: vec![straight(10.0, Some(Outcome::Success))],
        };
        let v = p.view(0.0, 0.0, 100.0);
        assert!((v.center[0] - 0.25).abs() < 1e-9 && (v.center[1] - 10.0).abs() < 1e-9);
        render(&[p], 100).unwrap();
    }
}
