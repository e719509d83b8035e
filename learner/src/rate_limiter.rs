//! Keeps the replay ratio (learner updates per environment step) fixed whatever the number of
//! actors, like Reverb's `SampleToInsertRatio`: the trainer waits when it is ahead of the data,
//! and ingestion waits when the data is more than `max_steps_ahead` steps ahead of training.
//! Ingestion waiting is what pushes back on the actors: the gRPC handler stops reading, HTTP/2
//! flow control fills, and the actors' sends block.
//!
//! At the end of the step budget ingestion stops waiting ([`RateLimiter::stop_ingest`]: what
//! actors still have in flight goes in at once) while the trainer goes on until it has done
//! every update the ratio allows for what was inserted up to the budget
//! ([`RateLimiter::is_paid`]): a run whose budget was reached at N steps ends with
//! ⌊(N − learning_starts + 1)·ratio⌋ updates however far ingestion had run ahead. What arrives
//! after (the actors' batches in flight) goes into the buffer but owes no updates, so the end
//! of a run takes at most the `max_steps_ahead` steps' worth of updates.
//!
//! The ratio may change during a run ([`RateLimiter::set_ratio`], a curriculum stage's own
//! ratio): the updates allowed then continue from what was allowed at the change, at the new
//! rate, so nothing owed is forgiven and nothing is owed twice.

use std::sync::{Condvar, Mutex};
use std::time::Duration;
use tokio::sync::watch;

#[derive(Clone, Copy, Debug, Default)]
struct State {
    inserted: u64,
    updates: u64,
    closed: bool,
    /// Ingestion no longer waits (the budget is reached); the trainer still may update.
    ingest_stopped: bool,
    /// Transitions inserted when ingestion stopped: updates are owed for these only.
    owed_for: Option<u64>,
    /// Updates per inserted transition from `base.start` on.
    ratio: f64,
    /// Where the current ratio took over.
    base: Base,
}

/// The point from which the current ratio counts: `updates` allowed at `start - 1` inserted
/// transitions, then `ratio` per transition. At the start of a run `start` is
/// `learning_starts` and `updates` 0.
#[derive(Clone, Copy, Debug, Default)]
struct Base {
    start: u64,
    updates: u64,
}

/// What [`RateLimiter::pressure`] reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pressure {
    /// Updates the ratio allows that the trainer has not done yet.
    pub updates_owed: u64,
    /// Ingestion would wait for the trainer now (backpressure on the actors).
    pub ingest_blocked: bool,
    /// The limiter is closed (end of run).
    pub closed: bool,
}

/// The shared ratio keeper between async ingestion and the trainer thread.
#[derive(Debug)]
pub struct RateLimiter {
    learning_starts: u64,
    max_steps_ahead: u64,
    state: Mutex<State>,
    trainer_wakeup: Condvar,
    updates_tx: watch::Sender<u64>,
}

impl RateLimiter {
    /// `ratio` updates per inserted transition once `learning_starts` transitions are in.
    pub fn new(ratio: f64, learning_starts: u64, max_steps_ahead: u64) -> Self {
        let (updates_tx, _) = watch::channel(0);
        let base = Base { start: learning_starts, updates: 0 };
        Self {
            learning_starts,
            max_steps_ahead,
            state: Mutex::new(State { ratio, base, ..State::default() }),
            trainer_wakeup: Condvar::new(),
            updates_tx,
        }
    }

    /// Resumes from checkpointed counters.
    pub fn restore(&self, inserted: u64, updates: u64) {
        let mut s = self.state.lock().expect("rate limiter lock");
        s.inserted = inserted;
        s.updates = updates;
        self.updates_tx.send_replace(updates);
    }

    /// Updates allowed now: for what was inserted, up to the budget once ingestion stopped.
    fn allowed(&self, s: &State) -> u64 {
        Self::allowed_at(s, s.owed_for.map_or(s.inserted, |n| n.min(s.inserted)))
    }

    /// Updates allowed once `inserted` transitions have arrived, at the current ratio (for a
    /// count before the current ratio took over: what was allowed when it did).
    pub fn updates_allowed(&self, inserted: u64) -> u64 {
        Self::allowed_at(&self.state.lock().expect("rate limiter lock"), inserted)
    }

    fn allowed_at(s: &State, inserted: u64) -> u64 {
        if inserted < s.base.start {
            // Before `learning_starts` (0), or before the current ratio took over.
            return s.base.updates;
        }
        s.base.updates + ((inserted - s.base.start + 1) as f64 * s.ratio).floor() as u64
    }

    fn may_insert(&self, s: &State) -> bool {
        if s.inserted < self.learning_starts {
            return true;
        }
        // Steps inserted beyond what the updates done so far account for.
        let covered = s.base.start as f64 + (s.updates as f64 - s.base.updates as f64) / s.ratio;
        (s.inserted as f64) - covered < self.max_steps_ahead as f64
    }

