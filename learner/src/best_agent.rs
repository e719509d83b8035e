//! The run's best agent by its training-time evaluation: after each evaluation
//! ([`crate::evaluator`]) the agent of that moment is scored on what the evaluation measured (the
//! curriculum's training rooms and seeds, and the paper's gate test with `learner.eval_gate`),
//! and the best so far is kept in `best/` in the run directory: `policy.safetensors`,
//! `config.toml` and `best.json` (when, and why). `dvnav eval --checkpoint RUN/best` evaluates
//! it like any checkpoint.
//!
//! Why: an agent's skill swings from one evaluation to the next (the generalist experiments of
//! docs/results.md: the gate test moved by 3.3 robots of 12 between evaluations 2,000 updates
//! apart), so the last checkpoint is a draw from that swing. Picking among the evaluations a run
//! already makes uses only training rooms and seeds, never a held-out figure (issue 29).
//!
//! **The score** is the mean success rate over the evaluation's rooms (each room one vote,
//! whatever its episodes), or with `[learner.selection]` over the selection's rows (each room
//! and robot one vote, [`crate::selection`]) instead; with the gate test, the mean of that and
//! the share of the gate's robots that pass, so the kept check weighs as much as the rooms
//! together. With a gate bar (`learner.selection.gate_min_passed`) the gate is a threshold
//! instead: an agent that passes at least that many robots ranks above every agent that
//! passes fewer, and the rooms (or the selection's rows) alone score it. Why: averaged, one
//! more gate robot (1/12 of half the score) outweighed 7 points of local success, and g32
//! kept a 12-of-12 agent that was worse in the held-out rooms than its 11-of-12 peers. Agents
//! below the bar rank among themselves as they would without one (the rooms and the gate's
//! share averaged): ranked by the rooms alone, a run that never reached the bar kept a gate-7
//! agent over its gate-11 ones (g40, seed 1). A later evaluation that ranks as high replaces
//! the kept one (more training, same score).

use dvnav_eval::{RobotResult, RoomSummary};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The best agent's directory inside a run directory.
pub const BEST_DIR: &str = "best";
/// What `best/` holds besides the agent: [`BestRecord`] as JSON.
pub const BEST_JSON: &str = "best.json";

/// Why the agent in `best/` was kept.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BestRecord {
    /// Learner updates when it was evaluated.
    pub updates: u64,
    /// Environment steps received by then.
    pub env_steps: u64,
    /// The weight version evaluated.
    pub policy_version: u64,
    /// The selection score ([`selection_score`]).
    pub score: f64,
    /// Mean success rate over the evaluation's rooms (NaN, `null` in the file, when no room
    /// had episodes and the selection's rows scored).
    #[serde(deserialize_with = "crate::json_f64::f64_or_nan")]
    pub rooms_success: f64,
    /// Rooms that counted.
    pub rooms: usize,
    /// Gate robots that passed, when the gate test ran.
    pub gate_passed: Option<usize>,
    /// Gate robots tested.
    pub gate_robots: Option<usize>,
    /// Mean success rate over the selection's rows, with `[learner.selection]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select_success: Option<f64>,
    /// The gate bar it was ranked by (`learner.selection.gate_min_passed`), when there was one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gate_bar: Option<usize>,
}

impl BestRecord {
    /// Whether it clears its gate bar (always, without one).
    pub fn clears_gate_bar(&self) -> bool {
        self.gate_bar.is_none_or(|bar| self.gate_passed.is_some_and(|passed| passed >= bar))
    }

    /// What orders agents on the same side of their gate bar: the score, except below the bar,
    /// where the gate's share of passing robots is averaged in as it is without a bar.
    pub fn rank_score(&self) -> f64 {
        match (self.clears_gate_bar(), self.gate_passed, self.gate_robots) {
            (false, Some(passed), Some(robots)) if robots > 0 => {
                with_gate(self.score, passed as f64 / robots as f64)
            }
            _ => self.score,
        }
    }

    /// Whether `self` ranks below `other`: an agent below its gate bar ranks below every agent
    /// that clears its own, and [`Self::rank_score`] orders agents on the same side.
    pub fn ranks_below(&self, other: &BestRecord) -> bool {
        (self.clears_gate_bar(), self.rank_score()) < (other.clears_gate_bar(), other.rank_score())
    }
}

