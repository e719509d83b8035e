//! Room files: rooms as TOML that users write, and the built-in rooms in `rooms/`.
//!
//! One file describes one room, or one layout instanced at several sides (the training rooms
//! Env_0..Env_3 are one layout at 8, 7, 6 and 5 m). The format, key by key (lengths in metres,
//! world frame: x right, y up, origin at the room's centre; README § Rooms has an example):
//!
//! | key | what |
//! |---|---|
//! | `name`, `side` | a single room: its name and the side of its square |
//! | `layout_side` + `[[instances]]` (`name`, `side`, optional `description`) | a layout written for a room of side `layout_side`, built once per instance: positions (obstacle anchors, route points, spawn regions, wall segments) scale by `side / layout_side`, obstacle sizes do not |
//! | `description` | one line shown by `dvnav rooms list` |
//! | `wall_thickness` | default 0.2 |
//! | `[walls]` `square` (default true), `segments = [{ from, to, thickness? }]` | the four walls of the square, plus straight walls; `square = false` makes any other outline (then spawn regions are required) |
//! | `[[obstacles]]` `shape = "box"` (`center`, `half_extents`, `angle` rad), `"circle"` (`center`, `radius`), `"polygon"` (`points`, convex, counter-clockwise), `"compound"` (`at`, `parts = [..]`: boxes, circles, polygons relative to `at`) | static obstacles; when instanced, a box or circle moves with its centre, a polygon with its vertex mean, a compound with `at` |
//! | `[[spawn_regions]]` `name`, `min`, `max`, `starts`, `goals` (default true) | rectangles where training episodes start / end; none: the whole free square |
//! | `[[routes]]` `name`, `start`, `heading_deg`, `goals` | evaluation routes: a start pose and goals visited in order (`eval` is the one design §4 scores) |
//! | `[[timed_obstacles]]` `at_step`, `obstacle = { shape = …, … }` | obstacles that appear after `at_step` control steps |
//!
//! A file is refused with the line and the reason: TOML syntax and unknown keys (from `toml`'s
//! spans), then every shape (positive sizes, convex counter-clockwise polygons, no nested
//! compounds), then the geometry of every instance (obstacles, wall segments and spawn regions
//! inside the square, route starts and goals inside the square and outside every shape,
//! unique names). Nothing here panics on bad input.

use super::spec::{
    DEFAULT_WALL_THICKNESS, ObstacleSpec, Point, RoomSpec, Route, SpawnRegion, TimedObstacle,
    WallSegment,
};
use serde::Deserialize;
use std::fmt;
use std::path::Path;
use toml::Spanned;

/// The built-in room files, embedded so the binary works from any directory: `(file, text)`.
pub const BUILTIN_FILES: [(&str, &str); 3] = [
    ("rooms/training.toml", include_str!("../../../rooms/training.toml")),
    ("rooms/gate.toml", include_str!("../../../rooms/gate.toml")),
    ("rooms/dynamic.toml", include_str!("../../../rooms/dynamic.toml")),
];

/// A room or footprint file that cannot be used: where and why.
#[derive(Clone, Debug, PartialEq)]
pub struct SpecFileError {
    /// The file (a path, or the built-in file's name).
    pub source: String,
    /// 1-based line of the offending value, when known.
    pub line: Option<usize>,
    /// The key, e.g. `obstacles[2]` (0-based indices); empty for a syntax error.
    pub key: String,
    /// What is wrong.
    pub reason: String,
}

impl fmt::Display for SpecFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.source)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if !self.key.is_empty() {
            write!(f, ": `{}`", self.key)?;
        }
        write!(f, ": {}", self.reason)
    }
}

impl std::error::Error for SpecFileError {}

/// 1-based line of byte offset `at` in `text`.
pub fn line_of(text: &str, at: usize) -> usize {
    text.as_bytes()[..at.min(text.len())].iter().filter(|&&b| b == b'\n').count() + 1
}

