//! Occupancy-grid maps as rooms: the ROS `map_server` format (a YAML file naming a PGM or PNG
//! image) and plain black-and-white images, turned into a [`RoomSpec`] of axis-aligned boxes.
//!
//! # Names
//!
//! [`is_map_name`] tells `Room::load` which names are maps; [`load`] reads them:
//!
//! | name | what |
//! |---|---|
//! | `PATH.yaml`, `PATH.yml` | a map_server map file (below) |
//! | `PATH.png`, `PATH.pgm` | the image alone, at [`DEFAULT_RESOLUTION`] (0.05 m/px), with map_server's default thresholds: dark is occupied |
//! | `PATH.png:resolution=0.025` | the same at another resolution (m/px) |
//!
//! The room is named after the file's stem (`maps/willow.yaml` → `willow`).
//!
//! # The map file
//!
//! | key | what |
//! |---|---|
//! | `image` | the image, relative to the YAML file's directory (or absolute): PGM (binary P5 or ASCII P2) or PNG (grey, grey + alpha, RGB, RGBA) |
//! | `resolution` | metres per pixel, finite and > 0 |
//! | `origin` | `[x, y, yaw]`: the map-frame pose (m, m, rad) of the image's lower-left corner |
//! | `occupied_thresh`, `free_thresh` | in [0, 1], `free_thresh < occupied_thresh`; default 0.65 and 0.196 (map_server's) |
//! | `negate` | 0 or 1 (`false` / `true`); default 0 |
//! | `mode` | `trinary` (default), `scale` or `raw` |
//!
//! Any other key is refused, as `room_file` refuses unknown keys: a misspelt `occupied_tresh`
//! would otherwise silently fall back to a default.
//!
//! # From pixels to cells, as map_server does it
//!
//! A pixel's shade is the mean of its red, green and blue values (a grey pixel's value), and in
//! `trinary` mode its opacity too when the image has alpha; as a fraction of 255. Its occupancy
//! probability is p = 1 − shade, i.e. (255 − value)/255 (p = shade with `negate`). A cell is
//! [`Cell::Occupied`] when p > `occupied_thresh`, [`Cell::Free`] when p < `free_thresh`, and
//! [`Cell::Unknown`] otherwise. `scale` mode is the same except that a pixel that is not fully
//! opaque is unknown and the cells between the thresholds (map_server's graded 1..99 %) count as
//! unknown. `raw` mode reads the shade × 255 as the occupancy in percent (0..100, beyond: unknown;
//! `negate` ignored, as map_server ignores it) and applies the same thresholds to percent / 100.
//!
//! # Unknown is an obstacle
//!
//! Only free cells are free space; unknown cells are obstacles like occupied ones. In a map made
//! by SLAM they are almost always outside the building (or inside walls and furniture the
//! scanner never saw into), so a robot must never be spawned there, and a policy must not learn
//! to drive through them as if they were open floor.
//!
//! # From cells to shapes
//!
//! The image is cropped to the bounding box of its free cells plus one cell on every side
//! (everything outside is obstacle anyway and no beam from free space can reach it: the ring of
//! cells just outside the free cells' box is not free, or is the image's edge, which the walls
//! close). The obstacle cells in the crop are merged into axis-aligned rectangles, greedily (a run
//! along a row, extended down while the whole run below is obstacle too), each one
//! [`ObstacleSpec::Box`]. The room's square has side max(width, height) of the crop in metres,
//! with the crop centred at the origin and the square's four walls around it; the part of the
//! square beside the crop is padded with obstacle boxes. Hundreds (a clean map) to tens of thousands
//! (a noisy one) of boxes result; the LiDAR caster culls them by a uniform grid (`caster.rs`),
//! so a scan costs about what is in sight.
//!
//! # Frames
//!
//! The room frame is the map frame moved (and, for an `origin` yaw other than 0, turned) so that
//! the crop's centre is the origin; [`MapFrame`] converts points both ways, and the room's
//! `description` states the offset.

