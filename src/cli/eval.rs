//! `dvnav eval`: a checkpoint on the training rooms (routes and random episodes), the gate test
//! or the dynamic scenario; a table or JSON, and optionally MCAP + CSV and a trajectory figure.
//! The evaluation itself is [`dvnav_eval`].

use super::eval_out::{self, Rows};
use clap::{Args, ValueEnum};
use dvnav_config::Config;
use dvnav_eval::episode_log::LogMetadata;
use dvnav_eval::{
    EvalLogger, GATE_RADII, GateGeometry, RunOptions, TRAINING_ROUTE, Task, parse_radii,
    robot_results, robot_tasks, room_summaries, room_tasks, run_tasks, training_tasks,
};
use dvnav_nav::dvst::{Dvst, MetaRobot, VariedRobot};
use dvnav_nav::policy::{MetaAgent, NavPolicy};
use dvnav_sim::{Footprint, Room};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Evaluate a policy checkpoint: success / collision / timeout rates, the paper's score S and
/// time to goal per room, the evaluation routes, the gate test (which way each robot size
/// went) or the dynamic scenario.
/// `--tasks long`'s step-limit factor ([`dvnav_sim::subgoal::SubgoalConfig::time_limit_factor`]):
/// the slack the paper's 400 steps leave a 10 m path in its rooms.
const LONG_TASK_TIME_LIMIT_FACTOR: f64 = 4.0;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A checkpoint directory (`RUN/checkpoints/ckpt-N`), a model directory, or a
    /// `policy.safetensors` file; the `config.toml` beside it (else the defaults) gives the
    /// network and the simulator's constants.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// training: Env_0..Env_3 (routes and random episodes); gate: the gate test, one robot per
    /// radius; dynamic: obstacles appear on the route, one robot per radius.
    #[arg(long, value_enum, default_value_t = Scenario::Training)]
    pub scenario: Scenario,
    /// Evaluate in these rooms instead of a scenario's: random episodes (--episodes) in each,
    /// for every robot of --radii or --footprint (through DVST by default), or the checkpoint's
    /// own robot. A built-in room name, a generated room (`generated:corridors:9001`), a room
    /// file (`.toml`) or an occupancy-grid map (`.yaml`, `.png`, `.pgm`); repeatable.
    #[arg(long, value_name = "NAME|FILE|MAP")]
    pub room: Vec<String>,
    /// With `--scenario generated`: the generator kind (clutter, corridors, rooms, paper, walls).
    #[arg(long, value_name = "KIND")]
    pub kind: Option<String>,
    /// With `--scenario generated`: generator seeds A:B (A included, B excluded), one room
    /// each.
    #[arg(long, value_name = "A:B")]
    pub seeds: Option<String>,
    /// Random episodes per room (training scenario and --room), seeded by --seed.
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Robot radii START:STOP:STEP in metres, both ends included (gate: default
    /// 0.20:0.75:0.05, the paper's twelve robots; dynamic: default 0.2:0.6:0.2).
    #[arg(long, value_parser = parse_radii_arg)]
    pub radii: Option<Radii>,
    /// Gate and dynamic scenarios: drive these robots instead of circles (footprint files as
    /// `dvnav transfer` reads them: any shape, cargo, margin, own velocity bounds; repeatable).
    /// Reports give each robot's bounding radius.
    #[arg(long, value_name = "FILE", conflicts_with = "radii")]
    pub footprint: Vec<PathBuf>,
    /// Seed of the random episodes' starts and goals.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// How a robot of another size is driven (gate, dynamic): through DVST (design §5), by
    /// the plain meta agent as if it were the meta robot, or with its own radius as the
    /// policy's input. Default: `radius` for a checkpoint trained with the radius input
    /// (`env.radius_input`, the SAC_RI baseline), `dvst` otherwise.
    #[arg(long, value_enum)]
    pub transfer: Option<Transfer>,
    /// DVST safety margin (m): the scaled robot covers the robot inflated by this much (the
    /// paper inflates its real robots' radii by 0.03 m). Default: 0 for circles, a footprint
    /// file's own `margin`.
    #[arg(long)]
    pub margin: Option<f64>,
    /// Print JSON: one object per room (training, dynamic) or per robot (gate).
    #[arg(long)]
    pub json: bool,
    /// Write every evaluation episode to MCAP (`DIR/eval-NNNNN.mcap`), one CSV row per episode
    /// (`DIR/episodes.csv`) and the report (`DIR/summary.json`).
    #[arg(long, value_name = "DIR")]
    pub out_dir: Option<PathBuf>,
    /// Draw every trajectory over its room (one panel per room) into this PNG.
    #[arg(long, value_name = "PNG")]
    pub out: Option<PathBuf>,
    /// LiDAR range noise σ (m) for this evaluation (default: none, whatever the checkpoint
    /// trained with; `[env.robustness]` of the checkpoint's config is never used here).
    #[arg(long, value_name = "SIGMA", default_value_t = 0.0)]
    pub noise_std: f64,
    /// Share of LiDAR beams that drop out of every scan (read range_max or 0).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    pub dropout: f64,
    /// Cycles of observation latency: the policy sees the observation of K cycles ago.
    #[arg(long, value_name = "K", default_value_t = 0)]
    pub latency: u32,
    /// With --latency: carry the delayed scan and goal forward to the robot's pose now by the
    /// commands sent since (`env.latency_compensation`), as a controller that knows its
    /// sensors' delay would.
    #[arg(long)]
    pub latency_compensation: bool,
    /// With --latency: no compensation, whatever the checkpoint's config says (an agent trained
    /// with `env.latency_compensation` is measured with it by default).
    #[arg(long, conflicts_with = "latency_compensation")]
    pub no_latency_compensation: bool,
    /// A collision monitor on the policy's commands (`dvnav_sim::safety`, Nav2's Collision
    /// Monitor in "approach" mode): each command's v is scaled down so that the robot, driving it
    /// for this many seconds, would not reach a return of its observed scan; ω is the policy's.
    /// 0: off.
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    pub safety_horizon: f64,
    /// The stall escape, a recovery behaviour (`dvnav_nav::escape`): a robot that has come no
    /// closer to its goal for this many seconds (by half its radius: 0.1 m for the meta robot)
    /// samples its policy's own noise, tanh(μ + σ·ε), for as long, then drives
    /// deterministically again, and escapes again after as long without progress. Seeded per
    /// episode. 3 s was best on tuning rooms. A robot following a planned path (`--subgoals
    /// planner`) replans after a stall instead. 0: off (the deterministic policy throughout).
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    pub escape_after: f64,
    /// Gaussian actuation noise σ on the executed command: `V,W` (m/s, rad/s).
    #[arg(long, value_name = "V,W", value_parser = parse_pair)]
    pub actuation_noise: Option<[f64; 2]>,
    /// Control-period jitter: each step lasts dt·(1 + u), u uniform in [−J, J].
    #[arg(long, value_name = "J", default_value_t = 0.0)]
    pub dt_jitter: f64,
    /// Random tasks at least this far apart (m; default: the checkpoint's
    /// env.min_start_goal_distance).
    #[arg(long, value_name = "M")]
    pub min_distance: Option<f64>,
    /// Random tasks at most this far apart (m; default: no bound). Local tasks in buildings:
    /// `--min-distance 2 --max-distance 5 --max-path-ratio 1.5`.
    #[arg(long, value_name = "M")]
    pub max_distance: Option<f64>,
    /// Random tasks whose shortest path for the robot is at most this many times the
    /// straight line (default: no bound).
    #[arg(long, value_name = "R")]
    pub max_path_ratio: Option<f64>,
    /// Observe through a real robot's LiDAR: a sensor file (`sensors/*.toml`: readings, field of
    /// view, ranges, noise, how its driver writes "no return", where it sits on the robot). The
    /// simulator produces that sensor's LaserScan at its mounting and resamples it to the meta
    /// agent's beams exactly as `dvnav serve` does. Default: the meta agent's own LiDAR at the
    /// axle centre.
    #[arg(long, value_name = "FILE")]
    pub sensor: Option<PathBuf>,
    /// Random tasks of a kind: `local` (2-5 m apart, path at most 1.5× the straight line: the
    /// held-out suite's local tasks) or `long` (any goal the robot can reach 5-10 m away in a
    /// straight line, however long the way round, no path-ratio bound; followed along a
    /// planned path unless --subgoals none). --min-distance, --max-distance and --max-path-ratio override
    /// the kind's bounds. Default: the checkpoint's own task bounds.
    #[arg(long, value_enum, value_name = "KIND")]
    pub tasks: Option<Tasks>,
    /// `planner`: plan a path for each robot's size and feed the agent a lookahead point on
    /// it as its goal (pure pursuit, replans, the rotation shim); `none`: the agent sees only
    /// the final goal (mapless; with --tasks long the path is still planned, for path_ratio).
    /// Default: planner for long tasks, none otherwise.
    #[arg(long, value_enum, value_name = "MODE")]
    pub subgoals: Option<Subgoals>,
    /// With subgoals: the lookahead L (m) for the meta robot (times μ for other sizes).
    #[arg(long, value_name = "M")]
    pub lookahead: Option<f64>,
    /// With subgoals: no rotation shim (the agent drives from the first cycle after a plan).
    #[arg(long, conflicts_with = "rotation_shim")]
    pub no_rotation_shim: bool,
    /// With subgoals: the rotation shim on whatever the checkpoint's config says (after each
    /// plan the robot turns in place until the subgoal is within `shim_angle_deg`).
    #[arg(long)]
    pub rotation_shim: bool,
    /// With subgoals: clearance (m) the planner keeps beyond the robot's bounding radius
    /// (`[env.subgoals.planner] margin_m`; 0 by default).
    #[arg(long, value_name = "M")]
    pub planner_margin: Option<f64>,
    /// With a planned route: each episode's step limit is at least K times the steps its
    /// planned path takes at v_max (`[env.subgoals] time_limit_factor`). Default: 4 for
    /// --tasks long (a 30 m route through a building gets the time it needs), else the
    /// checkpoint's (0: `env.max_steps` for every episode).
    #[arg(long, value_name = "K")]
    pub time_limit_factor: Option<f64>,
    /// Episodes stepped at once; the policy sees them as one batch.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
}

