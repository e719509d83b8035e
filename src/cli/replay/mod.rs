//! `dvnav replay`: the DVST controller over a recorded ROS 2 bag. At each LaserScan it takes
//! the latest odometry (pose and velocity in the odometry frame), the goal in that frame, and
//! asks the controller what it would have commanded, exactly as `dvnav serve` answers a robot
//! sending that scan; the commands go to a CSV file, the scans and the path to a figure. Try a
//! bag of your own robot before letting the controller drive it.

mod bag;
mod ros;

use crate::render::replay::ReplayFigure;
use clap::Args;
use dvnav_nav::dvst::controller::{RobotInput, Scan};
use dvnav_nav::dvst::{LaserScan, SensorSetup};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `dvnav replay`.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The bag: an MCAP file, or a rosbag2 directory of them (`ros2 bag record -s mcap`).
    bag: PathBuf,
    /// Topic of the LiDAR's `sensor_msgs/msg/LaserScan`.
    #[arg(long, default_value = "/scan")]
    scan_topic: String,
    /// Topic of the robot's `nav_msgs/msg/Odometry`.
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// The goal `X,Y` (m) in the odometry frame.
    #[arg(long, value_parser = parse_goal, allow_hyphen_values = true)]
    goal: [f64; 2],
    /// The robot's footprint file (see `footprints/`; its `[lidar]` table places the sensor).
    /// Default: the meta robot itself, its LiDAR on the axle centre.
    #[arg(long)]
    footprint: Option<PathBuf>,
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
    /// The goal tolerance (m): the meta agent's, scaled by μ.
    pub goal_tolerance: f64,
    /// Meta beams no valid reading reached.
    pub filled_beams: usize,
    /// The nearest valid return of the scan (m); empty when it has none.
    pub nearest_m: Option<f64>,
}

/// What a replay found, for the closing line.
#[derive(Debug)]
struct Replayed {
    rows: Vec<CommandRow>,
    /// Scans before the first odometry: nothing to say where the robot was.
    skipped: usize,
    /// Each row's scan, in the sensor frame, for the figure.
    scans: Vec<ros::LaserScan>,
}

/// Runs `dvnav replay`.
pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    super::serve::single_candle_thread();
    let footprint_text = match &args.footprint {
        Some(f) => std::fs::read_to_string(f)
            .map_err(|e| anyhow::anyhow!("{}: cannot read the footprint file: {e}", f.display()))?,
        None => String::new(),
    };
    let ctl = super::serve::controller_for(
        &args.checkpoint,
        &footprint_text,
        args.footprint.as_deref(),
        args.margin,
    )?;
    let rec = bag::read(&args.bag, &args.scan_topic, &args.odom_topic)?;
    eprintln!(
        "replay: {} scans on {}, {} odometry messages on {}, goal ({}, {}) in the odometry frame",
        rec.scans.len(),
        args.scan_topic,
        rec.odometry.len(),
        args.odom_topic,
        args.goal[0],
        args.goal[1]
    );
    let out = replay(&ctl, rec, args.goal)?;
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
        let canvas = crate::render::replay::render(&figure(&out, &lidar, args.goal), 900)?;
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

fn replay(
    ctl: &dvnav_nav::dvst::DvstController,
    rec: bag::Recording,
    goal: [f64; 2],
) -> anyhow::Result<Replayed> {
    let mut odom = rec.odometry.iter().peekable();
    // Without odometry the sensor stood still at the odometry frame's origin.
    let fixed = rec.odometry.is_empty().then(ros::Odometry::at_rest);
    let mut latest: Option<&ros::Odometry> = fixed.as_ref();
    let t0 = rec.scans[0].0;
    let mut out = Replayed { rows: Vec::new(), skipped: 0, scans: Vec::new() };
    for (k, (t, scan)) in rec.scans.into_iter().enumerate() {
        while let Some((_, o)) = odom.next_if(|(to, _)| *to <= t) {
            latest = Some(o);
        }
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
        let input =
            RobotInput::new(Scan::Laser(laser), goal_distance, goal_angle, odom_v, odom_omega);
        let c = ctl.act(&input).map_err(|e| anyhow::anyhow!("scan {k} (log time {t} ns): {e}"))?;
        let nearest = scan
            .ranges
            .iter()
            .map(|&r| f64::from(r))
            .filter(|r| (f64::from(scan.range_min)..=f64::from(scan.range_max)).contains(r))
            .min_by(f64::total_cmp);
        out.rows.push(CommandRow {
            scan: k,
            time_s: (t - t0) as f64 * 1e-9,
            stamp_s: scan.header.stamp.seconds(),
            x,
            y,
            yaw,
            goal_distance,
            goal_angle: (goal_angle.sin()).atan2(goal_angle.cos()),
            odom_v,
            odom_omega,
            v: c.v,
            omega: c.omega,
            arrived: c.arrived,
            goal_tolerance: c.goal_tolerance,
            filled_beams: c.filled_beams,
            nearest_m: nearest,
        });
        out.scans.push(scan);
    }
    Ok(out)
}

/// The figure of a replay: the path, every scan's returns in the odometry frame, the goal.
fn figure(out: &Replayed, lidar: &SensorSetup, goal: [f64; 2]) -> ReplayFigure {
    let arrived = out.rows.iter().find(|r| r.arrived);
    ReplayFigure {
        path: out.rows.iter().map(|r| ([r.x, r.y], r.v)).collect(),
        returns: out.rows.iter().zip(&out.scans).flat_map(|(r, s)| returns(r, s, lidar)).collect(),
        goal,
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

/// The valid returns of `scan` taken at `row`'s pose by a sensor mounted as `lidar` says, in
/// the odometry frame.
fn returns<'a>(
    row: &'a CommandRow,
    scan: &'a ros::LaserScan,
    lidar: &'a SensorSetup,
) -> impl Iterator<Item = [f64; 2]> + 'a {
    let (c, s) = (row.yaw.cos(), row.yaw.sin());
    let sensor = [row.x + c * lidar.x - s * lidar.y, row.y + s * lidar.x + c * lidar.y];
    let (lo, hi) = (f64::from(scan.range_min), f64::from(scan.range_max));
    scan.ranges.iter().enumerate().filter_map(move |(j, &r)| {
        let r = f64::from(r);
        let a = row.yaw
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