use super::room_file::SpecFileError;
use super::spec::{DEFAULT_WALL_THICKNESS, ObstacleSpec, Point, RoomSpec};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Resolution (m/px) of an image named without a `:resolution=` suffix: 5 cm, the usual
/// resolution of 2-D SLAM maps (map_saver, slam_toolbox, gmapping).
pub const DEFAULT_RESOLUTION: f64 = 0.05;

/// map_server's `occupied_thresh` when none is given.
pub const DEFAULT_OCCUPIED_THRESH: f64 = 0.65;

/// map_server's `free_thresh` when none is given: the unknown grey 205 of map_saver's images
/// (p = 50/255 ≈ 0.1961) lies just above it.
pub const DEFAULT_FREE_THRESH: f64 = 0.196;

/// Largest image width or height (px) accepted: 4000 px is 200 m at 5 cm, more than any
/// building a robot is trained or evaluated in, and 16 M cells keeps loading within a second.
pub const MAX_SIDE_PX: u32 = 4000;

/// How pixel values become occupancy (map_server's `mode`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Occupied, free or unknown by the two thresholds (map_server's default).
    #[default]
    Trinary,
    /// Like trinary, but a transparent pixel is unknown (and map_server grades the cells between
    /// the thresholds, which count as unknown here).
    Scale,
    /// The value is the occupancy in percent (0..100; beyond: unknown).
    Raw,
}

/// What a map file says (or the defaults, for an image named alone).
#[derive(Clone, Debug, PartialEq)]
pub struct MapMeta {
    /// The image, as a path that can be opened (the YAML's directory joined).
    pub image: PathBuf,
    /// Metres per pixel.
    pub resolution: f64,
    /// Map-frame pose `[x, y, yaw]` (m, m, rad) of the image's lower-left corner.
    pub origin: [f64; 3],
    /// Occupied when the occupancy probability is above this.
    pub occupied_thresh: f64,
    /// Free when the occupancy probability is below this.
    pub free_thresh: f64,
    /// Dark is free and light occupied.
    pub negate: bool,
    /// How values become occupancy.
    pub mode: Mode,
}

impl MapMeta {
    /// An image named alone: `resolution` m/px, origin at its lower-left corner, map_server's
    /// default thresholds, trinary, not negated.
    pub fn for_image(image: PathBuf, resolution: f64) -> MapMeta {
        MapMeta {
            image,
            resolution,
            origin: [0.0; 3],
            occupied_thresh: DEFAULT_OCCUPIED_THRESH,
            free_thresh: DEFAULT_FREE_THRESH,
            negate: false,
            mode: Mode::Trinary,
        }
    }

    /// The cell of one pixel, from its 8-bit red, green, blue and alpha values (a grey pixel has
    /// r = g = b; `has_alpha` says whether the image has an alpha channel at all).
    pub fn classify(&self, [r, g, b, a]: [u8; 4], has_alpha: bool) -> Cell {
        let (mut sum, mut n) = (r as u32 + g as u32 + b as u32, 3u32);
        if self.mode == Mode::Trinary && has_alpha {
            // map_server averages the opacity in with the colour in trinary mode.
            sum += a as u32;
            n += 1;
        }
        let p = match self.mode {
            Mode::Trinary | Mode::Scale => {
                if self.mode == Mode::Scale && has_alpha && a != 255 {
                    return Cell::Unknown;
                }
                let num = if self.negate { sum } else { 255 * n - sum };
                num as f64 / (255 * n) as f64
            }
            Mode::Raw => {
                let percent = (sum as f64 / n as f64).round();
                if percent > 100.0 {
                    return Cell::Unknown;
                }
                percent / 100.0
            }
        };
        if p > self.occupied_thresh {
            Cell::Occupied
        } else if p < self.free_thresh {
            Cell::Free
        } else {
            Cell::Unknown
        }
    }
}

/// One cell of an occupancy grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cell {
    /// Open floor.
    Free,
    /// An obstacle.
    Occupied,
    /// Neither: unknown to the map (in `scale` mode also a graded occupancy between the
    /// thresholds). An obstacle in the room (see the module docs for why).
    Unknown,
}

