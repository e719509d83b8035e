//! [`PolicyThread`]: a policy on a thread of its own, answering many callers with one forward
//! pass for all the observations that arrived while it was busy.
//!
//! A server driving many robots gets observations from many connections at once. Behind a
//! mutex each would wait for the ones before it, one forward pass each, and a waiting caller
//! would block the async worker it runs on, stalling every other connection of that worker.
//! Here callers only queue their observation and wait on a one-shot reply (asynchronously, in
//! a service), and the thread takes everything queued at once: under load the batch grows and
//! the cost per command falls, which is what keeps the tail latency bounded as robots are
//! added (`dvnav bench serve`, figures in docs/results.md).

use crate::policy::NavPolicy;
use std::sync::mpsc;
use tokio::sync::oneshot;

/// The most observations one forward pass takes.
pub const MAX_BATCH: usize = 64;

/// A command, or why the policy failed (as text: the error is shared by a whole batch).
pub type Reply = Result<(f64, f64), String>;

const GONE: &str = "the policy thread is gone (the policy panicked)";

struct Job {
    obs: Vec<f32>,
    reply: ReplyTo,
}

/// Where a job's answer goes: an async waiter, or a thread blocked on it.
enum ReplyTo {
    Async(oneshot::Sender<Reply>),
    Blocking(mpsc::SyncSender<Reply>),
}

impl ReplyTo {
    /// A caller that gave up waiting is no fault of the others: its answer is dropped.
    fn send(self, r: Reply) {
        match self {
            ReplyTo::Async(s) => drop(s.send(r)),
            ReplyTo::Blocking(s) => drop(s.send(r)),
        }
    }
}

/// The policy's thread and the queue to it. Dropping it ends the thread once the queue is
/// drained.
#[derive(Debug)]
pub struct PolicyThread {
    queue: mpsc::Sender<Job>,
    obs_dim: usize,
}

impl PolicyThread {
    /// Moves `policy` onto a new thread named `name`.
    pub fn spawn<P: NavPolicy + Send + 'static>(
        mut policy: P,
        name: &str,
    ) -> std::io::Result<Self> {
        let obs_dim = policy.obs_dim();
        let (queue, jobs) = mpsc::channel::<Job>();
        std::thread::Builder::new().name(name.to_string()).spawn(move || {
            let mut obs = Vec::with_capacity(MAX_BATCH * obs_dim);
            while let Ok(first) = jobs.recv() {
                let mut batch = vec![first];
                while batch.len() < MAX_BATCH {
                    match jobs.try_recv() {
                        Ok(job) => batch.push(job),
                        Err(_) => break,
                    }
                }
                obs.clear();
                batch.iter().for_each(|j| obs.extend_from_slice(&j.obs));
                match policy.act_batch(&obs) {
                    Ok(commands) if commands.len() == batch.len() => {
                        for (job, c) in batch.into_iter().zip(commands) {
                            job.reply.send(Ok(c));
                        }
                    }
                    Ok(commands) => {
                        let why =
                            format!("{} commands for {} observations", commands.len(), batch.len());
                        batch.into_iter().for_each(|j| j.reply.send(Err(why.clone())));
                    }
                    Err(e) => {
                        let why = format!("{e:#}");
                        batch.into_iter().for_each(|j| j.reply.send(Err(why.clone())));
                    }
                }
            }
        })?;
        Ok(PolicyThread { queue, obs_dim })
    }

    /// The command for one observation of the policy's length, awaited.
    ///
    /// # Panics
    /// If `obs` is not one observation long.
    pub async fn act(&self, obs: Vec<f32>) -> Reply {
        let (reply, answer) = oneshot::channel();
        self.queue(obs, ReplyTo::Async(reply));
        answer.await.unwrap_or_else(|_| Err(GONE.into()))
    }

    /// The command for one observation, blocking this thread until it comes.
    ///
    /// # Panics
    /// If `obs` is not one observation long.
    pub fn act_blocking(&self, obs: Vec<f32>) -> Reply {
        let (reply, answer) = mpsc::sync_channel(1);
        self.queue(obs, ReplyTo::Blocking(reply));
        answer.recv().unwrap_or_else(|_| Err(GONE.into()))
    }

    fn queue(&self, obs: Vec<f32>, reply: ReplyTo) {
        assert_eq!(obs.len(), self.obs_dim, "one observation");
        // The thread ends only when this sender is dropped, or if the policy panicked: then
        // the job is dropped here and its waiter learns the thread is gone.
        let _ = self.queue.send(Job { obs, reply });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// Answers (first value, batch size) and counts forward passes; slow, so batches form.
    struct Slow {
        passes: Arc<AtomicUsize>,
    }

    impl NavPolicy for Slow {
        fn beams(&self) -> usize {
            1
        }
        fn act(&mut self, _: &[f32]) -> anyhow::Result<(f64, f64)> {
            unreachable!("the thread asks for batches")
        }
        fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
            self.passes.fetch_add(1, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(5));
            anyhow::ensure!(obs[0] >= 0.0, "a negative first value");
            let n = obs.len() / 5;
            Ok(obs.chunks(5).map(|o| (f64::from(o[0]), n as f64)).collect())
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (1.0, 1.0)
        }
    }

    #[test]
    fn observations_queued_together_share_a_forward_pass_and_get_their_own_answer() {
        let passes = Arc::new(AtomicUsize::new(0));
        let t = PolicyThread::spawn(Slow { passes: passes.clone() }, "test-policy").unwrap();
        let one = t.act_blocking(vec![7.0; 5]);
        assert_eq!(one, Ok((7.0, 1.0)));
        // 40 observations queued at once: each gets its own command, in far fewer passes.
        let t = Arc::new(t);
        let waits: Vec<_> = (0..40)
            .map(|k| {
                let t = t.clone();
                std::thread::spawn(move || t.act_blocking(vec![k as f32; 5]))
            })
            .collect();
        let got: Vec<(f64, f64)> = waits.into_iter().map(|w| w.join().unwrap().unwrap()).collect();
        assert!(got.iter().enumerate().all(|(k, c)| c.0 == k as f64), "{got:?}");
        let passes_now = passes.load(Ordering::SeqCst);
        assert!(passes_now <= 4, "{passes_now} passes for 41 observations");
        assert!(got.iter().any(|c| c.1 > 1.0), "batches formed");
        // A failing pass fails the observations in it, and the thread goes on.
        assert_eq!(t.act_blocking(vec![-1.0; 5]), Err("a negative first value".into()));
        // Awaited, from an async caller.
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        assert_eq!(rt.block_on(t.act(vec![2.0; 5])), Ok((2.0, 1.0)));
    }
}
