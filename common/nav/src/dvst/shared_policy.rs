//! [`SharedPolicy`]: one policy answering many callers, with one forward pass for all the
//! observations that arrive while it is busy.
//!
//! A server driving many robots gets observations from many connections at once. Behind a plain
//! mutex each would wait for the ones before it, one forward pass each, and a waiting caller
//! would block the async worker it runs on, stalling every other connection of that worker. A
//! thread of the policy's own instead costs every call two cross-thread wake-ups, which on an
//! idle virtual machine made the tail worse, not better (`dvnav bench serve`, docs/results.md).
//! So callers combine: each queues its observation; the caller that finds the policy free runs
//! everything queued, in one batch, on its own thread, and hands out the answers; the others
//! wait on a one-shot reply (asynchronously in a service). A lone caller pays no hand-over.
//!
//! **Deterministic by default:** a forward pass over several observations computes each row with
//! other kernels than a pass over one (measured: bit-identical for 1 and 2 rows, different in
//! the last bits from 3 on), so a robot's command would depend on who else is being served and
//! identical runs would diverge. By default the holder therefore runs each queued observation in
//! a pass of its own: the same observation and weights give the same command whatever else is
//! queued. [`SharedPolicy::batched`] trades that for throughput under load (one pass for up to
//! [`MAX_BATCH`] observations: about a third of the cost per command at 64 robots).

use crate::policy::NavPolicy;
use std::sync::{Mutex, MutexGuard, PoisonError, mpsc};
use tokio::sync::oneshot;

/// The most observations one forward pass takes.
pub const MAX_BATCH: usize = 64;

/// A command, or why the policy failed (as text: the error is shared by a whole batch).
pub type Reply = Result<(f64, f64), String>;

const GONE: &str = "the policy's answer was lost (the policy panicked)";

struct Job {
    obs: Vec<f32>,
    /// ε for a sampled action (the stall escape), `None` for the deterministic one.
    noise: Option<[f32; 2]>,
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

/// A policy shared by many callers.
pub struct SharedPolicy<P> {
    policy: Mutex<P>,
    queue: Mutex<Vec<Job>>,
    obs_dim: usize,
    /// One forward pass for everything queued, instead of one per observation.
    batched: std::sync::atomic::AtomicBool,
}

impl<P> std::fmt::Debug for SharedPolicy<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedPolicy").field("obs_dim", &self.obs_dim).finish_non_exhaustive()
    }
}

impl<P: NavPolicy> SharedPolicy<P> {
    /// Shares `policy`.
    pub fn new(policy: P) -> Self {
        let obs_dim = policy.obs_dim();
        SharedPolicy {
            policy: Mutex::new(policy),
            queue: Mutex::new(Vec::new()),
            obs_dim,
            batched: false.into(),
        }
    }

    /// Shares `policy`, answering everything queued in one forward pass: cheaper per command
    /// under load, but a command then depends in its last bits on the other observations of
    /// its pass.
    pub fn batched(policy: P) -> Self {
        SharedPolicy { batched: true.into(), ..SharedPolicy::new(policy) }
    }

    /// Switches between one pass per observation (`false`, the default) and one pass for
    /// everything queued (`true`, [`SharedPolicy::batched`]).
    pub fn set_batched(&self, on: bool) {
        self.batched.store(on, std::sync::atomic::Ordering::Relaxed);
    }

    /// The command for one observation of the policy's length, awaited: sampled with noise ε
    /// if given ([`NavPolicy::act_batch_noisy`]), else deterministic.
    ///
    /// # Panics
    /// If `obs` is not one observation long.
    pub async fn act(&self, obs: Vec<f32>, noise: Option<[f32; 2]>) -> Reply {
        let (reply, answer) = oneshot::channel();
        self.queue_and_combine(obs, noise, ReplyTo::Async(reply));
        answer.await.unwrap_or_else(|_| Err(GONE.into()))
    }

    /// The command for one observation, blocking this thread until it comes.
    ///
    /// # Panics
    /// If `obs` is not one observation long.
    pub fn act_blocking(&self, obs: Vec<f32>, noise: Option<[f32; 2]>) -> Reply {
        let (reply, answer) = mpsc::sync_channel(1);
        self.queue_and_combine(obs, noise, ReplyTo::Blocking(reply));
        answer.recv().unwrap_or_else(|_| Err(GONE.into()))
    }