impl Cell {
    /// Whether the room has an obstacle here (occupied or unknown).
    pub fn is_obstacle(self) -> bool {
        self != Cell::Free
    }
}

/// An occupancy grid: one [`Cell`] per pixel, row-major, row 0 the image's top row.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    /// Columns (px).
    pub width: usize,
    /// Rows (px).
    pub height: usize,
    /// `width · height` cells, row after row from the top.
    pub cells: Vec<Cell>,
}

impl OccupancyGrid {
    /// The cell at column `col`, row `row` (from the top).
    pub fn at(&self, col: usize, row: usize) -> Cell {
        self.cells[row * self.width + col]
    }

    /// `[c0, r0, c1, r1]`: the columns `c0..c1` and rows `r0..r1` holding every free cell;
    /// `None` without one.
    pub fn free_bounds(&self) -> Option<[usize; 4]> {
        let mut b = [usize::MAX, usize::MAX, 0, 0];
        for (i, c) in self.cells.iter().enumerate() {
            if *c == Cell::Free {
                let (col, row) = (i % self.width, i / self.width);
                b = [b[0].min(col), b[1].min(row), b[2].max(col + 1), b[3].max(row + 1)];
            }
        }
        (b[2] > 0).then_some(b)
    }

    /// The obstacle cells inside `crop` (`[c0, r0, c1, r1]`) as few axis-aligned rectangles
    /// `[c0, r0, c1, r1]` (columns `c0..c1`, rows `r0..r1`) that cover each of them exactly
    /// once and no free cell: greedy, from the first uncovered obstacle cell in reading order
    /// its run along the row, extended down while the whole run below is uncovered obstacle.
    /// (Choosing, per start cell, the width of largest area instead gives no fewer boxes on the
    /// maps of `maps/`.)
    pub fn rectangles(&self, crop: [usize; 4]) -> Vec<[usize; 4]> {
        let [x0, y0, x1, y1] = crop;
        let w = x1 - x0;
        let mut used = vec![false; w * (y1 - y0)];
        let open = |used: &[bool], c: usize, r: usize| {
            self.at(c, r).is_obstacle() && !used[(r - y0) * w + (c - x0)]
        };
        let mut out = Vec::new();
        for r in y0..y1 {
            for c in x0..x1 {
                if !open(&used, c, r) {
                    continue;
                }
                let mut c_end = c + 1;
                while c_end < x1 && open(&used, c_end, r) {
                    c_end += 1;
                }
                let mut r_end = r + 1;
                while r_end < y1 && (c..c_end).all(|x| open(&used, x, r_end)) {
                    r_end += 1;
                }
                for rr in r..r_end {
                    used[(rr - y0) * w + (c - x0)..(rr - y0) * w + (c_end - x0)].fill(true);
                }
                out.push([c, r, c_end, r_end]);
            }
        }
        out
    }
}

/// How map-frame points (the map file's frame) and room-frame points relate.
#[derive(Clone, Debug, PartialEq)]
pub struct MapFrame {
    /// The map file's `origin`: map-frame pose (m, m, rad) of the image's lower-left corner.
    pub origin: [f64; 3],
    /// Metres per pixel.
    pub resolution: f64,
    /// Image height (px): rows count from the top, the map's y axis from the bottom.
    pub image_height: usize,
    /// The crop `[c0, r0, c1, r1]` (columns `c0..c1`, rows `r0..r1` from the top) the room is
    /// built from; its centre is the room's origin.
    pub crop: [usize; 4],
}

impl MapFrame {
    /// The room's origin in the image frame (m from the image's lower-left corner, x along the
    /// columns, y up the rows).
    pub fn center(&self) -> Point {
        let [c0, r0, c1, r1] = self.crop;
        let h2 = 2 * self.image_height;
        [(c0 + c1) as f64 * 0.5 * self.resolution, (h2 - r0 - r1) as f64 * 0.5 * self.resolution]
    }

