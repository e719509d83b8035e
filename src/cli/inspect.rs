//! `dvnav inspect`: summaries, per-episode listings, one episode's detail, and file checks of
//! MCAP episode logs; `--json` for each.

use clap::{Args, ValueEnum};
use dvnav_eval::episode_log::{
    EpisodeRecord, FileCheck, check_files, episode_detail, read_episodes, read_steps, summarize,
};
use dvnav_sim::Outcome;
use serde::Serialize;
use serde_json::json;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Summarize MCAP episode logs per actor and stage (episodes, success / collision / timeout
/// rates, mean steps, mean return); list episodes; show one episode; check files.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// An .mcap file, a directory of them, or a run directory (searched recursively).
    pub path: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Which episodes.
    #[command(flatten)]
    pub filter: EpisodeFilter,
    /// One line per episode instead of the per-actor summary.
    #[arg(long, conflicts_with_all = ["episode", "check"])]
    pub list: bool,
    /// Decode every message of every file against its schema; report finished and unfinished
    /// files, message counts and bytes per 1,000 logged steps. Exits 1 on any error (an
    /// unfinished tail left by a killed actor is not one).
    #[arg(long, conflicts_with = "episode")]
    pub check: bool,
}

/// Episode outcome, for filters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OutcomeArg {
    /// Reached the goal.
    Success,
    /// Touched an obstacle.
    Collision,
    /// Ran out of steps.
    Timeout,
}

impl OutcomeArg {
    fn matches(self, proto: i32) -> bool {
        let want = match self {
            OutcomeArg::Success => Outcome::Success,
            OutcomeArg::Collision => Outcome::Collision,
            OutcomeArg::Timeout => Outcome::Timeout,
        };
        dvnav_link::wire::outcome_from_proto(proto) == Some(want)
    }
}

/// Selects logged episodes (shared by `inspect` and `plot trajectories`).
#[derive(Args, Debug, Clone, Default, Serialize)]
pub struct EpisodeFilter {
    /// Only this actor (e.g. `actor-0`).
    #[arg(long)]
    pub actor: Option<String>,
    /// Only this curriculum stage (0: the 8 m room).
    #[arg(long)]
    pub stage: Option<u32>,
    /// Only episodes with this outcome.
    #[arg(long, value_enum)]
    #[serde(skip)]
    pub outcome: Option<OutcomeArg>,
    /// Only episodes in this room (e.g. `env0`).
    #[arg(long)]
    pub room: Option<String>,
    /// Only this episode id (ids are unique within an actor; add --actor when several actors
    /// have it).
    #[arg(long, value_name = "ID")]
    pub episode: Option<u64>,
}

impl EpisodeFilter {
    /// Whether `r` passes every filter that is set.
    pub fn matches(&self, r: &EpisodeRecord) -> bool {
        let s = &r.summary;
        self.actor.as_ref().is_none_or(|a| *a == s.actor)
            && self.stage.is_none_or(|st| st == s.stage)
            && self.outcome.is_none_or(|o| o.matches(s.outcome))
            && self.room.as_ref().is_none_or(|room| *room == s.room)
            && self.episode.is_none_or(|id| id == s.episode_id)
    }

    /// The records that pass.
    pub fn apply(&self, records: Vec<EpisodeRecord>) -> Vec<EpisodeRecord> {
        records.into_iter().filter(|r| self.matches(r)).collect()
    }

    fn as_json(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        v["outcome"] = json!(self.outcome.map(|o| format!("{o:?}").to_lowercase()));
        v
    }
}

/// One row of `--list`.
#[derive(Debug, Serialize)]
struct ListRow<'a> {
    actor: &'a str,
    episode_id: u64,
    env_index: u32,
    stage: u32,
    room: &'a str,
    outcome: &'static str,
    steps: u32,
    episode_return: f64,
    score: f64,
    policy_version: u64,
    warmup: bool,
    mu: f64,
    file: &'a Path,
}

fn outcome_name(v: i32) -> &'static str {
    dvnav_link::wire::outcome_from_proto(v).map_or("unspecified", |o| o.as_str())
}

