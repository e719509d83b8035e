//! Live metrics of a learner: Prometheus text over HTTP (`/metrics`) and rows in
//! `metrics.csv`, both rendered from the same [`Sample`] of [`LearnerState`].
//!
//! - [`LiveMetrics`] lives inside the state. Ingestion records into it what counters alone do
//!   not keep: the policy lag of every transition (current weight version minus the version
//!   that acted; PID transitions, version 0, have no lag) and per-stage episode outcomes.
//! - [`Sampler`] takes a [`Sample`] every [`SAMPLE_EVERY`]: counters, rates over the last
//!   [`RATE_WINDOW`], the lag of the transitions since the previous sample. [`record`] runs it,
//!   appends a CSV row per sample and keeps the rendered text for the HTTP layer.
//! - [`serve`] is a minimal HTTP/1.1 responder (one request per connection, `Connection:
//!   close`): enough for Prometheus, curl, a browser and Kubernetes probes, with no HTTP stack
//!   to configure. Rendering is the plain function [`render_prometheus`], unit-tested on its
//!   own. Besides `/metrics` it answers the health probes: `GET /healthz` (200 while the
//!   process serves) and `GET /readyz` (200 while the learner takes actors, 503 while starting
//!   and once the run is finished; [`LearnerState::readiness`]).

use crate::state::{LearnerState, Readiness, StatusSnapshot};
use dvnav_link::core::TransitionBatch;
use dvnav_sim::Outcome;
use serde::Serialize;
use std::collections::{BTreeMap, VecDeque};
use std::fmt::Write as _;
use std::future::Future;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// How often the learner samples its metrics (and appends to `metrics.csv`).
pub const SAMPLE_EVERY: Duration = Duration::from_secs(2);
/// Rates (steps/s, updates/s) are taken over about this much wall time, to smooth out the
/// batch-sized steps in which transitions arrive.
pub const RATE_WINDOW: Duration = Duration::from_secs(10);
/// Episodes per stage in the per-stage success rate (the curriculum's default window).
pub const STAGE_WINDOW: usize = 50;
/// Largest HTTP request head accepted (bytes).
const MAX_REQUEST_BYTES: usize = 8 * 1024;
/// A client that sends no complete request head within this time is dropped.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// Policy lag (weight versions) of a set of transitions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LagStats {
    /// Sum of lags.
    pub sum: u64,
    /// Transitions counted (those that a policy chose, not the PID controller).
    pub count: u64,
    /// Largest lag.
    pub max: u64,
}

impl LagStats {
    fn add(&mut self, lag: u64) {
        self.sum += lag;
        self.count += 1;
        self.max = self.max.max(lag);
    }

    /// Mean lag; NaN when no policy-chosen transition was counted.
    pub fn mean(&self) -> f64 {
        if self.count == 0 { f64::NAN } else { self.sum as f64 / self.count as f64 }
    }
}

/// Episode outcomes of one curriculum stage.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StageStats {
    /// Stage index.
    pub stage: u32,
    /// Episodes reported in this stage, all of the run.
    pub episodes: u64,
    /// Of which successes.
    pub successes: u64,
    /// Success rate over the stage's last [`STAGE_WINDOW`] episodes (NaN before any).
    pub recent_success_rate: f64,
}

#[derive(Debug, Default)]
struct StageAcc {
    episodes: u64,
    successes: u64,
    recent: VecDeque<bool>,
}

#[derive(Debug, Default)]
struct LiveInner {
    lag: LagStats,
    window_lag: LagStats,
    stages: BTreeMap<u32, StageAcc>,
    env_steps_per_s: f64,
    updates_per_s: f64,
    recent_lag: LagStats,
    text: Arc<String>,
}

