//! The actor's [`Adder`]: collects transitions into batches of `actor.batch_transitions` (each
//! observation once, paired by position: [`BatchWriter`]) and hands full batches to the
//! transition stream through a bounded channel, encoded once ([`EncodedBatch`]) here on the
//! loop's thread: the link sends those bytes, and sends them again after a reconnect. When the
//! learner pushes back, the channel fills and `add` blocks: the environment loop slows down
//! instead of buffering without limit.
//!
//! A batch is also handed over once its first transition is `max_delay` old (a quarter
//! of the heartbeat interval), even part full: a slow actor still shows the learner it is alive and
//! moving, so the watchdog can name one that stopped within a heartbeat (and the learner sees
//! its transitions sooner).
//!
//! An episode's report goes in the batch that holds its last transition: a batch that comes
//! due on an episode's last step waits for that episode's [`Adder::add_episode`], which the
//! loop calls next. The learner refuses a batch whose reports its transitions do not back
//! (`dvnav_link::consistency`).

use crate::credits::Credits;
use dvnav_link::core::{Adder, BatchWriter, EpisodeStats};
use dvnav_link::wire::EncodedBatch;
use dvnav_sim::obs::ACTION_DIM;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// Batches transitions for the gRPC stream.
pub struct BatchingAdder {
    writer: BatchWriter,
    /// The most transitions a batch holds (`actor.batch_transitions`).
    batch_size: usize,
    /// The size of the batch being filled: `batch_size`, or less as the learner advises.
    target: usize,
    tx: mpsc::Sender<EncodedBatch>,
    max_delay: Duration,
    /// When the batch being filled got its first transition or episode.
    opened: Option<Instant>,
    /// Batches that may await an acknowledgement; one is taken per batch, before the step
    /// that starts it ([`Adder::ready`]; see [`Credits`]).
    credits: Option<Arc<Credits>>,
    /// A credit is taken for the batch being filled (or about to be).
    holds_credit: bool,
    /// Transitions handed to the stream.
    pub handed_over: u64,
}

impl BatchingAdder {
    /// Sends batches of `batch_size` transitions into `tx`, or fewer once the oldest has waited
    /// `max_delay`.
    pub fn new(
        obs_dim: usize,
        batch_size: usize,
        max_delay: Duration,
        tx: mpsc::Sender<EncodedBatch>,
    ) -> Self {
        Self {
            writer: BatchWriter::new(obs_dim, batch_size),
            batch_size,
            target: batch_size,
            tx,
            max_delay,
            opened: None,
            credits: None,
            holds_credit: false,
            handed_over: 0,
        }
    }

    /// Starts each batch only with a credit from `credits`: the loop blocks before the step
    /// that starts a batch while `actor.max_batches_in_flight` batches await an
    /// acknowledgement. The batch then holds what the learner advised with its last
    /// acknowledgement, if that is fewer than `batch_size`.
    pub fn with_credits(mut self, credits: Arc<Credits>) -> Self {
        self.credits = Some(credits);
        self
    }

    /// Notes the batch's first content, and whether it is due: full, or open for `max_delay`.
    fn due(&mut self) -> bool {
        let opened = *self.opened.get_or_insert_with(Instant::now);
        self.writer.len() >= self.target || opened.elapsed() >= self.max_delay
    }

    fn send(&mut self) -> anyhow::Result<()> {
        if self.writer.is_empty() {
            return Ok(());
        }
        let full = EncodedBatch::new(&self.writer.take());
        self.opened = None;
        self.holds_credit = false;
        let n = full.len() as u64;
        self.tx
            .blocking_send(full)
            .map_err(|_| anyhow::anyhow!("the transition stream to the learner is closed"))?;
        self.handed_over += n;
        Ok(())
    }
}

impl Adder for BatchingAdder {
    fn add_first(&mut self, env: usize, obs: &[f32]) -> anyhow::Result<()> {
        self.writer.add_first(env, obs)
    }

    fn add(
        &mut self,
        env: usize,
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) -> anyhow::Result<()> {
        self.ready()?;
        self.writer.add(env, action, reward, next_obs, terminated, truncated, policy_version)?;
        // An episode's last step waits for its report (see the module docs).
        if self.due() && !(terminated || truncated) {
            self.send()?;
        }
        Ok(())
    }