fn list_row(r: &EpisodeRecord) -> ListRow<'_> {
    let s = &r.summary;
    ListRow {
        actor: &s.actor,
        episode_id: s.episode_id,
        env_index: s.env_index,
        stage: s.stage,
        room: &s.room,
        outcome: outcome_name(s.outcome),
        steps: s.steps,
        episode_return: s.episode_return,
        score: s.score,
        policy_version: s.policy_version,
        warmup: s.warmup,
        mu: s.mu,
        file: &r.file,
    }
}

pub fn run(args: InspectArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.path.exists(), "{} does not exist", args.path.display());
    if args.check {
        return check(&args);
    }
    let records = args.filter.apply(read_episodes(&args.path)?);
    if args.filter.episode.is_some() {
        return detail(&args, &records);
    }
    if args.list {
        return list(&args, &records);
    }
    let groups = summarize(&records);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "path": args.path,
                "filters": args.filter.as_json(),
                "episodes": records.len(),
                "groups": groups,
            }))?
        );
        return Ok(ExitCode::SUCCESS);
    }
    if records.is_empty() {
        println!("no logged episodes under {} match", args.path.display());
        return Ok(ExitCode::SUCCESS);
    }
    println!("{} logged episodes under {}", records.len(), args.path.display());
    println!(
        "{:<16} {:>5} {:>8} {:>8} {:>9} {:>8} {:>10} {:>11}",
        "actor",
        "stage",
        "episodes",
        "success",
        "collision",
        "timeout",
        "mean steps",
        "mean return"
    );
    for g in &groups {
        println!(
            "{:<16} {:>5} {:>8} {:>7.1}% {:>8.1}% {:>7.1}% {:>10.1} {:>11.2}",
            g.actor,
            g.stage,
            g.episodes,
            100.0 * g.success_rate,
            100.0 * g.collision_rate,
            100.0 * g.timeout_rate,
            g.mean_steps,
            g.mean_return
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn list(args: &InspectArgs, records: &[EpisodeRecord]) -> anyhow::Result<ExitCode> {
    let rows: Vec<ListRow<'_>> = records.iter().map(list_row).collect();
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "path": args.path,
                "filters": args.filter.as_json(),
                "episodes": rows.len(),
                "list": rows,
            }))?
        );
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{:<12} {:>7} {:>3} {:>5} {:<6} {:<9} {:>5} {:>8} {:>6} {:>6} {:>6}  file",
        "actor",
        "episode",
        "env",
        "stage",
        "room",
        "outcome",
        "steps",
        "return",
        "score",
        "policy",
        "warmup"
    );
    for r in &rows {
        println!(
            "{:<12} {:>7} {:>3} {:>5} {:<6} {:<9} {:>5} {:>8.2} {:>6.2} {:>6} {:>6}  {}",
            r.actor,
            r.episode_id,
            r.env_index,
            r.stage,
            r.room,
            r.outcome,
            r.steps,
            r.episode_return,
            r.score,
            r.policy_version,
            if r.warmup { "pid" } else { "" },
            r.file.file_name().map_or_else(String::new, |f| f.to_string_lossy().into_owned()),
        );
    }
    println!("{} episodes", rows.len());
    Ok(ExitCode::SUCCESS)
}