/// What [`LiveMetrics`] adds to a status snapshot.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct LiveSnapshot {
    /// Environment steps per second over the last [`RATE_WINDOW`].
    pub env_steps_per_s: f64,
    /// Learner updates per second over the last [`RATE_WINDOW`].
    pub updates_per_s: f64,
    /// Policy lag of the whole run.
    pub policy_lag: LagStats,
    /// Policy lag of the transitions of the latest sample interval.
    pub recent_policy_lag: LagStats,
    /// Per stage, in stage order.
    pub stages: Vec<StageStats>,
}

/// Metrics that ingestion records and the sampler reads; one per [`LearnerState`].
#[derive(Debug, Default)]
pub struct LiveMetrics {
    inner: Mutex<LiveInner>,
}

impl LiveMetrics {
    fn lock(&self) -> std::sync::MutexGuard<'_, LiveInner> {
        self.inner.lock().expect("live metrics lock")
    }

    /// Records an accepted batch: the lag of every policy-chosen transition against
    /// `current_version`, and the outcome of every finished episode.
    pub fn record_batch(&self, batch: &TransitionBatch, current_version: u64) {
        let mut m = self.lock();
        for &v in &batch.policy_versions {
            if v > 0 {
                let lag = current_version.saturating_sub(v);
                m.lag.add(lag);
                m.window_lag.add(lag);
            }
        }
        for e in &batch.episodes {
            let s = m.stages.entry(e.stage).or_default();
            let success = e.outcome == Outcome::Success;
            s.episodes += 1;
            s.successes += u64::from(success);
            if s.recent.len() == STAGE_WINDOW {
                s.recent.pop_front();
            }
            s.recent.push_back(success);
        }
    }

    /// The snapshot that goes into [`StatusSnapshot`].
    pub fn snapshot(&self) -> LiveSnapshot {
        let m = self.lock();
        LiveSnapshot {
            env_steps_per_s: m.env_steps_per_s,
            updates_per_s: m.updates_per_s,
            policy_lag: m.lag,
            recent_policy_lag: m.recent_lag,
            stages: m
                .stages
                .iter()
                .map(|(&stage, s)| StageStats {
                    stage,
                    episodes: s.episodes,
                    successes: s.successes,
                    recent_success_rate: if s.recent.is_empty() {
                        f64::NAN
                    } else {
                        s.recent.iter().filter(|&&x| x).count() as f64 / s.recent.len() as f64
                    },
                })
                .collect(),
        }
    }

    /// The Prometheus text of the latest sample (empty before the first).
    pub fn text(&self) -> Arc<String> {
        self.lock().text.clone()
    }

    /// Ends a sample interval: stores the rates and the rendered text, and returns the lag of
    /// the interval's transitions.
    fn close_interval(&self, env_steps_per_s: f64, updates_per_s: f64) -> LagStats {
        let mut m = self.lock();
        m.env_steps_per_s = env_steps_per_s;
        m.updates_per_s = updates_per_s;
        m.recent_lag = std::mem::take(&mut m.window_lag);
        m.recent_lag
    }

    fn set_text(&self, text: String) {
        self.lock().text = Arc::new(text);
    }
}

/// One sample of the metrics.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Seconds since the sampler started.
    pub elapsed_s: f64,
    /// Counters, including [`LiveSnapshot`] with the rates of this sample.
    pub status: StatusSnapshot,
    /// Room name of each curriculum stage, for labels.
    pub rooms: Vec<String>,
    /// The learner process's memory.
    pub memory: crate::process_memory::ProcessMemory,
}

/// Takes [`Sample`]s; keeps the short history that rates are computed over.
#[derive(Debug)]
pub struct Sampler {
    started: Instant,
    /// (seconds since start, env steps, updates), oldest first.
    history: VecDeque<(f64, u64, u64)>,
}

impl Default for Sampler {
    fn default() -> Self {
        Self::new()
    }
}

impl Sampler {
    /// A sampler whose clock starts now.
    pub fn new() -> Self {
        Self { started: Instant::now(), history: VecDeque::new() }
    }

