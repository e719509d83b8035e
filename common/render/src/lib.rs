//! # dvnav-render
//!
//! Figures as PNG, drawn in pure Rust: [`tiny_skia`] rasterizes shapes and an embedded 8x8
//! bitmap font ([`text`]) writes labels, so rendering needs no system fonts or graphics
//! libraries and gives the same pixels on every machine. The `dvnav` command's figures and the
//! Python package's `render_mode = "rgb_array"` frames both come from here.
//!
//! # Layout
//! - [`Canvas`]: a pixmap with the few primitives figures use (lines, polygons, discs, text).
//! - [`WorldView`]: metres in a room's world frame (y up) to pixels (y down) in a panel.
//! - [`curves`]: learning curves, mean ± std over runs, one panel per room.
//! - [`room`]: walls and obstacles of a [`dvnav_sim::RoomSpec`].
//! - [`trajectories`]: `dvnav plot trajectories`, episode paths over their rooms.
//! - [`room_map`]: `dvnav rooms show`, a room with its spawn regions, routes, timed obstacles
//!   and a robot footprint.
//! - [`dvst`]: `dvnav transfer --out`, the meta, varied and dimension-scaled robots.
//! - [`replay`]: `dvnav replay --figure`, a recorded scan and the robot's path.
//! - [`frame`]: one moment of a [`dvnav_sim::NavEnv`]: room, robot, LiDAR rays and goal.

pub mod curves;
pub mod dvst;
pub mod frame;
pub mod replay;
pub mod room;
pub mod room_map;
pub mod text;
pub mod trajectories;

use tiny_skia::{FillRule, LineCap, LineJoin, Paint, PathBuilder, Pixmap, Stroke, Transform};

/// An sRGB colour with alpha, 8 bits per channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rgba(pub u8, pub u8, pub u8, pub u8);

impl Rgba {
    /// An opaque colour from `0xRRGGBB`.
    pub const fn hex(rgb: u32) -> Self {
        Rgba((rgb >> 16) as u8, (rgb >> 8) as u8, rgb as u8, 255)
    }

    /// The same colour with alpha `a`.
    pub const fn alpha(self, a: u8) -> Self {
        Rgba(self.0, self.1, self.2, a)
    }

    fn paint(self) -> Paint<'static> {
        let mut p = Paint::default();
        p.set_color_rgba8(self.0, self.1, self.2, self.3);
        p.anti_alias = true;
        p
    }
}

/// White.
pub const WHITE: Rgba = Rgba::hex(0xffffff);
/// Near-black for text and frames.
pub const INK: Rgba = Rgba::hex(0x202020);

/// A drawing surface in pixels, origin top left.
pub struct Canvas {
    pixmap: Pixmap,
}

impl Canvas {
    /// A `width` x `height` canvas filled with `background`.
    pub fn new(width: u32, height: u32, background: Rgba) -> anyhow::Result<Self> {
        let mut pixmap = Pixmap::new(width, height)
            .ok_or_else(|| anyhow::anyhow!("cannot make a {width}x{height} image"))?;
        let Rgba(r, g, b, a) = background;
        pixmap.fill(tiny_skia::Color::from_rgba8(r, g, b, a));
        Ok(Self { pixmap })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.pixmap.width()
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.pixmap.height()
    }

    /// The colour at (x, y), un-premultiplied; `None` outside (tests read figures back).
    #[cfg(test)]
    pub fn pixel(&self, x: u32, y: u32) -> Option<Rgba> {
        let p = self.pixmap.pixel(x, y)?.demultiply();
        Some(Rgba(p.red(), p.green(), p.blue(), p.alpha()))
    }

    /// Fills an axis-aligned rectangle.
    pub fn fill_rect(&mut self, x: f32, y: f32, w: f32, h: f32, color: Rgba) {
        if let Some(r) = tiny_skia::Rect::from_xywh(x, y, w, h) {
            self.pixmap.fill_rect(r, &color.paint(), Transform::identity(), None);
        }
    }

