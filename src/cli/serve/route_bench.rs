//! The routed fleet of `dvnav bench serve`: robots the server plans for on a real building's
//! map (`SetMap`, then `SetGoal` per leg), each `Act` carrying the robot's pose, and every robot
//! now and then far off its path so that the server replans for it (on its planner thread, asked
//! by that `Act`). It measures what a replanning robot costs the others: the latency of every
//! call, and of the calls that asked for a replan.

use super::latency::Latency;
use dvnav_proto::controller::v1 as pb;
use dvnav_sim::grid_map;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The routed fleet's load.
#[derive(Clone, Debug)]
pub struct RouteLoad {
    /// The map the server plans on (map_server YAML).
    pub map: PathBuf,
    /// Robots, each on its own connection.
    pub robots: usize,
    /// Each robot's control rate (Hz).
    pub rate_hz: f64,
    /// How long they drive (s, after 1 s of settling).
    pub seconds: f64,
    /// Every this many calls a robot reports a pose far from its path (the next leg's start):
    /// the server starts a replan for it in that call.
    pub stray_every: usize,
}

/// What the routed fleet measured.
#[derive(Debug, serde::Serialize)]
pub struct RouteFigures {
    pub route_map: String,
    pub route_robots: usize,
    pub route_rate_hz: f64,
    pub route_stray_every: usize,
    pub route_calls: usize,
    /// Replans the server reported during the timed calls.
    pub route_replans: u64,
    pub route_p50_ms: f64,
    pub route_p99_ms: f64,
    pub route_max_ms: f64,
    /// The calls that asked the server for a replan (it plans on its planner thread; a later
    /// call of the robot's takes up the new path).
    pub route_replan_calls: usize,
    pub route_replan_p50_ms: f64,
    pub route_replan_max_ms: f64,
    /// The other calls: what a replanning robot costs the rest of the fleet.
    pub route_other_p99_ms: f64,
    pub route_target_p99_ms: f64,
    pub route_meets_target: bool,
}

/// One robot's legs: start and goal pairs (map frame) reachable for a disc of `radius`, drawn
/// as `dvnav eval` draws its tasks in the map's room.
fn legs(
    room: &std::sync::Arc<dvnav_sim::Room>,
    frame: &grid_map::MapFrame,
    radius: f64,
    robot: usize,
    n: usize,
) -> Vec<[[f64; 2]; 2]> {
    use dvnav_sim::{EnvConfig, Footprint, NavEnv};
    let cfg = EnvConfig::default();
    let seed = 1000 + robot as u64;
    let mut env = NavEnv::with_footprint(room.clone(), &cfg, seed, Footprint::circle(radius));
    (0..n)
        .map(|_| {
            env.reset();
            let (a, b) = (env.start().position(), env.goal());
            [frame.room_to_map(a), frame.room_to_map(b)]
        })
        .collect()
}

fn pose(p: [f64; 2]) -> Option<pb::Pose2D> {
    Some(pb::Pose2D { x: p[0], y: p[1], yaw: 0.0 })
}

