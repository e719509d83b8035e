//! `dvnav rooms`: the built-in rooms (and room files) as a table, JSON, or a PNG map.

use crate::render::room_map::render_room;
use clap::{Args, Subcommand};
use dvnav_nav::dvst::VariedRobot;
use dvnav_sim::{Room, RoomSpec};
use std::path::PathBuf;
use std::process::ExitCode;

/// `dvnav rooms`.
#[derive(Args, Debug)]
pub struct RoomsArgs {
    #[command(subcommand)]
    command: RoomsCommand,
}

#[derive(Subcommand, Debug)]
enum RoomsCommand {
    /// One line per built-in room (or per room of the given files): name, size, obstacles,
    /// routes.
    List {
        /// Room files to list instead of the built-in rooms.
        files: Vec<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Draw a room (built-in name or a room file) to a PNG: walls, obstacles, spawn regions,
    /// routes with numbered goals, obstacles that appear later.
    Show {
        /// A built-in room name (`dvnav rooms list`) or the path of a room file.
        room: String,
        /// Output PNG; a file with several rooms writes NAME-ROOM.png for each.
        #[arg(long, default_value = "room.png")]
        out: PathBuf,
        /// Draw this robot footprint (a footprint TOML file, e.g. from `footprints/`) at the
        /// first route's start.
        #[arg(long)]
        footprint: Option<PathBuf>,
        /// Map size in pixels.
        #[arg(long, default_value_t = 800)]
        size: u32,
    },
}

/// One room's summary.
#[derive(serde::Serialize)]
struct RoomRow {
    name: String,
    side_m: f64,
    walls: String,
    obstacles: usize,
    obstacle_parts: usize,
    timed_obstacles: usize,
    spawn_regions: Vec<String>,
    routes: Vec<RouteRow>,
    description: String,
}

#[derive(serde::Serialize)]
struct RouteRow {
    name: String,
    start: [f64; 3],
    goals: Vec<[f64; 2]>,
}

fn row(s: &RoomSpec) -> RoomRow {
    RoomRow {
        name: s.name.clone(),
        side_m: s.side,
        walls: match (s.square_walls, s.wall_segments.len()) {
            (true, 0) => "square".into(),
            (true, n) => format!("square + {n} segments"),
            (false, n) => format!("{n} segments"),
        },
        obstacles: s.obstacles.len(),
        obstacle_parts: s.obstacles.iter().map(|o| o.primitives().len()).sum(),
        timed_obstacles: s.timed_obstacles.len(),
        spawn_regions: s.spawn_regions.iter().map(|r| r.name.clone()).collect(),
        routes: s
            .routes
            .iter()
            .map(|r| RouteRow {
                name: r.name.clone(),
                start: [r.start[0], r.start[1], r.heading_deg],
                goals: r.goals.clone(),
            })
            .collect(),
        description: s.description.clone(),
    }
}

/// Runs `dvnav rooms`.
pub fn run(args: RoomsArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        RoomsCommand::List { files, json } => {
            let mut specs = Vec::new();
            if files.is_empty() {
                specs = dvnav_sim::room_file::builtin_specs();
            }
            for f in &files {
                specs.extend(Room::from_file(f)?.iter().map(|r| r.spec().clone()));
            }
            let rows: Vec<RoomRow> = specs.iter().map(row).collect();
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&serde_json::json!({ "rooms": rows }))?
                );
            } else {
                println!(
                    "{:<9} {:>8}  {:<20} {:>9}  {:>5}  {:<16} description",
                    "name", "size", "walls", "obstacles", "timed", "routes"
                );
                for r in &rows {
                    let routes: Vec<String> =
                        r.routes.iter().map(|x| format!("{}({})", x.name, x.goals.len())).collect();
                    println!(
                        "{:<9} {:>8}  {:<20} {:>9}  {:>5}  {:<16} {}",
                        r.name,
                        format!("{0}x{0} m", r.side_m),
                        r.walls,
                        format!("{} ({})", r.obstacles, r.obstacle_parts),
                        r.timed_obstacles,
                        routes.join(","),
                        r.description
                    );
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        RoomsCommand::Show { room, out, footprint, size } => {
            anyhow::ensure!((64..=8192).contains(&size), "--size must be in 64..=8192 pixels");
            // A DVST varied-robot file (`footprints/`) is a footprint file with a few keys more.
            let footprint =
                footprint.map(|p| VariedRobot::load(&p).map(|r| r.footprint)).transpose()?;
            let rooms = Room::load(&room)?;
            if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)?;
            }
            for r in &rooms {
                let path = if rooms.len() == 1 {
                    out.clone()
                } else {
                    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("room");
                    out.with_file_name(format!("{stem}-{}.png", r.name()))
                };
                let canvas = render_room(r.spec(), footprint.as_ref(), size)?;
                std::fs::write(&path, canvas.encode_png()?)?;
                eprintln!(
                    "dvnav rooms: {} -> {} ({}x{} px)",
                    r.name(),
                    path.display(),
                    canvas.width(),
                    canvas.height()
                );
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