    fn queue(&self) -> MutexGuard<'_, Vec<Job>> {
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Queues the job, then runs the queue for as long as this caller holds the policy.
    ///
    /// No job is stranded: a caller that fails to take the policy queued its job before
    /// trying, so the holder either drains it or, having released the policy, sees it in the
    /// queue and tries again.
    fn queue_and_combine(&self, obs: Vec<f32>, noise: Option<[f32; 2]>, reply: ReplyTo) {
        assert_eq!(obs.len(), self.obs_dim, "one observation");
        self.queue().push(Job { obs, noise, reply });
        loop {
            let mut policy = match self.policy.try_lock() {
                Ok(p) => p,
                Err(std::sync::TryLockError::Poisoned(p)) => p.into_inner(),
                Err(std::sync::TryLockError::WouldBlock) => return,
            };
            let mut obs = Vec::new();
            let mut noise = Vec::new();
            loop {
                let batch: Vec<Job> = {
                    let mut q = self.queue();
                    let n = q.len().min(MAX_BATCH);
                    q.drain(..n).collect()
                };
                if batch.is_empty() {
                    break;
                }
                if self.batched.load(std::sync::atomic::Ordering::Relaxed) {
                    obs.clear();
                    batch.iter().for_each(|j| obs.extend_from_slice(&j.obs));
                    noise.clear();
                    noise.extend(batch.iter().map(|j| j.noise));
                    answer(&mut *policy, &obs, &noise, batch);
                } else {
                    for Job { obs, noise, reply } in batch {
                        let job = Job { obs: Vec::new(), noise, reply };
                        answer(&mut *policy, &obs, &[noise], vec![job]);
                    }
                }
            }
            drop(policy);
            if self.queue().is_empty() {
                return;
            }
        }
    }
}