/// Sets the map, then drives `load.robots` robots of bounding radius `radius` (m: their legs
/// are drawn reachable for it) on it until `load.seconds` have passed.
pub async fn drive(
    url: &str,
    load: &RouteLoad,
    radius: f64,
    act: impl Fn(usize, &str) -> pb::ActRequest + Clone + Send + 'static,
) -> anyhow::Result<RouteFigures> {
    let source = load.map.display().to_string();
    let map = grid_map::load(&source)?;
    let room = std::sync::Arc::new(dvnav_sim::Room::try_new(map.spec.clone())?);
    let yaml = std::fs::read_to_string(&load.map)?;
    let image = std::fs::read(&map.meta.image)?;
    let mut client = pb::controller_client::ControllerClient::connect(url.to_string()).await?;
    client.set_map(pb::SetMapRequest { map_yaml: yaml, image }).await?;

    let period = Duration::from_secs_f64(1.0 / load.rate_hz);
    let until = Instant::now() + Duration::from_secs_f64(load.seconds + 1.0);
    let mut robots = tokio::task::JoinSet::new();
    for n in 0..load.robots {
        let mut client = pb::controller_client::ControllerClient::connect(url.to_string()).await?;
        let legs = legs(&room, &map.frame, radius, n, 16);
        let id = format!("routed-{n}");
        let phase = period.mul_f64(n as f64 / load.robots as f64);
        let (stray_every, act) = (load.stray_every.max(1), act.clone());
        robots.spawn(async move {
            let timed_from = Instant::now() + Duration::from_secs(1);
            let mut tick = tokio::time::interval_at((Instant::now() + phase).into(), period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            // Each timed call's latency (ms) and whether it asked the server for a replan.
            let mut calls: Vec<(f64, bool)> = Vec::new();
            let (mut leg, mut at, mut replans_before, mut replans) = (0, legs[0][0], 0, 0u64);
            let (mut replanning_before, mut asked_timed) = (false, false);
            let set_goal = |leg: usize| pb::SetGoalRequest {
                robot_id: id.clone(),
                start: pose(legs[leg % legs.len()][0]),
                goal: pose(legs[leg % legs.len()][1]),
            };
            client.set_goal(set_goal(leg)).await?;
            let (mut k, mut strays) = (0, 0);
            while Instant::now() < until {
                tick.tick().await;
                k += 1;
                if k % stray_every == 0 {
                    // Far from the path, in free space: another leg's start, a new one each
                    // time (the same point twice would lie on the path planned from it).
                    strays += 1;
                    at = legs[(leg + strays) % legs.len()][0];
                }
                let mut r = act(n * 1000 + k, &id);
                r.pose = pose(at);
                let t = Instant::now();
                let reply = client.act(r).await?.into_inner();
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let asked = reply.replanning && !replanning_before;
                let timed = t >= timed_from;
                // A replan counts when the call that asked for it was timed.
                if asked_timed {
                    replans += u64::from(reply.replans.saturating_sub(replans_before));
                }
                if reply.replans > replans_before || asked {
                    asked_timed = asked && timed;
                }
                if timed {
                    calls.push((ms, asked));
                }
                replans_before = reply.replans;
                replanning_before = reply.replanning;
                // Drive towards the subgoal (0.05 m a call); a new leg once there or blocked.
                let to = [reply.subgoal_x - at[0], reply.subgoal_y - at[1]];
                let d = to[0].hypot(to[1]);
                if reply.following_route && d > 1e-9 {
                    let s = (0.05 / d).min(1.0);
                    at = [at[0] + s * to[0], at[1] + s * to[1]];
                }
                // (While the server replans, the reply is still about the old path.)
                let done = reply.blocked || reply.remaining_m < 0.3;
                if !reply.following_route || (done && !reply.replanning) {
                    leg += 1;
                    at = legs[leg % legs.len()][0];
                    client.set_goal(set_goal(leg)).await?;
                    replans_before = 0;
                    (replanning_before, asked_timed) = (false, false);
                }
            }
            anyhow::Ok((calls, replans))
        });
    }
    let (mut calls, mut replans) = (Vec::new(), 0);
    while let Some(r) = robots.join_next().await {
        let (c, n) = r??;
        calls.extend(c);
        replans += n;
    }
    anyhow::ensure!(!calls.is_empty(), "the routed fleet made no timed call");
    let every = Latency::of(calls.iter().map(|c| c.0).collect());
    let (replanning, others): (Vec<&(f64, bool)>, Vec<_>) = calls.iter().partition(|c| c.1);
    let replanning: Vec<f64> = replanning.into_iter().map(|c| c.0).collect();
    let others: Vec<f64> = others.into_iter().map(|c| c.0).collect();
    let other = Latency::of(if others.is_empty() { vec![0.0] } else { others });
    let (replan_p50, replan_max) = if replanning.is_empty() {
        (f64::NAN, f64::NAN)
    } else {
        let l = Latency::of(replanning.clone());
        (l.p50, l.max)
    };
    Ok(RouteFigures {
        route_map: source,
        route_robots: load.robots,
        route_rate_hz: load.rate_hz,
        route_stray_every: load.stray_every,
        route_calls: calls.len(),
        route_replans: replans,
        route_p50_ms: every.p50,
        route_p99_ms: every.p99,
        route_max_ms: every.max,
        route_replan_calls: replanning.len(),
        route_replan_p50_ms: replan_p50,
        route_replan_max_ms: replan_max,
        route_other_p99_ms: other.p99,
        route_target_p99_ms: 10.0,
        route_meets_target: every.p99 <= 10.0,
    })
}
