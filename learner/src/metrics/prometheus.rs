//! The Prometheus text exposition format (version 0.0.4) of a [`Sample`]:
//! [`render_prometheus`], a plain function unit-tested on its own.

use super::sample::Sample;
use crate::state::{ActorCounters, StageStats};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

/// Escapes a Prometheus label value.
fn label(v: &str) -> String {
    v.replace('\\', "\\\\").replace('"', "\\\"").replace('\n', "\\n")
}

/// A float in Prometheus text format (`NaN`, `+Inf`, `-Inf` spelled its way).
pub(super) fn num(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "+Inf".into() } else { "-Inf".into() }
    } else {
        format!("{v}")
    }
}

/// Renders a sample in the Prometheus text exposition format (version 0.0.4).
pub fn render_prometheus(sample: &Sample) -> String {
    let s = &sample.status;
    let s_mem = &sample.memory;
    let live = &s.live;
    let mut out = String::with_capacity(4096);
    let mut metric = |name: &str, kind: &str, help: &str, rows: &[(String, f64)]| {
        let _ = writeln!(out, "# HELP {name} {help}");
        let _ = writeln!(out, "# TYPE {name} {kind}");
        for (labels, v) in rows {
            let _ = writeln!(out, "{name}{labels} {}", num(*v));
        }
    };
    let one = |v: f64| [(String::new(), v)];
    metric(
        "dvnav_env_steps_total",
        "counter",
        "Environment steps (transitions) accepted into the replay buffer.",
        &one(s.transitions_received as f64),
    );
    metric(
        "dvnav_env_steps_per_second",
        "gauge",
        "Environment steps per second over the last 10 s.",
        &one(live.env_steps_per_s),
    );
    metric("dvnav_updates_total", "counter", "SAC updates done.", &one(s.updates as f64));
    metric(
        "dvnav_updates_per_second",
        "gauge",
        "SAC updates per second over the last 10 s.",
        &one(live.updates_per_s),
    );
    metric(
        "dvnav_episodes_total",
        "counter",
        "Episodes reported by actors.",
        &one(s.episodes as f64),
    );
    metric(
        "dvnav_transitions_received_total",
        "counter",
        "Transitions accepted.",
        &one(s.transitions_received as f64),
    );
    metric(
        "dvnav_transitions_rejected_total",
        "counter",
        "Transitions refused as malformed.",
        &one(s.transitions_rejected as f64),
    );
    let rows = |m: &BTreeMap<String, u64>, key: &str| -> Vec<(String, f64)> {
        m.iter().map(|(k, v)| (format!("{{{key}=\"{}\"}}", label(k)), *v as f64)).collect()
    };
    metric(
        "dvnav_requests_rejected_total",
        "counter",
        "Refused registrations and batches by reason: the offending field of a malformed batch, unknown_actor, protocol_version, unauthenticated, invalid_request, shutting_down, stream_oversized (a message over the size limit), stream_broken (a transition stream that broke: undecodable bytes, a killed actor, a cut link).",
        &rows(&s.rejected_by_reason, "reason"),
    );
    metric(
        "dvnav_write_failures_total",
        "counter",
        "Failed writes by output (checkpoint, metrics_csv, eval_csv); training goes on and the next write tries again.",
        &rows(&s.write_failures, "output"),
    );
    let stalled: Vec<(String, f64)> = ["ingest", "trainer", "rate_limiter"]
        .iter()
        .map(|c| c.to_string())
        .chain(s.actors.iter().filter(|a| a.connected).map(|a| format!("actor:{}", a.name)))
        .chain(s.stalled.iter().map(|x| x.component.clone()))
        .collect::<BTreeSet<_>>()
        .into_iter()
        .map(|c| {
            let v = s.stalled.iter().any(|x| x.component == c) as u8 as f64;
            (format!("{{component=\"{}\"}}", label(&c)), v)
        })
        .collect();
    metric(
        "dvnav_stalled",
        "gauge",
        "1 while the watchdog finds the component stuck (no progress for 0.6 of learner.heartbeat_s; /readyz and the learner log say what and its last error).",
        &stalled,
    );
    let memory = [
        ("dvnav_process_resident_bytes", "The learner's resident memory.", s_mem.resident_bytes),
        (
            "dvnav_heap_in_use_bytes",
            "Bytes allocated and not freed: grows only with a leak, unlike resident memory, which keeps the allocator's high-water mark.",
            s_mem.heap_in_use_bytes,
        ),
    ];
    for (name, help, v) in memory {
        if let Some(v) = v {
            metric(name, "gauge", help, &one(v as f64));
        }
    }
    metric(
        "dvnav_replay_size",
        "gauge",
        "Transitions in the replay buffer.",
        &one(s.replay_size as f64),
    );
    metric(
        "dvnav_connected_actors",
        "gauge",
        "Actors with an open transition stream.",
        &one(s.actors.iter().filter(|a| a.connected).count() as f64),
    );
    metric(
        "dvnav_weight_version",
        "gauge",
        "Newest published weight version.",
        &one(s.weight_version as f64),
    );
    metric(
        "dvnav_policy_lag_versions_mean",
        "gauge",
        "Mean policy lag (current weight version minus the version that acted) of the transitions received since the previous sample (2 s); NaN when none was policy-driven.",
        &one(live.recent_policy_lag.mean()),
    );
    metric(
        "dvnav_policy_lag_versions_max",
        "gauge",
        "Largest policy lag of the transitions received since the previous sample (2 s).",
        &one(live.recent_policy_lag.max as f64),
    );
    metric(
        "dvnav_policy_lag_versions_sum",
        "counter",
        "Sum of the policy lag of every policy-driven transition of the run.",
        &one(live.policy_lag.sum as f64),
    );
    metric(
        "dvnav_policy_lag_versions_count",
        "counter",
        "Policy-driven transitions of the run (PID warm-up transitions have no lag).",
        &one(live.policy_lag.count as f64),
    );
    let pct = live.policy_lag_percentiles;
    let quantile = |q: &str, v: Option<u64>| {
        (format!("{{quantile=\"{q}\"}}"), v.map_or(f64::NAN, |v| v as f64))
    };
    metric(
        "dvnav_policy_lag_versions_quantile",
        "gauge",
        "Percentiles of the policy lag over every policy-driven transition of the run (nearest rank; NaN before the first).",
        &[quantile("0.5", pct.p50), quantile("0.95", pct.p95), quantile("0.99", pct.p99)],
    );
    metric(
        "dvnav_stage",
        "gauge",
        "Current curriculum stage (0 is the largest room).",
        &one(s.stage as f64),
    );
    metric(
        "dvnav_curriculum_success_rate",
        "gauge",
        "Success rate over the curriculum window of the current stage.",
        &one(s.success_rate),
    );
    let room = |stage: u32| sample.rooms.get(stage as usize).map_or("", String::as_str);
    let stage_rows = |f: &dyn Fn(&StageStats) -> f64| -> Vec<(String, f64)> {
        live.stages
            .iter()
            .map(|st| {
                (format!("{{stage=\"{}\",room=\"{}\"}}", st.stage, label(room(st.stage))), f(st))
            })
            .collect()
    };
    metric(
        "dvnav_stage_success_rate",
        "gauge",
        "Success rate over the last 50 episodes of each stage.",
        &stage_rows(&|st| st.recent_success_rate),
    );
    metric(
        "dvnav_stage_episodes_total",
        "counter",
        "Episodes reported per stage.",
        &stage_rows(&|st| st.episodes as f64),
    );
    metric(
        "dvnav_critic_loss",
        "gauge",
        "Latest critic loss (sum over both critics).",
        &one(s.critic_loss),
    );
    metric("dvnav_actor_loss", "gauge", "Latest actor (policy) loss.", &one(s.actor_loss));
    metric("dvnav_alpha", "gauge", "Entropy temperature alpha.", &one(s.alpha));
    metric(
        "dvnav_policy_entropy",
        "gauge",
        "The policy's entropy estimate, -mean log pi, at its last update.",
        &one(s.policy_entropy),
    );
    let actor_rows = |f: &dyn Fn(&ActorCounters) -> f64| -> Vec<(String, f64)> {
        s.actors.iter().map(|a| (format!("{{actor=\"{}\"}}", label(&a.name)), f(a))).collect()
    };
    metric(
        "dvnav_actor_transitions_received_total",
        "counter",
        "Transitions accepted, per actor.",
        &actor_rows(&|a| a.transitions_received as f64),
    );
    metric(
        "dvnav_actor_transitions_rejected_total",
        "counter",
        "Transitions refused, per actor.",
        &actor_rows(&|a| a.transitions_rejected as f64),
    );
    metric(
        "dvnav_actor_connected",
        "gauge",
        "1 while the actor's transition stream is open.",
        &actor_rows(&|a| f64::from(u8::from(a.connected))),
    );
    metric(
        "dvnav_step_budget",
        "gauge",
        "Environment steps the run is to take.",
        &one(s.step_budget as f64),
    );
    metric(
        "dvnav_done",
        "gauge",
        "1 once the step budget is reached or shutdown began.",
        &one(f64::from(u8::from(s.done))),
    );
    metric(
        "dvnav_uptime_seconds",
        "gauge",
        "Seconds since the learner started sampling.",
        &one(sample.elapsed_s),
    );
    out
}
