//! `run_summary.json`: the learner's and the actors' own summaries merged with what the
//! supervisor saw of each process. Every file is read as the type its writer wrote
//! ([`LearnerSummary`], [`ActorSummary`]), so a renamed field is a compile error here, not a
//! silent null.

use super::supervisor::{ActorFailure, ActorSlot, Proc};
use dvnav_actor::run::ActorSummary;
use dvnav_learner::curriculum::StageChange;
use dvnav_learner::run::LearnerSummary;
use serde::{Deserialize, Serialize, de::DeserializeOwned};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A JSON file another process wrote, as its type: `None` when it is missing (a killed process
/// writes none); one that does not parse is said on stderr, naming the file, and also `None`.
pub(super) fn read_json<T: DeserializeOwned>(path: &Path) -> Option<T> {
    let bytes = std::fs::read(path).ok()?;
    serde_json::from_slice(&bytes)
        .map_err(|e| eprintln!("dvnav train: cannot read {}: {e}", path.display()))
        .ok()
}

/// `run_summary.json`: the learner's counters, each actor process's own counts, how each
/// process ended, and the actor failures and restarts.
///
/// `actors` has one entry per process, restarts included (`actor` names the actor it ran as,
/// `restart` counts from 0). A killed process writes no summary: its `transitions_sent` is
/// null and it is listed in `unreported_actors`; the learner's counts of it stand.
/// `transitions_sent` is the sum over the processes that reported, and
/// `transitions_accounted` says whether each of them had every transition it sent received or
/// rejected by the learner (nothing lost, nothing counted twice). `clean_shutdown` holds when
/// the learner and every actor's last process ended cleanly: a failed process that was
/// replaced does not spoil it (`actor_failures` tells what happened), one that was not does.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct RunSummary {
    pub run_id: Option<String>,
    pub transitions_sent: u64,
    pub transitions_received: Option<u64>,
    pub transitions_rejected: Option<u64>,
    pub transitions_accounted: bool,
    pub unreported_actors: Vec<String>,
    pub transitions_received_from_unreported: u64,
    pub episodes: Option<u64>,
    pub updates: Option<u64>,
    pub weight_version: Option<u64>,
    pub replay_size: Option<u64>,
    pub stage: Option<u32>,
    pub stage_changes: Option<Vec<StageChange>>,
    pub skilled: Option<StageChange>,
    pub success_rate: Option<f64>,
    pub critic_loss: Option<f64>,
    pub actor_loss: Option<f64>,
    pub alpha: Option<f64>,
    pub losses_finite: Option<bool>,
    pub step_budget: Option<u64>,
    pub final_checkpoint: Option<PathBuf>,
    pub wall_time_s: f64,
    pub env_steps_per_s: f64,
    pub updates_per_s: f64,
    /// Percentiles of the policy lag (weight versions) over the run.
    pub policy_lag: Option<dvnav_learner::state::LagPercentiles>,
    pub learner_exit_status: Option<String>,
    pub clean_shutdown: bool,
    pub actor_restarts: usize,
    pub restarts: BTreeMap<String, usize>,
    pub actor_failures: Vec<ActorFailure>,
    pub actors: Vec<ProcessSummary>,
}

/// One actor process in `run_summary.json`: the learner's counts of it, its own, how it ended.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct ProcessSummary {
    pub name: String,
    pub actor: String,
    pub restart: usize,
    pub pid: u32,
    pub actor_id: Option<u32>,
    pub transitions_sent: Option<u64>,
    pub transitions_received: Option<u64>,
    pub transitions_rejected: Option<u64>,
    pub episodes: Option<u64>,
    pub batches: Option<u64>,
    pub duplicate_batches: Option<u64>,
    pub min_policy_version: Option<u64>,
    pub max_policy_version: Option<u64>,
    pub env_steps: Option<u64>,
    pub env_steps_per_s: Option<f64>,
    pub logged_episodes: Option<u64>,
    pub exit_status: Option<String>,
    pub ran_s: Option<f64>,
    pub clean_exit: bool,
    pub stop_reason: Option<String>,
    pub replaced_by: Option<String>,
}