/// `--tasks`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Tasks {
    /// 2-5 m apart, shortest path at most 1.5× the straight line.
    Local,
    /// At least 5 m apart, any route.
    Long,
}

/// `--subgoals`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Subgoals {
    /// Follow the planner's path by lookahead subgoals.
    Planner,
    /// The final goal only (mapless).
    None,
}

/// Which scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Scenario {
    /// The curriculum rooms: each room's route and random episodes.
    Training,
    /// The gate room, one circular robot per radius.
    Gate,
    /// The dynamic room, one circular robot per radius.
    Dynamic,
    /// Generated rooms (--kind, --seeds): random episodes per room and robot, as --room.
    Generated,
}

impl Scenario {
    fn name(self) -> &'static str {
        match self {
            Scenario::Training => "training",
            Scenario::Gate => "gate",
            Scenario::Dynamic => "dynamic",
            Scenario::Generated => "generated",
        }
    }
}

/// How robots of other sizes are driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Transfer {
    /// Dimension-variable skill transfer around the meta agent.
    Dvst,
    /// The meta agent unchanged.
    None,
    /// The robot's own radius as the policy's extra input, no DVST: checkpoints trained with
    /// `env.radius_input = true` (the environments write each robot's radius after ω).
    Radius,
}

impl Transfer {
    fn name(self) -> &'static str {
        match self {
            Transfer::Dvst => "dvst",
            Transfer::None => "none",
            Transfer::Radius => "radius",
        }
    }

    /// `--transfer`, or its default for the checkpoint: a policy with the radius input is
    /// driven with each robot's radius, one without it cannot be.
    fn for_checkpoint(asked: Option<Transfer>, cfg: &Config) -> anyhow::Result<Transfer> {
        match (asked, cfg.env.radius_input) {
            (None, true) | (Some(Transfer::Radius), true) => Ok(Transfer::Radius),
            (None, false) => Ok(Transfer::Dvst),
            (Some(Transfer::Radius), false) => anyhow::bail!(
                "--transfer radius needs a checkpoint trained with the radius input \
                 (env.radius_input = true in its config.toml)"
            ),
            (Some(t), true) => anyhow::bail!(
                "--transfer {}: this checkpoint takes the robot radius as an input \
                 (env.radius_input = true); it drives each robot with its own radius \
                 (--transfer radius, the default)",
                t.name()
            ),
            (Some(t), false) => Ok(t),
        }
    }
}

