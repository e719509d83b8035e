//! [`Credits`]: how many batches an actor may have handed to the learner and not yet had
//! acknowledged (`actor.max_batches_in_flight`).
//!
//! Why: a batch's policy lag is the weight versions published between its acting and its
//! insertion. Batches queued in front of the learner's rate limiter (the send queue, the
//! link's channel, the HTTP/2 window: a dozen per actor) each wait for the updates of those
//! before them, and their transitions arrived up to 25 versions stale. With credits the
//! environment loop blocks *before* it starts a batch until one is free: with one credit an
//! actor acts its next batch only once the learner has taken the last, so what the learner
//! inserts was acted a batch ago, not a queue ago.
//!
//! The adder takes a credit before the step that starts a batch (`Adder::ready`, so the step
//! acts with the weights that arrived while it waited); the link gives it back
//! when the learner acknowledges the batch (inserted or a duplicate), and closes the credits
//! when it ends, so a loop waiting for one fails instead of hanging.
//!
//! One batch in flight per actor is still a lot when many actors share a small learner: eight
//! actors' 128-transition batches kept ~1,000 transitions ahead of it (lag p95 14 versions). So
//! the credits also carry the learner's advice on how big the next batch should be (its share
//! of `learner.transitions_in_flight`), which the link updates from every acknowledgement.

use std::sync::{Condvar, Mutex};

#[derive(Debug)]
struct State {
    free: usize,
    closed: bool,
    /// The learner's advised batch size (0: none).
    advice: usize,
}

/// Batches that may be in flight; shared by the adder (loop thread) and the link.
#[derive(Debug)]
pub struct Credits {
    state: Mutex<State>,
    freed: Condvar,
}

impl Credits {
    /// `n` batches may be in flight (at least 1).
    pub fn new(n: usize) -> Self {
        Self {
            state: Mutex::new(State { free: n.max(1), closed: false, advice: 0 }),
            freed: Condvar::new(),
        }
    }

    /// Takes a credit, blocking the calling thread until one is free, and returns the
    /// learner's latest advice on the batch's size (`None`: none given); an error once closed.
    pub fn take(&self) -> anyhow::Result<Option<usize>> {
        let mut s = self.state.lock().expect("credits lock");
        loop {
            if s.closed {
                anyhow::bail!("the transition stream to the learner is closed");
            }
            if s.free > 0 {
                s.free -= 1;
                return Ok((s.advice > 0).then_some(s.advice));
            }
            s = self.freed.wait(s).expect("credits lock");
        }
    }

    /// Gives back `n` credits (batches acknowledged).
    pub fn give(&self, n: usize) {
        if n > 0 {
            self.state.lock().expect("credits lock").free += n;
            self.freed.notify_all();
        }
    }

    /// The learner's advice on batch size, for batches started from now on (0: none).
    pub fn advise(&self, batch_transitions: u32) {
        self.state.lock().expect("credits lock").advice = batch_transitions as usize;
    }

    /// No more credits, ever: a waiting or later [`Credits::take`] fails.
    pub fn close(&self) {
        self.state.lock().expect("credits lock").closed = true;
        self.freed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn a_taker_waits_for_an_acknowledgement_and_fails_once_closed() {
        let c = Arc::new(Credits::new(1));
        c.take().unwrap();
        let waiter = {
            let c = c.clone();
            std::thread::spawn(move || c.take())
        };
        std::thread::sleep(Duration::from_millis(50));
        assert!(!waiter.is_finished(), "no credit until the batch is acknowledged");
        c.give(1);
        waiter.join().unwrap().unwrap();
        let waiter = {
            let c = c.clone();
            std::thread::spawn(move || c.take())
        };
        std::thread::sleep(Duration::from_millis(50));
        c.close();
        assert!(waiter.join().unwrap().is_err());
    }
}
