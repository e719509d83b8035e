//! Publishes versioned policy weights and stage assignments to every subscriber (Acme's
//! VariableSource). Backed by a `watch` channel: a slow actor skips straight to the newest
//! version instead of queueing old ones. Each version's safetensors are serialized once and
//! shared by every actor's stream (`dvnav_link::wire::policy_bytes`), never copied per actor.

use dvnav_link::core::{self, Variables};
use std::sync::Arc;
use tokio::sync::watch;

/// The learner's side of weight distribution.
#[derive(Debug)]
pub struct VariableSource {
    tx: watch::Sender<Arc<Variables>>,
}

impl VariableSource {
    /// Starts with `initial` (version 1: the freshly initialised policy).
    pub fn new(initial: Variables) -> Self {
        let (tx, _) = watch::channel(Arc::new(initial));
        Self { tx }
    }

    /// A receiver that sees the current variables and every later change.
    pub fn subscribe(&self) -> watch::Receiver<Arc<Variables>> {
        self.tx.subscribe()
    }

    /// The newest variables.
    pub fn current(&self) -> Arc<Variables> {
        self.tx.borrow().clone()
    }

    /// Publishes new weights as the next version, keeping the rest.
    pub fn publish_weights(&self, policy: Vec<u8>) -> u64 {
        let mut version = 0;
        self.tx.send_modify(|v| {
            let mut next = (**v).clone();
            next.version += 1;
            next.policy = Arc::new(policy);
            version = next.version;
            *v = Arc::new(next);
        });
        version
    }

    /// Continues a resumed run's numbering: `policy` becomes version `version` (what the
    /// checkpoint had published last), so versions keep increasing across a resume.
    pub fn restore(&self, version: u64, policy: Vec<u8>) {
        self.tx.send_modify(|v| {
            let mut next = (**v).clone();
            next.version = version.max(1);
            next.policy = Arc::new(policy);
            *v = Arc::new(next);
        });
    }

    /// Changes stage, warm-up or stop flags without a new weight version; notifies only when
    /// something changed.
    pub fn set_run_state(&self, stage: u32, room: &str, warmup: bool, stop: bool) {
        self.tx.send_if_modified(|v| {
            if v.stage == stage && v.room == room && v.warmup == warmup && v.stop == stop {
                return false;
            }
            let mut next = (**v).clone();
            next.stage = stage;
            next.room = room.to_string();
            next.warmup = warmup;
            next.stop = stop;
            *v = Arc::new(next);
            true
        });
    }
}

impl core::VariableSource for VariableSource {
    fn latest(&self) -> Option<Arc<Variables>> {
        Some(self.current())
    }
}
