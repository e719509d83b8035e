//! `dvnav plot`: figures from a run, as PNG ([`crate::render`]).

use super::inspect::EpisodeFilter;
use crate::render::trajectories::{RoomPanel, Trajectory, render};
use clap::{Args, Subcommand};
use dvnav_eval::episode_log::{EpisodeRecord, read_episodes, read_steps};
use dvnav_learner::evaluator::EvalRow;
use dvnav_learner::metrics::csv_log;
use dvnav_sim::Room;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Draw figures from MCAP episode logs.
#[derive(Args, Debug)]
pub struct PlotArgs {
    #[command(subcommand)]
    command: PlotCommand,
}

#[derive(Subcommand, Debug)]
enum PlotCommand {
    /// The selected episodes' paths over their rooms (one panel per room), coloured by
    /// outcome: green success, red collision, orange timeout.
    Trajectories(TrajectoriesArgs),
    /// Learning curves of one or more runs (seeds), mean ± std over the runs against
    /// environment steps, one panel per room: the paper's score S of the deterministic policy
    /// on each room's evaluation route (`eval.csv`, written every `learner.eval_every_updates`),
    /// or with `--metric success` the training success rate over the curriculum window
    /// (`metrics.csv`).
    Curves(CurvesArgs),
}

/// `dvnav plot curves`.
#[derive(Args, Debug)]
pub struct CurvesArgs {
    /// Run directories (each with a `metrics.csv`), e.g. one per seed.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// The PNG to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Points along the step axis.
    #[arg(long, default_value_t = 100)]
    pub points: usize,
    /// What to draw.
    #[arg(long, value_enum, default_value_t = CurveMetric::Score)]
    pub metric: CurveMetric,
}

/// `dvnav plot curves --metric`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CurveMetric {
    /// Score S on each room's evaluation route (`eval.csv`), in [−1, 1].
    Score,
    /// Training success rate per stage over the curriculum window (`metrics.csv`).
    Success,
}

/// Per room, the `(env_steps, route score)` rows of a run's `eval.csv`.
fn score_series(run: &Path) -> anyhow::Result<BTreeMap<u32, Vec<(f64, f64)>>> {
    let path = run.join("eval.csv");
    if let Err(e) = std::fs::metadata(&path) {
        anyhow::bail!(
            "cannot read {}: {e} (runs from before evaluation during training have none: use --metric success)",
            path.display()
        );
    }
    let rooms = dvnav_config::Config::default().curriculum.rooms;
    let mut out: BTreeMap<u32, Vec<(f64, f64)>> = BTreeMap::new();
    for row in EvalRow::read(&path)? {
        let Some(k) = rooms.iter().position(|r| *r == row.room) else { continue };
        out.entry(k as u32).or_default().push((row.env_steps as f64, row.score));
    }
    Ok(out)
}

/// `dvnav plot trajectories`.
#[derive(Args, Debug)]
pub struct TrajectoriesArgs {
    /// An .mcap file, a directory of them, or a run directory (searched recursively).
    pub path: PathBuf,
    /// The PNG to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Which episodes.
    #[command(flatten)]
    pub filter: EpisodeFilter,
    /// Draw at most this many episodes, the latest ones (highest ids per actor).
    #[arg(long, default_value_t = 100)]
    pub max: usize,
    /// Side of each room panel (pixels).
    #[arg(long, default_value_t = 640)]
    pub size: u32,
}

pub fn run(args: PlotArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        PlotCommand::Trajectories(a) => trajectories(a),
        PlotCommand::Curves(a) => curves(a),
    }
}

/// Per stage, the `(env_steps, success rate)` rows of a run's `metrics.csv` where the rate is
/// defined.
fn success_series(run: &Path) -> anyhow::Result<BTreeMap<u32, Vec<(f64, f64)>>> {
    let path = run.join("metrics.csv");
    if let Err(e) = std::fs::metadata(&path) {
        anyhow::bail!("cannot read {}: {e} (is it a run directory?)", path.display());
    }
    let mut out: BTreeMap<u32, Vec<(f64, f64)>> = BTreeMap::new();
    for row in csv_log::read(&path)? {
        for (k, &v) in row.success_rate_stage.iter().enumerate() {
            if v.is_finite() {
                out.entry(k as u32).or_default().push((row.env_steps as f64, v));
            }
        }
    }
    Ok(out)
}