fn detail(args: &InspectArgs, records: &[EpisodeRecord]) -> anyhow::Result<ExitCode> {
    let id = args.filter.episode.expect("called with --episode");
    let record = match records {
        [] => anyhow::bail!("no logged episode {id} under {} matches", args.path.display()),
        [one] => one,
        many => {
            let actors: BTreeSet<&str> = many.iter().map(|r| r.summary.actor.as_str()).collect();
            anyhow::bail!(
                "episode {id} was logged by {} actors ({}); choose one with --actor",
                many.len(),
                actors.into_iter().collect::<Vec<_>>().join(", ")
            )
        }
    };
    let mut steps = read_steps(&record.file, &BTreeSet::from([id]))?;
    let detail = episode_detail(record, &steps.remove(&id).unwrap_or_default());
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "path": args.path, "episode": detail }))?
        );
        return Ok(ExitCode::SUCCESS);
    }
    let d = &detail;
    let pair = |p: [f64; 2]| format!("({:.2}, {:.2})", p[0], p[1]);
    let rows: Vec<(&str, String)> = vec![
        (
            "episode",
            format!("{} (actor {} #{}, env {})", d.episode_id, d.actor, d.actor_id, d.env_index),
        ),
        ("stage / room", format!("{} / {}", d.stage, d.room)),
        ("outcome", d.outcome.clone()),
        ("steps", format!("{} ({} step records logged)", d.steps, d.logged_steps)),
        ("return", format!("{:.3}", d.episode_return)),
        ("score", format!("{:.3}", d.score)),
        (
            "driver",
            if d.warmup { "PID warm-up".into() } else { format!("policy v{}", d.policy_version) },
        ),
        ("footprint", format!("{} (mu = {})", d.footprint, d.mu)),
        (
            "start -> goal",
            format!(
                "{} -> {} ({:.2} m apart)",
                pair(d.start),
                pair(d.goal),
                d.start_goal_distance_m
            ),
        ),
        ("path length", format!("{:.2} m", d.path_length_m)),
        (
            "goal distance",
            format!(
                "{:.2} m at the end, {:.2} m closest",
                d.final_goal_distance_m, d.min_goal_distance_m
            ),
        ),
        (
            "velocity",
            format!(
                "mean v {:.3} m/s (max {:.3}), mean |w| {:.3} rad/s",
                d.mean_v, d.max_v, d.mean_abs_omega
            ),
        ),
        ("sim time", format!("{:.1} s .. {:.1} s in the file", d.start_time_s, d.end_time_s)),
        ("seed", d.seed.to_string()),
        ("file", d.file.display().to_string()),
    ];
    for (k, v) in rows {
        println!("{k:<14} {v}");
    }
    Ok(ExitCode::SUCCESS)
}

/// Totals over checked files.
#[derive(Debug, Default, Serialize)]
struct CheckTotals {
    files: usize,
    finished: usize,
    unfinished: usize,
    with_errors: usize,
    bytes: u64,
    steps: u64,
    complete_episodes: u64,
    messages: u64,
    /// Disk bytes per 1,000 logged steps (all topics, compressed, with indexes).
    bytes_per_1000_steps: f64,
}

fn totals(checks: &[FileCheck]) -> CheckTotals {
    let mut t = CheckTotals { files: checks.len(), ..Default::default() };
    for c in checks {
        t.finished += usize::from(c.finished);
        t.unfinished += usize::from(!c.finished);
        t.with_errors += usize::from(!c.is_ok());
        t.bytes += c.bytes;
        t.steps += c.steps;
        t.complete_episodes += c.complete_episodes;
        t.messages += c.messages;
    }
    t.bytes_per_1000_steps =
        if t.steps == 0 { f64::NAN } else { t.bytes as f64 * 1000.0 / t.steps as f64 };
    t
}

fn check(args: &InspectArgs) -> anyhow::Result<ExitCode> {
    let checks = check_files(&args.path)?;
    let t = totals(&checks);
    let code = if t.with_errors == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE };
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "path": args.path,
                "ok": t.with_errors == 0,
                "totals": t,
                "files": checks,
            }))?
        );
        return Ok(code);
    }
    for c in &checks {
        let state = match (c.is_ok(), c.finished) {
            (false, _) => "ERROR",
            (true, true) => "finished",
            (true, false) => "unfinished",
        };
        println!(
            "{:<10} {:>9} B {:>7} msgs {:>6} steps {:>4} episodes  {}",
            state,
            c.bytes,
            c.messages,
            c.steps,
            c.complete_episodes,
            c.file.display()
        );
        if let Some(t) = &c.truncated {
            println!("           readable up to the damaged or missing tail: {t}");
        }
        for e in &c.errors {
            println!("           error: {e}");
        }
    }
    println!(
        "{} files ({} finished, {} unfinished, {} with errors), {} complete episodes, {} steps, {} bytes: {:.0} bytes ({:.1} KiB) per 1,000 logged steps",
        t.files,
        t.finished,
        t.unfinished,
        t.with_errors,
        t.complete_episodes,
        t.steps,
        t.bytes,
        t.bytes_per_1000_steps,
        t.bytes_per_1000_steps / 1024.0
    );
    Ok(code)
}