/// Parses TOML into `T`, turning a syntax or schema error into a [`SpecFileError`] with the
/// line `toml` points at.
pub fn parse_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    source: &str,
) -> Result<T, SpecFileError> {
    toml::from_str(text).map_err(|e| SpecFileError {
        source: source.to_string(),
        line: e.span().map(|s| line_of(text, s.start)),
        key: String::new(),
        reason: e.message().trim_end().to_string(),
    })
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RoomFile {
    name: Option<Spanned<String>>,
    side: Option<Spanned<f64>>,
    layout_side: Option<Spanned<f64>>,
    #[serde(default)]
    instances: Vec<Spanned<Instance>>,
    #[serde(default)]
    description: String,
    wall_thickness: Option<Spanned<f64>>,
    walls: Option<WallsFile>,
    #[serde(default)]
    obstacles: Vec<Spanned<ObstacleSpec>>,
    #[serde(default)]
    spawn_regions: Vec<Spanned<SpawnRegion>>,
    #[serde(default)]
    routes: Vec<Spanned<Route>>,
    #[serde(default)]
    timed_obstacles: Vec<Spanned<TimedObstacle>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WallsFile {
    #[serde(default = "yes")]
    square: bool,
    #[serde(default)]
    segments: Vec<Spanned<WallSegment>>,
}

fn yes() -> bool {
    true
}

/// A room a file asks for: name, side, description, and the span it was named at.
type RoomToBuild = (String, f64, Option<String>, Option<std::ops::Range<usize>>);

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Instance {
    name: String,
    side: f64,
    #[serde(default)]
    description: Option<String>,
}

/// Builds errors for one file.
struct Ctx<'a> {
    text: &'a str,
    source: &'a str,
}

impl Ctx<'_> {
    fn err(
        &self,
        span: Option<std::ops::Range<usize>>,
        key: &str,
        reason: impl fmt::Display,
    ) -> SpecFileError {
        SpecFileError {
            source: self.source.to_string(),
            line: span.map(|s| line_of(self.text, s.start)),
            key: key.to_string(),
            reason: reason.to_string(),
        }
    }
}

fn finite_point(p: &Point) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// Parses a room file: every room it describes, checked. `source` names the file in errors.
pub fn parse_room_file(text: &str, source: &str) -> Result<Vec<RoomSpec>, SpecFileError> {
    parse_instances(text, source, None)
}

