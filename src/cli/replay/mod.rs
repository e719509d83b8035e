//! `dvnav replay`: the DVST controller over a recorded ROS 2 bag. At each LaserScan it takes
//! the latest odometry (pose and velocity in the odometry frame), the goal in that frame, and
//! asks the controller what it would have commanded, exactly as `dvnav serve` answers a robot
//! sending that scan; the commands go to a CSV file, the scans and the path to a figure. Try a
//! bag of your own robot before letting the controller drive it.
//!
//! A bag with the robot's own planner's paths (`nav_msgs/msg/Path` on `--plan-topic`, Nav2's
//! `/plan`) is replayed as `dvnav serve` drives a robot on a route (`SetRoute`): each path, from
//! its log time on, is the robot's route, each scan's odometry pose goes with it, and the
//! controller picks the subgoal; the rows and the figure show the plans and the subgoals.

mod bag;
mod mount;
mod ros;

use crate::render::replay::ReplayFigure;
use clap::Args;
use dvnav_nav::dvst::controller::{MAX_SPEED, RobotInput, Scan};
use dvnav_nav::dvst::{LaserScan, SensorSetup};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `dvnav replay`.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The bag: an MCAP file or a rosbag2 SQLite file (`.db3`), or a rosbag2 directory of
    /// either (`ros2 bag record`).
    bag: PathBuf,
    /// Topic of the LiDAR's `sensor_msgs/msg/LaserScan`.
    #[arg(long, default_value = "/scan")]
    scan_topic: String,
    /// Topic of the robot's `nav_msgs/msg/Odometry`.
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// The goal `X,Y` (m) in the odometry frame. Not needed when the bag has goals on
    /// `--goal-topic` or the planner's paths on `--plan-topic`: those replace it from their
    /// log time on.
    #[arg(long, value_parser = parse_goal, allow_hyphen_values = true)]
    goal: Option<[f64; 2]>,
    /// Topic of the robot's planner's `nav_msgs/msg/Path` (Nav2's `/plan`), in the odometry
    /// frame: each path is the robot's route from its log time on, the controller picks the
    /// subgoal on it. A bag without this topic is replayed towards `--goal`.
    #[arg(long, default_value = "/plan")]
    plan_topic: String,
    /// Topic of the goals sent to the robot, `geometry_msgs/msg/PoseStamped` (Nav2's and
    /// RViz's `/goal_pose`), in the odometry frame: each is the goal from its log time on
    /// (a route from `--plan-topic` goes first while there is one).
    #[arg(long, default_value = "/goal_pose")]
    goal_topic: String,
    /// The robot's footprint file (see `footprints/`; its `[lidar]` table places the sensor).
    /// Default: the meta robot itself, its LiDAR on the axle centre.
    #[arg(long)]
    footprint: Option<PathBuf>,
    /// Keep the footprint file's `[lidar]` mounting even when the bag's `/tf_static` places
    /// the scan's frame elsewhere on the robot (by default /tf_static's wins, with a warning).
    #[arg(long)]
    ignore_tf_static: bool,
    /// The meta agent: a model directory, a checkpoint directory or a `policy.safetensors`.
    #[arg(long, default_value = "models/meta-r0.2")]
    checkpoint: PathBuf,
    /// Safety margin (m), replacing the footprint file's.
    #[arg(long)]
    margin: Option<f64>,
    /// Write one row per scan: pose, goal, the robot's velocity and the command.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Draw the path, the goal and the scans (every scan's returns, in the odometry frame) to
    /// this PNG.
    #[arg(long)]
    figure: Option<PathBuf>,
}

fn parse_goal(s: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let xy: Vec<f64> = parts.iter().filter_map(|p| p.parse().ok()).collect();
    match xy[..] {
        [x, y] if parts.len() == 2 && x.is_finite() && y.is_finite() => Ok([x, y]),
        _ => Err(format!("`{s}` is not a goal `X,Y` in metres, e.g. `--goal 3.5,-1.2`")),
    }
}