pub(super) fn merge_summaries(
    out: &Path,
    learner: &Proc,
    actors: &[ActorSlot],
    failures: &[ActorFailure],
    wall: f64,
) -> RunSummary {
    let l: Option<LearnerSummary> = read_json(&out.join("learner_summary.json"));
    let status = l.as_ref().map(|l| &l.status);
    let mut per_actor = Vec::new();
    let mut sent_total = 0u64;
    let mut accounted = l.is_some();
    let mut unreported = Vec::new();
    let mut unreported_received = 0u64;
    let mut restarts = BTreeMap::new();
    let mut all_clean = learner.status.is_some_and(|s| s.success()) && l.is_some();
    for slot in actors {
        restarts.insert(slot.actor.clone(), slot.restarts());
        for (k, a) in slot.procs.iter().enumerate() {
            let s: Option<ActorSummary> =
                read_json(&out.join("actors").join(&a.name).join("summary.json"));
            let at_learner = status.and_then(|st| st.actors.iter().find(|x| x.name == a.name));
            let (received, rejected) =
                at_learner.map_or((0, 0), |c| (c.transitions_received, c.transitions_rejected));
            let sent = s.as_ref().map(|s| s.transitions_sent);
            match sent {
                Some(n) => {
                    sent_total += n;
                    accounted &= n == received + rejected;
                }
                None => {
                    unreported.push(a.name.clone());
                    unreported_received += received;
                }
            }
            let ok = a.status.is_some_and(|s| s.success()) && s.is_some();
            if k + 1 == slot.procs.len() {
                all_clean &= ok;
            }
            let own = s.as_ref().map(|s| &s.loop_counters);
            per_actor.push(ProcessSummary {
                name: a.name.clone(),
                actor: slot.actor.clone(),
                restart: k,
                pid: a.child.id(),
                actor_id: at_learner.map(|c| c.actor_id),
                transitions_sent: sent,
                transitions_received: at_learner.map(|c| c.transitions_received),
                transitions_rejected: at_learner.map(|c| c.transitions_rejected),
                episodes: at_learner.map(|c| c.episodes),
                batches: at_learner.map(|c| c.batches),
                duplicate_batches: at_learner.map(|c| c.duplicate_batches),
                min_policy_version: own.map(|c| c.min_policy_version),
                max_policy_version: own.map(|c| c.max_policy_version),
                env_steps: own.map(|c| c.env_steps),
                env_steps_per_s: s.as_ref().map(|s| s.env_steps_per_s),
                logged_episodes: own.map(|c| c.logged_episodes),
                exit_status: a.status.map(|s| s.to_string()),
                ran_s: a.ran.map(|d| d.as_secs_f64()),
                clean_exit: ok,
                stop_reason: s.as_ref().map(|s| s.stop_reason.clone()),
                replaced_by: slot.procs.get(k + 1).map(|p| p.name.clone()),
            });
        }
    }
    let received = status.map(|s| s.transitions_received);
    let updates = status.map(|s| s.updates);
    RunSummary {
        run_id: status.map(|s| s.run_id.clone()),
        transitions_sent: sent_total,
        transitions_received: received,
        transitions_rejected: status.map(|s| s.transitions_rejected),
        transitions_accounted: accounted,
        unreported_actors: unreported,
        transitions_received_from_unreported: unreported_received,
        episodes: status.map(|s| s.episodes),
        updates,
        weight_version: status.map(|s| s.weight_version),
        replay_size: status.map(|s| s.replay_size),
        stage: status.map(|s| s.stage),
        stage_changes: status.map(|s| s.stage_changes.clone()),
        skilled: status.and_then(|s| s.skilled.clone()),
        success_rate: status.map(|s| s.success_rate),
        critic_loss: status.map(|s| s.critic_loss),
        actor_loss: status.map(|s| s.actor_loss),
        alpha: status.map(|s| s.alpha),
        losses_finite: status.map(|s| s.losses_finite),
        step_budget: status.map(|s| s.step_budget),
        final_checkpoint: l.as_ref().and_then(|l| l.final_checkpoint.clone()),
        wall_time_s: wall,
        env_steps_per_s: received.unwrap_or(0) as f64 / wall,
        updates_per_s: updates.unwrap_or(0) as f64 / wall,
        policy_lag: status.map(|s| s.live.policy_lag_percentiles),
        learner_exit_status: learner.status.map(|s| s.to_string()),
        clean_shutdown: all_clean,
        actor_restarts: actors.iter().map(ActorSlot::restarts).sum(),
        restarts,
        actor_failures: failures.to_vec(),
        actors: per_actor,
    }
}
