//! `dvnav train --seeds N`: the same config trained with N seeds one after the other, and the
//! table and `seeds_summary.json` that compare them.

use super::summary::{RunSummary, read_json};
use super::{TrainArgs, default_out, run_one};
use dvnav_learner::curriculum::StageChange;
use dvnav_learner::metrics::csv_log;
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;

/// `--seeds N`: the runs one after the other, then their summary.
pub(super) fn run_seeds(args: TrainArgs, n: usize) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(n >= 1, "--seeds must be at least 1");
    let base_cfg = super::super::load_config(args.config.as_ref())?;
    let first = args.seed.unwrap_or(base_cfg.run.seed);
    let out = args.out.clone().unwrap_or_else(default_out);
    let mut rows = Vec::new();
    let mut all_ok = true;
    for seed in first..first + n as u64 {
        let dir = out.join(format!("seed-{seed}"));
        eprintln!("dvnav train: seed {seed} ({} of {n}) in {}", seed - first + 1, dir.display());
        let one =
            TrainArgs { seed: Some(seed), out: Some(dir.clone()), seeds: None, ..args.clone() };
        let code = run_one(one)?;
        all_ok &= code == ExitCode::SUCCESS;
        rows.push(seed_row(seed, &dir));
    }
    eprintln!("\nseed  stage  skilled at (steps)  time to skill (s)  wall (s)");
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.0}"));
    for r in &rows {
        eprintln!(
            "{:<5} {:<6} {:<19} {:<18} {}",
            r.seed,
            r.stage.map_or("-".to_string(), |s| s.to_string()),
            opt(r.skilled_env_steps.map(|n| n as f64)),
            opt(r.time_to_skill_s),
            opt(r.wall_time_s)
        );
    }
    let skilled = rows.iter().filter(|r| r.skilled_env_steps.is_some()).count();
    eprintln!("{skilled} of {n} seeds reached the last room's threshold");
    let best = keep_best_seed(&out, &rows)?;
    let summary = SeedsSummary { seeds: rows, skilled, runs: n, best };
    std::fs::write(out.join("seeds_summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    Ok(if all_ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// Of the seeds' best agents (`seed-S/best`, kept by each run's own training-time evaluation),
/// the highest-scoring becomes `OUT/best`: the config's agent, picked among its seeds on the
/// same evaluation. `None` when no seed kept one (no evaluation ran).
fn keep_best_seed(out: &Path, rows: &[SeedRow]) -> anyhow::Result<Option<BestSeed>> {
    use dvnav_learner::best_agent::{BEST_DIR, BestAgent, best_of_runs};
    let dirs: Vec<std::path::PathBuf> = rows.iter().map(|r| r.run_dir.clone().into()).collect();
    let Some((i, record)) = best_of_runs(&dirs) else {
        eprintln!("no seed kept a best agent (no training-time evaluation ran)");
        return Ok(None);
    };
    BestAgent::open(out).adopt(&dirs[i])?;
    let seed = rows[i].seed;
    eprintln!(
        "best agent: seed {seed} (score {:.3}, {} updates) -> {}",
        record.score,
        record.updates,
        out.join(BEST_DIR).display()
    );
    Ok(Some(BestSeed { seed, record }))
}

/// `seeds_summary.json`.
#[derive(Serialize)]
struct SeedsSummary {
    seeds: Vec<SeedRow>,
    /// Seeds whose last room reached the curriculum threshold.
    skilled: usize,
    runs: usize,
    /// The seed whose best agent is `OUT/best`, and why it was kept.
    best: Option<BestSeed>,
}

/// The seed whose best agent scored highest.
#[derive(Serialize)]
struct BestSeed {
    seed: u64,
    #[serde(flatten)]
    record: dvnav_learner::best_agent::BestRecord,
}

/// One seed's line of `seeds_summary.json`.
#[derive(Serialize)]
pub(super) struct SeedRow {
    seed: u64,
    run_dir: String,
    stage: Option<u32>,
    stage_changes: Option<Vec<StageChange>>,
    skilled_env_steps: Option<u64>,
    time_to_skill_s: Option<f64>,
    wall_time_s: Option<f64>,
    env_steps: Option<u64>,
}

/// One seed's row, from its run directory's `run_summary.json` (all `None` without one).
pub(super) fn seed_row(seed: u64, dir: &Path) -> SeedRow {
    let s: Option<RunSummary> = read_json(&dir.join("run_summary.json"));
    let skilled_env_steps = s.as_ref().and_then(|s| s.skilled.as_ref()).map(|c| c.env_steps);
    SeedRow {
        seed,
        run_dir: dir.display().to_string(),
        stage: s.as_ref().and_then(|s| s.stage),
        stage_changes: s.as_ref().and_then(|s| s.stage_changes.clone()),
        skilled_env_steps,
        time_to_skill_s: skilled_env_steps.and_then(|n| time_at_steps(dir, n)),
        wall_time_s: s.as_ref().map(|s| s.wall_time_s),
        env_steps: s.as_ref().and_then(|s| s.transitions_received),
    }
}

/// Wall time (s) at which the run's `metrics.csv` first shows `steps` environment steps.
pub fn time_at_steps(dir: &Path, steps: u64) -> Option<f64> {
    let rows = csv_log::read(&dir.join("metrics.csv")).ok()?;
    rows.iter().find(|r| r.env_steps >= steps && r.time_s.is_finite()).map(|r| r.time_s)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SUMMARY: &str = r#"{
        "transitions_sent": 700, "transitions_received": 700, "transitions_accounted": true,
        "unreported_actors": [], "transitions_received_from_unreported": 0, "stage": 3,
        "skilled": {"stage": 3, "room": "env3", "env_steps": 500, "updates": 90},
        "wall_time_s": 12.5, "env_steps_per_s": 56.0, "updates_per_s": 7.2,
        "clean_shutdown": true, "actor_restarts": 0, "restarts": {}, "actor_failures": [],
        "actors": []
    }"#;

    #[test]
    fn a_seed_row_reads_the_typed_run_summary_and_the_time_to_skill_from_metrics_csv() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("run_summary.json"), SUMMARY).unwrap();
        std::fs::write(dir.path().join("metrics.csv"), "time_s,env_steps\n1.0,100\n2.5,600\n")
            .unwrap();
        let row = seed_row(7, dir.path());
        assert_eq!((row.seed, row.stage, row.skilled_env_steps), (7, Some(3), Some(500)));
        assert_eq!((row.time_to_skill_s, row.wall_time_s), (Some(2.5), Some(12.5)));
        assert_eq!(row.env_steps, Some(700));
    }

    #[test]
    fn a_summary_with_a_renamed_field_is_refused_whole_not_read_as_nulls() {
        let dir = tempfile::tempdir().unwrap();
        let renamed = SUMMARY.replace("\"wall_time_s\"", "\"wall_s\"");
        std::fs::write(dir.path().join("run_summary.json"), renamed).unwrap();
        let row = seed_row(7, dir.path());
        assert_eq!((row.stage, row.skilled_env_steps, row.wall_time_s), (None, None, None));
    }
}