/// [`parse_room_file`], or with `only = Some((name, side))` the file's layout at that one side
/// instead of its own instances.
fn parse_instances(
    text: &str,
    source: &str,
    only: Option<(&str, f64)>,
) -> Result<Vec<RoomSpec>, SpecFileError> {
    let ctx = Ctx { text, source };
    let file: RoomFile = parse_toml(text, source)?;

    // Which rooms: one (`name`, `side`) or a layout with instances.
    let single = file.name.is_some() || file.side.is_some();
    let rooms: Vec<RoomToBuild> = match (single, &file.layout_side, file.instances.is_empty()) {
        (true, None, true) => {
            let name = file.name.as_ref().ok_or_else(|| {
                ctx.err(None, "name", "a room file needs `name` (or `[[instances]]`)")
            })?;
            let side = file.side.as_ref().ok_or_else(|| {
                ctx.err(Some(name.span()), "side", "a room file needs `side` (m)")
            })?;
            vec![(name.get_ref().clone(), *side.get_ref(), None, Some(side.span()))]
        }
        (false, Some(_), false) => file
            .instances
            .iter()
            .map(|i| {
                let v = i.get_ref();
                (v.name.clone(), v.side, v.description.clone(), Some(i.span()))
            })
            .collect(),
        (false, Some(ls), true) => {
            return Err(ctx.err(
                Some(ls.span()),
                "instances",
                "`layout_side` needs at least one `[[instances]]` (name and side)",
            ));
        }
        (false, None, false) => {
            return Err(ctx.err(
                Some(file.instances[0].span()),
                "layout_side",
                "`[[instances]]` need `layout_side`: the side the layout's positions are \
                     written for",
            ));
        }
        (true, _, _) => {
            let span = file.name.as_ref().map(|n| n.span());
            return Err(ctx.err(
                span,
                "name",
                "give either `name` and `side` (one room) or `layout_side` and \
                     `[[instances]]` (a layout at several sides), not both",
            ));
        }
        (false, None, true) => {
            return Err(ctx.err(
                None,
                "name",
                "a room file needs `name` and `side`, or `layout_side` and `[[instances]]`",
            ));
        }
    };
    let rooms = match only {
        Some((name, side)) if file.layout_side.is_some() => {
            let description = file
                .instances
                .iter()
                .find(|i| i.get_ref().name == name)
                .and_then(|i| i.get_ref().description.clone());
            vec![(name.to_string(), side, description, None)]
        }
        _ => rooms,
    };
    let layout_side = match &file.layout_side {
        Some(ls) => {
            let v = *ls.get_ref();
            if !(v.is_finite() && v > 0.0) {
                return Err(ctx.err(
                    Some(ls.span()),
                    "layout_side",
                    format!("must be positive, got {v}"),
                ));
            }
            Some(v)
        }
        None => None,
    };
    for (i, (name, side, _, span)) in rooms.iter().enumerate() {
        let key = if layout_side.is_some() { format!("instances[{i}]") } else { "side".into() };
        if !(side.is_finite() && *side > 0.0) {
            return Err(ctx.err(span.clone(), &key, format!("side must be positive, got {side}")));
        }
        if name.trim().is_empty() {
            return Err(ctx.err(span.clone(), &key, "name must not be empty"));
        }
        if rooms[..i].iter().any(|r| &r.0 == name) {
            return Err(ctx.err(span.clone(), &key, format!("room `{name}` is listed twice")));
        }
    }
    let thickness = match &file.wall_thickness {
        Some(t) if !(t.get_ref().is_finite() && *t.get_ref() > 0.0) => {
            return Err(ctx.err(
                Some(t.span()),
                "wall_thickness",
                format!("must be positive, got {}", t.get_ref()),
            ));
        }
        Some(t) => *t.get_ref(),
        None => DEFAULT_WALL_THICKNESS,
    };

    // Every shape on its own.
    for (i, o) in file.obstacles.iter().enumerate() {
        o.get_ref()
            .validate()
            .map_err(|e| ctx.err(Some(o.span()), &format!("obstacles[{i}]"), e))?;
    }
    for (i, t) in file.timed_obstacles.iter().enumerate() {
        t.get_ref()
            .obstacle
            .validate()
            .map_err(|e| ctx.err(Some(t.span()), &format!("timed_obstacles[{i}].obstacle"), e))?;
    }
    let (square, segments) = match &file.walls {
        Some(w) => (w.square, w.segments.as_slice()),
        None => (true, &[][..]),
    };
    for (i, w) in segments.iter().enumerate() {
        let s = w.get_ref();
        let key = format!("walls.segments[{i}]");
        if !(finite_point(&s.from) && finite_point(&s.to)) || s.from == s.to {
            return Err(ctx.err(Some(w.span()), &key, "needs two distinct, finite ends"));
        }
        if let Some(t) = s.thickness.filter(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(ctx.err(
                Some(w.span()),
                &key,
                format!("thickness must be positive, got {t}"),
            ));
        }
    }
    if !square && file.spawn_regions.is_empty() {
        let span = segments.first().map(|s| s.span());
        return Err(ctx.err(
            span,
            "walls.square",
            "a room without the square's walls needs `[[spawn_regions]]`: the sampler cannot \
             tell the inside of other outlines from the outside",
        ));
    }
    for (i, r) in file.spawn_regions.iter().enumerate() {
        let v = r.get_ref();
        let key = format!("spawn_regions[{i}]");
        if !(finite_point(&v.min)
            && finite_point(&v.max)
            && v.min[0] < v.max[0]
            && v.min[1] < v.max[1])
        {
            return Err(ctx.err(
                Some(r.span()),
                &key,
                "needs finite `min` below and left of `max`",
            ));
        }
        if !(v.starts || v.goals) {
            return Err(ctx.err(Some(r.span()), &key, "`starts` and `goals` are both false"));
        }
        if file.spawn_regions[..i].iter().any(|o| o.get_ref().name == v.name) {
            return Err(ctx.err(Some(r.span()), &key, format!("name `{}` is used twice", v.name)));
        }
    }
    for kind in [true, false] {
        let any = file
            .spawn_regions
            .iter()
            .any(|r| if kind { r.get_ref().starts } else { r.get_ref().goals });
        if !file.spawn_regions.is_empty() && !any {
            let what = if kind { "starts" } else { "goals" };
            return Err(ctx.err(
                Some(file.spawn_regions[0].span()),
                "spawn_regions",
                format!("no region is for {what}; set `{what} = true` on one"),
            ));
        }
    }
    for (i, r) in file.routes.iter().enumerate() {
        let v = r.get_ref();
        let key = format!("routes[{i}]");
        if v.goals.is_empty() {
            return Err(ctx.err(Some(r.span()), &key, "needs at least one goal"));
        }
        if !(finite_point(&v.start)
            && v.goals.iter().all(finite_point)
            && v.heading_deg.is_finite())
        {
            return Err(ctx.err(Some(r.span()), &key, "non-finite start, heading or goal"));
        }
        if file.routes[..i].iter().any(|o| o.get_ref().name == v.name) {
            return Err(ctx.err(Some(r.span()), &key, format!("name `{}` is used twice", v.name)));
        }
    }

    // Each room, instanced and checked against its square.
    let mut out = Vec::with_capacity(rooms.len());
    for (name, side, instance_description, _) in rooms {
        let s = layout_side.map_or(1.0, |ls| side / ls);
        let at = |p: Point| [p[0] * s, p[1] * s];
        let place = |o: &ObstacleSpec| -> ObstacleSpec {
            match o {
                ObstacleSpec::Compound { at: a, parts } => {
                    ObstacleSpec::Compound { at: at(*a), parts: parts.clone() }
                }
                ObstacleSpec::Box { center, half_extents, angle } => ObstacleSpec::Box {
                    center: at(*center),
                    half_extents: *half_extents,
                    angle: *angle,
                },
                ObstacleSpec::Circle { center, radius } => {
                    ObstacleSpec::Circle { center: at(*center), radius: *radius }
                }
                ObstacleSpec::Polygon { .. } => {
                    let a = o.anchor();
                    o.translated([a[0] * (s - 1.0), a[1] * (s - 1.0)])
                }
            }
        };
        let spec = RoomSpec {
            name: name.clone(),
            side,
            wall_thickness: thickness,
            obstacles: file.obstacles.iter().map(|o| place(o.get_ref())).collect(),
            description: instance_description.unwrap_or_else(|| file.description.clone()),
            square_walls: square,
            wall_segments: segments
                .iter()
                .map(|w| {
                    let w = w.get_ref();
                    WallSegment { from: at(w.from), to: at(w.to), thickness: w.thickness }
                })
                .collect(),
            spawn_regions: file
                .spawn_regions
                .iter()
                .map(|r| {
                    let r = r.get_ref();
                    SpawnRegion { min: at(r.min), max: at(r.max), ..r.clone() }
                })
                .collect(),
            routes: file
                .routes
                .iter()
                .map(|r| {
                    let r = r.get_ref();
                    Route {
                        start: at(r.start),
                        goals: r.goals.iter().map(|&g| at(g)).collect(),
                        ..r.clone()
                    }
                })
                .collect(),
            timed_obstacles: file
                .timed_obstacles
                .iter()
                .map(|t| TimedObstacle {
                    at_step: t.get_ref().at_step,
                    obstacle: place(&t.get_ref().obstacle),
                })
                .collect(),
        };
        check_geometry(&ctx, &file, &spec)?;
        out.push(spec);
    }
    Ok(out)
}