fn parse_pair(s: &str) -> Result<[f64; 2], String> {
    let (a, b) = s.split_once(',').ok_or_else(|| format!("`{s}`: expected V,W"))?;
    let num = |x: &str| x.trim().parse::<f64>().map_err(|_| format!("`{x}` is not a number"));
    Ok([num(a)?, num(b)?])
}

/// The simulator's constants for this evaluation: the checkpoint's, with the robustness
/// perturbations of the command line (none by default) instead of any of its training.
fn eval_env(args: &EvalArgs, cfg: &Config) -> anyhow::Result<dvnav_config::EnvConfig> {
    // What only training draws (varied robots, perturbations, subgoal shares) is not an
    // evaluation setting: every episode drives the robot the command names, with the noise,
    // perturbations and subgoals of the command line.
    let mut env = cfg.env.clean();
    env.lidar.noise_std = args.noise_std;
    match args.tasks {
        Some(Tasks::Local) => {
            env.min_start_goal_distance = 2.0;
            env.max_start_goal_distance = 5.0;
            env.max_path_ratio = 1.5;
        }
        Some(Tasks::Long) => {
            env.min_start_goal_distance = 5.0;
            // Building-sized maps have goals 50 m away: beyond T_max at v_max (400 cycles
            // make 40 m). 10 m in a straight line keeps every route drivable in time.
            env.max_start_goal_distance = 10.0;
            env.max_path_ratio = 0.0;
            env.reachable_tasks = true;
        }
        None => {}
    }
    let subgoals = args.subgoals.unwrap_or(match args.tasks {
        Some(Tasks::Long) => Subgoals::Planner,
        _ => Subgoals::None,
    });
    let plan = subgoals == Subgoals::Planner || args.tasks == Some(Tasks::Long);
    env.subgoals = plan.then(|| {
        let base = cfg.env.subgoals.clone().unwrap_or_default();
        dvnav_sim::subgoal::SubgoalConfig {
            follow: subgoals == Subgoals::Planner,
            // A run's mixed training share is not an evaluation setting: every task the same way.
            follow_share: 1.0,
            lookahead_m: args.lookahead.unwrap_or(base.lookahead_m),
            rotation_shim: (base.rotation_shim || args.rotation_shim) && !args.no_rotation_shim,
            planner: dvnav_sim::planner::PlannerConfig {
                margin_m: args.planner_margin.unwrap_or(base.planner.margin_m),
                ..base.planner.clone()
            },
            time_limit_factor: args.time_limit_factor.unwrap_or(
                if args.tasks == Some(Tasks::Long) && base.time_limit_factor == 0.0 {
                    LONG_TASK_TIME_LIMIT_FACTOR
                } else {
                    base.time_limit_factor
                },
            ),
            ..base
        }
    });
    anyhow::ensure!(
        plan || (args.lookahead.is_none()
            && !args.no_rotation_shim
            && !args.rotation_shim
            && args.planner_margin.is_none()
            && args.time_limit_factor.is_none()),
        "--lookahead, --rotation-shim, --no-rotation-shim, --planner-margin and --time-limit-factor \
         are for \
         --subgoals planner (or --tasks long)"
    );
    if let Some(s) = &env.subgoals {
        s.check().map_err(|(k, r)| {
            let k = if k.ends_with("lookahead_m") {
                "--lookahead".to_string()
            } else if k.ends_with("planner.margin_m") {
                "--planner-margin".to_string()
            } else if k.ends_with("time_limit_factor") {
                "--time-limit-factor".to_string()
            } else {
                k
            };
            anyhow::anyhow!("{k}: {r}")
        })?;
    }
    if let Some(d) = args.min_distance {
        env.min_start_goal_distance = d;
    }
    if let Some(d) = args.max_distance {
        env.max_start_goal_distance = d;
    }
    if let Some(r) = args.max_path_ratio {
        env.max_path_ratio = r;
    }
    anyhow::ensure!(
        env.min_start_goal_distance >= 0.0
            && (env.max_start_goal_distance == 0.0
                || env.max_start_goal_distance >= env.min_start_goal_distance),
        "--max-distance ({}) must not be below --min-distance ({})",
        env.max_start_goal_distance,
        env.min_start_goal_distance
    );
    anyhow::ensure!(
        env.max_path_ratio == 0.0 || env.max_path_ratio >= 1.0,
        "--max-path-ratio must be at least 1 (a path is never shorter than the straight line)"
    );
    if let Some(path) = &args.sensor {
        env.sensor = Some(dvnav_sim::SensorSpec::load(path)?);
    }
    env.robustness = dvnav_sim::RobustnessConfig {
        beam_dropout: args.dropout,
        latency_steps: args.latency,
        actuation_noise_std: args.actuation_noise.unwrap_or([0.0, 0.0]),
        dt_jitter: args.dt_jitter,
        randomize: None,
    };
    anyhow::ensure!(
        !args.latency_compensation || args.latency > 0,
        "--latency-compensation carries a delayed observation forward: it needs --latency K \
         (K ≥ 1 cycles)"
    );
    env.latency_compensation =
        (env.latency_compensation || args.latency_compensation) && !args.no_latency_compensation;
    anyhow::ensure!(
        args.noise_std.is_finite() && args.noise_std >= 0.0,
        "--noise-std must be a σ of at least 0 m, not {}",
        args.noise_std
    );
    let flag = |k: &str| match k {
        "beam_dropout" => "--dropout",
        "latency_steps" => "--latency",
        "actuation_noise_std" => "--actuation-noise",
        _ => "--dt-jitter",
    };
    env.robustness.check().map_err(|(k, r)| anyhow::anyhow!("{}: {r}", flag(&k)))?;
    Ok(env)
}