/// One scan's row of `--out`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CommandRow {
    /// The scan's index in the bag (0-based) and its log time (s since the first scan).
    pub scan: usize,
    pub time_s: f64,
    /// The scan's header stamp (s).
    pub stamp_s: f64,
    /// The robot's pose in the odometry frame (m, m, rad), from the latest odometry.
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
    /// The goal at this scan (odometry frame, m): the route's end, the latest goal message, or
    /// `--goal`.
    pub goal_x: f64,
    pub goal_y: f64,
    /// The goal as the controller sees it: distance (m) and bearing (rad, robot frame).
    pub goal_distance: f64,
    pub goal_angle: f64,
    /// The robot's velocity from the odometry (m/s, rad/s).
    pub odom_v: f64,
    pub odom_omega: f64,
    /// The command: linear (m/s) and angular (rad/s) velocity.
    pub v: f64,
    pub omega: f64,
    /// Within the goal tolerance (the command is then 0, 0).
    pub arrived: bool,
    /// On a route (`--plan-topic`): the subgoal the controller fed the agent (odometry frame,
    /// m) and the path left to the route's goal (m); empty without a route.
    pub subgoal_x: Option<f64>,
    pub subgoal_y: Option<f64>,
    pub remaining_m: Option<f64>,
    /// The goal tolerance (m): the meta agent's, scaled by μ.
    pub goal_tolerance: f64,
    /// Meta beams no valid reading reached.
    pub filled_beams: usize,
    /// The nearest valid return of the scan (m); empty when it has none.
    pub nearest_m: Option<f64>,
    /// The least clearance (m) between the disc covering the robot and the scan's returns
    /// along the arc the command would drive in the next [`ARC_HORIZON_S`] if the world stood
    /// still; negative: the command drives into a return. Empty without returns.
    pub arc_clearance_m: Option<f64>,
    /// The same for the recorded velocity (the robot's own driver), for comparison.
    pub recorded_arc_clearance_m: Option<f64>,
}

/// How far ahead (s) [`CommandRow::arc_clearance_m`] follows a command: five control periods of
/// the meta agent (0.2 s each), about what it takes to stop from v_max at its deceleration.
pub const ARC_HORIZON_S: f64 = 1.0;

/// The least distance between a disc of `radius` at the poses of the arc `(v, ω)` drives from
/// `pose` over [`ARC_HORIZON_S`] (sampled every 0.05 s) and `points`, less `radius`; `None`
/// without points.
fn arc_clearance(
    pose: [f64; 3],
    v: f64,
    omega: f64,
    radius: f64,
    points: &[[f64; 2]],
) -> Option<f64> {
    const STEPS: usize = 20;
    let [x, y, yaw] = pose;
    let at = |t: f64| {
        if omega.abs() < 1e-9 {
            [x + v * t * yaw.cos(), y + v * t * yaw.sin()]
        } else {
            let h = yaw + omega * t;
            [x + v / omega * (h.sin() - yaw.sin()), y - v / omega * (h.cos() - yaw.cos())]
        }
    };
    let centres: Vec<[f64; 2]> =
        (0..=STEPS).map(|k| at(ARC_HORIZON_S * k as f64 / STEPS as f64)).collect();
    points
        .iter()
        .flat_map(|p| centres.iter().map(move |c| (p[0] - c[0]).hypot(p[1] - c[1])))
        .min_by(f64::total_cmp)
        .map(|d| d - radius)
}

/// What a replay found, for the closing line.
#[derive(Debug)]
struct Replayed {
    rows: Vec<CommandRow>,
    /// Scans before the first odometry: nothing to say where the robot was.
    skipped: usize,
    /// Odometry messages no robot could have sent (see [`ros::Odometry::implausible`]),
    /// passed over, and why the first was.
    implausible: (usize, Option<String>),
    /// Each row's scan, in the sensor frame, for the figure.
    scans: Vec<ros::LaserScan>,
    /// Every route taken, in order (odometry frame).
    plans: Vec<Vec<[f64; 2]>>,
    /// The goal at the last scan: `--goal`, or the last route's end.
    goal: [f64; 2],
}