/// Checks one instanced room: everything inside its square, route points in free space.
fn check_geometry(ctx: &Ctx<'_>, file: &RoomFile, spec: &RoomSpec) -> Result<(), SpecFileError> {
    const EPS: f64 = 1e-9;
    let h = spec.side / 2.0;
    let room = if file.layout_side.is_some() {
        format!("room `{}` (side {} m): ", spec.name, spec.side)
    } else {
        String::new()
    };
    let inside = |lo: Point, hi: Point, margin: f64| {
        lo[0] >= -h - margin - EPS
            && lo[1] >= -h - margin - EPS
            && hi[0] <= h + margin + EPS
            && hi[1] <= h + margin + EPS
    };
    let out_of_room = |what: &str, lo: Point, hi: Point| {
        format!(
            "{room}{what} reaches outside the room: it spans x {:.3}..{:.3}, y {:.3}..{:.3}, the \
             room ±{h}",
            lo[0], hi[0], lo[1], hi[1]
        )
    };
    for (i, (o, f)) in spec.obstacles.iter().zip(&file.obstacles).enumerate() {
        let [lo, hi] = o.aabb();
        if !inside(lo, hi, 0.0) {
            let what = format!("the {}", o.kind());
            return Err(ctx.err(
                Some(f.span()),
                &format!("obstacles[{i}]"),
                out_of_room(&what, lo, hi),
            ));
        }
    }
    for (i, (t, f)) in spec.timed_obstacles.iter().zip(&file.timed_obstacles).enumerate() {
        let [lo, hi] = t.obstacle.aabb();
        if !inside(lo, hi, 0.0) {
            let what = format!("the {}", t.obstacle.kind());
            let key = format!("timed_obstacles[{i}].obstacle");
            return Err(ctx.err(Some(f.span()), &key, out_of_room(&what, lo, hi)));
        }
    }
    let segments = file.walls.as_ref().map_or(&[][..], |w| w.segments.as_slice());
    for (i, (w, f)) in spec.wall_segments.iter().zip(segments).enumerate() {
        let [lo, hi] = w.to_box(spec.wall_thickness).aabb();
        if !inside(lo, hi, spec.wall_thickness) {
            let key = format!("walls.segments[{i}]");
            return Err(ctx.err(Some(f.span()), &key, out_of_room("the wall", lo, hi)));
        }
    }
    for (i, (r, f)) in spec.spawn_regions.iter().zip(&file.spawn_regions).enumerate() {
        if !inside(r.min, r.max, 0.0) {
            let key = format!("spawn_regions[{i}]");
            return Err(ctx.err(Some(f.span()), &key, out_of_room("the region", r.min, r.max)));
        }
    }
    let walls = spec.walls();
    let blocked = |p: Point| -> Option<String> {
        if !inside(p, p, 0.0) {
            return Some(format!("lies outside the room (±{h})"));
        }
        if let Some(k) = spec.obstacles.iter().position(|o| o.contains(p)) {
            return Some(format!("lies inside obstacles[{k}] ({})", spec.obstacles[k].kind()));
        }
        if let Some(k) = spec.timed_obstacles.iter().position(|t| t.obstacle.contains(p)) {
            return Some(format!("lies inside timed_obstacles[{k}]"));
        }
        if walls.iter().any(|w| w.contains(p)) {
            return Some("lies inside a wall".to_string());
        }
        None
    };
    for (i, (r, f)) in spec.routes.iter().zip(&file.routes).enumerate() {
        let key = format!("routes[{i}]");
        if let Some(why) = blocked(r.start) {
            let p = r.start;
            return Err(ctx.err(
                Some(f.span()),
                &key,
                format!("{room}start ({}, {}) {why}", p[0], p[1]),
            ));
        }
        for (k, &g) in r.goals.iter().enumerate() {
            if let Some(why) = blocked(g) {
                let msg = format!("{room}goal {k} ({}, {}) {why}", g[0], g[1]);
                return Err(ctx.err(Some(f.span()), &key, msg));
            }
        }
    }
    Ok(())
}