    /// Samples `state`: rates over the last [`RATE_WINDOW`] (0 at the first sample), the lag
    /// of the transitions since the previous sample; stores both and the rendered text in the
    /// state's [`LiveMetrics`].
    pub fn sample(&mut self, state: &LearnerState) -> Sample {
        let t = self.started.elapsed().as_secs_f64();
        let before = state.status();
        let now = (t, before.transitions_received, before.updates);
        while self.history.len() > 1
            && self.history.get(1).is_some_and(|h| t - h.0 >= RATE_WINDOW.as_secs_f64())
        {
            self.history.pop_front();
        }
        let (steps_per_s, updates_per_s) = match self.history.front() {
            Some(&(t0, s0, u0)) if t > t0 => (
                now.1.saturating_sub(s0) as f64 / (t - t0),
                now.2.saturating_sub(u0) as f64 / (t - t0),
            ),
            _ => (0.0, 0.0),
        };
        self.history.push_back(now);
        state.live().close_interval(steps_per_s, updates_per_s);
        let sample = Sample {
            elapsed_s: t,
            status: state.status(),
            rooms: state.config().curriculum.rooms.clone(),
            memory: crate::process_memory::ProcessMemory::read(),
        };
        state.live().set_text(render_prometheus(&sample));
        sample
    }
}

/// Escapes a Prometheus label value.
fn label(v: &str) -> String {
    v.replace('\\', "\\\\").replace('"', "\\\"").replace('\n', "\\n")
}