/// Runs `dvnav replay`.
pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    super::serve::single_candle_thread();
    let footprint_text = match &args.footprint {
        Some(f) => std::fs::read_to_string(f)
            .map_err(|e| anyhow::anyhow!("{}: cannot read the footprint file: {e}", f.display()))?,
        None => String::new(),
    };
    let topics = bag::Topics {
        scan: &args.scan_topic,
        odom: &args.odom_topic,
        plan: &args.plan_topic,
        goal: &args.goal_topic,
        tf_static: "/tf_static",
    };
    let rec = bag::read(&args.bag, &topics)?;
    let controller = |lidar| {
        super::serve::controller_for(
            &args.checkpoint,
            &footprint_text,
            args.footprint.as_deref(),
            args.margin,
            lidar,
        )
    };
    let mut ctl = controller(None)?;
    // Where the sensor is, as far as the bag says: what the arc clearances are measured with,
    // even when `--ignore-tf-static` drives the controller with the footprint's mounting.
    let mut truth = ctl.footprint(ROBOT).robot.lidar;
    if let Some([x, y, yaw]) = tf_static_mount(&rec, &ctl, &args)? {
        (truth.x, truth.y, truth.yaw) = (x, y, yaw);
        if !args.ignore_tf_static {
            ctl = controller(Some([x, y, yaw]))?;
        }
    }
    anyhow::ensure!(
        args.goal.is_some() || !rec.plans.is_empty() || !rec.goals.is_empty(),
        "{}: no goal: give `--goal X,Y` (odometry frame), or record the goals sent to the robot \
         (geometry_msgs/msg/PoseStamped on `--goal-topic`, now {}) or its planner's \
         nav_msgs/msg/Path (on `--plan-topic`, now {})",
        args.bag.display(),
        args.goal_topic,
        args.plan_topic
    );
    eprintln!(
        "replay: {} scans on {}, {} odometry messages on {}, {} paths on {}, {} goals on {}, {}",
        rec.scans.len(),
        args.scan_topic,
        rec.odometry.len(),
        args.odom_topic,
        rec.plans.len(),
        args.plan_topic,
        rec.goals.len(),
        args.goal_topic,
        match args.goal {
            Some(g) => format!("goal ({}, {}) in the odometry frame until one arrives", g[0], g[1]),
            None => "the goal at each path's end or from each goal message".into(),
        }
    );
    let out = replay(&ctl, rec, args.goal, &truth)?;
    if let (n @ 1.., Some(first)) = &out.implausible {
        eprintln!(
            "replay: passed over {n} odometry message{} on {} that no robot could have sent (the \
             first at {first}); each scan takes the latest plausible one",
            if *n == 1 { "" } else { "s" },
            args.odom_topic
        );
    }
    anyhow::ensure!(
        !out.rows.is_empty(),
        "{}: every scan comes before the first odometry message; nothing to replay",
        args.bag.display()
    );
    if let Some(path) = &args.out {
        write_rows(path, &out.rows)?;
        eprintln!("replay: wrote {} commands to {}", out.rows.len(), path.display());
    }
    if let Some(path) = &args.figure {
        let lidar = ctl.footprint("").robot.lidar;
        let canvas = crate::render::replay::render(&figure(&out, &lidar), 900)?;
        std::fs::write(path, canvas.encode_png()?)
            .map_err(|e| anyhow::anyhow!("cannot write --figure {}: {e}", path.display()))?;
        eprintln!("replay: drew {}", path.display());
    }
    let arrived = out.rows.iter().find(|r| r.arrived);
    let last = out.rows.last().expect("rows checked above");
    println!(
        "{} commands ({} scans before the first odometry skipped); {}; last: v = {:.3} m/s, ω = \
         {:.3} rad/s at {:.2} m from the goal",
        out.rows.len(),
        out.skipped,
        match arrived {
            Some(r) => format!("arrived at scan {} ({:.2} s)", r.scan, r.time_s),
            None => "never within the goal tolerance".into(),
        },
        last.v,
        last.omega,
        last.goal_distance
    );
    Ok(ExitCode::SUCCESS)
}