/// A simulated sensor must sit within every robot it is mounted on: outside, it could see
/// from inside a wall.
fn check_sensor_mount(
    sensor: &dvnav_sim::SensorSpec,
    tasks: &[Task],
    default_radius: f64,
) -> anyhow::Result<()> {
    let offset = sensor.x.hypot(sensor.y);
    for t in tasks {
        let r = t.radius.unwrap_or(default_radius);
        anyhow::ensure!(
            offset < r,
            "--sensor: the sensor sits {offset:.3} m from the axle centre, outside the robot of \
             radius {r} m; mount it within the robot's body (its x and y)"
        );
    }
    Ok(())
}

/// Parsed `--radii`.
#[derive(Clone, Debug)]
pub struct Radii(pub Vec<f64>);

fn parse_radii_arg(s: &str) -> Result<Radii, String> {
    parse_radii(s).map(Radii).map_err(|e| e.to_string())
}

/// Reads the policy weights and the configuration of a checkpoint, and checks that they make a
/// policy.
fn load_checkpoint(path: &Path) -> anyhow::Result<(Vec<u8>, Config)> {
    let file = dvnav_nav::policy::read_policy(path)?;
    MetaAgent::from_policy_file(&file)?;
    Ok((file.weights, file.config))
}

/// The one place that decides what drives a robot of radius `radius`: the meta agent wrapped
/// in DVST for that robot (μ = radius / meta radius), the plain meta agent, or (`Radius`) the
/// agent of a radius-input checkpoint, which reads the robot's radius from its observation:
/// the environments of the checkpoint's `env` config write it after ω, taken from the robot
/// they simulate, so the radius seen is always that robot's own. Returns the policy and μ.
fn robot_policy(
    weights: &[u8],
    cfg: &Config,
    robot: Option<&VariedRobot>,
    radius: f64,
    transfer: Transfer,
    margin: Option<f64>,
) -> anyhow::Result<(Box<dyn NavPolicy>, f64)> {
    let agent = MetaAgent::from_safetensors(weights, cfg)?;
    match transfer {
        Transfer::None | Transfer::Radius => {
            anyhow::ensure!(
                (transfer == Transfer::Radius) == cfg.env.radius_input,
                "--transfer {} does not fit a checkpoint with env.radius_input = {}",
                transfer.name(),
                cfg.env.radius_input
            );
            Ok((Box::new(agent), 1.0))
        }
        Transfer::Dvst => {
            let meta = MetaRobot::trained(&cfg.env)?;
            let mut robot = robot.cloned().unwrap_or_else(|| VariedRobot {
                meta,
                ..VariedRobot::new(Footprint::circle(radius))
            });
            if let Some(m) = margin {
                robot.margin = m;
            }
            let dvst = Dvst::for_run(agent, &cfg.env, robot)?;
            let mu = dvst.mu();
            Ok((Box::new(dvst), mu))
        }
    }
}