    fn add_episode(&mut self, stats: EpisodeStats) -> anyhow::Result<()> {
        self.writer.add_episode(stats);
        if self.due() {
            self.send()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> anyhow::Result<()> {
        self.send()
    }

    /// Takes the next batch's credit, if it needs one and has none yet: blocks while
    /// `actor.max_batches_in_flight` batches await an acknowledgement.
    fn ready(&mut self) -> anyhow::Result<()> {
        if let Some(c) = &self.credits
            && !self.holds_credit
        {
            let advice = c.take()?;
            self.target = advice.map_or(self.batch_size, |a| a.clamp(1, self.batch_size));
            self.holds_credit = true;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn add(adder: &mut BatchingAdder, n: usize) {
        let obs = vec![0.5; 4];
        for _ in 0..n {
            adder.add(0, [0.1, 0.2], 1.0, &obs, false, false, 1).unwrap();
        }
    }

    #[test]
    fn full_batches_go_at_once_and_a_part_batch_goes_when_its_first_transition_is_old() {
        let (tx, mut rx) = mpsc::channel(16);
        let mut adder = BatchingAdder::new(4, 8, Duration::from_millis(200), tx);
        adder.add_first(0, &[0.5; 4]).unwrap();
        add(&mut adder, 8 + 3);
        assert_eq!(rx.try_recv().unwrap().len(), 8);
        assert!(rx.try_recv().is_err(), "3 fresh transitions wait for more");
        std::thread::sleep(Duration::from_millis(250));
        add(&mut adder, 1);
        assert_eq!(rx.try_recv().unwrap().len(), 4, "the old part batch goes with the next add");
        // The clock restarts with the next batch's first transition.
        add(&mut adder, 1);
        assert!(rx.try_recv().is_err());
        assert_eq!(adder.handed_over, 12);
    }

    #[test]
    fn the_next_batch_starts_only_once_the_last_is_acknowledged() {
        let (tx, mut rx) = mpsc::channel(16);
        let credits = Arc::new(Credits::new(1));
        let mut adder =
            BatchingAdder::new(4, 4, Duration::from_secs(60), tx).with_credits(credits.clone());
        adder.add_first(0, &[0.5; 4]).unwrap();
        add(&mut adder, 4);
        assert_eq!(rx.try_recv().unwrap().len(), 4, "the first batch went");
        // Its acknowledgement has not come: the loop blocks before the next transition.
        let next = std::thread::spawn(move || {
            add(&mut adder, 1);
            adder
        });
        std::thread::sleep(Duration::from_millis(100));
        assert!(!next.is_finished(), "no transition of a second batch before the ack");
        credits.give(1);
        let adder = next.join().unwrap();
        assert_eq!(adder.writer.len(), 1);
    }

    #[test]
    fn ready_waits_for_the_next_batch_s_credit_and_takes_it_once() {
        let (tx, mut rx) = mpsc::channel(16);
        let credits = Arc::new(Credits::new(1));
        let mut adder =
            BatchingAdder::new(4, 4, Duration::from_secs(60), tx).with_credits(credits.clone());
        adder.add_first(0, &[0.5; 4]).unwrap();
        adder.ready().unwrap();
        adder.ready().unwrap();
        add(&mut adder, 4);
        assert_eq!(rx.try_recv().unwrap().len(), 4);
        let next = std::thread::spawn(move || {
            adder.ready().unwrap();
            adder
        });
        std::thread::sleep(Duration::from_millis(100));
        assert!(!next.is_finished(), "the next step waits before it acts");
        credits.give(1);
        let mut adder = next.join().unwrap();
        add(&mut adder, 1);
        assert_eq!(adder.writer.len(), 1, "the credit taken by ready serves the batch");
    }

    #[test]
    fn batches_hold_what_the_learner_advises_up_to_their_own_size() {
        let (tx, mut rx) = mpsc::channel(16);
        let credits = Arc::new(Credits::new(8));
        let mut adder =
            BatchingAdder::new(4, 8, Duration::from_secs(60), tx).with_credits(credits.clone());
        adder.add_first(0, &[0.5; 4]).unwrap();
        add(&mut adder, 8);
        assert_eq!(rx.try_recv().unwrap().len(), 8, "no advice: the configured size");
        credits.advise(3);
        add(&mut adder, 6);
        assert_eq!((rx.try_recv().unwrap().len(), rx.try_recv().unwrap().len()), (3, 3));
        credits.advise(100);
        add(&mut adder, 8);
        assert_eq!(rx.try_recv().unwrap().len(), 8, "never more than its own size");
        credits.advise(0);
        add(&mut adder, 8);
        assert_eq!(rx.try_recv().unwrap().len(), 8, "advice withdrawn");
    }

    #[test]
    fn an_episode_report_goes_with_its_last_transition() {
        let (tx, mut rx) = mpsc::channel(16);
        let mut adder = BatchingAdder::new(4, 4, Duration::from_secs(60), tx);
        adder.add_first(0, &[0.5; 4]).unwrap();
        add(&mut adder, 3);
        // The fourth transition fills the batch and ends the episode.
        adder.add(0, [0.1, 0.2], 10.0, &[0.7; 4], true, false, 1).unwrap();
        assert!(rx.try_recv().is_err(), "the full batch waits for the episode's report");
        let stats = EpisodeStats {
            env_index: 0,
            stage: 0,
            room: "env0".into(),
            outcome: dvnav_sim::Outcome::Success,
            steps: 4,
            episode_return: 13.0,
            policy_version: 1,
            warmup: false,
            varied: false,
        };
        adder.add_episode(stats).unwrap();
        let mut bytes = Vec::new();
        rx.try_recv().unwrap().write(0, 0, &mut bytes);
        let msg = dvnav_link::wire::batch_from_proto(
            prost::Message::decode(bytes.as_slice()).unwrap(),
            4,
        )
        .unwrap();
        assert_eq!((msg.len(), msg.episodes.len(), msg.terminated[3]), (4, 1, true));
    }
}