/// Reads a spec file (room, footprint, …) as text, with the name its errors cite; `what`
/// names the kind in the error when it cannot be read ("room file").
pub fn read_spec_file(path: &Path, what: &str) -> Result<(String, String), SpecFileError> {
    let source = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| SpecFileError {
        source: source.clone(),
        line: None,
        key: String::new(),
        reason: format!("cannot read the {what}: {e}"),
    })?;
    Ok((text, source))
}

/// Reads and parses a room file.
pub fn load_room_file(path: &Path) -> Result<Vec<RoomSpec>, SpecFileError> {
    let (text, source) = read_spec_file(path, "room file")?;
    parse_room_file(&text, &source)
}

/// Every built-in room, file by file, in the order of [`BUILTIN_FILES`].
///
/// # Panics
/// If a built-in file is invalid (a test keeps them valid).
pub fn builtin_specs() -> Vec<RoomSpec> {
    BUILTIN_FILES
        .iter()
        .flat_map(|(source, text)| match parse_room_file(text, source) {
            Ok(rooms) => rooms,
            Err(e) => panic!("built-in room file: {e}"),
        })
        .collect()
}

impl RoomSpec {
    /// The training layout (`rooms/training.toml`) instanced at `side` metres: obstacle
    /// positions scale by `side / 8`, obstacle sizes stay the same, so smaller rooms are more
    /// crowded. Env_0..Env_3 are sides 8, 7, 6 and 5 (`Room::builtin("env0")`, …); the layout is
    /// checked to leave ≥ 0.6 m gaps down to side 5.
    pub fn training(name: &str, side: f64) -> RoomSpec {
        training_layout(name, side)
    }
}