/// The robots of `--footprint`, in order.
fn load_robots(files: &[PathBuf]) -> anyhow::Result<Vec<VariedRobot>> {
    files.iter().map(|f| VariedRobot::load(f).map_err(anyhow::Error::from)).collect()
}

/// The scenario's tasks, and the room each group of results is drawn in.
fn tasks(args: &EvalArgs, cfg: &Config) -> anyhow::Result<Vec<Task>> {
    if let Some(rooms) = room_list(args)? {
        let mut loaded = Vec::new();
        for name in &rooms {
            loaded.extend(Room::load(name)?);
        }
        let robots: Vec<Option<(Footprint, f64)>> = if !args.footprint.is_empty() {
            load_robots(&args.footprint)?
                .into_iter()
                .map(|r| {
                    let radius = r.footprint.bounding_radius();
                    Some((r.footprint, radius))
                })
                .collect()
        } else if let Some(r) = &args.radii {
            r.0.iter().map(|&r| Some((Footprint::circle(r), r))).collect()
        } else {
            vec![None]
        };
        return Ok(room_tasks(&loaded, &robots, args.episodes, args.seed));
    }
    Ok(match args.scenario {
        Scenario::Generated => unreachable!("room_list names the generated rooms"),
        Scenario::Training => {
            // Each curriculum stage: its room, or four representatives of a room set.
            let mut rooms = Vec::new();
            for stage in &cfg.curriculum.rooms {
                let set = dvnav_sim::room_set::RoomSet::parse(stage)?;
                let names = if set.is_single() { vec![stage.clone()] } else { set.sample(4) };
                for name in names {
                    rooms.extend(Room::load(&name)?);
                }
            }
            training_tasks(&rooms, TRAINING_ROUTE, args.episodes, args.seed)
        }
        Scenario::Gate | Scenario::Dynamic => {
            let name = args.scenario.name();
            let room = Room::builtin(name)?;
            let route = room
                .spec()
                .route(name)
                .ok_or_else(|| anyhow::anyhow!("room `{name}` has no route `{name}`"))?
                .clone();
            let default = if args.scenario == Scenario::Gate { GATE_RADII } else { "0.2:0.6:0.2" };
            let radii = match &args.radii {
                Some(r) => r.0.clone(),
                None => parse_radii(default)?,
            };
            if !args.footprint.is_empty() {
                let robots = load_robots(&args.footprint)?;
                let radii: Vec<f64> =
                    robots.iter().map(|r| r.footprint.bounding_radius()).collect();
                let mut tasks = robot_tasks(&room, &route, &radii, args.seed);
                for (t, r) in tasks.iter_mut().zip(robots) {
                    t.footprint = Some(r.footprint);
                }
                return Ok(tasks);
            }
            if let Some(r) = radii.iter().find(|&&r| 2.0 * r >= room.side()) {
                anyhow::bail!(
                    "a robot of radius {r} m does not fit the {0}x{0} m room",
                    room.side()
                );
            }
            robot_tasks(&room, &route, &radii, args.seed)
        }
    })
}

