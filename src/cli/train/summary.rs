//! `run_summary.json`: the learner's and the actors' own summaries merged with what the
//! supervisor saw of each process.

use super::supervisor::{ActorFailure, ActorSlot, Proc};
use serde_json::{Value, json};
use std::path::Path;

pub(super) fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
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
pub(super) fn merge_summaries(
    out: &Path,
    learner: &Proc,
    actors: &[ActorSlot],
    failures: &[ActorFailure],
    wall: f64,
) -> anyhow::Result<Value> {
    let l = read_json(&out.join("learner_summary.json")).unwrap_or(Value::Null);
    let learner_actors = l["actors"].as_array().cloned().unwrap_or_default();
    let mut per_actor = Vec::new();
    let mut sent_total = 0u64;
    let mut accounted = !l.is_null();
    let mut unreported = Vec::new();
    let mut unreported_received = 0u64;
    let mut restarts = serde_json::Map::new();
    let mut all_clean = learner.status.is_some_and(|s| s.success()) && !l.is_null();
    for slot in actors {
        restarts.insert(slot.actor.clone(), json!(slot.restarts()));
        for (k, a) in slot.procs.iter().enumerate() {
            let s = read_json(&out.join("actors").join(&a.name).join("summary.json"))
                .unwrap_or(Value::Null);
            let at_learner = learner_actors
                .iter()
                .find(|x| x["name"] == a.name.as_str())
                .cloned()
                .unwrap_or(Value::Null);
            let count = |v: &Value| v.as_u64().unwrap_or(0);
            let (received, rejected) = (
                count(&at_learner["transitions_received"]),
                count(&at_learner["transitions_rejected"]),
            );
            let sent = s["transitions_sent"].as_u64();
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
            let ok = a.status.is_some_and(|s| s.success()) && !s.is_null();
            if k + 1 == slot.procs.len() {
                all_clean &= ok;
            }
            per_actor.push(json!({
                "name": a.name,
                "actor": slot.actor,
                "restart": k,
                "pid": a.child.id(),
                "actor_id": at_learner["actor_id"],
                "transitions_sent": sent,
                "transitions_received": at_learner["transitions_received"],
                "transitions_rejected": at_learner["transitions_rejected"],
                "episodes": at_learner["episodes"],
                "batches": at_learner["batches"],
                "duplicate_batches": at_learner["duplicate_batches"],
                "min_policy_version": s["min_policy_version"],
                "max_policy_version": s["max_policy_version"],
                "env_steps": s["env_steps"],
                "env_steps_per_s": s["env_steps_per_s"],
                "logged_episodes": s["logged_episodes"],
                "exit_status": a.status.map(|s| s.to_string()),
                "ran_s": a.ran.map(|d| d.as_secs_f64()),
                "clean_exit": ok,
                "stop_reason": s["stop_reason"],
                "replaced_by": slot.procs.get(k + 1).map(|p| p.name.clone()),
            }));
        }
    }
    let actor_restarts: usize = actors.iter().map(ActorSlot::restarts).sum();
    Ok(json!({
        "run_id": l["run_id"],
        "transitions_sent": sent_total,
        "transitions_received": l["transitions_received"],
        "transitions_rejected": l["transitions_rejected"],
        "transitions_accounted": accounted,
        "unreported_actors": unreported,
        "transitions_received_from_unreported": unreported_received,
        "episodes": l["episodes"],
        "updates": l["updates"],
        "weight_version": l["weight_version"],
        "replay_size": l["replay_size"],
        "stage": l["stage"],
        "stage_changes": l["stage_changes"],
        "skilled": l["skilled"],
        "success_rate": l["success_rate"],
        "critic_loss": l["critic_loss"],
        "actor_loss": l["actor_loss"],
        "alpha": l["alpha"],
        "losses_finite": l["losses_finite"],
        "step_budget": l["step_budget"],
        "final_checkpoint": l["final_checkpoint"],
        "wall_time_s": wall,
        "env_steps_per_s": l["transitions_received"].as_u64().unwrap_or(0) as f64 / wall,
        "updates_per_s": l["updates"].as_u64().unwrap_or(0) as f64 / wall,
        "learner_exit_status": learner.status.map(|s| s.to_string()),
        "clean_shutdown": all_clean,
        "actor_restarts": actor_restarts,
        "restarts": restarts,
        "actor_failures": failures,
        "actors": per_actor,
    }))
}