/// What one evaluation measured of an agent: its rows in the training rooms, the gate test
/// when it ran, and the selection's rows when `[learner.selection]` asked for them.
#[derive(Clone, Copy, Debug)]
pub struct Measured<'a> {
    /// The training-time evaluation's rows.
    pub rows: &'a [RoomSummary],
    /// The gate test's robots.
    pub gate: Option<&'a [RobotResult]>,
    /// The selection's rows.
    pub selection: Option<&'a [RoomSummary]>,
}

/// The selection score of one evaluation (see the module docs), or `None` when no room (or,
/// with the selection, no row of it) had episodes. With a gate bar the gate does not enter
/// the score ([`BestRecord::ranks_below`] puts it first instead).
pub fn selection_score(m: Measured, gate_bar: Option<usize>) -> Option<f64> {
    let rooms = mean_success(m.selection.unwrap_or(m.rows))?.0;
    Some(match m.gate {
        Some(robots) if !robots.is_empty() && gate_bar.is_none() => {
            with_gate(rooms, gate_share(robots))
        }
        _ => rooms,
    })
}

/// The mean success rate over the rows (rooms, or rooms and robots) that had episodes, each
/// one vote, and how many there were; `None` when none had.
pub fn mean_success(rows: &[RoomSummary]) -> Option<(f64, usize)> {
    let rates: Vec<f64> =
        rows.iter().filter(|r| r.rates.episodes > 0).map(|r| r.rates.success_rate).collect();
    (!rates.is_empty()).then(|| (rates.iter().sum::<f64>() / rates.len() as f64, rates.len()))
}

/// The score without a gate bar: the rooms' mean and the gate's share of passing robots, each
/// half.
fn with_gate(rooms: f64, gate_share: f64) -> f64 {
    (rooms + gate_share) / 2.0
}

fn gate_share(robots: &[RobotResult]) -> f64 {
    robots.iter().filter(|r| r.passes_gate_test()).count() as f64 / robots.len() as f64
}

/// When an evaluated agent was trained to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Moment {
    /// Learner updates.
    pub updates: u64,
    /// Environment steps received.
    pub env_steps: u64,
    /// The weight version.
    pub policy_version: u64,
}

/// Keeps the best agent of a run in `RUN/best`.
#[derive(Debug)]
pub struct BestAgent {
    run_dir: PathBuf,
    kept: Option<BestRecord>,
    gate_bar: Option<usize>,
}

impl BestAgent {
    /// The keeper for the run in `run_dir`, starting from the agent already kept there (a
    /// resumed run), if any.
    pub fn open(run_dir: &Path) -> Self {
        let kept = std::fs::read(run_dir.join(BEST_DIR).join(BEST_JSON))
            .ok()
            .and_then(|bytes| serde_json::from_slice(&bytes).ok());
        Self { run_dir: run_dir.to_path_buf(), kept, gate_bar: None }
    }

    /// Ranks agents by the gate bar `min_passed` (0: none, the gate is half the score).
    pub fn with_gate_bar(mut self, min_passed: usize) -> Self {
        self.gate_bar = (min_passed > 0).then_some(min_passed);
        self
    }

    /// What is kept now.
    pub fn kept(&self) -> Option<&BestRecord> {
        self.kept.as_ref()
    }

    /// Scores the evaluation `m` of the agent `policy` (safetensors bytes) trained to `at` and
    /// keeps the agent unless it ranks below the kept one; `config_toml` is the run's
    /// configuration, written beside the weights. Returns the record when it was kept.
    pub fn offer(
        &mut self,
        at: Moment,
        policy: &[u8],
        m: Measured,
        config_toml: &str,
    ) -> anyhow::Result<Option<&BestRecord>> {
        let Some(score) = selection_score(m, self.gate_bar) else { return Ok(None) };
        let (rooms_mean, rooms) = mean_success(m.rows).unwrap_or((f64::NAN, 0));
        let gate = m.gate;
        let record = BestRecord {
            updates: at.updates,
            env_steps: at.env_steps,
            policy_version: at.policy_version,
            score,
            rooms_success: rooms_mean,
            rooms,
            gate_passed: gate.map(|g| g.iter().filter(|r| r.passes_gate_test()).count()),
            gate_robots: gate.map(<[RobotResult]>::len),
            select_success: m.selection.and_then(mean_success).map(|(s, _)| s),
            gate_bar: self.gate_bar,
        };
        if self.kept.as_ref().is_some_and(|k| record.ranks_below(k)) {
            return Ok(None);
        }
        self.write(&record, policy, config_toml)?;
        Ok(Some(self.kept.insert(record)))
    }

