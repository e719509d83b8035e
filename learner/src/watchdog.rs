//! Names the part of the learner that stopped making progress.
//!
//! Five times per heartbeat interval (`learner.heartbeat_s`) the learner hands the
//! [`Watchdog`] an [`Observation`] of its progress counters; the watchdog remembers when each
//! counter last moved and reports a [`Stall`] for each component expected to move that has not
//! for three of those samples. The last progress happened at most one sample before it was
//! seen, so a stalled component is named 0.6 to 0.8 of a heartbeat after its last progress: the
//! last fifth is slack for a late sample on a busy machine, so it is named within one
//! heartbeat interval. Actors hand over a batch at least every quarter interval, even a part
//! one (`actor::adder`): a live actor shows progress at least every 0.45 interval as sampled,
//! well inside the 0.6 that would make it a stall.
//!
//! - `ingest`: actors are connected but no transition has been accepted, and the rate limiter
//!   is not what holds them back;
//! - `trainer`: the rate limiter owes updates but the update counter does not move;
//! - `rate_limiter`: ingestion waits for updates while the limiter owes none, so neither side
//!   can move (should never happen; it would be a limiter bug);
//! - `actor:<name>`: an actor's transition stream is open but it sent no batch.
//!
//! The logic is pure (time comes in as a [`Duration`] since start), so the tests drive it with a
//! fake clock; [`run`] is the task that reads the state's progress counters
//! ([`LearnerState::progress`], which holds no stalls), logs each stall at warn level with its
//! duration and last error, and reports them to the state ([`LearnerState::set_stalled`]) for
//! `/metrics` (`dvnav_stalled{component}`), `/readyz` and, past `learner.liveness_stall_s`,
//! `/healthz`. What it reads and what it reports are apart: it never reads its own report.

use crate::state::LearnerState;
pub use crate::state::Stall;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// When the watchdog looks and how long without progress makes a stall, for one heartbeat
/// interval (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    /// How often it samples the counters: a fifth of the heartbeat.
    pub sample_every: Duration,
    /// How long a component expected to move may show no progress: the heartbeat less two
    /// samples, one for the progress seen late and one of slack for a late sample.
    pub stall_after: Duration,
}

impl Timing {
    /// The timing for a heartbeat interval.
    pub fn for_heartbeat(heartbeat: Duration) -> Self {
        let sample_every = heartbeat / 5;
        Self { sample_every, stall_after: heartbeat - 2 * sample_every }
    }
}

/// One actor as the watchdog sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct ActorObservation {
    /// Its name.
    pub name: String,
    /// A transition stream is open.
    pub connected: bool,
    /// Batches accepted so far (and duplicates acknowledged: both are signs of life).
    pub batches: u64,
    /// Its last refusal or stream error.
    pub last_error: Option<String>,
}

/// The progress counters at one heartbeat.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Observation {
    /// Transitions accepted.
    pub transitions_received: u64,
    /// Updates done.
    pub updates: u64,
    /// Updates the rate limiter allows that are not done yet.
    pub updates_owed: u64,
    /// Ingestion waits for the trainer (backpressure).
    pub ingest_blocked: bool,
    /// The run is over (budget reached or shutting down): nothing is expected to move.
    pub done: bool,
    /// The trainer's last error.
    pub trainer_last_error: Option<String>,
    /// Per actor.
    pub actors: Vec<ActorObservation>,
}

impl Observation {
    /// The counters of `state` now.
    pub fn of(state: &LearnerState) -> Self {
        let st = state.progress();
        let p = state.limiter().pressure();
        Self {
            transitions_received: st.transitions_received,
            updates: st.updates,
            updates_owed: p.updates_owed,
            ingest_blocked: p.ingest_blocked,
            done: st.done || p.closed,
            trainer_last_error: st.trainer_last_error,
            actors: st
                .actors
                .into_iter()
                .map(|a| ActorObservation {
                    name: a.name,
                    connected: a.connected,
                    batches: a.batches + a.duplicate_batches,
                    last_error: a.last_error,
                })
                .collect(),
        }
    }
}