fn curves(args: CurvesArgs) -> anyhow::Result<ExitCode> {
    use crate::render::curves::{Axes, Curve, Panel, mean_std_on_grid, render};
    let mut per_stage: BTreeMap<u32, Vec<Vec<(f64, f64)>>> = BTreeMap::new();
    let mut x_max: f64 = 0.0;
    for run in &args.runs {
        let series = match args.metric {
            CurveMetric::Score => score_series(run)?,
            CurveMetric::Success => success_series(run)?,
        };
        for (k, series) in series {
            x_max = series.iter().fold(x_max, |m, (x, _)| m.max(*x));
            per_stage.entry(k).or_default().push(series);
        }
    }
    anyhow::ensure!(
        !per_stage.is_empty(),
        "no rows in the runs' {} yet",
        match args.metric {
            CurveMetric::Score => "eval.csv",
            CurveMetric::Success => "metrics.csv",
        }
    );
    let n = args.points.max(2);
    let grid: Vec<f64> = (0..n).map(|i| x_max * i as f64 / (n - 1) as f64).collect();
    let rooms = dvnav_config::Config::default().curriculum.rooms;
    let panels: Vec<Panel> = per_stage
        .iter()
        .map(|(k, runs)| Panel {
            title: match rooms.get(*k as usize) {
                Some(r) => format!("stage {k}: {r}"),
                None => format!("stage {k}"),
            },
            curves: vec![Curve {
                label: format!("{} run(s)", runs.len()),
                points: mean_std_on_grid(runs, &grid),
            }],
        })
        .collect();
    let axes = match args.metric {
        CurveMetric::Score => {
            Axes { x_max, y_min: -1.0, y_max: 1.0, y_label: "route score S".into() }
        }
        CurveMetric::Success => {
            Axes { x_max, y_min: 0.0, y_max: 1.0, y_label: "success rate".into() }
        }
    };
    let canvas = render(&panels, &axes, 480, 360)?;
    std::fs::write(&args.out, canvas.encode_png()?)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", args.out.display()))?;
    println!(
        "wrote {} ({} stage panel(s), {} run(s), up to {} steps)",
        args.out.display(),
        panels.len(),
        args.runs.len(),
        x_max
    );
    Ok(ExitCode::SUCCESS)
}

/// The latest `max` records (highest ids, per actor in turn), in their original order.
fn latest(mut records: Vec<EpisodeRecord>, max: usize) -> Vec<EpisodeRecord> {
    if records.len() > max {
        // Records are sorted by (actor id, episode id); rank by id across actors.
        let mut ids: Vec<u64> = records.iter().map(|r| r.summary.episode_id).collect();
        ids.sort_unstable();
        let cut = ids[ids.len() - max];
        let mut above = records.iter().filter(|r| r.summary.episode_id > cut).count();
        records.retain(|r| {
            let id = r.summary.episode_id;
            if id > cut {
                true
            } else if id == cut && above < max {
                above += 1;
                true
            } else {
                false
            }
        });
    }
    records
}

/// The room an episode was logged in, rebuilt from its logged name as `dvnav eval --room`
/// builds it: a built-in or a generated room (a generator seed names its whole room). A map or
/// room file is logged by its own name, not its path: drawn without the room.
fn room_of(name: &str) -> Option<dvnav_sim::RoomSpec> {
    match Room::load(name) {
        Ok(rooms) if rooms.len() == 1 => Some(rooms[0].spec().clone()),
        Ok(_) => {
            tracing::warn!(room = %name, "drawing paths without the room: its name loads several");
            None
        }
        Err(e) => {
            tracing::warn!(room = %name, error = %e, "drawing paths without the room");
            None
        }
    }
}

/// Reads the paths of `records` (grouped by file, so each file is read once) and groups them
/// by room.
fn panels(records: &[EpisodeRecord]) -> anyhow::Result<Vec<RoomPanel>> {
    let mut by_file: BTreeMap<&Path, BTreeSet<u64>> = BTreeMap::new();
    for r in records {
        by_file.entry(r.file.as_path()).or_default().insert(r.summary.episode_id);
    }
    let mut steps = BTreeMap::new();
    for (file, ids) in by_file {
        for (id, s) in read_steps(file, &ids)? {
            steps.insert((file.to_path_buf(), id), s);
        }
    }
    let mut rooms: BTreeMap<String, RoomPanel> = BTreeMap::new();
    for r in records {
        let s = &r.summary;
        let Some(path) = steps.get(&(r.file.clone(), s.episode_id)) else {
            tracing::warn!(episode = s.episode_id, file = %r.file.display(), "no step records; skipped");
            continue;
        };
        let panel = rooms.entry(s.room.clone()).or_insert_with(|| RoomPanel {
            name: s.room.clone(),
            room: room_of(&s.room),
            trajectories: Vec::new(),
        });
        panel.trajectories.push(Trajectory {
            points: path.iter().map(|p| [p.x, p.y]).collect(),
            outcome: dvnav_link::wire::outcome_from_proto(s.outcome),
            goal: [s.goal_x, s.goal_y],
            radius: footprint_radius(&s.footprint),
            plan: Vec::new(),
        });
    }
    Ok(rooms.into_values().collect())
}