    /// Keeps the best agent of another run (`from`, a run directory with a `best/`) as this
    /// run's, whole: a config trained with several seeds keeps its best seed's agent
    /// ([`best_of_runs`]). Returns what it kept.
    pub fn adopt(&mut self, from: &Path) -> anyhow::Result<&BestRecord> {
        use anyhow::Context;
        let dir = from.join(BEST_DIR);
        let read = |name: &str| {
            std::fs::read(dir.join(name))
                .with_context(|| format!("cannot read {}", dir.join(name).display()))
        };
        let record: BestRecord = serde_json::from_slice(&read(BEST_JSON)?).with_context(|| {
            format!("{}: not a best-agent record", dir.join(BEST_JSON).display())
        })?;
        let policy = read(crate::checkpoint::POLICY_FILE)?;
        let config = String::from_utf8(read("config.toml")?)
            .with_context(|| format!("{}: not UTF-8", dir.join("config.toml").display()))?;
        self.write(&record, &policy, &config)?;
        Ok(self.kept.insert(record))
    }

    /// Writes the agent into `best.tmp`, then swaps it in, so `best/` is always whole.
    fn write(&self, record: &BestRecord, policy: &[u8], config_toml: &str) -> anyhow::Result<()> {
        use anyhow::Context;
        let best = self.run_dir.join(BEST_DIR);
        let tmp = self.run_dir.join(format!("{BEST_DIR}.tmp"));
        let old = self.run_dir.join(format!("{BEST_DIR}.old"));
        for stale in [&tmp, &old] {
            if stale.exists() {
                std::fs::remove_dir_all(stale)?;
            }
        }
        std::fs::create_dir_all(&tmp)
            .with_context(|| format!("cannot create {}", tmp.display()))?;
        std::fs::write(tmp.join(crate::checkpoint::POLICY_FILE), policy)?;
        std::fs::write(tmp.join("config.toml"), config_toml)?;
        std::fs::write(tmp.join(BEST_JSON), serde_json::to_vec_pretty(record)?)?;
        if best.exists() {
            std::fs::rename(&best, &old)?;
        }
        std::fs::rename(&tmp, &best)
            .with_context(|| format!("cannot move {} to {}", tmp.display(), best.display()))?;
        if old.exists() {
            std::fs::remove_dir_all(&old)?;
        }
        Ok(())
    }
}