/// One forward pass for `batch`, each job answered (deterministic rows as `act_batch` gives
/// them: the noisy path leaves them bit-identical).
fn answer<P: NavPolicy>(policy: &mut P, obs: &[f32], noise: &[Option<[f32; 2]>], batch: Vec<Job>) {
    let commands = if noise.iter().all(Option::is_none) {
        policy.act_batch(obs)
    } else {
        policy.act_batch_noisy(obs, noise)
    };
    match commands {
        Ok(commands) if commands.len() == batch.len() => {
            for (job, c) in batch.into_iter().zip(commands) {
                job.reply.send(Ok(c));
            }
        }
        Ok(commands) => {
            let why = format!("{} commands for {} observations", commands.len(), batch.len());
            batch.into_iter().for_each(|j| j.reply.send(Err(why.clone())));
        }
        Err(e) => {
            let why = format!("{e:#}");
            batch.into_iter().for_each(|j| j.reply.send(Err(why.clone())));
        }
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
            unreachable!("the shared policy asks for batches")
        }
        fn act_batch(&mut self, obs: &[f32]) -> anyhow::Result<Vec<(f64, f64)>> {
            self.passes.fetch_add(1, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(2));
            anyhow::ensure!(obs[0] >= 0.0, "a negative first value");
            let n = obs.len() / 5;
            Ok(obs.chunks(5).map(|o| (f64::from(o[0]), n as f64)).collect())
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (1.0, 1.0)
        }
    }

    #[test]
    fn concurrent_callers_share_forward_passes_and_each_gets_its_own_answer() {
        let passes = Arc::new(AtomicUsize::new(0));
        let p = Arc::new(SharedPolicy::batched(Slow { passes: passes.clone() }));
        assert_eq!(p.act_blocking(vec![7.0; 5], None), Ok((7.0, 1.0)), "alone: its own pass");
        // 16 threads x 25 calls at once: every call answered with its own value (none
        // stranded, none swapped), in fewer passes than calls.
        let callers: Vec<_> = (0..16)
            .map(|t| {
                let p = p.clone();
                std::thread::spawn(move || {
                    (0..25)
                        .map(|k| {
                            let v = (t * 100 + k) as f32;
                            let got = p.act_blocking(vec![v; 5], None).unwrap();
                            assert_eq!(got.0, f64::from(v));
                            got.1
                        })
                        .collect::<Vec<f64>>()
                })
            })
            .collect();
        let sizes: Vec<f64> = callers.into_iter().flat_map(|c| c.join().unwrap()).collect();
        assert_eq!(sizes.len(), 400);
        let passes_now = passes.load(Ordering::SeqCst) - 1;
        assert!(passes_now < 300, "{passes_now} passes for 400 concurrent calls");
        assert!(sizes.iter().any(|&n| n > 1.0), "batches formed");
        // A failing pass fails the observations in it, and the policy goes on; awaited too.
        assert_eq!(p.act_blocking(vec![-1.0; 5], None), Err("a negative first value".into()));
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        assert_eq!(rt.block_on(p.act(vec![2.0; 5], None)), Ok((2.0, 1.0)));
    }

    #[test]
    fn by_default_each_observation_has_a_pass_of_its_own_batched_shares_them() {
        for (batched, most) in [(false, 1.0), (true, 16.0)] {
            let passes = Arc::new(AtomicUsize::new(0));
            let slow = Slow { passes: passes.clone() };
            let p = Arc::new(if batched {
                SharedPolicy::batched(slow)
            } else {
                SharedPolicy::new(slow)
            });
            let callers: Vec<_> = (0..16)
                .map(|t| {
                    let p = p.clone();
                    std::thread::spawn(move || {
                        (0..10)
                            .map(|_| p.act_blocking(vec![t as f32; 5], None).unwrap().1)
                            .fold(0.0, f64::max)
                    })
                })
                .collect();
            let largest = callers.into_iter().map(|c| c.join().unwrap()).fold(0.0, f64::max);
            assert!(largest <= most, "batched {batched}: a pass of {largest}");
            if batched {
                assert!(largest > 1.0, "batches formed");
            }
        }
    }

    /// The shipped meta agent: one robot's command is bit-identical alone and queued with 1
    /// and 10 other robots (a pass over several observations computes rows differently).
    #[test]
    fn a_robots_command_does_not_depend_on_who_else_is_served() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/meta-r0.2");
        let (agent, cfg) = crate::policy::MetaAgent::load(dir.as_ref()).unwrap();
        let d = cfg.env.obs_layout().dim();
        let obs = |k: usize| -> Vec<f32> {
            let mut o: Vec<f32> =
                (0..d).map(|i| 0.3 + 4.0 * (1.0 + ((i + 11 * k) as f32 * 0.04).sin())).collect();
            o[d - 4..].copy_from_slice(&[1.5 + k as f32 * 0.1, 0.3, 0.2, -0.1]);
            o
        };
        let p = SharedPolicy::new(agent);
        let mut policy = p.policy.lock().unwrap();
        let run = |policy: &mut crate::policy::MetaAgent, others: usize, batched: bool| {
            let (tx, rx) = mpsc::sync_channel(1);
            let mut jobs = vec![Job { obs: obs(0), noise: None, reply: ReplyTo::Blocking(tx) }];
            for k in 1..=others {
                let (tx, _) = mpsc::sync_channel(1);
                // The others sampled or not: the robot's deterministic row stays as it is.
                let noise = (k % 2 == 0).then_some([0.5, -0.5]);
                jobs.push(Job { obs: obs(k), noise, reply: ReplyTo::Blocking(tx) });
            }
            if batched {
                let all: Vec<f32> = jobs.iter().flat_map(|j| j.obs.clone()).collect();
                let noise: Vec<_> = jobs.iter().map(|j| j.noise).collect();
                answer(policy, &all, &noise, jobs);
            } else {
                for Job { obs, noise, reply } in jobs {
                    answer(policy, &obs, &[noise], vec![Job { obs: Vec::new(), noise, reply }]);
                }
            }
            rx.recv().unwrap().unwrap()
        };
        let alone = run(&mut policy, 0, false);
        assert_eq!(run(&mut policy, 1, false), alone);
        assert_eq!(run(&mut policy, 10, false), alone);
        // What the default avoids: in one pass with 10 others, the last bits move.
        assert_ne!(run(&mut policy, 10, true), alone);
    }
}