/// The sensor's mounting from the bag's `/tf_static` when it differs from the footprint file's
/// (said on stderr, with which one the controller drives with).
fn tf_static_mount(
    rec: &bag::Recording,
    ctl: &dvnav_nav::dvst::DvstController,
    args: &ReplayArgs,
) -> anyhow::Result<Option<[f64; 3]>> {
    if rec.tf_static.is_empty() {
        return Ok(None);
    }
    let sensor = &rec.scans[0].1.header.frame_id;
    let base =
        rec.odometry.first().map(|(_, o)| o.child_frame_id.as_str()).filter(|f| !f.is_empty());
    let Some((base, tf)) = mount::sensor_mount(&rec.tf_static, sensor, base) else {
        eprintln!(
            "replay: /tf_static has no chain of transforms from the scan's frame `{sensor}` to \
             the robot's `{}`; the sensor sits where the footprint's [lidar] table says",
            base.unwrap_or("base frame")
        );
        return Ok(None);
    };
    let lidar = ctl.footprint(ROBOT).robot.lidar;
    let file = mount::Mount { x: lidar.x, y: lidar.y, yaw: lidar.yaw };
    if !tf.differs_from(&file) {
        return Ok(None);
    }
    let source = args
        .footprint
        .as_ref()
        .map_or("the meta robot (no --footprint)".to_string(), |f| f.display().to_string());
    let (chosen, how) = if args.ignore_tf_static {
        ("the footprint's", "--ignore-tf-static")
    } else {
        ("/tf_static's", "set the footprint's [lidar] table to it, or --ignore-tf-static")
    };
    eprintln!(
        "replay: /tf_static mounts `{sensor}` at x = {:.3} m, y = {:.3} m, yaw = {:.1}° in \
         `{base}`; {source} says x = {:.3} m, y = {:.3} m, yaw = {:.1}°; replaying with \
         {chosen} ({how})",
        tf.x,
        tf.y,
        tf.yaw.to_degrees(),
        file.x,
        file.y,
        file.yaw.to_degrees()
    );
    Ok(Some([tf.x, tf.y, tf.yaw]))
}

/// The robot id routes are set for: replay drives one robot.
const ROBOT: &str = "";

fn replay(
    ctl: &dvnav_nav::dvst::DvstController,
    rec: bag::Recording,
    goal: Option<[f64; 2]>,
    truth: &SensorSetup,
) -> anyhow::Result<Replayed> {
    let radius = ctl.footprint(ROBOT).robot.footprint.bounding_radius();
    let mut odom = rec.odometry.iter().peekable();
    let mut plans = rec.plans.iter().peekable();
    let mut goals = rec.goals.iter().peekable();
    // Without odometry the sensor stood still at the odometry frame's origin.
    let fixed = rec.odometry.is_empty().then(ros::Odometry::at_rest);
    let mut latest: Option<&ros::Odometry> = fixed.as_ref();
    let odom_frame = rec.odometry.first().map(|(_, o)| o.header.frame_id.clone());
    let t0 = rec.scans[0].0;
    let mut out = Replayed {
        rows: Vec::new(),
        skipped: 0,
        implausible: (0, None),
        scans: Vec::new(),
        plans: Vec::new(),
        goal: goal.unwrap_or_default(),
    };
    // The route's goal while the robot follows one, else the latest goal message, else `--goal`.
    let mut route_goal: Option<[f64; 2]> = None;
    let mut topic_goal: Option<[f64; 2]> = None;
    for (k, (t, scan)) in rec.scans.into_iter().enumerate() {
        while let Some((to, o)) = odom.next_if(|(to, _)| *to <= t) {
            match o.implausible(MAX_SPEED) {
                None => latest = Some(o),
                Some(why) => {
                    out.implausible.0 += 1;
                    out.implausible.1.get_or_insert(format!("log time {to} ns: {why}"));
                }
            }
        }
        while let Some((tp, path)) = plans.next_if(|(tp, _)| *tp <= t) {
            route_goal = take_route(ctl, *tp, path, odom_frame.as_deref(), &mut out.plans)?;
        }
        while let Some((_, g)) = goals.next_if(|(tg, _)| *tg <= t) {
            if topic_goal.is_none() {
                warn_frame("goals", &g.header.frame_id, odom_frame.as_deref());
            }
            topic_goal = Some([g.position.x, g.position.y]);
        }
        let Some(goal) = route_goal.or(topic_goal).or(goal) else {
            // No path or goal yet and no --goal: nothing to drive to.
            out.skipped += 1;
            continue;
        };
        out.goal = goal;
        let Some(o) = latest else {
            out.skipped += 1;
            continue;
        };
        let (x, y) = (o.pose.position.x, o.pose.position.y);
        let yaw = o.pose.orientation.yaw();
        let (dx, dy) = (goal[0] - x, goal[1] - y);
        let goal_distance = dx.hypot(dy);
        let goal_angle = dy.atan2(dx) - yaw;
        let (odom_v, odom_omega) = (o.twist.linear.x, o.twist.angular.z);
        let laser = LaserScan {
            angle_min: f64::from(scan.angle_min),
            angle_increment: f64::from(scan.angle_increment),
            range_min: f64::from(scan.range_min),
            range_max: f64::from(scan.range_max),
            ranges: &scan.ranges,
        };
        let mut input =
            RobotInput::new(Scan::Laser(laser), goal_distance, goal_angle, odom_v, odom_omega);
        input.robot_id = ROBOT;
        if route_goal.is_some() {
            input.pose = Some(dvnav_sim::Pose2::new(x, y, yaw));
        }
        let c = ctl.act(&input).map_err(|e| anyhow::anyhow!("scan {k} (log time {t} ns): {e}"))?;
        let nearest = scan
            .ranges
            .iter()
            .map(|&r| f64::from(r))
            .filter(|r| (f64::from(scan.range_min)..=f64::from(scan.range_max)).contains(r))
            .min_by(f64::total_cmp);
        let pose = [x, y, yaw];
        let points: Vec<[f64; 2]> = returns(pose, &scan, truth).collect();
        out.rows.push(CommandRow {
            scan: k,
            time_s: (t - t0) as f64 * 1e-9,
            stamp_s: scan.header.stamp.seconds(),
            x,
            y,
            yaw,
            goal_x: goal[0],
            goal_y: goal[1],
            goal_distance,
            goal_angle: (goal_angle.sin()).atan2(goal_angle.cos()),
            odom_v,
            odom_omega,
            v: c.v,
            omega: c.omega,
            arrived: c.arrived,
            subgoal_x: c.route.map(|r| r.subgoal[0]),
            subgoal_y: c.route.map(|r| r.subgoal[1]),
            remaining_m: c.route.map(|r| r.remaining_m),
            goal_tolerance: c.goal_tolerance,
            filled_beams: c.filled_beams,
            nearest_m: nearest,
            arc_clearance_m: arc_clearance(pose, c.v, c.omega, radius, &points),
            recorded_arc_clearance_m: arc_clearance(pose, odom_v, odom_omega, radius, &points),
        });
        out.scans.push(scan);
    }
    Ok(out)
}

