//! [`RobotTable`]: the robots one controller drives, by id, each with its own state: a bounded
//! table whose entries expire when their robot falls silent.
//!
//! A robot that stops calling (switched off, gone to charge) must not hold a place for ever,
//! and a caller inventing ids must not grow the table without bound: at most `capacity`
//! robots, and one idle for `idle` is dropped when room is needed or when the table is read.

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// One robot's entry.
#[derive(Clone, Debug)]
struct Entry<T> {
    state: T,
    last_seen: Instant,
}

/// The table was full of robots that are all still active.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "{capacity} robots are active on this server (none idle for {idle:?}); no room for another"
)]
pub struct TableFull {
    /// The table's capacity.
    pub capacity: usize,
    /// How long a robot must be silent before its place is freed.
    pub idle: Duration,
}

/// Robots by id, at most `capacity`, each dropped after `idle` without a call.
#[derive(Debug)]
pub struct RobotTable<T> {
    entries: HashMap<String, Entry<T>>,
    capacity: usize,
    idle: Duration,
}

impl<T: Clone> RobotTable<T> {
    /// An empty table.
    ///
    /// # Panics
    /// If `capacity` is 0.
    pub fn new(capacity: usize, idle: Duration) -> Self {
        assert!(capacity > 0, "a robot table holds at least one robot");
        RobotTable { entries: HashMap::new(), capacity, idle }
    }

    /// The state of robot `id` as of `now`, marking it seen; a robot not in the table is added
    /// with `new()`. Refused when the table is full of active robots.
    pub fn touch(
        &mut self,
        id: &str,
        now: Instant,
        new: impl FnOnce() -> T,
    ) -> Result<T, TableFull> {
        if let Some(e) = self.entries.get_mut(id) {
            if now.saturating_duration_since(e.last_seen) < self.idle {
                e.last_seen = now;
                return Ok(e.state.clone());
            }
            // Expired: as if it had been dropped already.
            self.entries.remove(id);
        }
        self.make_room(now)?;
        let state = new();
        self.entries.insert(id.to_string(), Entry { state: state.clone(), last_seen: now });
        Ok(state)
    }

    /// Sets robot `id`'s state as of `now`, adding it if need be.
    pub fn set(&mut self, id: &str, now: Instant, state: T) -> Result<(), TableFull> {
        if !self.entries.contains_key(id) {
            self.make_room(now)?;
        }
        self.entries.insert(id.to_string(), Entry { state, last_seen: now });
        Ok(())
    }

    /// Robot `id`'s state, if it is in the table and active at `now`; does not mark it seen.
    pub fn get(&self, id: &str, now: Instant) -> Option<T> {
        self.entries
            .get(id)
            .filter(|e| now.saturating_duration_since(e.last_seen) < self.idle)
            .map(|e| e.state.clone())
    }

    /// Robot `id`'s state, if it is in the table and active at `now`, marking it seen.
    pub fn seen(&mut self, id: &str, now: Instant) -> Option<T> {
        let idle = self.idle;
        let e = self.entries.get_mut(id)?;
        if now.saturating_duration_since(e.last_seen) >= idle {
            return None;
        }
        e.last_seen = now;
        Some(e.state.clone())
    }

    /// Drops robot `id`'s entry; says whether there was one.
    pub fn remove(&mut self, id: &str) -> bool {
        self.entries.remove(id).is_some()
    }

    /// Robots active at `now` (expired ones are dropped first).
    pub fn active(&mut self, now: Instant) -> usize {
        self.expire(now);
        self.entries.len()
    }

    /// The table's capacity and idle time.
    pub fn limits(&self) -> (usize, Duration) {
        (self.capacity, self.idle)
    }

    fn expire(&mut self, now: Instant) {
        let idle = self.idle;
        self.entries.retain(|_, e| now.saturating_duration_since(e.last_seen) < idle);
    }

    fn make_room(&mut self, now: Instant) -> Result<(), TableFull> {
        if self.entries.len() >= self.capacity {
            self.expire(now);
        }
        if self.entries.len() >= self.capacity {
            return Err(TableFull { capacity: self.capacity, idle: self.idle });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_are_kept_apart_bounded_and_expire_when_silent() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut table = RobotTable::new(2, s(10));
        assert_eq!(table.touch("a", t0, || 1), Ok(1));
        assert_eq!(table.touch("a", t0 + s(1), || 99), Ok(1), "known: its own state");
        table.set("b", t0 + s(2), 2).unwrap();
        assert_eq!((table.get("a", t0 + s(2)), table.get("b", t0 + s(2))), (Some(1), Some(2)));
        let full = table.touch("c", t0 + s(3), || 3).unwrap_err();
        assert_eq!(full, TableFull { capacity: 2, idle: s(10) });
        assert!(full.to_string().contains("2 robots are active"), "{full}");
        assert_eq!(table.get("c", t0 + s(3)), None, "a refused robot is not added");

        // `a` was last seen at 1 s, `b` at 2 s: at 11.5 s `a` has expired, `b` not.
        assert_eq!(table.get("a", t0 + s(11)), None);
        assert_eq!(table.touch("c", t0 + s(11), || 3), Ok(3), "a's place is free");
        assert_eq!(table.active(t0 + s(11)), 2);
        // `a` comes back: it starts over from `new`, not from what it had.
        assert!(table.touch("a", t0 + s(11), || 5).is_err(), "b and c are active");
        assert_eq!(table.active(t0 + s(12)), 1, "b expired at 12 s");
        assert_eq!(table.touch("a", t0 + s(12), || 5), Ok(5));
        assert_eq!(table.limits(), (2, s(10)));
    }
}