    /// A map-frame point (m) in the room frame.
    pub fn map_to_room(&self, p: Point) -> Point {
        let [ox, oy, yaw] = self.origin;
        let (s, c) = yaw.sin_cos();
        let (dx, dy) = (p[0] - ox, p[1] - oy);
        let m = self.center();
        [c * dx + s * dy - m[0], -s * dx + c * dy - m[1]]
    }

    /// A room-frame point (m) in the map frame.
    pub fn room_to_map(&self, q: Point) -> Point {
        let [ox, oy, yaw] = self.origin;
        let (s, c) = yaw.sin_cos();
        let m = self.center();
        let (gx, gy) = (q[0] + m[0], q[1] + m[1]);
        [ox + c * gx - s * gy, oy + s * gx + c * gy]
    }

    /// A map-frame heading (rad) in the room frame.
    pub fn map_yaw_to_room(&self, yaw: f64) -> f64 {
        super::wrap_angle(yaw - self.origin[2])
    }

    /// The room-frame centre of the image's cell at column `col`, row `row` (from the top).
    pub fn cell_center(&self, col: usize, row: usize) -> Point {
        let m = self.center();
        let r = self.resolution;
        [(col as f64 + 0.5) * r - m[0], (self.image_height as f64 - row as f64 - 0.5) * r - m[1]]
    }
}

/// A map loaded as a room: the room, how its frame relates to the map's, and the cells.
#[derive(Clone, Debug)]
pub struct GridMap {
    /// The room (boxes, square walls), ready for `Room::try_new`.
    pub spec: RoomSpec,
    /// Map frame ↔ room frame.
    pub frame: MapFrame,
    /// What the map file said.
    pub meta: MapMeta,
    /// The whole image's cells (not only the crop).
    pub grid: OccupancyGrid,
}

/// True when `name` names an occupancy-grid map: it ends in `.yaml`, `.yml`, `.png` or `.pgm`
/// (any case), or has a `.png:` / `.pgm:` options suffix.
pub fn is_map_name(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    [".yaml", ".yml", ".png", ".pgm"].iter().any(|e| lower.ends_with(e))
        || image_suffix_at(&lower).is_some()
}

/// Byte offset of the `:` that starts an image name's options (`x.png:resolution=…`).
fn image_suffix_at(lower: &str) -> Option<usize> {
    [".png:", ".pgm:"].iter().filter_map(|e| lower.rfind(e).map(|i| i + 4)).max()
}

/// Loads the map `name`: a map file, or an image with an optional `:resolution=` suffix.
pub fn load(name: &str) -> Result<GridMap, SpecFileError> {
    let lower = name.to_ascii_lowercase();
    let (meta, source, stem_of) = if lower.ends_with(".yaml") || lower.ends_with(".yml") {
        let path = Path::new(name);
        (read_map_file(path)?, name.to_string(), path.to_path_buf())
    } else {
        let (path, options) = match image_suffix_at(&lower) {
            Some(i) => (&name[..i], Some(&name[i + 1..])),
            None => (name, None),
        };
        let mut resolution = DEFAULT_RESOLUTION;
        for option in options.into_iter().flat_map(|o| o.split(',')) {
            let err = |key: &str, reason: String| SpecFileError {
                source: path.to_string(),
                line: None,
                key: key.to_string(),
                reason,
            };
            match option.split_once('=') {
                Some(("resolution", v)) => {
                    resolution = v
                        .trim()
                        .parse()
                        .map_err(|_| err("resolution", format!("`{v}` is not a number (m/px)")))?;
                }
                _ => {
                    return Err(err(
                        option.split('=').next().unwrap_or(option).trim(),
                        format!(
                            "unknown option `{option}`; the one option is `resolution=M_PER_PX`"
                        ),
                    ));
                }
            }
        }
        check_resolution(resolution, path, None)?;
        (MapMeta::for_image(PathBuf::from(path), resolution), path.to_string(), PathBuf::from(path))
    };
    let grid = read_grid(&meta, &source)?;
    let name: String =
        stem_of.file_stem().map_or_else(|| "map".into(), |s| s.to_string_lossy().into());
    let (spec, frame) = room_spec(&name, &meta, &grid, &source)?;
    Ok(GridMap { spec, frame, meta, grid })
}

