//! The actor's [`VariableSource`]: a background task follows the learner's `Variables` stream
//! and keeps the newest value; the environment loop reads it without blocking.

use dvnav_link::core::{VariableSource, Variables};
use std::sync::Arc;
use tokio::sync::watch;

/// The newest variables received from the learner.
#[derive(Clone)]
pub struct VariableClient {
    rx: watch::Receiver<Option<Arc<Variables>>>,
}

impl VariableClient {
    /// A client and the sender its background task feeds.
    pub fn new() -> (Self, watch::Sender<Option<Arc<Variables>>>) {
        let (tx, rx) = watch::channel(None);
        (Self { rx }, tx)
    }

    /// Waits until the first variables have arrived.
    pub async fn wait_first(&mut self) -> anyhow::Result<()> {
        self.rx.wait_for(|v| v.is_some()).await.map_err(|_| {
            anyhow::anyhow!("the variables stream ended before any weights arrived")
        })?;
        Ok(())
    }
}

impl VariableSource for VariableClient {
    fn latest(&self) -> Option<Arc<Variables>> {
        self.rx.borrow().clone()
    }
}