    /// Fills a closed polygon.
    pub fn fill_polygon(&mut self, points: &[(f32, f32)], color: Rgba) {
        if let Some(path) = polyline(points, true) {
            self.pixmap.fill_path(
                &path,
                &color.paint(),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
    }

    /// Strokes an open polyline (`closed`: back to the first point) `width` pixels wide.
    pub fn stroke_polyline(
        &mut self,
        points: &[(f32, f32)],
        closed: bool,
        width: f32,
        color: Rgba,
    ) {
        if let Some(path) = polyline(points, closed) {
            let stroke = Stroke {
                width,
                line_cap: LineCap::Round,
                line_join: LineJoin::Round,
                ..Default::default()
            };
            self.pixmap.stroke_path(&path, &color.paint(), &stroke, Transform::identity(), None);
        }
    }

    /// Fills a disc.
    pub fn fill_circle(&mut self, x: f32, y: f32, r: f32, color: Rgba) {
        if let Some(path) = PathBuilder::from_circle(x, y, r) {
            self.pixmap.fill_path(
                &path,
                &color.paint(),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
    }

    /// Strokes a circle.
    pub fn stroke_circle(&mut self, x: f32, y: f32, r: f32, width: f32, color: Rgba) {
        if let Some(path) = PathBuilder::from_circle(x, y, r) {
            let stroke = Stroke { width, ..Default::default() };
            self.pixmap.stroke_path(&path, &color.paint(), &stroke, Transform::identity(), None);
        }
    }

    /// Writes `s` with its top-left corner at (x, y), each font pixel `scale` pixels wide; see
    /// [`text`]. Returns the width drawn.
    pub fn text(&mut self, x: f32, y: f32, s: &str, scale: u32, color: Rgba) -> f32 {
        text::draw(self, x, y, s, scale, color)
    }

    /// The image as PNG bytes.
    pub fn encode_png(&self) -> anyhow::Result<Vec<u8>> {
        Ok(self.pixmap.encode_png()?)
    }

    /// The pixels as rows of RGB bytes, top row first (`height · width · 3` values), alpha
    /// dropped: the layout of Gymnasium's `rgb_array` frames.
    pub fn rgb(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.pixmap.pixels().len() * 3);
        for p in self.pixmap.pixels() {
            let c = p.demultiply();
            out.extend_from_slice(&[c.red(), c.green(), c.blue()]);
        }
        out
    }
}

fn polyline(points: &[(f32, f32)], closed: bool) -> Option<tiny_skia::Path> {
    let (&(x0, y0), rest) = points.split_first()?;
    let mut pb = PathBuilder::with_capacity(points.len() + 1, points.len() + 1);
    pb.move_to(x0, y0);
    for &(x, y) in rest {
        pb.line_to(x, y);
    }
    if closed {
        pb.close();
    }
    pb.finish()
}

/// Maps a square of the world (metres, y up) centred at `center` with side `side` onto a
/// square panel of `size` pixels whose top-left corner is (`left`, `top`).
#[derive(Clone, Copy, Debug)]
pub struct WorldView {
    /// Panel's left edge (px).
    pub left: f32,
    /// Panel's top edge (px).
    pub top: f32,
    /// Panel side (px).
    pub size: f32,
    /// World point at the panel's centre (m).
    pub center: [f64; 2],
    /// World extent shown across the panel (m).
    pub side: f64,
}

impl WorldView {
    /// Pixels per metre.
    pub fn scale(&self) -> f32 {
        (f64::from(self.size) / self.side) as f32
    }

    /// The pixel of world point `p`.
    pub fn px(&self, p: [f64; 2]) -> (f32, f32) {
        let s = f64::from(self.size) / self.side;
        let x = f64::from(self.left) + f64::from(self.size) * 0.5 + (p[0] - self.center[0]) * s;
        let y = f64::from(self.top) + f64::from(self.size) * 0.5 - (p[1] - self.center[1]) * s;
        (x as f32, y as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_view_flips_y_and_centres() {
        let v = WorldView { left: 10.0, top: 20.0, size: 100.0, center: [0.0, 0.0], side: 10.0 };
        assert_eq!(v.px([0.0, 0.0]), (60.0, 70.0));
        assert_eq!(v.px([5.0, 5.0]), (110.0, 20.0), "top right corner");
        assert_eq!(v.px([-5.0, -5.0]), (10.0, 120.0), "bottom left corner");
        assert_eq!(v.scale(), 10.0);
    }

    #[test]
    fn shapes_change_the_pixels_they_cover_and_no_others() {
        let mut c = Canvas::new(50, 50, WHITE).unwrap();
        c.fill_rect(10.0, 10.0, 10.0, 10.0, Rgba::hex(0xff0000));
        assert_eq!(c.pixel(15, 15), Some(Rgba::hex(0xff0000)));
        assert_eq!(c.pixel(25, 15), Some(WHITE));
        c.fill_circle(35.0, 35.0, 5.0, Rgba::hex(0x0000ff));
        assert_eq!(c.pixel(35, 35), Some(Rgba::hex(0x0000ff)));
        assert_eq!(c.pixel(35, 44), Some(WHITE));
        c.stroke_polyline(&[(0.0, 45.5), (20.0, 45.5)], false, 3.0, Rgba::hex(0x00ff00));
        assert_eq!(c.pixel(10, 45), Some(Rgba::hex(0x00ff00)));
        assert_eq!(c.pixel(10, 40), Some(WHITE));
        c.fill_polygon(&[(30.0, 2.0), (48.0, 2.0), (48.0, 20.0)], INK);
        assert_eq!(c.pixel(46, 4), Some(INK));
        assert_eq!(c.pixel(32, 18), Some(WHITE), "below the diagonal");
        let png = c.encode_png().unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