/// Of several runs of one config (its seeds), the one whose `best/` ranks highest on the runs'
/// own evaluation ([`BestRecord::ranks_below`]), and its record: `(index into runs, record)`.
/// Runs with no `best/` do not count; of equal ranks the first run's stands. Only
/// training-time evaluations decide: the same evaluation, so the same score, for every seed of
/// the config.
pub fn best_of_runs(runs: &[PathBuf]) -> Option<(usize, BestRecord)> {
    let mut best: Option<(usize, BestRecord)> = None;
    for (i, run) in runs.iter().enumerate() {
        if let Some(record) = BestAgent::open(run).kept
            && best.as_ref().is_none_or(|(_, b)| b.ranks_below(&record))
        {
            best = Some((i, record));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_eval::{GateRoute, Rates};
    use dvnav_sim::Outcome;

    fn room(success: f64, episodes: usize) -> RoomSummary {
        RoomSummary {
            room: "r".into(),
            radius: None,
            rates: Rates {
                episodes,
                success_rate: success,
                collision_rate: 1.0 - success,
                timeout_rate: 0.0,
                mean_score: 0.0,
                mean_time_s: None,
                mean_path_length_m: None,
                reversal_rate: 0.0,
                mean_abs_domega: 0.0,
                routes: None,
            },
            route: None,
        }
    }

    fn rooms(rows: &[RoomSummary]) -> Measured<'_> {
        Measured { rows, gate: None, selection: None }
    }

    fn at(updates: u64) -> Moment {
        Moment { updates, env_steps: 4 * updates, policy_version: 1 }
    }

    #[test]
    fn the_score_is_the_rooms_mean_and_the_gate_weighs_as_much() {
        let rows = [room(1.0, 10), room(0.5, 10), room(0.0, 0)];
        assert_eq!(
            selection_score(Measured { rows: &rows, gate: None, selection: None }, None),
            Some(0.75),
            "a room without episodes does not vote"
        );
        let none = Measured { rows: &[room(0.3, 0)], gate: None, selection: None };
        assert_eq!(selection_score(none, None), None);
        assert_eq!(
            selection_score(Measured { rows: &rows, gate: Some(&[]), selection: None }, None),
            Some(0.75)
        );
        // The selection's rows, when there, score instead of the rooms.
        let sel = [room(0.2, 16), room(0.4, 16)];
        let m = Measured { rows: &rows, gate: None, selection: Some(&sel) };
        assert!((selection_score(m, None).unwrap() - 0.3).abs() < 1e-12);
        let m = Measured { rows: &[], gate: None, selection: Some(&sel[..0]) };
        assert_eq!(selection_score(m, None), None, "a selection without episodes does not score");
    }

    #[test]
    fn the_best_agent_is_kept_replaced_only_by_as_good_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut best = BestAgent::open(dir.path());
        assert!(best.kept().is_none());
        let kept = best.offer(at(100), b"first", rooms(&[room(0.6, 5)]), "a = 1\n").unwrap();
        assert_eq!(kept.map(|k| k.updates), Some(100));
        assert!(
            best.offer(at(200), b"worse", rooms(&[room(0.5, 5)]), "a = 1\n").unwrap().is_none()
        );
        let kept = best.offer(at(300), b"later", rooms(&[room(0.6, 5)]), "a = 2\n").unwrap();
        assert_eq!(kept.map(|k| (k.updates, k.score)), Some((300, 0.6)));
        let on_disk = dir.path().join(BEST_DIR);
        assert_eq!(std::fs::read(on_disk.join("policy.safetensors")).unwrap(), b"later");
        assert_eq!(std::fs::read_to_string(on_disk.join("config.toml")).unwrap(), "a = 2\n");
        assert!(!dir.path().join("best.tmp").exists() && !dir.path().join("best.old").exists());
        // A resumed run starts from what was kept.
        let mut again = BestAgent::open(dir.path());
        assert_eq!(again.kept().map(|k| k.updates), Some(300));
        assert!(again.offer(at(400), b"no", rooms(&[room(0.4, 5)]), "").unwrap().is_none());
    }

    #[test]
    fn with_the_selection_its_rows_decide_and_the_record_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut best = BestAgent::open(dir.path());
        let sel = [room(0.8, 16), room(0.6, 16)];
        let m = Measured { rows: &[room(0.1, 5)], gate: None, selection: Some(&sel) };
        let kept = best.offer(at(100), b"a", m, "").unwrap().cloned().unwrap();
        assert!((kept.score - 0.7).abs() < 1e-12 && (kept.rooms_success - 0.1).abs() < 1e-12);
        assert_eq!(kept.select_success, Some(kept.score));
        // Better rooms, a worse selection: not kept.
        let worse = [room(0.5, 16), room(0.6, 16)];
        let m = Measured { rows: &[room(1.0, 5)], gate: None, selection: Some(&worse) };
        assert!(best.offer(at(200), b"b", m, "").unwrap().is_none());
        // No room rows but a selection: kept, the rooms' mean unknown, and it reads back.
        let m = Measured { rows: &[], gate: None, selection: Some(&sel) };
        assert_eq!(best.offer(at(300), b"c", m, "").unwrap().map(|k| k.updates), Some(300));
        let again = BestAgent::open(dir.path());
        let k = again.kept().unwrap();
        assert!(k.updates == 300 && k.rooms_success.is_nan() && k.rooms == 0, "{k:?}");
    }

    /// Twelve gate robots of which `passed` pass (the small ones through the gate on a
    /// straight path, the others round the wall's left end).
    fn gate(passed: usize) -> Vec<RobotResult> {
        (0..12)
            .map(|i| {
                let radius = 0.2 + 0.05 * i as f64;
                let through = radius <= 0.25 + 1e-9;
                RobotResult {
                    room: "gate".into(),
                    radius,
                    outcome: if i < passed { Outcome::Success } else { Outcome::Collision },
                    steps: 100,
                    time_s: 10.0,
                    path_length_m: 3.0,
                    score: 0.0,
                    route: if through { GateRoute::Gate } else { GateRoute::Left },
                    reversal_rate: 0.0,
                    mean_abs_domega: 0.0,
                }
            })
            .collect()
    }

    #[test]
    fn with_a_gate_bar_the_gate_is_a_threshold_and_the_selection_ranks_above_it() {
        // g32's three seeds: 12 of 12 with selection 0.851, 11 with 0.925, 11 with 0.913.
        fn m<'a>(gate: &'a [RobotResult], sel: &'a [RoomSummary]) -> Measured<'a> {
            Measured { rows: &[], gate: Some(gate), selection: Some(sel) }
        }
        let gates = [gate(12), gate(11), gate(10)];
        let (g12, g11, g10) = (&gates[0][..], &gates[1][..], &gates[2][..]);
        assert_eq!(g12.iter().filter(|r| r.passes_gate_test()).count(), 12);
        let sels = [[room(0.851, 16)], [room(0.925, 16)], [room(0.938, 16)]];
        let (s851, s925, s938) = (&sels[0][..], &sels[1][..], &sels[2][..]);
        // Averaged (no bar), the 12-of-12 agent wins; with the bar at 11 the better selection.
        let avg = |m| selection_score(m, None).unwrap();
        assert!(avg(m(g12, s851)) > avg(m(g11, s925)));
        assert!((selection_score(m(g12, s851), Some(11)).unwrap() - 0.851).abs() < 1e-12);

        let dir = tempfile::tempdir().unwrap();
        let mut best = BestAgent::open(dir.path()).with_gate_bar(11);
        let offer = |best: &mut BestAgent, u, m| best.offer(at(u), b"w", m, "").unwrap().cloned();
        // Below the bar an agent is kept until one clears it, then never replaces it; below
        // it the gate counts as without a bar (g40 seed 1 kept a gate-7 agent by its rooms).
        assert!(offer(&mut best, 100, m(g10, s938)).is_some());
        let sels_below = [[room(0.99, 16)], [room(0.95, 16)]];
        let g7 = gate(7);
        assert!(offer(&mut best, 150, m(&g7, &sels_below[0])).is_none(), "7 of 12 at 0.99");
        assert_eq!(offer(&mut best, 160, m(g10, &sels_below[1])).map(|k| k.updates), Some(160));
        assert!(offer(&mut best, 170, m(g10, s851)).is_none(), "the same gate, worse rooms");
        let kept = offer(&mut best, 200, m(g12, s851)).unwrap();
        assert!(kept.clears_gate_bar() && kept.gate_bar == Some(11));
        assert!(offer(&mut best, 300, m(g10, s938)).is_none(), "10 of 12 is below the bar");
        assert_eq!(offer(&mut best, 400, m(g11, s925)).map(|k| k.updates), Some(400));
        assert!(offer(&mut best, 500, m(g12, s851)).is_none(), "the selection ranks above 11");
        assert_eq!(BestAgent::open(dir.path()).kept().unwrap().gate_bar, Some(11));

        // Across seeds: each record carries its bar.
        let runs: Vec<PathBuf> = (1..=3).map(|s| dir.path().join(format!("seed-{s}"))).collect();
        for (run, (g, s)) in runs.iter().zip([(g12, s851), (g11, s925), (g10, s938)]) {
            std::fs::create_dir_all(run).unwrap();
            offer(&mut BestAgent::open(run).with_gate_bar(11), 100, m(g, s)).unwrap();
        }
        assert_eq!(best_of_runs(&runs).map(|(i, _)| i), Some(1));
    }

    #[test]
    fn the_best_of_several_runs_is_the_highest_kept_score_and_is_adopted_whole() {
        let dir = tempfile::tempdir().unwrap();
        let runs: Vec<PathBuf> = (1..=4).map(|s| dir.path().join(format!("seed-{s}"))).collect();
        let scores = [Some(0.7), Some(0.9), None, Some(0.9)];
        for (run, score) in runs.iter().zip(scores) {
            std::fs::create_dir_all(run).unwrap();
            if let Some(s) = score {
                let policy = format!("weights of {}", run.display());
                let mut best = BestAgent::open(run);
                best.offer(at(100), policy.as_bytes(), rooms(&[room(s, 5)]), "a = 1\n").unwrap();
            }
        }
        // seed-2 and seed-4 tie: the first stands; seed-3 kept nothing and does not count.
        let (i, record) = best_of_runs(&runs).unwrap();
        assert_eq!((i, record.score), (1, 0.9));
        assert_eq!(best_of_runs(&runs[2..3]), None);
        let mut all = BestAgent::open(dir.path());
        assert_eq!(all.adopt(&runs[i]).unwrap(), &record);
        let kept = dir.path().join(BEST_DIR);
        let want = format!("weights of {}", runs[1].display());
        assert_eq!(std::fs::read(kept.join("policy.safetensors")).unwrap(), want.as_bytes());
        assert_eq!(BestAgent::open(dir.path()).kept(), Some(&record));
        // A run without a best agent cannot be adopted; what was kept stays whole.
        let err = all.adopt(&runs[2]).unwrap_err().to_string();
        assert!(err.contains("best.json"), "{err}");
        assert_eq!(std::fs::read(kept.join("policy.safetensors")).unwrap(), want.as_bytes());
    }
}
