//! Learning curves: one panel per room, the mean of a metric over runs (seeds) against
//! environment steps, with a ±1 std band, as the paper's learning-curve figure.

use super::{Canvas, INK, Rgba, WHITE, text};

/// One curve: `(x, mean, std)` points in increasing x.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    /// Legend text.
    pub label: String,
    /// Points: environment steps, mean over runs, standard deviation over runs.
    pub points: Vec<(f64, f64, f64)>,
}

/// One panel.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Title above the plot.
    pub title: String,
    /// The curves drawn in it.
    pub curves: Vec<Curve>,
}

/// Axis ranges and labels shared by every panel.
#[derive(Clone, Debug, PartialEq)]
pub struct Axes {
    /// Largest x (environment steps).
    pub x_max: f64,
    /// y range.
    pub y_min: f64,
    /// y range.
    pub y_max: f64,
    /// y axis label.
    pub y_label: String,
}

const COLORS: [Rgba; 4] =
    [Rgba::hex(0x1f77b4), Rgba::hex(0xd62728), Rgba::hex(0x2ca02c), Rgba::hex(0x9467bd)];
const MARGIN_LEFT: f32 = 70.0;
const MARGIN_BOTTOM: f32 = 50.0;
const MARGIN_TOP: f32 = 36.0;
const MARGIN_RIGHT: f32 = 16.0;

/// A compact tick label: 0, 5k, 1.5M.
pub fn tick_label(v: f64) -> String {
    let (n, suffix) = if v.abs() >= 1e6 {
        (v / 1e6, "M")
    } else if v.abs() >= 1e3 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let s = if (n - n.round()).abs() < 1e-9 { format!("{}", n.round()) } else { format!("{n:.1}") };
    format!("{s}{suffix}")
}

/// Draws `panels` side by side, each `w` x `h` pixels.
pub fn render(panels: &[Panel], axes: &Axes, w: u32, h: u32) -> anyhow::Result<Canvas> {
    anyhow::ensure!(!panels.is_empty(), "nothing to plot");
    let mut c = Canvas::new(w * panels.len() as u32, h, WHITE)?;
    for (i, p) in panels.iter().enumerate() {
        draw_panel(&mut c, p, axes, (i as u32 * w) as f32, w as f32, h as f32);
    }
    Ok(c)
}

fn draw_panel(c: &mut Canvas, p: &Panel, axes: &Axes, left: f32, w: f32, h: f32) {
    let (x0, x1) = (left + MARGIN_LEFT, left + w - MARGIN_RIGHT);
    let (y0, y1) = (h - MARGIN_BOTTOM, MARGIN_TOP);
    let x_max = axes.x_max.max(1.0);
    let span = (axes.y_max - axes.y_min).max(1e-9);
    let px = |x: f64, y: f64| -> (f32, f32) {
        let fx = (x / x_max).clamp(0.0, 1.0) as f32;
        let fy = ((y - axes.y_min) / span).clamp(0.0, 1.0) as f32;
        (x0 + fx * (x1 - x0), y0 + fy * (y1 - y0))
    };
    let grid = Rgba::hex(0xdddddd);
    for k in 0..=4 {
        let y = axes.y_min + span * k as f64 / 4.0;
        let (_, py) = px(0.0, y);
        c.stroke_polyline(&[(x0, py), (x1, py)], false, 1.0, grid);
        let label = format!("{y:.2}");
        c.text(x0 - 8.0 - text::width(&label, 1), py - 4.0, &label, 1, INK);
        let x = x_max * k as f64 / 4.0;
        let (pxx, _) = px(x, axes.y_min);
        c.stroke_polyline(&[(pxx, y0), (pxx, y1)], false, 1.0, grid);
        let label = tick_label(x);
        let lw = text::width(&label, 1);
        c.text((pxx - lw / 2.0).min(left + w - lw - 2.0), y0 + 8.0, &label, 1, INK);
    }
    c.stroke_polyline(&[(x0, y1), (x0, y0), (x1, y0)], false, 1.5, INK);
    let title_w = c.text(x0, 8.0, &p.title, 2, INK);
    c.text(x0 + title_w + 12.0, 14.0, &axes.y_label, 1, INK);
    c.text(
        (x0 + x1) / 2.0 - text::width("environment steps", 1) / 2.0,
        h - 18.0,
        "environment steps",
        1,
        INK,
    );
    for (i, curve) in p.curves.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        if curve.points.is_empty() {
            continue;
        }
        // Band: mean + std forward, mean − std back.
        let mut band: Vec<(f32, f32)> =
            curve.points.iter().map(|&(x, m, s)| px(x, m + s)).collect();
        band.extend(curve.points.iter().rev().map(|&(x, m, s)| px(x, m - s)));
        c.fill_polygon(&band, color.alpha(50));
        let line: Vec<(f32, f32)> = curve.points.iter().map(|&(x, m, _)| px(x, m)).collect();
        c.stroke_polyline(&line, false, 2.0, color);
        let ly = y1 + 6.0 + 12.0 * i as f32;
        c.stroke_polyline(&[(x1 - 120.0, ly + 4.0), (x1 - 104.0, ly + 4.0)], false, 2.0, color);
        c.text(x1 - 100.0, ly, &curve.label, 1, INK);
    }
}

/// Mean and standard deviation over runs of step functions sampled on `grid`: each run's value
/// at x is its last value at or before x; runs with no value yet are left out at that x.
pub fn mean_std_on_grid(runs: &[Vec<(f64, f64)>], grid: &[f64]) -> Vec<(f64, f64, f64)> {
    let mut out = Vec::with_capacity(grid.len());
    for &x in grid {
        let vals: Vec<f64> = runs
            .iter()
            .filter_map(|r| r.iter().take_while(|(rx, _)| *rx <= x).last().map(|&(_, v)| v))
            .collect();
        if vals.is_empty() {
            continue;
        }
        let n = vals.len() as f64;
        let mean = vals.iter().sum::<f64>() / n;
        let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        out.push((x, mean, var.sqrt()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_std_follow_the_runs_step_functions() {
        let runs = vec![vec![(0.0, 0.0), (10.0, 1.0)], vec![(5.0, 0.5)]];
        let g = mean_std_on_grid(&runs, &[0.0, 5.0, 10.0]);
        assert_eq!(g[0], (0.0, 0.0, 0.0)); // only the first run has a value at 0
        assert_eq!(g[1], (5.0, 0.25, 0.25));
        assert_eq!(g[2], (10.0, 0.75, 0.25));
    }

    #[test]
    fn tick_labels_are_compact() {
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(5000.0), "5k");
        assert_eq!(tick_label(1_500_000.0), "1.5M");
        assert_eq!(tick_label(12_500.0), "12.5k");
    }

    #[test]
    fn a_curve_colours_the_plot_where_its_mean_is() {
        let panel = Panel {
            title: "env0".into(),
            curves: vec![Curve {
                label: "a".into(),
                points: vec![(0.0, 1.0, 0.0), (100.0, 1.0, 0.0)],
            }],
        };
        let axes = Axes { x_max: 100.0, y_min: 0.0, y_max: 1.0, y_label: "y".into() };
        let c = render(&[panel], &axes, 400, 300).unwrap();
        // y = 1 is the top of the plot area (MARGIN_TOP); halfway across, the line is drawn.
        let p = c.pixel(200, MARGIN_TOP as u32).unwrap();
        assert_eq!((p.0, p.1, p.2), (0x1f, 0x77, 0xb4), "{p:?}");
        // Far below the line, the plot is white.
        assert_eq!(c.pixel(200, 200).unwrap(), WHITE);
    }
}
