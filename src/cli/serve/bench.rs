//! `dvnav bench serve`: the controller's latency, at batch 1 with the meta agent's own scan
//! layout and with a 1,081-beam LaserScan (resampling included), through gRPC over loopback
//! and in-process; and a fleet of robots, each on its own connection at its own control rate,
//! on one server.

use super::latency::Latency;
use super::{load_controller, robot_input, serve, single_candle_thread};
use dvnav_nav::dvst::DvstController;
use dvnav_proto::controller::v1 as pb;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What `dvnav bench serve` measures beyond the single robot's calls.
#[derive(Clone, Copy, Debug)]
pub struct FleetLoad {
    /// Robots, each with its own connection and robot id.
    pub robots: usize,
    /// Each robot's control rate (Hz).
    pub rate_hz: f64,
    /// How long the fleet drives.
    pub seconds: f64,
    /// Every Act of the bench (all parts) says its scan is this old (s), so the server carries
    /// it forward by the commands it sent that robot (`ActRequest.scan_age_s`).
    pub scan_age_s: f64,
    /// The server's collision monitor horizon (s; 0: off).
    pub safety_horizon_s: f64,
}

/// What `dvnav bench serve --json` prints: latency of one command (ms), through the gRPC
/// service over loopback and in-process (checks, resampling, DVST and the policy, no network).
#[derive(serde::Serialize)]
pub struct ServeBench {
    calls: usize,
    /// `ActRequest.scan_age_s` of every call.
    scan_age_s: f64,
    /// The server's collision monitor horizon (s; 0: off).
    safety_horizon_s: f64,
    grpc_p50_ms: f64,
    grpc_p99_ms: f64,
    grpc_mean_ms: f64,
    grpc_max_ms: f64,
    in_process_p50_ms: f64,
    in_process_p99_ms: f64,
    in_process_mean_ms: f64,
    in_process_max_ms: f64,
    target_p99_ms: f64,
    meets_target: bool,
    /// The same with a Hokuyo UTM-30LX's LaserScan (1,081 readings over 270°).
    laser_beams: usize,
    laser_grpc_p50_ms: f64,
    laser_grpc_p99_ms: f64,
    laser_grpc_max_ms: f64,
    laser_in_process_p50_ms: f64,
    laser_in_process_p99_ms: f64,
    laser_meets_target: bool,
    /// The fleet: `fleet_robots` robots at `fleet_rate_hz` each for `fleet_seconds`, half of
    /// them with a footprint of their own, all sending LaserScans.
    fleet_robots: usize,
    fleet_rate_hz: f64,
    fleet_seconds: f64,
    fleet_calls: usize,
    fleet_calls_per_s: f64,
    fleet_p50_ms: f64,
    fleet_p99_ms: f64,
    fleet_max_ms: f64,
    fleet_target_p99_ms: f64,
    fleet_meets_target: bool,
    beams: usize,
    mu: f64,
    model: String,
    footprint: String,
    /// Robots the server plans for and replans for (`--route-map`); absent with `--route-map ''`.
    #[serde(flatten)]
    route: Option<super::route_bench::RouteFigures>,
}

/// A scan that changes from call to call, like a robot moving through a room.
fn ranges(n: usize, k: usize) -> Vec<f32> {
    (0..n)
        .map(|i| 0.3 + 4.0 * (1.0 + ((i + 7 * k) as f32 * 0.05 * 540.0 / n as f32).sin()))
        .collect()
}

/// A Hokuyo UTM-30LX: 1,081 readings 0.25° apart over 270°, some with no return.
fn hokuyo(k: usize) -> pb::LaserScan {
    let mut r = ranges(1081, k);
    r.iter_mut().skip(k % 13).step_by(29).for_each(|x| *x = f32::INFINITY);
    pb::LaserScan {
        angle_min: -135f64.to_radians(),
        angle_increment: 0.25f64.to_radians(),
        range_min: 0.023,
        range_max: 30.0,
        ranges: r,
    }
}

fn request(beams: usize, k: usize, laser: bool, robot: &str, age: f64) -> pb::ActRequest {
    pb::ActRequest {
        scan: if laser { Vec::new() } else { ranges(beams, k) },
        laser_scan: laser.then(|| hokuyo(k)),
        goal_distance: 0.5 + (k % 40) as f64 * 0.1,
        goal_angle: ((k % 60) as f64 - 30.0) * 0.05,
        v: 0.2,
        omega: 0.1,
        robot_id: robot.into(),
        expected_footprint_version: 0,
        pose: None,
        scan_age_s: age,
    }
}

const WARMUP: usize = 50;