    /// The replay ratio from now on (a curriculum stage's own): the updates allowed continue
    /// from what the old ratio allowed for what is inserted now. The same ratio changes
    /// nothing.
    pub fn set_ratio(&self, ratio: f64) {
        let mut s = self.state.lock().expect("rate limiter lock");
        // After the budget the run only pays what it owes at the ratio it owed it.
        if ratio == s.ratio || s.ingest_stopped {
            return;
        }
        let base = if s.inserted >= self.learning_starts {
            Base { start: s.inserted + 1, updates: Self::allowed_at(&s, s.inserted) }
        } else {
            s.base
        };
        self.take_over(&mut s, ratio, base);
    }

    /// A resumed run's ratio: the updates done so far are all that is allowed until `start`
    /// transitions are in, then `ratio` per transition. For runs whose ratio changed on the
    /// way, where [`RateLimiter::restore`]'s count cannot be read back through one ratio.
    pub fn continue_at(&self, ratio: f64, start: u64) {
        let mut s = self.state.lock().expect("rate limiter lock");
        let base = Base { start, updates: s.updates };
        self.take_over(&mut s, ratio, base);
    }

    /// `ratio` counts from `base` on; wakes both sides, since either may now go on (the
    /// trainer if the new ratio allows more, ingestion if it allows fewer).
    fn take_over(&self, s: &mut State, ratio: f64, base: Base) {
        s.base = base;
        s.ratio = ratio;
        self.trainer_wakeup.notify_all();
        self.updates_tx.send_replace(s.updates);
    }

    /// The current replay ratio.
    pub fn ratio(&self) -> f64 {
        self.state.lock().expect("rate limiter lock").ratio
    }

    /// Waits (asynchronously) until ingestion may proceed; returns at once when closed.
    pub async fn wait_to_insert(&self) {
        let mut rx = self.updates_tx.subscribe();
        loop {
            {
                let s = self.state.lock().expect("rate limiter lock");
                if s.closed || s.ingest_stopped || self.may_insert(&s) {
                    return;
                }
            }
            if rx.changed().await.is_err() {
                return;
            }
        }
    }

    /// Updates owed now (allowed by the ratio but not yet done) and whether ingestion would
    /// have to wait: what the watchdog reads to tell a slow trainer from a
    /// limiter that cannot make progress.
    pub fn pressure(&self) -> Pressure {
        let s = self.state.lock().expect("rate limiter lock");
        Pressure {
            updates_owed: self.allowed(&s).saturating_sub(s.updates),
            ingest_blocked: !s.closed && !s.ingest_stopped && !self.may_insert(&s),
            closed: s.closed,
        }
    }

    /// Records inserted transitions and wakes the trainer.
    pub fn inserted(&self, n: u64) {
        let mut s = self.state.lock().expect("rate limiter lock");
        s.inserted += n;
        self.trainer_wakeup.notify_all();
    }

    /// Blocks the trainer until an update is allowed (true) or the limiter is closed (false).
    /// Wakes at least every `tick` so the caller can check other conditions.
    pub fn wait_to_update(&self, tick: Duration) -> bool {
        let mut s = self.state.lock().expect("rate limiter lock");
        loop {
            if s.closed {
                return false;
            }
            if s.updates < self.allowed(&s) {
                return true;
            }
            let (guard, timeout) =
                self.trainer_wakeup.wait_timeout(s, tick).expect("rate limiter lock");
            s = guard;
            if timeout.timed_out() && !s.closed && s.updates >= self.allowed(&s) {
                return false;
            }
        }
    }

    /// Records one finished update and wakes waiting ingestion.
    pub fn updated(&self) {
        let mut s = self.state.lock().expect("rate limiter lock");
        s.updates += 1;
        self.updates_tx.send_replace(s.updates);
    }

    /// Releases every waiter for good (shutdown, or the end of the step budget).
    pub fn close(&self) {
        let mut s = self.state.lock().expect("rate limiter lock");
        s.closed = true;
        self.trainer_wakeup.notify_all();
        let u = s.updates;
        self.updates_tx.send_replace(u);
    }

    /// The end of the step budget: ingestion stops waiting for the trainer (waiters are
    /// released), and the trainer goes on paying the updates the ratio owes.
    pub fn stop_ingest(&self) {
        let mut s = self.state.lock().expect("rate limiter lock");
        s.ingest_stopped = true;
        let inserted = s.inserted;
        s.owed_for.get_or_insert(inserted);
        let u = s.updates;
        self.updates_tx.send_replace(u);
    }

    /// Every update the ratio allows for what was inserted is done.
    pub fn is_paid(&self) -> bool {
        let s = self.state.lock().expect("rate limiter lock");
        s.updates >= self.allowed(&s)
    }

    /// True once closed.
    pub fn is_closed(&self) -> bool {
        self.state.lock().expect("rate limiter lock").closed
    }