/// The robot's planner sent `path` at log time `t` (ns): it becomes the robot's route, as
/// `SetRoute` makes it; an empty path (a planner that failed) clears the route. Returns the
/// route's goal.
fn take_route(
    ctl: &dvnav_nav::dvst::DvstController,
    t: u64,
    path: &ros::Path,
    odom_frame: Option<&str>,
    taken: &mut Vec<Vec<[f64; 2]>>,
) -> anyhow::Result<Option<[f64; 2]>> {
    let points = path.points();
    if points.is_empty() {
        ctl.clear_route(ROBOT).map_err(|e| anyhow::anyhow!("path at log time {t} ns: {e}"))?;
        return Ok(None);
    }
    if taken.is_empty() {
        warn_frame("paths", &path.header.frame_id, odom_frame);
    }
    let goal = *points.last().expect("not empty");
    ctl.set_route(ROBOT, points.clone())
        .map_err(|e| anyhow::anyhow!("path at log time {t} ns: {e}"))?;
    taken.push(points);
    Ok(Some(goal))
}

/// Says once that `what` (paths, goals) come in another frame than the odometry: replay has no
/// map -> odom transform and reads them as the odometry frame.
fn warn_frame(what: &str, frame: &str, odom_frame: Option<&str>) {
    if let Some(odom) = odom_frame
        && !frame.is_empty()
        && frame != odom
    {
        eprintln!(
            "replay: the {what} are in frame `{frame}`, the odometry in `{odom}`; replay reads \
             both as the odometry frame (it has no map -> odom transform)"
        );
    }
}

/// The figure of a replay: the path, every scan's returns in the odometry frame, the goal, and
/// the routes and subgoals when the robot followed its planner's paths.
fn figure(out: &Replayed, lidar: &SensorSetup) -> ReplayFigure {
    let arrived = out.rows.iter().find(|r| r.arrived);
    ReplayFigure {
        plans: out.plans.clone(),
        subgoals: out.rows.iter().filter_map(|r| Some([r.subgoal_x?, r.subgoal_y?])).collect(),
        path: out.rows.iter().map(|r| ([r.x, r.y], r.v)).collect(),
        returns: out
            .rows
            .iter()
            .zip(&out.scans)
            .flat_map(|(r, s)| returns([r.x, r.y, r.yaw], s, lidar))
            .collect(),
        goal: out.goal,
        tolerance: out.rows[0].goal_tolerance,
        arrived: arrived.map(|r| (r.time_s, [r.x, r.y])),
        duration_s: out.rows.last().map_or(0.0, |r| r.time_s),
        commanded_path: commanded_path(&out.rows),
        omega: out.rows.iter().map(|r| (r.time_s, r.omega, r.odom_omega)).collect(),
    }
}