/// When a component's progress counter last moved, or its stall condition last did not hold.
#[derive(Debug, Default)]
struct Progress {
    value: u64,
    since: Duration,
}

impl Progress {
    /// Notes the counter at `now`; `idle` says whether the component is expected to move.
    /// Returns how long it has been expected to move without moving.
    fn observe(&mut self, now: Duration, value: u64, expected_to_move: bool) -> Duration {
        if value != self.value || !expected_to_move {
            self.value = value;
            self.since = now;
        }
        now.saturating_sub(self.since)
    }
}

/// The watchdog's memory between heartbeats (see the module docs).
#[derive(Debug)]
pub struct Watchdog {
    stall_after: Duration,
    ingest: Progress,
    trainer: Progress,
    limiter: Progress,
    actors: BTreeMap<String, Progress>,
}

impl Watchdog {
    /// A watchdog reporting components stuck for at least `stall_after`.
    pub fn new(stall_after: Duration) -> Self {
        Self {
            stall_after,
            ingest: Progress::default(),
            trainer: Progress::default(),
            limiter: Progress::default(),
            actors: BTreeMap::new(),
        }
    }

    /// Takes the counters seen at `now` (time since start) and returns what is stuck.
    pub fn check(&mut self, now: Duration, o: &Observation) -> Vec<Stall> {
        let live = !o.done;
        let connected = o.actors.iter().filter(|a| a.connected).count();
        let mut stalls = Vec::new();
        let mut stall = |component: String, idle: Duration, what: String, last_error| {
            if idle >= self.stall_after {
                stalls.push(Stall { component, for_s: idle.as_secs_f64(), what, last_error });
            }
        };
        let idle = self.ingest.observe(
            now,
            o.transitions_received,
            live && connected > 0 && !o.ingest_blocked,
        );
        let ingest_error = o.actors.iter().rev().find_map(|a| a.last_error.clone());
        stall(
            "ingest".into(),
            idle,
            format!("no transition accepted while {connected} actor(s) are connected"),
            ingest_error,
        );
        let idle = self.trainer.observe(now, o.updates, live && o.updates_owed > 0);
        stall(
            "trainer".into(),
            idle,
            format!("no update while the rate limiter owes {} update(s)", o.updates_owed),
            o.trainer_last_error.clone(),
        );
        let idle = self.limiter.observe(
            now,
            o.transitions_received + o.updates,
            live && o.ingest_blocked && o.updates_owed == 0,
        );
        stall(
            "rate_limiter".into(),
            idle,
            "ingestion waits for updates but no update is owed".into(),
            None,
        );
        self.actors.retain(|name, _| o.actors.iter().any(|a| &a.name == name));
        for a in &o.actors {
            let p = self
                .actors
                .entry(a.name.clone())
                .or_insert(Progress { value: a.batches, since: now });
            // An actor held back by backpressure is not silent by its own doing.
            let idle = p.observe(now, a.batches, live && a.connected && !o.ingest_blocked);
            stall(
                format!("actor:{}", a.name),
                idle,
                "stream open but no batch arrives".into(),
                a.last_error.clone(),
            );
        }
        stalls
    }
}