fn in_process(
    ctl: &DvstController,
    calls: usize,
    laser: bool,
    age: f64,
) -> anyhow::Result<Latency> {
    let mut ms = Vec::with_capacity(calls);
    for k in 0..WARMUP + calls {
        let r = request(ctl.beams(), k, laser, "bench", age);
        let t = Instant::now();
        ctl.act(&robot_input(&r).map_err(|e| anyhow::anyhow!("{}", e.message()))?)?;
        if k >= WARMUP {
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    Ok(Latency::of(ms))
}

/// Latency of `calls` commands, one at a time, each form of scan, through the service over
/// loopback gRPC (client and server in this process, on `dvnav`'s 2-worker runtime) and
/// in-process; then the fleet.
pub fn bench(
    checkpoint: &Path,
    footprint: &Path,
    calls: usize,
    fleet: FleetLoad,
    route: Option<super::route_bench::RouteLoad>,
) -> anyhow::Result<ServeBench> {
    anyhow::ensure!(calls >= 100, "--calls must be at least 100 for a p99");
    anyhow::ensure!(
        fleet.robots >= 1 && fleet.rate_hz > 0.0 && fleet.seconds >= 1.0,
        "the fleet needs at least 1 robot, a positive rate and 1 s"
    );
    single_candle_thread();
    let ctl = load_controller(checkpoint, footprint, None)?.with_robot_limits(
        fleet.robots + route.as_ref().map_or(0, |r| r.robots) + 1,
        Duration::from_secs(600),
    )?;
    let ctl = ctl
        .with_safety_horizon(fleet.safety_horizon_s)
        .map_err(|e| anyhow::anyhow!("--safety-horizon: {e:#}"))?;
    let ctl = Arc::new(ctl);
    let info = ctl.info("");
    let beams = info.beams;
    let age = fleet.scan_age_s;
    anyhow::ensure!(
        age.is_finite() && (0.0..=dvnav_sim::latency::MAX_SCAN_AGE_S).contains(&age),
        "--scan-age-s must lie in [0, {}] s, not {age}",
        dvnav_sim::latency::MAX_SCAN_AGE_S
    );
    let local = in_process(&ctl, calls, false, age)?;
    let local_laser = in_process(&ctl, calls, true, age)?;
    let cargo = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("footprints/circle-with-cargo.toml"),
    )?;

    let mu = info.footprint.mu;
    let (remote, remote_laser, fleet_ms, routed) = super::super::runtime()?.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let url = format!("http://{addr}");
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(serve(
            listener,
            async {
                let _ = stopped.await;
            },
            ctl.clone(),
            None,
            None,
        ));
        let mut client = pb::controller_client::ControllerClient::connect(url.clone()).await?;
        let mut one_at_a_time = async |laser: bool| -> anyhow::Result<Latency> {
            let mut ms = Vec::with_capacity(calls);
            for k in 0..WARMUP + calls {
                let r = request(beams, k, laser, "bench", age);
                let t = Instant::now();
                client.act(r).await?;
                if k >= WARMUP {
                    ms.push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
            Ok(Latency::of(ms))
        };
        let meta = one_at_a_time(false).await?;
        let laser = one_at_a_time(true).await?;
        let fleet_ms = drive_fleet(&url, fleet, beams, &cargo).await?;
        let routed = match &route {
            Some(load) => {
                let act = move |k: usize, id: &str| request(beams, k, true, id, age);
                // The server's robot: the meta robot's 0.2 m scaled by DVST's μ.
                Some(super::route_bench::drive(&url, load, 0.2 * mu, act).await?)
            }
            None => None,
        };
        let _ = stop.send(());
        server.await??;
        anyhow::Ok((meta, laser, fleet_ms, routed))
    })?;
    let fleet_calls = fleet_ms.len();
    let f = Latency::of(fleet_ms);
    let fp = &info.footprint;
    Ok(ServeBench {
        calls,
        scan_age_s: age,
        safety_horizon_s: fleet.safety_horizon_s,
        grpc_p50_ms: remote.p50,
        grpc_p99_ms: remote.p99,
        grpc_mean_ms: remote.mean,
        grpc_max_ms: remote.max,
        in_process_p50_ms: local.p50,
        in_process_p99_ms: local.p99,
        in_process_mean_ms: local.mean,
        in_process_max_ms: local.max,
        target_p99_ms: 2.0,
        meets_target: remote.p99 <= 2.0,
        laser_beams: 1081,
        laser_grpc_p50_ms: remote_laser.p50,
        laser_grpc_p99_ms: remote_laser.p99,
        laser_grpc_max_ms: remote_laser.max,
        laser_in_process_p50_ms: local_laser.p50,
        laser_in_process_p99_ms: local_laser.p99,
        laser_meets_target: remote_laser.p99 <= 2.0,
        fleet_robots: fleet.robots,
        fleet_rate_hz: fleet.rate_hz,
        fleet_seconds: fleet.seconds,
        fleet_calls,
        fleet_calls_per_s: fleet_calls as f64 / fleet.seconds,
        fleet_p50_ms: f.p50,
        fleet_p99_ms: f.p99,
        fleet_max_ms: f.max,
        fleet_target_p99_ms: 10.0,
        fleet_meets_target: f.p99 <= 10.0,
        beams,
        mu: fp.mu,
        model: format!("{} ({})", info.model.name, info.model.version),
        footprint: footprint.display().to_string(),
        route: routed,
    })
}

/// `fleet.robots` robots, each on its own connection, calling Act with a LaserScan every
/// 1/rate s (phases spread over one period) for `fleet.seconds`; every other robot first sets
/// a footprint of its own. Returns every call's latency (ms).
async fn drive_fleet(
    url: &str,
    fleet: FleetLoad,
    beams: usize,
    cargo: &str,
) -> anyhow::Result<Vec<f64>> {
    let (period, age) = (Duration::from_secs_f64(1.0 / fleet.rate_hz), fleet.scan_age_s);
    let until = Instant::now() + Duration::from_secs_f64(fleet.seconds + 1.0);
    let mut robots = tokio::task::JoinSet::new();
    for n in 0..fleet.robots {
        let mut client = pb::controller_client::ControllerClient::connect(url.to_string()).await?;
        let id = format!("robot-{n}");
        let expected = if n % 2 == 1 {
            let req =
                pb::SetFootprintRequest { footprint_toml: cargo.into(), robot_id: id.clone() };
            client.set_footprint(req).await?.into_inner().footprint_version
        } else {
            1
        };
        let phase = period.mul_f64(n as f64 / fleet.robots as f64);
        robots.spawn(async move {
            // One second to settle (connections, first calls), then timed.
            let timed_from = Instant::now() + Duration::from_secs(1);
            let mut tick = tokio::time::interval_at((Instant::now() + phase).into(), period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut ms = Vec::new();
            let mut k = n * 1000;
            while Instant::now() < until {
                tick.tick().await;
                let mut r = request(beams, k, true, &id, age);
                r.expected_footprint_version = expected;
                k += 1;
                let t = Instant::now();
                client.act(r).await?;
                if t >= timed_from {
                    ms.push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
            anyhow::Ok(ms)
        });
    }
    let mut all = Vec::new();
    while let Some(r) = robots.join_next().await {
        all.extend(r??);
    }
    anyhow::ensure!(!all.is_empty(), "the fleet made no timed call");
    Ok(all)
}

impl ServeBench {
    /// Lines for people.
    pub fn summary(&self) -> String {
        let met = |b: bool| if b { "met" } else { "missed" };
        format!(
            "controller, batch 1, {} calls: gRPC over loopback p50 {:.3} ms, p99 {:.3} ms, mean \
             {:.3} ms, max {:.3} ms (target p99 ≤ {} ms: {}); in-process p50 {:.3} ms, p99 {:.3} ms\n\
             with a {}-reading LaserScan: gRPC p50 {:.3} ms, p99 {:.3} ms (target p99 ≤ {} ms: \
             {}); in-process p50 {:.3} ms, p99 {:.3} ms\n\
             fleet: {} robots at {} Hz for {} s, {} calls ({:.0}/s): p50 {:.3} ms, p99 {:.3} ms, \
             max {:.3} ms (target p99 ≤ {} ms: {})",
            self.calls,
            self.grpc_p50_ms,
            self.grpc_p99_ms,
            self.grpc_mean_ms,
            self.grpc_max_ms,
            self.target_p99_ms,
            met(self.meets_target),
            self.in_process_p50_ms,
            self.in_process_p99_ms,
            self.laser_beams,
            self.laser_grpc_p50_ms,
            self.laser_grpc_p99_ms,
            self.target_p99_ms,
            met(self.laser_meets_target),
            self.laser_in_process_p50_ms,
            self.laser_in_process_p99_ms,
            self.fleet_robots,
            self.fleet_rate_hz,
            self.fleet_seconds,
            self.fleet_calls,
            self.fleet_calls_per_s,
            self.fleet_p50_ms,
            self.fleet_p99_ms,
            self.fleet_max_ms,
            self.fleet_target_p99_ms,
            met(self.fleet_meets_target),
        ) + &self.route.as_ref().map(route_summary).unwrap_or_default()
    }
}

fn route_summary(r: &super::route_bench::RouteFigures) -> String {
    format!(
        "\nrouted fleet on {}: {} robots at {} Hz, each off its path every {} calls: {} calls, {} \
         replans: p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms (target p99 ≤ {} ms: {}); the \
         replanning calls p50 {:.3} ms, max {:.3} ms; the others p99 {:.3} ms",
        r.route_map,
        r.route_robots,
        r.route_rate_hz,
        r.route_stray_every,
        r.route_calls,
        r.route_replans,
        r.route_p50_ms,
        r.route_p99_ms,
        r.route_max_ms,
        r.route_target_p99_ms,
        if r.route_meets_target { "met" } else { "missed" },
        r.route_replan_p50_ms,
        r.route_replan_max_ms,
        r.route_other_p99_ms,
    )
}
