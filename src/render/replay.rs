//! `dvnav replay --figure`: a replayed bag in the odometry frame: every scan's returns (light,
//! where the sensor saw them from the pose of the time), the robot's path coloured by the
//! commanded speed, the start, the goal with its tolerance, and where it arrived.

use super::{Canvas, INK, Rgba, WHITE, WorldView, text};
use crate::cli::replay::CommandRow;
use crate::cli::replay::ros::LaserScan;
use dvnav_nav::dvst::SensorSetup;

const MARGIN: f32 = 16.0;
const TITLE: f32 = 28.0;
const RETURN: Rgba = Rgba::hex(0x9aa5b1);
const START: Rgba = Rgba::hex(0x2b6cb0);
const GOAL: Rgba = Rgba::hex(0x2f855a);

/// The returns of `scan` taken at `row`'s pose, in the odometry frame.
fn returns<'a>(
    row: &'a CommandRow,
    scan: &'a LaserScan,
    lidar: &'a SensorSetup,
) -> impl Iterator<Item = [f64; 2]> + 'a {
    let (c, s) = (row.yaw.cos(), row.yaw.sin());
    let sensor = [row.x + c * lidar.x - s * lidar.y, row.y + s * lidar.x + c * lidar.y];
    scan.ranges.iter().enumerate().filter_map(move |(j, &r)| {
        let r = f64::from(r);
        let valid =
            r.is_finite() && r >= f64::from(scan.range_min) && r <= f64::from(scan.range_max);
        let a = row.yaw
            + lidar.yaw
            + f64::from(scan.angle_min)
            + j as f64 * f64::from(scan.angle_increment);
        valid.then(|| [sensor[0] + r * a.cos(), sensor[1] + r * a.sin()])
    })
}

/// The figure, `size` pixels square for the map.
pub fn render(
    rows: &[CommandRow],
    scans: &[LaserScan],
    lidar: &SensorSetup,
    goal: [f64; 2],
    size: u32,
) -> anyhow::Result<Canvas> {
    anyhow::ensure!(!rows.is_empty() && rows.len() == scans.len(), "nothing to draw");
    // Frame the path and the goal, with 3 m around them: scans reach far, the path matters.
    let (mut lo, mut hi) = (goal, goal);
    for r in rows {
        for (i, v) in [r.x, r.y].into_iter().enumerate() {
            lo[i] = lo[i].min(v);
            hi[i] = hi[i].max(v);
        }
    }
    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]) + 6.0;
    let center = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let view = WorldView { left: MARGIN, top: TITLE + MARGIN, size: size as f32, center, side };
    let mut canvas =
        Canvas::new(size + 2 * MARGIN as u32, size + (TITLE + 2.0 * MARGIN) as u32, WHITE)?;
    let inside = |(x, y): (f32, f32)| {
        (view.left..view.left + view.size).contains(&x)
            && (view.top..view.top + view.size).contains(&y)
    };
    for (row, scan) in rows.iter().zip(scans) {
        for p in returns(row, scan, lidar).map(|p| view.px(p)).filter(|&p| inside(p)) {
            canvas.fill_rect(p.0 - 0.5, p.1 - 0.5, 1.5, 1.5, RETURN.alpha(90));
        }
    }
    // The path, each step coloured by the commanded speed: red stopped, green at the fastest.
    let v_max = rows.iter().map(|r| r.v.abs()).fold(1e-9, f64::max);
    for w in rows.windows(2) {
        let t = (w[1].v.abs() / v_max) as f32;
        let color = Rgba((220.0 * (1.0 - t)) as u8, (160.0 * t) as u8, 60, 255);
        let line = [view.px([w[0].x, w[0].y]), view.px([w[1].x, w[1].y])];
        canvas.stroke_polyline(&line, false, 3.0, color);
    }
    let first = &rows[0];
    let (sx, sy) = view.px([first.x, first.y]);
    canvas.fill_circle(sx, sy, 6.0, START);
    let (gx, gy) = view.px(goal);
    let tolerance = rows[0].goal_tolerance;
    canvas.stroke_circle(gx, gy, (tolerance as f32 * view.scale()).max(6.0), 2.0, GOAL);
    canvas.fill_circle(gx, gy, 4.0, GOAL);
    let arrived = rows.iter().find(|r| r.arrived);
    if let Some(r) = arrived {
        let (ax, ay) = view.px([r.x, r.y]);
        canvas.stroke_circle(ax, ay, 8.0, 2.0, INK);
    }
    let title = format!(
        "{} scans, {:.1} s; start blue, goal green; {}",
        rows.len(),
        rows.last().map_or(0.0, |r| r.time_s),
        match arrived {
            Some(r) => format!("arrived at {:.1} s", r.time_s),
            None => "not arrived".into(),
        }
    );
    text::draw(&mut canvas, MARGIN, MARGIN, &title, 2, INK);
    Ok(canvas)
}