/// Looks at `state` at `timing.sample_every` until `stop` is cancelled: logs each new stall at
/// warn level (component, how long, what, last error) and again every minute while it lasts,
/// logs when it clears, and reports the current stalls to the state for `/metrics`, the probes
/// and the summary.
pub async fn run(state: Arc<LearnerState>, timing: Timing, stop: CancellationToken) {
    let started = Instant::now();
    let mut watchdog = Watchdog::new(timing.stall_after);
    let mut ticks = tokio::time::interval(timing.sample_every);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Components stalled at the previous sample, with when each was last logged.
    let mut previous: BTreeMap<String, Instant> = BTreeMap::new();
    const REPEAT: Duration = Duration::from_secs(60);
    loop {
        let tick = tokio::select! {
            tick = ticks.tick() => tick,
            () = stop.cancelled() => break,
        };
        // The sample's scheduled time, not when this task got to run: with the time it ran, a
        // sample a little later than the one that saw the last progress would measure just
        // under `stall_after` three samples on, and the stall would be named a sample late
        // (a whole heartbeat after the last progress, seen on a busy machine).
        let stalls = watchdog.check(tick.duration_since(started), &Observation::of(&state));
        let now = Instant::now();
        let mut current = BTreeMap::new();
        for s in &stalls {
            let logged = previous.get(&s.component).copied();
            let due = logged.is_none_or(|t| now.duration_since(t) >= REPEAT);
            current.insert(s.component.clone(), if due { now } else { logged.unwrap_or(now) });
            if !due {
                continue;
            }
            tracing::warn!(
                component = %s.component,
                stalled_for_s = s.for_s.round(),
                what = %s.what,
                last_error = s.last_error.as_deref().unwrap_or("none"),
                "watchdog: component stalled"
            );
        }
        for c in previous.keys().filter(|c| !current.contains_key(*c)) {
            tracing::info!(component = %c, "watchdog: component moving again");
        }
        previous = current;
        state.set_stalled(stalls);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: Duration = Duration::from_secs(1);

    fn actor(name: &str, connected: bool, batches: u64) -> ActorObservation {
        ActorObservation { name: name.into(), connected, batches, last_error: None }
    }

    fn components(stalls: &[Stall]) -> Vec<&str> {
        stalls.iter().map(|s| s.component.as_str()).collect()
    }

    #[test]
    fn a_healthy_run_reports_nothing() {
        let mut w = Watchdog::new(30 * S);
        for t in 0..20u64 {
            let o = Observation {
                transitions_received: 100 * t,
                updates: 50 * t,
                updates_owed: 3,
                actors: vec![actor("a", true, t), actor("b", true, 2 * t)],
                ..Default::default()
            };
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty(), "t={t}");
        }
    }

    #[test]
    fn no_transitions_from_connected_actors_is_an_ingest_stall_naming_the_silent_actor() {
        let mut w = Watchdog::new(30 * S);
        let mut o = Observation {
            transitions_received: 500,
            actors: vec![actor("a", true, 5), actor("b", true, 9)],
            ..Default::default()
        };
        assert!(w.check(Duration::ZERO, &o).is_empty());
        // b goes on; a falls silent with an error on record.
        o.actors[0].last_error = Some("malformed transition batch: field `rewards`".into());
        for t in 1..=2u64 {
            o.transitions_received += 10;
            o.actors[1].batches += 1;
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty());
        }
        o.transitions_received += 10;
        o.actors[1].batches += 1;
        let stalls = w.check(30 * S, &o);
        assert_eq!(components(&stalls), ["actor:a"]);
        assert_eq!(stalls[0].for_s, 30.0);
        assert!(stalls[0].last_error.as_deref().unwrap().contains("rewards"));
        // Now nothing arrives at all.
        for t in 4..=6u64 {
            let stalls = w.check(Duration::from_secs(10 * t), &o);
            if t < 6 {
                assert_eq!(components(&stalls), ["actor:a"]);
            } else {
                assert_eq!(components(&stalls), ["ingest", "actor:a", "actor:b"]);
                assert_eq!(stalls[0].for_s, 30.0);
                assert!(stalls[0].what.contains("2 actor(s)"));
            }
        }
        // A disconnected actor is not expected to send; the stall clears when data flows.
        o.actors[0].connected = false;
        o.transitions_received += 1;
        o.actors[1].batches += 1;
        assert!(w.check(70 * S, &o).is_empty());
    }

    #[test]
    fn owed_updates_not_done_are_a_trainer_stall_with_its_last_error() {
        let mut w = Watchdog::new(30 * S);
        let mut o = Observation {
            updates: 10,
            updates_owed: 0,
            trainer_last_error: Some("checkpoint: cannot write /x: No space left".into()),
            ..Default::default()
        };
        // Nothing owed (warm-up, or caught up): never a stall however long.
        for t in 0..10u64 {
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty());
        }
        // Owed from the heartbeat at 100 s on (last seen not owed at 90 s).
        o.updates_owed = 4;
        for t in 10..12u64 {
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty(), "t={t}");
        }
        let stalls = w.check(120 * S, &o);
        assert_eq!(components(&stalls), ["trainer"]);
        assert!(stalls[0].what.contains("owes 4"));
        assert!(stalls[0].last_error.as_deref().unwrap().contains("No space left"));
        o.updates += 1;
        assert!(w.check(140 * S, &o).is_empty());
    }

    #[test]
    fn ingestion_blocked_with_no_update_owed_is_a_rate_limiter_stall_not_an_actor_one() {
        let mut w = Watchdog::new(30 * S);
        let o = Observation {
            transitions_received: 1_000,
            updates: 7,
            ingest_blocked: true,
            actors: vec![actor("a", true, 3)],
            ..Default::default()
        };
        for t in 0..3u64 {
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty());
        }
        assert_eq!(components(&w.check(30 * S, &o)), ["rate_limiter"]);
        // Blocked because the trainer is behind is the trainer's stall, not the limiter's.
        let mut w = Watchdog::new(30 * S);
        let o = Observation { updates_owed: 2, ..o };
        w.check(Duration::ZERO, &o);
        assert_eq!(components(&w.check(30 * S, &o)), ["trainer"]);
    }

    #[test]
    fn a_finished_run_is_never_stalled() {
        let mut w = Watchdog::new(30 * S);
        let o = Observation {
            updates_owed: 9,
            ingest_blocked: true,
            done: true,
            actors: vec![actor("a", true, 1)],
            ..Default::default()
        };
        for t in 0..10u64 {
            assert!(w.check(Duration::from_secs(10 * t), &o).is_empty());
        }
    }

    /// The task stores what it finds in the state (and so in `/metrics`), on tokio's paused
    /// clock: no real sleeping. The trainer stops (never starts) at 0 s: it is named by 0.8 of
    /// a heartbeat, not before 0.6.
    #[tokio::test(start_paused = true)]
    async fn the_task_names_a_stuck_trainer_within_one_heartbeat() {
        let mut cfg = dvnav_config::Config::default();
        cfg.sac.learning_starts = 0;
        let state = Arc::new(LearnerState::new(cfg, "r".into(), None, vec![]));
        // Transitions in make updates owed; nobody trains.
        state.limiter().inserted(100);
        assert!(state.limiter().pressure().updates_owed > 0);
        state.record_trainer_error("boom".into());
        let heartbeat = Duration::from_secs(5);
        let stop = CancellationToken::new();
        let task = tokio::spawn(run(state.clone(), Timing::for_heartbeat(heartbeat), stop.clone()));
        tokio::time::sleep(heartbeat / 2).await;
        assert!(state.status().stalled.is_empty(), "named before 0.6 heartbeat");
        tokio::time::sleep(heartbeat * 3 / 10).await;
        let stalled = state.status().stalled;
        assert_eq!(components(&stalled), ["trainer"]);
        assert!(stalled[0].for_s <= heartbeat.as_secs_f64() * 0.8, "{stalled:?}");
        assert_eq!(stalled[0].last_error.as_deref(), Some("boom"));
        stop.cancel();
        task.await.unwrap();
    }

    #[test]
    fn timing_names_a_stall_within_one_heartbeat_of_the_last_progress() {
        for h in [0.1, 1.0, 5.0, 30.0] {
            let heartbeat = Duration::from_secs_f64(h);
            let t = Timing::for_heartbeat(heartbeat);
            // Progress just after a sample is seen one sample later: the worst case, with a
            // sample of slack left for a busy machine.
            assert!(t.stall_after + 2 * t.sample_every <= heartbeat, "{t:?}");
            // An actor that hands over a batch every quarter heartbeat is seen moving at least
            // every quarter plus one sample: never a stall.
            assert!(heartbeat / 4 + t.sample_every < t.stall_after, "{t:?}");
        }
    }
}