/// The rooms of `--room`, or of `--scenario generated --kind K --seeds A:B`; `None` for the
/// other scenarios.
fn room_list(args: &EvalArgs) -> anyhow::Result<Option<Vec<String>>> {
    if args.scenario == Scenario::Generated {
        anyhow::ensure!(args.room.is_empty(), "--room and --scenario generated exclude each other");
        let kind = args.kind.as_deref().ok_or_else(|| {
            anyhow::anyhow!(
                "--scenario generated needs --kind (one of {})",
                dvnav_sim::generate::KINDS.join(", ")
            )
        })?;
        let seeds = args.seeds.as_deref().unwrap_or("9000:9010");
        let (a, b) = seeds
            .split_once(':')
            .and_then(|(a, b)| Some((a.parse::<u64>().ok()?, b.parse::<u64>().ok()?)))
            .filter(|(a, b)| a < b)
            .ok_or_else(|| {
                anyhow::anyhow!("--seeds `{seeds}`: expected A:B with A < B, e.g. 9000:9010")
            })?;
        return Ok(Some((a..b).map(|s| format!("generated:{kind}:{s}")).collect()));
    }
    anyhow::ensure!(
        args.kind.is_none() && args.seeds.is_none(),
        "--kind and --seeds are for --scenario generated"
    );
    if args.room.is_empty() {
        return Ok(None);
    }
    anyhow::ensure!(
        args.scenario == Scenario::Training,
        "--room replaces the scenario's rooms; leave out --scenario {}",
        args.scenario.name()
    );
    Ok(Some(args.room.clone()))
}