/// The training layout (`rooms/training.toml`) at any `side`, named `name`.
fn training_layout(name: &str, side: f64) -> RoomSpec {
    let (source, text) = BUILTIN_FILES[0];
    match parse_instances(text, source, Some((name, side))) {
        Ok(mut rooms) => rooms.remove(0),
        Err(e) => panic!("training layout at side {side}: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"name = "small"
side = 4.0

[[obstacles]]
shape = "circle"
center = [1.0, 1.0]
radius = 0.3

[[obstacles]]
shape = "compound"
at = [-1.0, 0.0]
parts = [
  { shape = "box", center = [0.0, 0.0], half_extents = [0.4, 0.05] },
  { shape = "polygon", points = [[0.3, 0.05], [0.5, 0.05], [0.4, 0.4]] },
]

[[spawn_regions]]
name = "south"
min = [-1.8, -1.8]
max = [1.8, -1.0]

[[routes]]
name = "eval"
start = [0.0, -1.5]
heading_deg = 90.0
goals = [[0.0, 1.5], [1.5, 0.0]]

[[timed_obstacles]]
at_step = 5
obstacle = { shape = "box", center = [0.0, 0.0], half_extents = [0.3, 0.3], angle = 0.2 }
"#;

    /// Parses `GOOD` with `from` replaced by `to` and returns the error.
    fn broken(from: &str, to: &str) -> SpecFileError {
        assert!(GOOD.contains(from), "{from}");
        parse_room_file(&GOOD.replacen(from, to, 1), "small.toml").unwrap_err()
    }

    #[test]
    fn a_good_file_loads_every_part() {
        let rooms = parse_room_file(GOOD, "small.toml").unwrap();
        assert_eq!(rooms.len(), 1);
        let r = &rooms[0];
        assert_eq!((r.name.as_str(), r.side), ("small", 4.0));
        assert_eq!(r.obstacles[1].primitives().len(), 2);
        assert_eq!(r.spawn_regions[0].name, "south");
        assert!(r.spawn_regions[0].starts && r.spawn_regions[0].goals);
        assert_eq!(r.route("eval").unwrap().goals.len(), 2);
        assert_eq!(r.timed_obstacles[0].at_step, 5);
        assert!(crate::Room::try_new(r.clone()).is_ok());
    }

    #[test]
    fn bad_files_are_refused_with_line_key_and_reason() {
        // (replace, with, line, key, words in the reason)
        let cases: [(&str, &str, usize, &str, &str); 11] = [
            ("radius = 0.3", "radius = -0.3", 4, "obstacles[0]", "radius must be positive"),
            (
                "[[0.3, 0.05], [0.5, 0.05], [0.4, 0.4]]",
                "[[0.3, 0.05], [0.4, 0.4], [0.5, 0.05]]",
                9,
                "obstacles[1]",
                "clockwise",
            ),
            (
                "[[0.3, 0.05], [0.5, 0.05], [0.4, 0.4]]",
                "[[0.3, 0.05], [0.5, 0.05], [0.4, 0.1], [0.45, 0.4], [0.3, 0.3]]",
                9,
                "obstacles[1]",
                "convex",
            ),
            ("center = [1.0, 1.0]", "center = [1.9, 1.0]", 4, "obstacles[0]", "outside the room"),
            (
                "goals = [[0.0, 1.5], [1.5, 0.0]]",
                "goals = [[0.0, 1.5], [1.0, 1.1]]",
                22,
                "routes[0]",
                "goal 1 (1, 1.1) lies inside obstacles[0]",
            ),
            ("start = [0.0, -1.5]", "start = [0.0, -2.5]", 22, "routes[0]", "outside the room"),
            ("max = [1.8, -1.0]", "max = [-1.9, -1.0]", 17, "spawn_regions[0]", "below and left"),
            ("radius = 0.3", "radios = 0.3", 4, "", "unknown field `radios`"),
            ("shape = \"circle\"", "shape = \"disc\"", 5, "", "disc"),
            ("side = 4.0", "side = \"big\"", 2, "", "invalid type"),
            ("side = 4.0", "side = 4.0\nside = 5.0", 3, "", "duplicate key"),
        ];
        for (from, to, line, key, words) in cases {
            let e = broken(from, to);
            assert_eq!(e.line, Some(line), "{from} → {to}: {e}");
            assert_eq!(e.key, key, "{from} → {to}: {e}");
            assert!(e.reason.contains(words), "{from} → {to}: {e}");
            let shown = e.to_string();
            assert!(shown.starts_with(&format!("small.toml:{line}:")), "{shown}");
        }
        // A compound part that is a compound, and a timed obstacle outside the room.
        let e = broken(
            "{ shape = \"box\", center = [0.0, 0.0], half_extents = [0.4, 0.05] }",
            "{ shape = \"compound\", parts = [] }",
        );
        assert!(e.key == "obstacles[1]" && e.reason.contains("compound"), "{e}");
        let e = broken(
            "center = [0.0, 0.0], half_extents = [0.3, 0.3]",
            "center = [0.0, 3.0], half_extents = [0.3, 0.3]",
        );
        assert_eq!(e.key, "timed_obstacles[0].obstacle", "{e}");
        // Neither a room nor a layout; a layout without instances.
        let e = parse_room_file("side = 3.0\n", "x.toml").unwrap_err();
        assert!(e.reason.contains("`name`"), "{e}");
        let e = parse_room_file("layout_side = 8.0\n", "x.toml").unwrap_err();
        assert_eq!((e.line, e.key.as_str()), (Some(1), "instances"), "{e}");
        // Non-square rooms need spawn regions.
        let e = parse_room_file(
            "name = \"n\"\nside = 4.0\n[walls]\nsquare = false\nsegments = [{ from = [0.0, -2.0], to = [0.0, 2.0] }]\n",
            "x.toml",
        )
        .unwrap_err();
        assert_eq!(e.key, "walls.square", "{e}");
        // Garbage never panics.
        for text in [
            "",
            "=",
            "[[obstacles]]\n",
            "name = 1",
            "\u{0}",
            "obstacles = 3\nname = \"a\"\nside = 1.0",
        ] {
            assert!(parse_room_file(text, "x.toml").is_err(), "{text:?}");
        }
    }

    #[test]
    fn layouts_scale_positions_not_sizes() {
        let text = "layout_side = 8.0\n[[instances]]\nname = \"big\"\nside = 8.0\n[[instances]]\n\
                    name = \"small\"\nside = 4.0\n[[obstacles]]\nshape = \"circle\"\n\
                    center = [2.0, 2.0]\nradius = 0.5\n[[obstacles]]\nshape = \"polygon\"\n\
                    points = [[-2.0, -2.0], [-1.0, -2.0], [-1.5, -1.0]]\n[[routes]]\n\
                    name = \"r\"\nstart = [0.0, 0.0]\ngoals = [[2.0, -2.0]]\n";
        let rooms = parse_room_file(text, "l.toml").unwrap();
        let small = &rooms[1];
        assert_eq!(small.obstacles[0], ObstacleSpec::Circle { center: [1.0, 1.0], radius: 0.5 });
        let a = small.obstacles[1].anchor();
        assert!((a[0] + 0.75).abs() < 1e-12 && (a[1] + 5.0 / 6.0).abs() < 1e-12, "{a:?}");
        let ObstacleSpec::Polygon { points } = &small.obstacles[1] else { panic!() };
        assert!(((points[1][0] - points[0][0]) - 1.0).abs() < 1e-12, "size kept");
        assert_eq!(small.routes[0].goals[0], [1.0, -1.0]);
    }

    #[test]
    fn builtin_files_load() {
        let names: Vec<String> = builtin_specs().into_iter().map(|s| s.name).collect();
        assert_eq!(names.len(), 7);
        for (source, text) in BUILTIN_FILES {
            let rooms = parse_room_file(text, source).unwrap();
            for r in rooms {
                assert!(!r.description.is_empty(), "{}", r.name);
                crate::Room::try_new(r).unwrap();
            }
        }
    }
}

#[cfg(test)]
mod readme {
    /// The example room file in README § Rooms parses, and so does its footprint example.
    #[test]
    fn readme_examples_load() {
        let readme = include_str!("../../../README.md");
        let rooms = &readme[readme.find("## Rooms").expect("README has § Rooms")..];
        let mut blocks = rooms.split("```toml\n").skip(1).map(|b| &b[..b.find("```").unwrap()]);
        let room = blocks.next().unwrap();
        let specs = super::parse_room_file(room, "README.md").unwrap();
        assert_eq!(specs[0].name, "corridor");
        crate::Room::try_new(specs[0].clone()).unwrap();
        let fp = crate::Footprint::from_toml_str(blocks.next().unwrap(), "README.md").unwrap();
        assert_eq!(fp.parts.len(), 2);
    }
}