/// The radius in a logged footprint description (`circle r=0.2`).
fn footprint_radius(footprint: &str) -> Option<f64> {
    footprint.strip_prefix("circle r=")?.trim().parse().ok().filter(|r: &f64| *r > 0.0)
}

fn trajectories(args: TrajectoriesArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.path.exists(), "{} does not exist", args.path.display());
    anyhow::ensure!(args.max > 0, "--max must be at least 1");
    let records = latest(args.filter.apply(read_episodes(&args.path)?), args.max);
    anyhow::ensure!(!records.is_empty(), "no logged episode under {} matches", args.path.display());
    let panels = panels(&records)?;
    let n: usize = panels.iter().map(|p| p.trajectories.len()).sum();
    let canvas = render(&panels, args.size)?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&args.out, canvas.encode_png()?)?;
    eprintln!(
        "dvnav plot: {n} episodes in {} rooms -> {} ({}x{} px)",
        panels.len(),
        args.out.display(),
        canvas.width(),
        canvas.height()
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(actor_id: u32, id: u64) -> EpisodeRecord {
        EpisodeRecord {
            file: PathBuf::from("x.mcap"),
            summary: dvnav_proto::EpisodeSummary { actor_id, episode_id: id, ..Default::default() },
        }
    }

    #[test]
    fn footprint_radius_is_read_from_circles_only() {
        assert_eq!(footprint_radius("circle r=0.2"), Some(0.2));
        assert_eq!(footprint_radius("rect 0.4x0.3"), None);
        assert_eq!(footprint_radius("circle r=-1"), None);
    }

    #[test]
    fn built_in_and_generated_rooms_are_drawn_and_a_map_name_is_not() {
        assert_eq!(room_of("env3").map(|r| r.name), Some("env3".to_string()));
        let generated = room_of("generated:paper:8000").expect("a generated room rebuilds");
        let again = Room::load("generated:paper:8000").unwrap();
        assert_eq!(&generated, again[0].spec(), "the same room as dvnav eval drove");
        assert_eq!(room_of("willow"), None, "a map is logged by name, not by path");
    }

    #[test]
    fn latest_keeps_the_highest_ids() {
        let records = vec![rec(0, 1), rec(0, 5), rec(0, 9), rec(1, 2), rec(1, 5), rec(1, 7)];
        let keep = |max| -> Vec<(u32, u64)> {
            latest(records.clone(), max)
                .iter()
                .map(|r| (r.summary.actor_id, r.summary.episode_id))
                .collect()
        };
        assert_eq!(keep(2), [(0, 9), (1, 7)]);
        assert_eq!(keep(3), [(0, 5), (0, 9), (1, 7)]);
        assert_eq!(keep(4), [(0, 5), (0, 9), (1, 5), (1, 7)]);
        assert_eq!(keep(10).len(), 6);
    }
}

#[cfg(test)]
mod curve_tests {
    use super::*;

    #[test]
    fn success_series_reads_each_stage_and_skips_undefined_and_torn_rows() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("metrics.csv"),
            "time_s,env_steps,success_rate_stage0,success_rate_stage1\n\
             0.0,0,NaN,NaN\n\
             2.0,100,0.5,NaN\n\
             4.0,200,0.9,0.1\n\
             6.0,300,0.9",
        )
        .unwrap();
        let s = success_series(dir.path()).unwrap();
        assert_eq!(s[&0], vec![(100.0, 0.5), (200.0, 0.9)]);
        assert_eq!(s[&1], vec![(200.0, 0.1)]);
        let err = success_series(&dir.path().join("missing")).unwrap_err().to_string();
        assert!(err.contains("metrics.csv"), "{err}");
    }

    #[test]
    fn curves_writes_a_png() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("metrics.csv"),
            "env_steps,success_rate_stage0\n0,0.1\n100,0.4\n200,0.8\n",
        )
        .unwrap();
        let out = dir.path().join("c.png");
        let args = |metric| CurvesArgs {
            runs: vec![dir.path().to_path_buf()],
            out: out.clone(),
            points: 10,
            metric,
        };
        curves(args(CurveMetric::Success)).unwrap();
        assert!(std::fs::read(&out).unwrap().starts_with(b"\x89PNG"));
        // No eval.csv: the score curves say what is missing and what to do.
        let err = curves(args(CurveMetric::Score)).unwrap_err().to_string();
        assert!(err.contains("eval.csv") && err.contains("--metric success"), "{err}");
    }

    #[test]
    fn score_series_reads_the_route_score_per_room() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("eval.csv"),
            "updates,env_steps,room,score\n2000,9000,env0,-1.0\n2000,9000,env3,0.25\n4000,18000,env0,0.5\n4000,18",
        )
        .unwrap();
        let s = score_series(dir.path()).unwrap();
        assert_eq!(s[&0], vec![(9000.0, -1.0), (18000.0, 0.5)]);
        assert_eq!(s[&3], vec![(9000.0, 0.25)]);
    }
}