/// A float in Prometheus text format (`NaN`, `+Inf`, `-Inf` spelled its way).
fn num(v: f64) -> String {
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
    let rows = |m: &std::collections::BTreeMap<String, u64>, key: &str| -> Vec<(String, f64)> {
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
        .collect::<std::collections::BTreeSet<_>>()
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
    let stage_rows = |f: &dyn Fn(&crate::metrics::StageStats) -> f64| -> Vec<(String, f64)> {
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
    let actor_rows = |f: &dyn Fn(&crate::state::ActorCounters) -> f64| -> Vec<(String, f64)> {
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

/// Column names of `metrics.csv`; one `success_rate_stage<i>` per curriculum room.
pub fn csv_header(stages: usize) -> String {
    let mut h = String::from(
        "time_s,env_steps,env_steps_per_s,updates,updates_per_s,episodes,replay_size,\
         connected_actors,weight_version,policy_lag_mean,policy_lag_max,stage,\
         curriculum_success_rate,critic_loss,actor_loss,alpha,transitions_received,\
         transitions_rejected",
    );
    for i in 0..stages {
        let _ = write!(h, ",success_rate_stage{i}");
    }
    h
}

/// One `metrics.csv` row (same columns as [`csv_header`]); NaN where there is no value yet.
pub fn csv_row(sample: &Sample) -> String {
    let s = &sample.status;
    let l = &s.live;
    let mut row = format!(
        "{:.3},{},{:.2},{},{:.3},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        sample.elapsed_s,
        s.transitions_received,
        l.env_steps_per_s,
        s.updates,
        l.updates_per_s,
        s.episodes,
        s.replay_size,
        s.actors.iter().filter(|a| a.connected).count(),
        s.weight_version,
        num(l.recent_policy_lag.mean()),
        l.recent_policy_lag.max,
        s.stage,
        num(s.success_rate),
        num(s.critic_loss),
        num(s.actor_loss),
        num(s.alpha),
        s.transitions_received,
        s.transitions_rejected,
    );
    for i in 0..sample.rooms.len() as u32 {
        let rate =
            l.stages.iter().find(|st| st.stage == i).map_or(f64::NAN, |st| st.recent_success_rate);
        let _ = write!(row, ",{}", num(rate));
    }
    row
}

/// Appends rows to `metrics.csv`; writes the header when the file is new or empty.
struct CsvLog {
    path: PathBuf,
    file: std::fs::File,
}

impl CsvLog {
    fn open(path: &Path, stages: usize) -> anyhow::Result<Self> {
        let fail = |e: std::io::Error| anyhow::anyhow!("cannot write {}: {e}", path.display());
        let mut file =
            std::fs::OpenOptions::new().create(true).append(true).open(path).map_err(fail)?;
        if file.metadata().map_err(fail)?.len() == 0 {
            writeln!(file, "{}", csv_header(stages)).map_err(fail)?;
        }
        Ok(Self { path: path.to_path_buf(), file })
    }

    fn append(&mut self, sample: &Sample, state: &LearnerState) {
        // A failed row (disk full) is logged and counted; the next sample tries again.
        if let Err(e) = writeln!(self.file, "{}", csv_row(sample)) {
            state.record_write_failure("metrics_csv", &self.path, &e);
        }
    }
}

/// Samples `state` every [`SAMPLE_EVERY`] until `stop` resolves, appending each sample to the
/// CSV at `csv` (if given), then takes a last sample.
pub async fn record(
    state: Arc<LearnerState>,
    csv: Option<PathBuf>,
    stop: impl Future<Output = ()>,
) -> anyhow::Result<()> {
    let mut csv =
        csv.map(|p| CsvLog::open(&p, state.config().curriculum.rooms.len())).transpose()?;
    let mut sampler = Sampler::new();
    let mut ticks = tokio::time::interval(SAMPLE_EVERY);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut released = tokio::time::Instant::now();
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = ticks.tick() => {
                let sample = sampler.sample(&state);
                if let Some(c) = csv.as_mut() {
                    c.append(&sample, &state);
                }
                if released.elapsed() >= crate::process_memory::RELEASE_EVERY {
                    released = tokio::time::Instant::now();
                    // Off the runtime's threads: it walks every arena.
                    tokio::task::spawn_blocking(crate::process_memory::release_free_memory);
                }
            }
            _ = &mut stop => break,
        }
    }
    let sample = sampler.sample(&state);
    if let Some(c) = csv.as_mut() {
        c.append(&sample, &state);
    }
    Ok(())
}

/// Paths the HTTP server answers (Kubernetes probes point at the last two;
/// `make check-deploy` checks the manifests against this list).
pub const HTTP_PATHS: [&str; 4] = ["/", "/metrics", "/healthz", "/readyz"];

/// Serves `GET /metrics` (the latest rendered sample), `/healthz` and `/readyz` on `listener`
/// until `shutdown` resolves.
pub async fn serve(
    listener: TcpListener,
    shutdown: impl Future<Output = ()>,
    state: Arc<LearnerState>,
) -> std::io::Result<()> {
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((sock, _)) => {
                    let state = state.clone();
                    tokio::spawn(async move {
                        let reply = tokio::time::timeout(
                            REQUEST_TIMEOUT,
                            respond(sock, &state),
                        )
                        .await;
                        if let Ok(Err(e)) = reply {
                            tracing::debug!(error = %e, "metrics request failed");
                        }
                    });
                }
                Err(e) => {
                    tracing::warn!(error = %e, "metrics listener: accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
            _ = &mut shutdown => return Ok(()),
        }
    }
}

/// Reads one request head and answers it.
async fn respond(mut sock: TcpStream, state: &LearnerState) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = sock.read(&mut chunk).await?;
        if n == 0 {
            break;
        }
        buf.extend_from_slice(&chunk[..n]);
        if buf.len() > MAX_REQUEST_BYTES {
            return write_response(&mut sock, "431 Request Header Fields Too Large", "", "").await;
        }
    }
    let head = String::from_utf8_lossy(&buf);
    let mut parts = head.lines().next().unwrap_or("").split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let path = target.split('?').next().unwrap_or("");
    const PROM: &str = "text/plain; version=0.0.4; charset=utf-8";
    const TEXT: &str = "text/plain; charset=utf-8";
    let head_only = method == "HEAD";
    let probe = |body: &str| if head_only { String::new() } else { body.to_string() };
    match (method, path) {
        ("GET", "/metrics") => {
            write_response(&mut sock, "200 OK", PROM, &state.live().text()).await
        }
        ("HEAD", "/metrics") => write_response(&mut sock, "200 OK", PROM, "").await,
        ("GET", "/") => {
            let body =
                "dvnav learner: Prometheus metrics at /metrics; probes at /healthz and /readyz\n";
            write_response(&mut sock, "200 OK", TEXT, body).await
        }
        // Liveness: this answer comes from the learner's runtime, so a process that answers
        // is alive and not wedged in its I/O; a trainer stalled past
        // `learner.liveness_stall_s` makes it 503 so a supervisor restarts (and resumes) it.
        ("GET" | "HEAD", "/healthz") => {
            let (status, body) = match state.liveness() {
                Ok(()) => ("200 OK", "ok\n".to_string()),
                Err(why) => ("503 Service Unavailable", format!("wedged: {why}\n")),
            };
            write_response(&mut sock, status, TEXT, &probe(&body)).await
        }
        // Readiness: whether it takes actors. A stall does not make it unready (actors could
        // not reconnect, which would not help), but the body names what is stalled.
        ("GET" | "HEAD", "/readyz") => {
            let (status, mut body) = match state.readiness() {
                Readiness::Ready => ("200 OK", "ready\n".to_string()),
                Readiness::Starting => ("503 Service Unavailable", "starting\n".to_string()),
                Readiness::Finished => (
                    "503 Service Unavailable",
                    "finished: the run takes no more actors\n".to_string(),
                ),
            };
            for s in state.stalled() {
                body += &format!(
                    "stalled: {} for {:.1} s: {}; last error: {}\n",
                    s.component,
                    s.for_s,
                    s.what,
                    s.last_error.as_deref().unwrap_or("none")
                );
            }
            write_response(&mut sock, status, TEXT, &probe(&body)).await
        }
        (_, "/metrics" | "/healthz" | "/readyz") => {
            write_response(&mut sock, "405 Method Not Allowed", "", "").await
        }
        _ => write_response(&mut sock, "404 Not Found", "text/plain", "not found\n").await,
    }
}