/// The map file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MapFile {
    image: String,
    resolution: f64,
    origin: Vec<f64>,
    occupied_thresh: Option<f64>,
    free_thresh: Option<f64>,
    /// 0/1 or a bool: checked after parsing, so the error can say what is allowed.
    negate: Option<serde_yaml_ng::Value>,
    #[serde(default)]
    mode: Mode,
}

/// 1-based line of the first `key:` in `text`.
fn line_of_key(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            l.trim_start().strip_prefix(key).is_some_and(|rest| rest.trim_start().starts_with(':'))
        })
        .map(|i| i + 1)
}

/// The key written on 1-based line `line` of `text`, if that line is `key: …`.
fn key_on_line(text: &str, line: usize) -> Option<String> {
    let l = text.lines().nth(line.checked_sub(1)?)?.trim_start();
    let (key, _) = l.split_once(':')?;
    let key = key.trim();
    (!key.is_empty() && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        .then(|| key.to_string())
}

fn check_resolution(r: f64, source: &str, line: Option<usize>) -> Result<(), SpecFileError> {
    if r.is_finite() && r > 0.0 {
        return Ok(());
    }
    Err(SpecFileError {
        source: source.to_string(),
        line,
        key: "resolution".into(),
        reason: format!("must be a finite number of metres per pixel above 0, got {r}"),
    })
}

/// Reads and checks a map_server map file; the image path is joined to the file's directory.
pub fn read_map_file(path: &Path) -> Result<MapMeta, SpecFileError> {
    let (text, source) = super::room_file::read_spec_file(path, "map file")?;
    parse_map_text(&text, &source, path.parent().unwrap_or(Path::new("")))
}

/// A map received whole (a map_server YAML and its image's bytes, as `dvnav serve`'s `SetMap`
/// gets them): the room, its frame, the cells. `source` names it in errors; the YAML's `image`
/// is not read from disk.
pub fn from_bytes(source: &str, map_yaml: &str, image: &[u8]) -> Result<GridMap, SpecFileError> {
    // The image comes with the text, so the text need not name one.
    let text = match line_of_key(map_yaml, "image") {
        Some(_) => map_yaml.to_string(),
        None => format!("{map_yaml}\nimage: {source}\n"),
    };
    let meta = parse_map_text(&text, source, Path::new(""))?;
    let reader = image::ImageReader::new(std::io::Cursor::new(image));
    let grid = decode_grid(&meta, reader, source, "the image")?;
    let (spec, frame) = room_spec("map", &meta, &grid, source)?;
    Ok(GridMap { spec, frame, meta, grid })
}

/// Checks a map_server map file's text; its image path is joined to `dir`.
fn parse_map_text(text: &str, source: &str, dir: &Path) -> Result<MapMeta, SpecFileError> {
    let source = source.to_string();
    let err = |key: &str, reason: String| SpecFileError {
        source: source.clone(),
        line: line_of_key(text, key),
        key: key.to_string(),
        reason,
    };
    let file: MapFile = serde_yaml_ng::from_str(text).map_err(|e| {
        let msg = e.to_string();
        let line = e.location().map(|l| l.line());
        let mut reason = match msg.rfind(" at line ") {
            Some(i) => msg[..i].to_string(),
            None => msg.clone(),
        };
        let key = if let Some(rest) = reason.strip_prefix("missing field `") {
            rest.split('`').next().unwrap_or("").to_string()
        } else if let Some(rest) = reason.strip_prefix("unknown field `") {
            let k = rest.split('`').next().unwrap_or("").to_string();
            reason = format!(
                "unknown key `{k}`; a map file has image, resolution, origin, occupied_thresh, \
                 free_thresh, negate and mode"
            );
            k
        } else {
            line.and_then(|l| key_on_line(text, l)).unwrap_or_default()
        };
        // serde_yaml_ng prefixes the path of a nested value ("origin[1]: …"); keep the message.
        if let Some((prefix, rest)) = reason.split_once(": ")
            && prefix == key
        {
            reason = rest.to_string();
        }
        SpecFileError { source: source.clone(), line, key, reason }
    })?;
    check_resolution(file.resolution, &source, line_of_key(text, "resolution"))?;
    let origin: [f64; 3] = file
        .origin
        .as_slice()
        .try_into()
        .ok()
        .filter(|o: &[f64; 3]| o.iter().all(|v| v.is_finite()))
        .ok_or_else(|| {
            err(
                "origin",
                format!("must be three finite numbers [x, y, yaw], got {:?}", file.origin),
            )
        })?;
    let occupied = file.occupied_thresh.unwrap_or(DEFAULT_OCCUPIED_THRESH);
    let free = file.free_thresh.unwrap_or(DEFAULT_FREE_THRESH);
    for (key, v) in [("occupied_thresh", occupied), ("free_thresh", free)] {
        if !(0.0..=1.0).contains(&v) {
            return Err(err(key, format!("must lie in [0, 1], got {v}")));
        }
    }
    if free >= occupied {
        return Err(err(
            "free_thresh",
            format!("must be below occupied_thresh ({occupied}), got {free}"),
        ));
    }
    let negate = match &file.negate {
        None => false,
        Some(serde_yaml_ng::Value::Bool(b)) => *b,
        Some(serde_yaml_ng::Value::Number(n)) if n.as_i64() == Some(0) => false,
        Some(serde_yaml_ng::Value::Number(n)) if n.as_i64() == Some(1) => true,
        Some(other) => {
            return Err(err("negate", format!("must be 0 or 1, got {other:?}")));
        }
    };
    if file.image.trim().is_empty() {
        return Err(err("image", "is empty; it names the map's PGM or PNG file".into()));
    }
    Ok(MapMeta {
        image: dir.join(&file.image),
        resolution: file.resolution,
        origin,
        occupied_thresh: occupied,
        free_thresh: free,
        negate,
        mode: file.mode,
    })
}

/// Decodes the image of `meta` into cells; errors cite `source` (the map file, or the image
/// named alone) and the key `image`.
pub fn read_grid(meta: &MapMeta, source: &str) -> Result<OccupancyGrid, SpecFileError> {
    let path = &meta.image;
    let err = |reason: String| SpecFileError {
        source: source.to_string(),
        line: None,
        key: "image".into(),
        reason,
    };
    if !path.is_file() {
        return Err(err(format!("no such file: {}", path.display())));
    }
    let reader = image::ImageReader::open(path)
        .map_err(|e| err(format!("cannot read {}: {e}", path.display())))?;
    decode_grid(meta, reader, source, &path.display().to_string())
}

/// Decodes an image (PNG or PGM, at most [`MAX_SIDE_PX`] a side) into the cells of `meta`.
fn decode_grid<R: std::io::BufRead + std::io::Seek>(
    meta: &MapMeta,
    reader: image::ImageReader<R>,
    source: &str,
    what: &str,
) -> Result<OccupancyGrid, SpecFileError> {
    let err = |reason: String| SpecFileError {
        source: source.to_string(),
        line: None,
        key: "image".into(),
        reason,
    };
    let reader =
        reader.with_guessed_format().map_err(|e| err(format!("cannot read {what}: {e}")))?;
    if !matches!(reader.format(), Some(image::ImageFormat::Png | image::ImageFormat::Pnm)) {
        return Err(err(format!("{} is not a PNG or PGM image", what)));
    }
    let unreadable = |e: image::ImageError| err(format!("cannot decode {}: {e}", what));
    let decoder = reader.into_decoder().map_err(unreadable)?;
    let (w, h) = image::ImageDecoder::dimensions(&decoder);
    if w > MAX_SIDE_PX || h > MAX_SIDE_PX {
        return Err(err(format!(
            "{} is {w} x {h} px, larger than the {MAX_SIDE_PX} x {MAX_SIDE_PX} px a map may be \
             (crop it, or halve its resolution)",
            what
        )));
    }
    if w == 0 || h == 0 {
        return Err(err(format!("{} has no pixels", what)));
    }
    let img = image::DynamicImage::from_decoder(decoder).map_err(unreadable)?;
    let has_alpha = img.color().has_alpha();
    let rgba = img.into_rgba8();
    let cells = rgba.pixels().map(|p| meta.classify(p.0, has_alpha)).collect();
    Ok(OccupancyGrid { width: w as usize, height: h as usize, cells })
}

/// The room of `grid`: the crop around its free cells as boxes, centred at the origin, padded
/// to a square with walls.
fn room_spec(
    name: &str,
    meta: &MapMeta,
    grid: &OccupancyGrid,
    source: &str,
) -> Result<(RoomSpec, MapFrame), SpecFileError> {
    let Some([f0, g0, f1, g1]) = grid.free_bounds() else {
        return Err(SpecFileError {
            source: source.to_string(),
            line: None,
            key: "image".into(),
            reason: format!(
                "{} has no free cell (occupancy below free_thresh = {}; negate = {})",
                meta.image.display(),
                meta.free_thresh,
                meta.negate as u8
            ),
        });
    };
    let crop = [
        f0.saturating_sub(1),
        g0.saturating_sub(1),
        (f1 + 1).min(grid.width),
        (g1 + 1).min(grid.height),
    ];
    let frame = MapFrame {
        origin: meta.origin,
        resolution: meta.resolution,
        image_height: grid.height,
        crop,
    };
    let res = meta.resolution;
    let [c0, r0, c1, r1] = crop;
    // Twice the crop centre in cells, so that box coordinates are exact integers times res/2.
    let (mx2, my2) = ((c0 + c1) as f64, (2 * grid.height - r0 - r1) as f64);
    let bx =
        |center: Point, half_extents: Point| ObstacleSpec::Box { center, half_extents, angle: 0.0 };
    let mut obstacles: Vec<ObstacleSpec> = grid
        .rectangles(crop)
        .into_iter()
        .map(|[a, t, b, u]| {
            let y2 = (2 * grid.height - t - u) as f64;
            bx(
                [((a + b) as f64 - mx2) * 0.5 * res, (y2 - my2) * 0.5 * res],
                [(b - a) as f64 * 0.5 * res, (u - t) as f64 * 0.5 * res],
            )
        })
        .collect();
    let (w, h) = ((c1 - c0) as f64 * res, (r1 - r0) as f64 * res);
    let side = w.max(h);
    // Pad the square beside the crop: two strips along the shorter dimension.
    let pad = (side - w.min(h)) / 2.0;
    if pad > 1e-9 * side {
        let (inner, far) = (w.min(h) / 2.0, side / 2.0);
        let c = (inner + far) / 2.0;
        for sgn in [-1.0, 1.0] {
            obstacles.push(if w < h {
                bx([sgn * c, 0.0], [pad / 2.0, far])
            } else {
                bx([0.0, sgn * c], [far, pad / 2.0])
            });
        }
    }
    let m = frame.room_to_map([0.0, 0.0]);
    let offset = if meta.origin[2] == 0.0 {
        format!("the room's origin is map point ({:.4}, {:.4}) (room = map − that)", m[0], m[1])
    } else {
        format!(
            "the room's origin is map point ({:.4}, {:.4}), its x axis at {:.4} rad in the map",
            m[0], m[1], meta.origin[2]
        )
    };
    let mut spec = RoomSpec::empty(name, side);
    spec.wall_thickness = DEFAULT_WALL_THICKNESS;
    spec.obstacles = obstacles;
    spec.description = format!(
        "occupancy-grid map {source}: {} x {} px at {res} m/px, cropped to {} x {} px around its \
         free space; {offset}",
        grid.width,
        grid.height,
        c1 - c0,
        r1 - r0
    );
    Ok((spec, frame))
}

#[cfg(test)]
mod tests;
