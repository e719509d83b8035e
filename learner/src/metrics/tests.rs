use super::*;
use crate::state::LagStats;
use dvnav_config::Config;
use dvnav_link::core::{EpisodeStats, TransitionBatch};
use dvnav_link::wire;
use dvnav_sim::Outcome;
use std::collections::BTreeMap;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

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
    // The last transitions end the episodes, one each.
    for i in 0..n {
        let ends = (n - 1 - i < episodes.len()).then(|| episodes[n - 1 - i].1);
        let terminated = ends.is_some_and(|o| o.is_terminal());
        let truncated = ends == Some(Outcome::Timeout);
        b.push(&vec![1.0; d], [0.0, 0.0], 0.1, &vec![1.0; d], terminated, truncated, version);
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
            varied: false,
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
        s.ingest(id, wire::batch_to_proto(b, id, seq as u64)).await.unwrap();
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
    // Percentiles over the run: 0,0,3,3,3,3.
    let q =
        |p: &str| value(&text, &format!("dvnav_policy_lag_versions_quantile{{quantile=\"{p}\"}}"));
    assert_eq!((q("0.5"), q("0.95"), q("0.99")), (3.0, 3.0, 3.0));
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
        "dvnav_policy_entropy",
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
    rt.block_on(s.ingest(id, wire::batch_to_proto(&batch(&config(), 40, 1, &[]), id, 0))).unwrap();
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
    let stop = CancellationToken::new();
    let task = tokio::spawn(record(s.clone(), Some(path.clone()), stop.clone()));
    tokio::task::yield_now().await;
    stop.cancel();
    task.await.unwrap().unwrap();
    // Appending again (a resumed run) adds rows, not a second header.
    record(s, Some(path.clone()), stop).await.unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], header);
    assert!(lines.len() >= 3, "{text}");
    assert!(lines[1..].iter().all(|l| !l.starts_with("time_s")));
}

/// What the learner writes, the readers (`dvnav plot`, `dvnav train --seeds`) read back, by
/// column name, per-stage columns included; a torn last line is skipped.
#[tokio::test]
async fn the_csv_reader_reads_back_what_the_log_writes() {
    let s = state().await;
    let sample = Sampler::new().sample(&s);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("metrics.csv");
    let mut log = CsvLog::open(&path, sample.rooms.len()).unwrap();
    log.append(&sample, &s);
    log.append(&sample, &s);
    let mut f = std::fs::OpenOptions::new().append(true).open(&path).unwrap();
    std::io::Write::write_all(&mut f, b"12.5,9,0.5").unwrap();
    let rows = csv_log::read(&path).unwrap();
    assert_eq!(rows.len(), 2);
    let row = &rows[0];
    assert_eq!((row.env_steps, row.policy_lag_max, row.weight_version), (9, 3, 5));
    assert_eq!(row.success_rate_stage.len(), sample.rooms.len());
    assert_eq!(row.success_rate_stage[0], 0.5);
    assert!(row.success_rate_stage[3].is_nan());
    assert_eq!(row.time_s, (sample.elapsed_s * 1e3).round() / 1e3);
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(text.lines().nth(1).unwrap(), csv_row(&sample));
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
    let stop = CancellationToken::new();
    let server = tokio::spawn(serve(listener, stop.clone(), s.clone()));
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
    stop.cancel();
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
    let stop = CancellationToken::new();
    let server = tokio::spawn(serve(listener, stop.clone(), s.clone()));
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
    let stall = |component: &str, for_s: f64| crate::state::Stall {
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
    stop.cancel();
    server.await.unwrap().unwrap();
}