async fn write_response(
    sock: &mut TcpStream,
    status: &str,
    content_type: &str,
    body: &str,
) -> std::io::Result<()> {
    let mut head =
        format!("HTTP/1.1 {status}\r\nContent-Length: {}\r\nConnection: close\r\n", body.len());
    if !content_type.is_empty() {
        let _ = write!(head, "Content-Type: {content_type}\r\n");
    }
    head.push_str("\r\n");
    sock.write_all(head.as_bytes()).await?;
    sock.write_all(body.as_bytes()).await?;
    sock.shutdown().await
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_config::Config;
    use dvnav_link::core::EpisodeStats;
    use dvnav_link::wire;

    fn config() -> Config {
        let mut cfg = Config::default();
        cfg.run.steps = 1_000;
        cfg.learner.max_steps_ahead = 1_000_000;
        cfg.replay.capacity = 64;
        cfg
    }

    /// `n` transitions acted by `version`, with one finished episode per entry of `episodes`.
    fn batch(cfg: &Config, n: usize, version: u64, episodes: &[(u32, Outcome)]) -> TransitionBatch {
        let d = cfg.obs_dim();
        let mut b = TransitionBatch::with_capacity(d, n);
        for _ in 0..n {
            b.push(&vec![1.0; d], [0.0, 0.0], 0.1, &vec![1.0; d], false, false, version);
        }
        for &(stage, outcome) in episodes {
            b.episodes.push(EpisodeStats {
                env_index: 0,
                stage,
                room: "env0".into(),
                outcome,
                steps: 3,
                episode_return: 1.0,
                policy_version: version,
                warmup: false,
            });
        }
        b
    }

    /// A state with actor `a-"1"` (a name that needs escaping) and some ingested batches.
    async fn state() -> Arc<LearnerState> {
        let cfg = config();
        let s = Arc::new(LearnerState::new(cfg.clone(), "r".into(), None, vec![]));
        let id = s.register("a-\"1\"", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        for _ in 0..4 {
            s.variables().publish_weights(vec![]);
        }
        // Weight version is 5 now: lags 5-2 = 3 and 5-5 = 0; PID transitions (version 0)
        // have none.
        let batches = [
            batch(&cfg, 4, 2, &[(0, Outcome::Success), (0, Outcome::Collision)]),
            batch(&cfg, 2, 5, &[(1, Outcome::Success)]),
            batch(&cfg, 3, 0, &[]),
        ];
        for (seq, b) in batches.iter().enumerate() {
            s.ingest(wire::batch_to_proto(b, id, seq as u64)).await.unwrap();
        }
        s.set_connected(id, true);
        s
    }

    /// The value of the sample line `name` (with labels) in Prometheus text.
    fn value(text: &str, series: &str) -> f64 {
        let line = text
            .lines()
            .find(|l| l.strip_prefix(series).is_some_and(|rest| rest.starts_with(' ')))
            .unwrap_or_else(|| panic!("no {series} in\n{text}"));
        line.rsplit(' ').next().unwrap().parse().unwrap()
    }

    #[tokio::test]
    async fn lag_and_stage_outcomes_are_recorded_at_ingestion() {
        let s = state().await;
        let live = s.status().live;
        assert_eq!(live.policy_lag, LagStats { sum: 4 * 3, count: 6, max: 3 });
        assert_eq!(live.stages.len(), 2);
        assert_eq!((live.stages[0].episodes, live.stages[0].successes), (2, 1));
        assert_eq!(live.stages[0].recent_success_rate, 0.5);
        assert_eq!(live.stages[1].recent_success_rate, 1.0);
    }

    #[tokio::test]
    async fn prometheus_text_has_every_headline_metric() {
        let s = state().await;
        let mut sampler = Sampler::new();
        let sample = sampler.sample(&s);
        let text = render_prometheus(&sample);
        assert_eq!(*s.live().text(), text, "the sampler stores what it rendered");
        assert_eq!(value(&text, "dvnav_env_steps_total"), 9.0);
        assert_eq!(value(&text, "dvnav_transitions_rejected_total"), 0.0);
        assert_eq!(value(&text, "dvnav_replay_size"), 9.0);
        assert_eq!(value(&text, "dvnav_connected_actors"), 1.0);
        assert_eq!(value(&text, "dvnav_weight_version"), 5.0);
        // The first interval holds every transition so far: mean of 3,3,3,3,0,0.
        assert_eq!(value(&text, "dvnav_policy_lag_versions_mean"), 2.0);
        assert_eq!(value(&text, "dvnav_policy_lag_versions_max"), 3.0);
        assert_eq!(value(&text, "dvnav_policy_lag_versions_count"), 6.0);
        assert_eq!(value(&text, "dvnav_stage_success_rate{stage=\"0\",room=\"env0\"}"), 0.5);
        assert_eq!(value(&text, "dvnav_stage_success_rate{stage=\"1\",room=\"env1\"}"), 1.0);
        assert_eq!(value(&text, "dvnav_actor_connected{actor=\"a-\\\"1\\\"\"}"), 1.0);
        for name in [
            "dvnav_env_steps_per_second",
            "dvnav_updates_per_second",
            "dvnav_updates_total",
            "dvnav_critic_loss",
            "dvnav_actor_loss",
            "dvnav_alpha",
            "dvnav_episodes_total",
        ] {
            assert!(value(&text, name).is_finite(), "{name}");
        }
        // (dvnav_heap_in_use_bytes needs the dvnav binary's counting allocator: the soak test.)
        #[cfg(target_os = "linux")]
        assert!(value(&text, "dvnav_process_resident_bytes") > 1e6, "{text}");
        // Every sample line belongs to a declared metric.
        let declared: Vec<&str> =
            text.lines().filter_map(|l| l.strip_prefix("# TYPE ")?.split(' ').next()).collect();
        for l in text.lines().filter(|l| !l.starts_with('#')) {
            let name = l.split(['{', ' ']).next().unwrap();
            assert!(declared.contains(&name), "{l}");
        }

        // The next interval has no transitions: the recent lag is NaN, the run's lag stays.
        let text = render_prometheus(&sampler.sample(&s));
        assert!(value(&text, "dvnav_policy_lag_versions_mean").is_nan());
        assert_eq!(value(&text, "dvnav_policy_lag_versions_sum"), 12.0);
    }

    #[test]
    fn rates_come_from_the_sample_history() {
        let s = LearnerState::new(config(), "r".into(), None, vec![]);
        let mut sampler = Sampler::new();
        // Pretend the first sample was taken 4 s ago with 100 fewer steps and 10 fewer updates.
        sampler.history.push_back((-4.0, 0, 0));
        let before = sampler.sample(&s);
        assert_eq!(before.status.live.env_steps_per_s, 0.0);
        let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        rt.block_on(s.ingest(wire::batch_to_proto(&batch(&config(), 40, 1, &[]), id, 0))).unwrap();
        let after = sampler.sample(&s);
        let rate = after.status.live.env_steps_per_s;
        // 40 steps over a little more than 4 s.
        assert!(rate > 9.0 && rate <= 10.0, "{rate}");
    }

    #[tokio::test]
    async fn csv_rows_match_the_header() {
        let s = state().await;
        let sample = Sampler::new().sample(&s);
        let header = csv_header(sample.rooms.len());
        let row = csv_row(&sample);
        assert_eq!(header.split(',').count(), row.split(',').count());
        let cols: BTreeMap<&str, &str> = header.split(',').zip(row.split(',')).collect();
        assert_eq!(cols["env_steps"], "9");
        assert_eq!(cols["policy_lag_max"], "3");
        assert_eq!(cols["success_rate_stage0"], "0.5");
        assert_eq!(cols["success_rate_stage3"], "NaN");

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.csv");
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(record(s.clone(), Some(path.clone()), async move {
            let _ = rx.await;
        }));
        tokio::task::yield_now().await;
        tx.send(()).unwrap();
        task.await.unwrap().unwrap();
        // Appending again (a resumed run) adds rows, not a second header.
        record(s, Some(path.clone()), async {}).await.unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], header);
        assert!(lines.len() >= 3, "{text}");
        assert!(lines[1..].iter().all(|l| !l.starts_with("time_s")));
    }

    async fn http(addr: std::net::SocketAddr, request: &str) -> String {
        let mut sock = TcpStream::connect(addr).await.unwrap();
        sock.write_all(request.as_bytes()).await.unwrap();
        let mut out = String::new();
        sock.read_to_string(&mut out).await.unwrap();
        out
    }

    #[tokio::test]
    async fn http_serves_metrics_and_refuses_the_rest() {
        let s = state().await;
        Sampler::new().sample(&s);
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(serve(
            listener,
            async move {
                let _ = rx.await;
            },
            s.clone(),
        ));
        let ok = http(addr, "GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n").await;
        let (head, body) = ok.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 200 OK"), "{head}");
        assert!(head.contains("Content-Type: text/plain; version=0.0.4"));
        assert!(head.contains(&format!("Content-Length: {}", body.len())));
        assert_eq!(body, s.live().text().as_str());
        assert!(http(addr, "GET /nope HTTP/1.1\r\n\r\n").await.starts_with("HTTP/1.1 404"));
        assert!(http(addr, "POST /metrics HTTP/1.1\r\n\r\n").await.starts_with("HTTP/1.1 405"));
        let huge = format!("GET /metrics HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(10_000));
        assert!(!http(addr, &huge).await.starts_with("HTTP/1.1 200"));
        tx.send(()).unwrap();
        server.await.unwrap().unwrap();
        assert!(TcpStream::connect(addr).await.is_err(), "the listener is closed");
    }

    fn status_line(reply: &str) -> &str {
        reply.lines().next().unwrap_or("")
    }

    #[tokio::test]
    async fn health_and_readiness_follow_the_run() {
        let s = Arc::new(LearnerState::new(config(), "r".into(), None, vec![]));
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(serve(
            listener,
            async move {
                let _ = rx.await;
            },
            s.clone(),
        ));
        let get = |path: &str| format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
        let healthz = http(addr, &get("/healthz")).await;
        assert_eq!(status_line(&healthz), "HTTP/1.1 200 OK", "{healthz}");
        assert!(healthz.ends_with("\r\n\r\nok\n"), "{healthz}");
        // No gRPC service yet: starting.
        let starting = http(addr, &get("/readyz")).await;
        assert_eq!(status_line(&starting), "HTTP/1.1 503 Service Unavailable", "{starting}");
        assert!(starting.ends_with("starting\n"), "{starting}");

        let _service = crate::service::LearnerService::new(s.clone());
        let ready = http(addr, &get("/readyz")).await;
        assert_eq!(status_line(&ready), "HTTP/1.1 200 OK", "{ready}");
        let head = http(addr, "HEAD /readyz HTTP/1.1\r\n\r\n").await;
        assert!(head.starts_with("HTTP/1.1 200 OK") && head.ends_with("\r\n\r\n"), "{head}");
        assert!(http(addr, "POST /readyz HTTP/1.1\r\n\r\n").await.starts_with("HTTP/1.1 405"));

        // Stalls: named in /readyz (still ready); a trainer stalled past
        // learner.liveness_stall_s (300 s by default) fails liveness, an actor never does.
        let stall = |component: &str, for_s: f64| crate::watchdog::Stall {
            component: component.into(),
            for_s,
            what: "no update while the rate limiter owes 3 update(s)".into(),
            last_error: Some("boom".into()),
        };
        s.set_stalled(vec![stall("trainer", 4.0), stall("actor:a", 900.0)]);
        let ready = http(addr, &get("/readyz")).await;
        assert_eq!(status_line(&ready), "HTTP/1.1 200 OK", "{ready}");
        assert!(ready.contains("stalled: trainer for 4.0 s: no update") && ready.contains("boom"));
        assert!(ready.contains("stalled: actor:a for 900.0 s"), "{ready}");
        assert!(http(addr, &get("/healthz")).await.starts_with("HTTP/1.1 200 OK"));
        s.set_stalled(vec![stall("trainer", 300.0)]);
        let wedged = http(addr, &get("/healthz")).await;
        assert_eq!(status_line(&wedged), "HTTP/1.1 503 Service Unavailable", "{wedged}");
        assert!(wedged.contains("wedged: trainer stalled for 300 s") && wedged.contains("boom"));
        s.set_stalled(vec![]);
        assert!(http(addr, &get("/healthz")).await.starts_with("HTTP/1.1 200 OK"));

        // The step budget is reached (or Ctrl-C): no more actors, though still alive.
        s.finish();
        let finished = http(addr, &get("/readyz")).await;
        assert_eq!(status_line(&finished), "HTTP/1.1 503 Service Unavailable", "{finished}");
        assert!(finished.contains("finished"), "{finished}");
        assert!(http(addr, &get("/healthz")).await.starts_with("HTTP/1.1 200 OK"));
        for path in HTTP_PATHS {
            let reply = http(addr, &get(path)).await;
            assert!(!reply.starts_with("HTTP/1.1 404"), "{path} is routed: {reply}");
        }
        tx.send(()).unwrap();
        server.await.unwrap().unwrap();
    }
}