/// Where the commands alone would have taken the robot: from the first row's pose, each
/// command (v, ω) held until the next scan, integrated along its arc (open loop: no odometry).
fn commanded_path(rows: &[CommandRow]) -> Vec<[f64; 2]> {
    let Some(first) = rows.first() else { return Vec::new() };
    let (mut x, mut y, mut yaw) = (first.x, first.y, first.yaw);
    let mut out = vec![[x, y]];
    for w in rows.windows(2) {
        let dt = (w[1].time_s - w[0].time_s).clamp(0.0, 1.0);
        let (v, omega) = (w[0].v, w[0].omega);
        // Sub-steps of at most 20 ms keep the arc's chord error far below a pixel.
        let n = ((dt / 0.02).ceil() as usize).max(1);
        let h = dt / n as f64;
        for _ in 0..n {
            let mid = yaw + 0.5 * omega * h;
            x += v * h * mid.cos();
            y += v * h * mid.sin();
            yaw += omega * h;
        }
        out.push([x, y]);
    }
    out
}

/// The valid returns of `scan` taken at `pose` (x, y, yaw in the odometry frame) by a sensor
/// mounted as `lidar` says, in the odometry frame.
fn returns<'a>(
    pose: [f64; 3],
    scan: &'a ros::LaserScan,
    lidar: &'a SensorSetup,
) -> impl Iterator<Item = [f64; 2]> + 'a {
    let [x, y, yaw] = pose;
    let (c, s) = (yaw.cos(), yaw.sin());
    let sensor = [x + c * lidar.x - s * lidar.y, y + s * lidar.x + c * lidar.y];
    let (lo, hi) = (f64::from(scan.range_min), f64::from(scan.range_max));
    scan.ranges.iter().enumerate().filter_map(move |(j, &r)| {
        let r = f64::from(r);
        let a = yaw
            + lidar.yaw
            + f64::from(scan.angle_min)
            + j as f64 * f64::from(scan.angle_increment);
        (lo..=hi).contains(&r).then(|| [sensor[0] + r * a.cos(), sensor[1] + r * a.sin()])
    })
}

fn write_rows(path: &Path, rows: &[CommandRow]) -> anyhow::Result<()> {
    let err =
        |e: &dyn std::fmt::Display| anyhow::anyhow!("cannot write --out {}: {e}", path.display());
    let mut w = csv::Writer::from_path(path).map_err(|e| err(&e))?;
    for r in rows {
        w.serialize(r).map_err(|e| err(&e))?;
    }
    w.flush().map_err(|e| err(&e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_arc_clearance_follows_the_command() {
        // A wall point 1 m ahead; the robot's disc has radius 0.2.
        let wall = [[1.0, 0.0]];
        let at_origin = [0.0, 0.0, 0.0];
        // Standing still: 1 − 0.2.
        let still = arc_clearance(at_origin, 0.0, 0.0, 0.2, &wall).unwrap();
        assert!((still - 0.8).abs() < 1e-12, "{still}");
        // 0.5 m/s straight at it for 1 s: 0.5 m nearer.
        let ahead = arc_clearance(at_origin, 0.5, 0.0, 0.2, &wall).unwrap();
        assert!((ahead - 0.3).abs() < 1e-12, "{ahead}");
        // Into it: negative.
        assert!(arc_clearance(at_origin, 1.0, 0.0, 0.2, &wall).unwrap() < 0.0);
        // Turning in place keeps the distance; a quarter turn at v = 0.5 curves away from it.
        let turn = arc_clearance(at_origin, 0.0, 1.5, 0.2, &wall).unwrap();
        assert!((turn - 0.8).abs() < 1e-12, "{turn}");
        let curve = arc_clearance(at_origin, 0.5, std::f64::consts::FRAC_PI_2, 0.2, &wall).unwrap();
        assert!(curve > 0.3 && curve < 0.8, "{curve}");
        // The arc starts at the pose, heading as it says: facing away, driving is safe.
        let away = arc_clearance([0.0, 0.0, std::f64::consts::PI], 0.5, 0.0, 0.2, &wall).unwrap();
        assert!((away - 0.8).abs() < 1e-12, "{away}");
        assert_eq!(arc_clearance(at_origin, 0.5, 0.0, 0.2, &[]), None);
    }
}