    /// (inserted, updates).
    pub fn counters(&self) -> (u64, u64) {
        let s = self.state.lock().expect("rate limiter lock");
        (s.inserted, s.updates)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratio_bounds_updates_by_inserted_steps() {
        let rl = RateLimiter::new(0.5, 10, 4);
        assert_eq!(rl.updates_allowed(9), 0);
        assert_eq!(rl.updates_allowed(10), 0);
        assert_eq!(rl.updates_allowed(11), 1);
        assert_eq!(rl.updates_allowed(29), 10);
        rl.inserted(9);
        assert!(!rl.wait_to_update(Duration::from_millis(1)));
        rl.inserted(3);
        assert!(rl.wait_to_update(Duration::from_millis(1)));
    }

    #[test]
    fn a_new_ratio_counts_on_from_what_the_old_one_allowed() {
        let rl = RateLimiter::new(0.5, 10, 4);
        rl.inserted(29);
        for _ in 0..4 {
            rl.updated();
        }
        assert_eq!(rl.pressure().updates_owed, 6);
        rl.set_ratio(0.25);
        assert_eq!(rl.ratio(), 0.25);
        // Nothing owed is forgiven; the new rate counts from the next transition on.
        assert_eq!(rl.pressure().updates_owed, 6);
        assert_eq!([30, 32, 33, 37, 41].map(|n| rl.updates_allowed(n)), [10, 10, 11, 12, 13]);
        // Ingestion may lead what the 10 updates cover (29 transitions) by 4 steps at the
        // new rate, once the trainer has paid what it owes.
        for _ in 0..6 {
            rl.updated();
        }
        rl.inserted(4);
        assert!(!rl.pressure().ingest_blocked);
        rl.inserted(1);
        assert!(rl.pressure().ingest_blocked, "34 inserted, 10 updates: 4 ahead of 30");
        rl.updated();
        assert!(!rl.pressure().ingest_blocked, "11 updates cover 34 at 0.25");
        // The same ratio changes nothing; after the budget nothing changes.
        rl.set_ratio(0.25);
        assert_eq!(rl.updates_allowed(37), 12);
        rl.stop_ingest();
        rl.set_ratio(1.0);
        assert_eq!(rl.ratio(), 0.25);
    }

    #[test]
    fn a_resumed_run_waits_for_start_then_counts_at_its_ratio() {
        let rl = RateLimiter::new(0.25, 10, 4);
        rl.restore(500, 40);
        rl.continue_at(0.5, 510);
        assert_eq!([500, 509, 510, 513].map(|n| rl.updates_allowed(n)), [40, 40, 40, 42]);
        assert_eq!(rl.pressure().updates_owed, 0);
    }

    #[test]
    fn a_ratio_set_before_learning_starts_is_the_ratio_from_the_start() {
        let rl = RateLimiter::new(0.5, 10, 4);
        rl.inserted(5);
        rl.set_ratio(1.0);
        assert_eq!([9, 10, 11, 29].map(|n| rl.updates_allowed(n)), [0, 1, 2, 20]);
    }

    #[test]
    fn ingestion_waits_until_training_catches_up() {
        let rl = RateLimiter::new(1.0, 10, 4);
        let may_insert = |inserted, updates| {
            let s = State { inserted, updates, ..*rl.state.lock().unwrap() };
            rl.may_insert(&s)
        };
        assert!(may_insert(0, 0));
        assert!(may_insert(13, 0));
        assert!(!may_insert(14, 0));
        assert!(may_insert(14, 1));
    }

    #[tokio::test]
    async fn blocked_ingestion_resumes_after_updates_and_on_close() {
        let rl = std::sync::Arc::new(RateLimiter::new(1.0, 0, 2));
        rl.inserted(5);
        let waiter = {
            let rl = rl.clone();
            tokio::spawn(async move { rl.wait_to_insert().await })
        };
        tokio::task::yield_now().await;
        assert!(!waiter.is_finished());
        for _ in 0..4 {
            rl.updated();
        }
        tokio::time::timeout(Duration::from_secs(5), waiter).await.unwrap().unwrap();

        rl.inserted(10);
        let waiter = {
            let rl = rl.clone();
            tokio::spawn(async move { rl.wait_to_insert().await })
        };
        rl.close();
        tokio::time::timeout(Duration::from_secs(5), waiter).await.unwrap().unwrap();
    }

    #[tokio::test]
    async fn after_the_budget_ingestion_goes_in_and_the_trainer_pays_what_it_owes() {
        let rl = std::sync::Arc::new(RateLimiter::new(0.5, 10, 4));
        rl.inserted(14);
        let waiter = {
            let rl = rl.clone();
            tokio::spawn(async move { rl.wait_to_insert().await })
        };
        tokio::task::yield_now().await;
        assert!(!waiter.is_finished(), "14 steps, no updates: 4 ahead");
        rl.inserted(6);
        // The batch that reaches the budget: (20 - 10 + 1) * 0.5 = 5 updates owed.
        rl.stop_ingest();
        tokio::time::timeout(Duration::from_secs(5), waiter).await.unwrap().unwrap();
        // What was in flight goes in, and owes nothing more.
        rl.inserted(100);
        assert_eq!(rl.pressure().updates_owed, 5);
        assert!(!rl.is_paid());
        for _ in 0..5 {
            assert!(rl.wait_to_update(Duration::from_millis(1)));
            rl.updated();
        }
        assert!(rl.is_paid());
        assert!(!rl.wait_to_update(Duration::from_millis(1)));
        assert!(!rl.pressure().ingest_blocked);
    }
}