/// Runs `dvnav eval`.
pub fn run(args: EvalArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.batch > 0, "--batch must be at least 1");
    anyhow::ensure!(
        args.margin.is_none_or(|m| m.is_finite() && m >= 0.0),
        "--margin must be a length of at least 0 m, not {:?}",
        args.margin
    );
    let in_rooms = room_list(&args)?.is_some();
    anyhow::ensure!(
        args.footprint.is_empty() || args.scenario != Scenario::Training || in_rooms,
        "--footprint is for the gate and dynamic scenarios and for --room"
    );
    let robots = load_robots(&args.footprint)?;
    if args.scenario == Scenario::Training && args.radii.is_some() && !in_rooms {
        anyhow::bail!("--radii is for the gate and dynamic scenarios and for --room");
    }
    let started = Instant::now();
    let (weights, cfg) = load_checkpoint(&args.checkpoint)?;
    let transfer = Transfer::for_checkpoint(args.transfer, &cfg)?;
    let tasks = tasks(&args, &cfg)?;
    // Policies: one shared meta agent (one batch) for training, one per robot otherwise.
    let mut owned: Vec<Box<dyn NavPolicy>> = Vec::new();
    let mut mus = Vec::new();
    match args.scenario {
        _ if in_rooms => {
            // One policy per robot (tasks[..].policy indexes them), in robot order.
            let mut seen = Vec::new();
            for t in &tasks {
                if seen.contains(&t.policy) {
                    continue;
                }
                seen.push(t.policy);
                if t.radius.is_none() {
                    owned.push(Box::new(MetaAgent::from_safetensors(&weights, &cfg)?));
                    mus.push(1.0);
                    continue;
                }
                let (p, mu) = robot_policy(
                    &weights,
                    &cfg,
                    robots.get(t.policy),
                    t.radius.unwrap_or(cfg.env.robot_radius),
                    transfer,
                    args.margin,
                )?;
                owned.push(p);
                mus.push(mu);
            }
        }
        Scenario::Training => owned.push(Box::new(MetaAgent::from_safetensors(&weights, &cfg)?)),
        Scenario::Gate | Scenario::Dynamic | Scenario::Generated => {
            for t in &tasks {
                let robot = robots.get(t.policy);
                let (p, mu) = robot_policy(
                    &weights,
                    &cfg,
                    robot,
                    t.radius.unwrap_or(cfg.env.robot_radius),
                    transfer,
                    args.margin,
                )?;
                owned.push(p);
                mus.push(mu);
            }
        }
    }
    let mut policies: Vec<&mut dyn NavPolicy> =
        owned.iter_mut().map(|p| p.as_mut() as &mut dyn NavPolicy).collect();

    let mut logger = match &args.out_dir {
        Some(dir) => {
            let meta = LogMetadata {
                run_id: format!("eval-{}", args.scenario.name()),
                config_hash: cfg.hash_hex(),
                seed: args.seed,
                ..Default::default()
            };
            Some(EvalLogger::create(dir, "eval", "eval", meta, cfg.logging.episodes_per_file)?)
        }
        None => None,
    };
    let groups = eval_out::group_index(&tasks);
    let total = tasks.len();
    let mut finished = 0;
    let mut last_report = Instant::now();
    eprintln!(
        "dvnav eval: {} scenario, {total} {} from {}",
        args.scenario.name(),
        if args.scenario == Scenario::Training { "routes and episodes" } else { "robots" },
        args.checkpoint.display()
    );
    anyhow::ensure!(
        args.safety_horizon.is_finite() && args.safety_horizon >= 0.0,
        "--safety-horizon must be a time of at least 0 s, not {}",
        args.safety_horizon
    );
    anyhow::ensure!(
        args.escape_after.is_finite() && args.escape_after >= 0.0,
        "--escape-after must be a time of at least 0 s (0: off), not {}",
        args.escape_after
    );
    let opts = RunOptions {
        window: args.batch,
        samples: logger.is_some(),
        safety_horizon_s: args.safety_horizon,
        escape_after_s: args.escape_after,
    };
    let env_cfg = eval_env(&args, &cfg)?;
    if let Some(s) = &env_cfg.sensor {
        check_sensor_mount(s, &tasks, cfg.env.robot_radius)?;
        eprintln!(
            "dvnav eval: observing through {} ({} readings over {}°, {}-{} m, σ {} m) at \
             x {} m, y {} m, yaw {} rad",
            if s.name.is_empty() { "the sensor" } else { &s.name },
            s.beams,
            s.fov_deg,
            s.range_min,
            s.range_max,
            s.noise_std,
            s.x,
            s.y,
            s.yaw
        );
    }
    let results = run_tasks(&tasks, &env_cfg, &mut policies, opts, &mut |task, done| {
        if let Some(l) = logger.as_mut() {
            l.log(task, groups[done.job] as u32, &done)?;
        }
        if done.job_done {
            finished += 1;
            if last_report.elapsed().as_secs_f64() >= 2.0 {
                eprintln!(
                    "dvnav eval: {finished}/{total} done ({:.0} s)",
                    started.elapsed().as_secs_f64()
                );
                last_report = Instant::now();
            }
        }
        Ok(())
    })?;
    if let Some(l) = logger {
        l.close()?;
    }

    let rows = match args.scenario {
        Scenario::Gate => {
            let room = tasks[0].room.clone();
            let route = room.spec().route("gate").expect("checked above").clone();
            let geometry = GateGeometry::from_room(room.spec(), &route)?;
            Rows::Robots(eval_out::gate_rows(
                robot_results(&tasks, &results, &geometry),
                &mus,
                transfer.name(),
            ))
        }
        Scenario::Training | Scenario::Dynamic | Scenario::Generated => {
            Rows::Rooms(room_summaries(&tasks, &results))
        }
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        // One μ per row: the policy of the row's robot (rows are per room and robot).
        let row_mus: Vec<f64> = match &rows {
            Rows::Rooms(rooms) if in_rooms => rooms
                .iter()
                .map(|r| {
                    tasks
                        .iter()
                        .find(|t| t.room.name() == r.room && t.radius == r.radius)
                        .and_then(|t| mus.get(t.policy).copied())
                        .unwrap_or(f64::NAN)
                })
                .collect(),
            _ => mus.clone(),
        };
        eval_out::print_table(&rows, &row_mus);
    }
    if let Some(dir) = &args.out_dir {
        eval_out::write_csv(&dir.join("episodes.csv"), args.scenario.name(), &tasks, &results)?;
        std::fs::write(dir.join("summary.json"), serde_json::to_vec_pretty(&rows)?)?;
        eprintln!("dvnav eval: episodes in {}", dir.display());
    }
    if let Some(png) = &args.out {
        eval_out::draw(png, &tasks, &results, &cfg.env)?;
        eprintln!("dvnav eval: trajectories in {}", png.display());
    }
    eprintln!("dvnav eval: {total} done in {:.1} s", started.elapsed().as_secs_f64());
    Ok(ExitCode::SUCCESS)
}
