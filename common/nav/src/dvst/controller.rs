//! [`DvstController`]: what `dvnav serve` does, without the network. Robots send their scan,
//! goal and velocity each control cycle ([`RobotInput`]) and get the meta agent's command
//! through DVST back ([`Command`]); each robot, by its id, has its own footprint, which can
//! change at run time ([`DvstController::set_footprint_toml`]).
//!
//! One meta agent drives every robot. A request is checked whole before anything else (a
//! malformed one never reaches the policy, and every field is bounded so that no valid request
//! can overflow the policy's f32 arithmetic); the robot's footprint state is an immutable
//! snapshot swapped whole by a footprint change, so every command is computed wholly with the
//! old footprint or wholly with the new one, and says which ([`Command::footprint_version`]).
//! Robots are held in a bounded [`RobotTable`]: an id never seen, or one silent for longer than
//! the idle time, drives with the server's default footprint.
//!
//! The meta robot is the one the model was trained as (its run configuration's
//! `env.robot_radius` or `env.footprint`): a footprint file that leaves `[meta]` out gets it,
//! one whose `[meta]` says otherwise is refused, since DVST's μ would then be computed for a
//! robot the agent never was.
//!
//! ```no_run
//! use dvnav_nav::dvst::controller::{DvstController, ModelId, RobotInput, Scan};
//! use dvnav_nav::policy::MetaAgent;
//! # fn main() -> anyhow::Result<()> {
//! let (agent, cfg) = MetaAgent::load("models/meta-r0.2".as_ref())?;
//! let toml = std::fs::read_to_string("footprints/paper-medium.toml")?;
//! let model = ModelId { name: "meta-r0.2".into(), version: "unversioned".into() };
//! let ctl = DvstController::new(agent, &cfg, model, &toml, "paper-medium.toml", None)?;
//! let scan = vec![10.0; ctl.beams()];
//! let input = RobotInput::new(Scan::Meta(&scan), 2.0, 0.3, 0.0, 0.0);
//! let command = ctl.act(&input)?;
//! println!("v = {:.3} m/s, ω = {:.3} rad/s at μ = {}", command.v, command.omega, command.mu);
//! # Ok(())
//! # }
//! ```

use super::footprint_file::VariedRobot;
use super::laser_scan::{self, BeamLayout, LaserScan, MAX_RANGE_M};
use super::robots::{RobotTable, TableFull};
use super::route::{PlanMap, RobotRoute, RouteRefusal, RouteStatus, check_pose, check_route};
use super::scale::MetaRobot;
use super::shared_policy::{Reply, SharedPolicy};
use super::transfer::{VelocityBounds, transfer_observation, transfer_policy};
use crate::escape::StallEscape;
use crate::policy::NavPolicy;
use dvnav_config::Config;
use dvnav_sim::latency::{self, CommandLog, MAX_SCAN_AGE_S};
use dvnav_sim::obs::{ANGULAR_VELOCITY, GOAL_ANGLE, GOAL_DISTANCE, LINEAR_VELOCITY, obs_dim};
use dvnav_sim::safety;
use dvnav_sim::subgoal::SubgoalConfig;
use dvnav_sim::{Pose2, SpecFileError};
use std::f64::consts::{PI, TAU};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

/// The fastest a robot may say it moves (m/s), and turns (rad/s): far beyond any ground robot,
/// well within f32.
pub const MAX_SPEED: f64 = 1.0e3;
/// The largest goal bearing (rad) accepted before wrapping.
pub const MAX_GOAL_ANGLE: f64 = 1.0e6;
/// The longest robot id (bytes).
pub const MAX_ROBOT_ID: usize = 128;
/// The longest footprint file (bytes).
pub const MAX_FOOTPRINT_TOML: usize = 64 * 1024;
/// Robots one controller drives at once, by default.
pub const DEFAULT_MAX_ROBOTS: usize = 256;
/// How long a robot may be silent before its place and footprint are dropped, by default.
pub const DEFAULT_ROBOT_IDLE: Duration = Duration::from_secs(600);
/// Forward passes [`DvstController::warm_up`] runs: the first pays the first-use costs, the
/// next ones settle the allocator.
const WARM_UP_PASSES: usize = 3;

/// FNV-1a's offset basis and prime: a robot's stall-escape seed is the FNV-1a hash of its id.
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// The model a controller drives with, as it reports it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelId {
    /// A name for people: the model or checkpoint directory.
    pub name: String,
    /// What tells two models apart: a fingerprint of the weights.
    pub version: String,
}

/// A robot's scan, in one of two forms.
#[derive(Clone, Copy, Debug)]
pub enum Scan<'a> {
    /// Ranges (m) already in the meta agent's beam layout ([`dvnav_sim::Lidar`]) from the axle
    /// centre: finite, ≥ 0, exactly [`DvstController::beams`] of them.
    Meta(&'a [f32]),
    /// Any LiDAR's scan as ROS describes it, resampled with the robot's
    /// [`super::SensorSetup`] ([`laser_scan`]).
    Laser(LaserScan<'a>),
}

/// One control cycle's observation, as the robot measures it (physical units, robot frame).
#[derive(Clone, Copy, Debug)]
pub struct RobotInput<'a> {
    /// What its LiDAR sees.
    pub scan: Scan<'a>,
    /// Distance to the goal (m), ≥ 0.
    pub goal_distance: f64,
    /// Bearing of the goal (rad, left positive); an angle outside [−π, π] is wrapped into it.
    pub goal_angle: f64,
    /// Current linear velocity (m/s).
    pub v: f64,
    /// Current angular velocity (rad/s).
    pub omega: f64,
    /// Which robot: its footprint is looked up by this id ("" is a robot like any other).
    pub robot_id: &'a str,
    /// The footprint version the robot believes it drives with; a command for another one is
    /// refused ([`ControllerError::FootprintChanged`]). `None`: any.
    pub expected_footprint_version: Option<u64>,
    /// The robot's pose in its route's frame: needed while it follows a route
    /// ([`DvstController::set_route`]), when the goal fields are not read.
    pub pose: Option<Pose2>,
    /// How long ago (s) the scan and the goal were measured, 0 to [`MAX_SCAN_AGE_S`]: above 0,
    /// the controller carries them forward to now by the commands it sent this robot since
    /// ([`dvnav_sim::latency`]). A route's pose is taken as now.
    pub scan_age_s: f64,
}

impl<'a> RobotInput<'a> {
    /// An input of robot "" that accepts any footprint version.
    pub fn new(scan: Scan<'a>, goal_distance: f64, goal_angle: f64, v: f64, omega: f64) -> Self {
        RobotInput {
            scan,
            goal_distance,
            goal_angle,
            v,
            omega,
            robot_id: "",
            expected_footprint_version: None,
            pose: None,
            scan_age_s: 0.0,
        }
    }
}

/// The answer to one [`RobotInput`].
#[derive(Clone, Debug, PartialEq)]
pub struct Command {
    /// Linear velocity (m/s), within the robot's bounds; 0 once arrived.
    pub v: f64,
    /// Angular velocity (rad/s), within the robot's bounds; 0 once arrived.
    pub omega: f64,
    /// The robot is within `goal_tolerance` of its goal.
    pub arrived: bool,
    /// The robot's [`FootprintState::goal_tolerance`] (m).
    pub goal_tolerance: f64,
    /// Meta beams no valid reading of a `LaserScan` reached (0 for the meta form).
    pub filled_beams: usize,
    /// The μ it was computed with.
    pub mu: f64,
    /// The footprint's name.
    pub footprint: String,
    /// Which footprint it was computed with ([`FootprintState::version`]).
    pub footprint_version: u64,
    /// While the robot follows a route: the subgoal given and the path left.
    pub route: Option<RouteStatus>,
}

/// A route as the controller took it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RouteSet {
    /// Poses in it.
    pub poses: usize,
    /// Its length (m).
    pub length_m: f64,
    /// The robot's lookahead (m): the meta agent's times the robot's μ.
    pub lookahead_m: f64,
}

/// A robot's footprint as a controller drives it: one immutable snapshot.
#[derive(Clone, Debug, PartialEq)]
pub struct FootprintState {
    /// The varied robot, as its file describes it (with the controller's margin, if one was
    /// forced, and the model's meta robot).
    pub robot: VariedRobot,
    /// Its μ.
    pub mu: f64,
    /// The dimension-scaled robot the meta agent drives.
    pub scaled: MetaRobot,
    /// The bounds commands stay within: the robot's own, else the meta agent's.
    pub bounds: VelocityBounds,
    /// The distance (m) within which the robot has arrived: the meta agent's goal tolerance
    /// scaled by μ, as the meta agent sees it.
    pub goal_tolerance: f64,
    /// 1 for the server's default footprint; every footprint change gets a new number, never
    /// used before by this server.
    pub version: u64,
}

/// What a controller expects and drives with, for one robot.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerInfo {
    /// Scan length the meta form of a request must carry.
    pub beams: usize,
    /// The meta agent's LiDAR field of view (degrees).
    pub fov_deg: f64,
    /// The meta agent's LiDAR range `[min, max]` (m): transferred scans are clamped to it.
    pub scan_range: [f64; 2],
    /// The control period the meta agent was trained at (s).
    pub control_period_s: f64,
    /// The meta agent's velocity bounds.
    pub meta_bounds: VelocityBounds,
    /// The robot asked about (its own footprint, else the default).
    pub footprint: FootprintState,
    /// The model.
    pub model: ModelId,
    /// Commands answered so far (all robots).
    pub commands: u64,
    /// Robots active now, at most `max_robots`, each dropped after `robot_idle` silent.
    pub robots: usize,
    /// See `robots`.
    pub max_robots: usize,
    /// See `robots`.
    pub robot_idle: Duration,
    /// The collision monitor's horizon (s; 0: off), [`DvstController::with_safety_horizon`].
    pub safety_horizon_s: f64,
    /// The stall escape's delay (s; 0: off), [`DvstController::with_stall_escape`].
    pub escape_after_s: f64,
}

/// Why a request was refused.
#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    /// A request field is missing, malformed or out of range; nothing changed.
    #[error("`{field}`: {reason}")]
    InvalidArgument {
        /// The request field, e.g. `scan[17]` or `footprint_toml`.
        field: String,
        /// What is wrong with it.
        reason: String,
    },
    /// No room for another robot.
    #[error(transparent)]
    TooManyRobots(#[from] TableFull),
    /// The robot's footprint is not the one it expected (its session expired, or another
    /// caller changed it): no command was computed.
    #[error(
        "robot `{robot}` drives with footprint version {current}, not {expected}; set its \
         footprint again (SetFootprint) or expect version {current}"
    )]
    FootprintChanged {
        /// The robot id.
        robot: String,
        /// The version the request expected.
        expected: u64,
        /// The robot's version now.
        current: u64,
    },
    /// The policy failed on a valid request.
    #[error("the policy failed: {0:#}")]
    Policy(anyhow::Error),
    /// A goal to plan for, but no map to plan on.
    #[error("no map to plan on: send one with SetMap first (or the route itself with SetRoute)")]
    NoMap,
}

impl From<RouteRefusal> for ControllerError {
    fn from(r: RouteRefusal) -> Self {
        ControllerError::InvalidArgument { field: r.field, reason: r.reason }
    }
}

impl ControllerError {
    fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        ControllerError::InvalidArgument { field: field.into(), reason: reason.into() }
    }
}

/// [`SharedPolicy`] of any policy, so that the controller need not name the policy's type.
trait SharedAct: Send + Sync + std::fmt::Debug {
    fn set_batched(&self, on: bool);
    fn act_blocking(&self, obs: Vec<f32>, noise: Option<[f32; 2]>) -> Reply;
    fn act(
        &self,
        obs: Vec<f32>,
        noise: Option<[f32; 2]>,
    ) -> std::pin::Pin<Box<dyn Future<Output = Reply> + Send + '_>>;
}

impl<P: NavPolicy + Send> SharedAct for SharedPolicy<P> {
    fn set_batched(&self, on: bool) {
        SharedPolicy::set_batched(self, on)
    }
    fn act_blocking(&self, obs: Vec<f32>, noise: Option<[f32; 2]>) -> Reply {
        SharedPolicy::act_blocking(self, obs, noise)
    }
    fn act(
        &self,
        obs: Vec<f32>,
        noise: Option<[f32; 2]>,
    ) -> std::pin::Pin<Box<dyn Future<Output = Reply> + Send + '_>> {
        Box::pin(SharedPolicy::act(self, obs, noise))
    }
}

/// A request checked and carried over to the meta robot, waiting for the policy (or already
/// answered: arrived).
struct Prepared {
    state: Arc<FootprintState>,
    filled_beams: usize,
    /// The meta observation, or `None` once arrived (or held by the rotation shim).
    meta_obs: Option<Vec<f32>>,
    /// While following a route: its status, and the rotation shim's command when it holds
    /// the robot.
    route: Option<RouteStatus>,
    shim: Option<(f64, f64)>,
    /// The commands sent this robot, for latency compensation; the new one joins them.
    log: Arc<Mutex<CommandLog>>,
    /// The meta scan, kept for the collision monitor when it is on.
    monitor_scan: Option<Vec<f32>>,
    /// ε for the stall escape's sampled action, `None` for the deterministic one.
    noise: Option<[f32; 2]>,
}

/// A meta agent driving many varied robots through DVST, shared by the requests of a service.
/// The meta agent is shared by the callers, batching what arrives together
/// ([`SharedPolicy`]).
#[derive(Debug)]
pub struct DvstController {
    policy: Box<dyn SharedAct>,
    robots: Mutex<RobotTable<Arc<FootprintState>>>,
    /// Routes of robots that follow one (`SetRoute`), bounded and expiring like `robots`.
    routes: Mutex<RobotTable<Arc<Mutex<RobotRoute>>>>,
    /// The commands each robot was sent lately (`scan_age_s`), bounded and expiring like
    /// `robots`; times are seconds since `clock`.
    command_logs: Mutex<RobotTable<Arc<Mutex<CommandLog>>>>,
    /// The stall escape's progress watch of each robot driving mapless, when it is on.
    escapes: Mutex<RobotTable<Arc<Mutex<StallEscape>>>>,
    clock: Instant,
    /// The subgoal rule's constants: the model's `env.subgoals`, else the defaults.
    subgoals: SubgoalConfig,
    /// The map `SetGoal` plans on (`SetMap`).
    map: Mutex<Option<Arc<PlanMap>>>,
    /// The robot of `dvnav serve --footprint`: every robot without one of its own.
    default_robot: Arc<FootprintState>,
    next_version: AtomicU64,
    beams: usize,
    fov_deg: f64,
    scan_range: [f64; 2],
    control_period_s: f64,
    /// The meta agent's goal tolerance (m).
    goal_tolerance: f64,
    meta_bounds: VelocityBounds,
    /// The model's meta robot: every footprint gets it.
    meta: MetaRobot,
    /// A margin forced on every footprint (`dvnav serve --margin`), else each file's own.
    margin: Option<f64>,
    model: ModelId,
    commands: AtomicU64,
    /// The collision monitor's horizon (s; 0: off), [`DvstController::with_safety_horizon`].
    safety_horizon_s: f64,
    /// The stall escape's delay (s; 0: off), [`DvstController::with_stall_escape`].
    escape_after_s: f64,
}

impl DvstController {
    /// Drives `policy`, trained with the run configuration `cfg`, for robots of the footprint
    /// file `robot_toml` (`source` names it in errors) unless they set their own. `margin`
    /// replaces the file's margin, here and in every later footprint. Room for
    /// [`DEFAULT_MAX_ROBOTS`] robots ([`with_robot_limits`](Self::with_robot_limits)).
    pub fn new<P: NavPolicy + Send + 'static>(
        policy: P,
        cfg: &Config,
        model: ModelId,
        robot_toml: &str,
        source: &str,
        margin: Option<f64>,
    ) -> anyhow::Result<Self> {
        let lidar = &cfg.env.lidar;
        anyhow::ensure!(
            policy.beams() == lidar.beams,
            "the policy reads {} beams, its configuration says {}",
            policy.beams(),
            lidar.beams
        );
        super::agent::check_standard_observation(&policy)?;
        if let Some(m) = margin {
            anyhow::ensure!(m.is_finite() && m >= 0.0, "the margin must be ≥ 0 m, got {m}");
        }
        let meta = MetaRobot::trained(&cfg.env)?;
        let (v_max, omega_max) = policy.velocity_bounds();
        let meta_bounds = VelocityBounds { v_max, omega_max };
        meta_bounds.validate()?;
        let scan_range = [lidar.range_min, lidar.range_max];
        let robot = robot_from_toml(robot_toml, source, meta, margin)?;
        let default_robot =
            Arc::new(footprint_state(robot, 1, meta_bounds, cfg.env.goal_tolerance)?);
        Ok(Self {
            policy: Box::new(SharedPolicy::new(policy)),
            robots: Mutex::new(RobotTable::new(DEFAULT_MAX_ROBOTS, DEFAULT_ROBOT_IDLE)),
            routes: Mutex::new(RobotTable::new(DEFAULT_MAX_ROBOTS, DEFAULT_ROBOT_IDLE)),
            command_logs: Mutex::new(RobotTable::new(DEFAULT_MAX_ROBOTS, DEFAULT_ROBOT_IDLE)),
            escapes: Mutex::new(RobotTable::new(DEFAULT_MAX_ROBOTS, DEFAULT_ROBOT_IDLE)),
            clock: Instant::now(),
            subgoals: cfg.env.subgoals.clone().unwrap_or_default(),
            map: Mutex::new(None),
            default_robot,
            next_version: AtomicU64::new(2),
            beams: lidar.beams,
            fov_deg: lidar.fov_deg,
            scan_range,
            control_period_s: cfg.env.dt,
            goal_tolerance: cfg.env.goal_tolerance,
            meta_bounds,
            meta,
            margin,
            model,
            commands: AtomicU64::new(0),
            safety_horizon_s: 0.0,
            escape_after_s: 0.0,
        })
    }

    /// At most `max_robots` robots at once, each dropped after `idle` without a call.
    pub fn with_robot_limits(self, max_robots: usize, idle: Duration) -> anyhow::Result<Self> {
        anyhow::ensure!(max_robots > 0, "a controller drives at least one robot");
        anyhow::ensure!(!idle.is_zero(), "the robot idle time must be above 0 s");
        *self.robots.lock().unwrap_or_else(PoisonError::into_inner) =
            RobotTable::new(max_robots, idle);
        *self.routes.lock().unwrap_or_else(PoisonError::into_inner) =
            RobotTable::new(max_robots, idle);
        *self.command_logs.lock().unwrap_or_else(PoisonError::into_inner) =
            RobotTable::new(max_robots, idle);
        *self.escapes.lock().unwrap_or_else(PoisonError::into_inner) =
            RobotTable::new(max_robots, idle);
        Ok(self)
    }

    /// A collision monitor on every command ([`dvnav_sim::safety`], as `dvnav eval
    /// --safety-horizon`): the policy's v is scaled down so that the meta robot's disc (its
    /// bounding disc for a rectangle), driving the command for `horizon_s` seconds, would not
    /// reach a return of the meta scan; ω is the policy's. 0 turns it off.
    pub fn with_safety_horizon(mut self, horizon_s: f64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            horizon_s.is_finite() && horizon_s >= 0.0,
            "the collision monitor's horizon must be a time of at least 0 s, not {horizon_s}"
        );
        self.safety_horizon_s = horizon_s;
        Ok(self)
    }

    /// The stall escape ([`crate::escape`], as `dvnav eval --escape-after`) for robots driving
    /// mapless (no route): one that has come no closer to its goal for `after_s` seconds (by
    /// half the meta robot's radius in the meta frame, μ times that in its own) is sent the
    /// meta policy's sampled action for as long, then the deterministic one again. A goal
    /// distance that jumps further than the robot could drive since its last call is a new
    /// goal. Each robot's noise is seeded by its id, so a replayed log gives the same
    /// commands. 0 turns it off.
    pub fn with_stall_escape(mut self, after_s: f64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            after_s.is_finite() && after_s >= 0.0,
            "the stall escape's delay must be a time of at least 0 s (0: off), not {after_s}"
        );
        self.escape_after_s = after_s;
        Ok(self)
    }

    /// With `on`, robots whose calls arrive together share one forward pass: cheaper per
    /// command under load, but a command then depends in its last bits on the others in its
    /// pass ([`super::shared_policy`]). Off by default: the same robot, observation and
    /// weights give the same command whoever else is served.
    pub fn with_batched_inference(self, on: bool) -> Self {
        self.policy.set_batched(on);
        self
    }

    /// Runs the policy once, on an open room with the goal ahead, so the first robot's first
    /// command does not pay for the forward pass's first-use costs (weights paged in,
    /// buffers allocated): a robot's control loop gives a call a few milliseconds, and a
    /// server should be ready when it says it listens. Counts no command and no robot.
    pub fn warm_up(&self) -> Result<(), ControllerError> {
        let b = self.beams;
        let mut obs = vec![self.scan_range[1] as f32; obs_dim(b)];
        obs[b + GOAL_DISTANCE] = 1.0;
        obs[b + GOAL_ANGLE] = 0.0;
        obs[b + LINEAR_VELOCITY] = 0.0;
        obs[b + ANGULAR_VELOCITY] = 0.0;
        for _ in 0..WARM_UP_PASSES {
            let (v, omega) = self
                .policy
                .act_blocking(obs.clone(), None)
                .map_err(|e| ControllerError::Policy(anyhow::Error::msg(e)))?;
            if !(v.is_finite() && omega.is_finite()) {
                return Err(ControllerError::Policy(anyhow::anyhow!(
                    "the meta policy answered a non-finite command ({v}, {omega}) to an open room"
                )));
            }
        }
        Ok(())
    }

    /// Scan length the meta form of a request must carry.
    pub fn beams(&self) -> usize {
        self.beams
    }

    /// The model it drives with.
    pub fn model(&self) -> &ModelId {
        &self.model
    }

    /// The command for one control cycle. A malformed input is refused, naming the field,
    /// before the policy sees it. Blocks until the policy answers ([`act_async`](Self::act_async)
    /// waits without blocking its thread).
    pub fn act(&self, input: &RobotInput) -> Result<Command, ControllerError> {
        let mut p = self.prepare(input)?;
        let reply = p.meta_obs.take().map(|obs| self.policy.act_blocking(obs, p.noise));
        self.finish(p, reply)
    }

    /// [`act`](Self::act) for an async caller: waits for the policy without blocking the
    /// caller's thread.
    pub async fn act_async(&self, input: &RobotInput<'_>) -> Result<Command, ControllerError> {
        let mut p = self.prepare(input)?;
        let reply = match p.meta_obs.take() {
            None => None,
            Some(obs) => Some(self.policy.act(obs, p.noise).await),
        };
        self.finish(p, reply)
    }

    /// Checks `input`, looks its robot up, resamples its scan and carries the observation over
    /// to the meta robot.
    fn prepare(&self, input: &RobotInput) -> Result<Prepared, ControllerError> {
        self.check(input)?;
        let state =
            self.robots().touch(input.robot_id, Instant::now(), || self.default_robot.clone())?;
        if let Some(expected) = input.expected_footprint_version
            && expected != state.version
        {
            return Err(ControllerError::FootprintChanged {
                robot: input.robot_id.to_string(),
                expected,
                current: state.version,
            });
        }
        let now = Instant::now();
        let log = self.command_logs.lock().unwrap_or_else(PoisonError::into_inner).touch(
            input.robot_id,
            now,
            || Arc::new(Mutex::new(CommandLog::default())),
        )?;
        let b = self.beams;
        let mut obs = vec![0.0f32; obs_dim(b)];
        let filled_beams = match input.scan {
            Scan::Meta(scan) => {
                obs[..b].copy_from_slice(scan);
                0
            }
            Scan::Laser(scan) => {
                let layout = BeamLayout::new(b, self.fov_deg);
                laser_scan::resample(&scan, &state.robot.lidar, layout, &mut obs[..b]).map_err(
                    |e| ControllerError::invalid(format!("laser_scan.{}", e.field), e.reason),
                )?
            }
        };
        let (input_goal_distance, input_goal_angle) = if input.scan_age_s > 0.0 {
            let t = now.duration_since(self.clock).as_secs_f64();
            let moved = log
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .motion_over(t - input.scan_age_s, t);
            self.carry_forward(&mut obs[..b], moved);
            latency::predict_goal(input.goal_distance, input.goal_angle, moved)
        } else {
            (input.goal_distance, input.goal_angle)
        };
        let route = self.follow_route(input, &state, &obs[..b])?;
        let (goal_distance, goal_angle, arrived, shim) = match &route {
            Some(r) => (r.goal_distance, r.goal_angle, r.arrived, r.shim),
            None => (
                input_goal_distance,
                input_goal_angle,
                input_goal_distance <= state.goal_tolerance,
                None,
            ),
        };
        let status = route.map(|r| r.status);
        if arrived || shim.is_some() {
            return Ok(Prepared {
                state,
                filled_beams,
                meta_obs: None,
                route: status,
                shim,
                log,
                monitor_scan: None,
                noise: None,
            });
        }
        obs[b + GOAL_DISTANCE] = goal_distance as f32;
        obs[b + GOAL_ANGLE] = wrap_angle(goal_angle) as f32;
        obs[b + LINEAR_VELOCITY] = input.v as f32;
        obs[b + ANGULAR_VELOCITY] = input.omega as f32;
        let mut meta_obs = vec![0.0f32; obs.len()];
        transfer_observation(&obs, b, state.mu, Some(self.scan_range), &mut meta_obs);
        let monitor_scan = (self.safety_horizon_s > 0.0).then(|| meta_obs[..b].to_vec());
        // A robot on a route replans when it stalls; the escape is for mapless driving, whose
        // goal distance is its progress (a route's subgoal stays a lookahead away).
        let noise = if self.escape_after_s > 0.0 && status.is_none() {
            self.escape_noise(input.robot_id, now, goal_distance, &state)?
        } else {
            None
        };
        Ok(Prepared {
            state,
            filled_beams,
            meta_obs: Some(meta_obs),
            route: status,
            shim: None,
            log,
            monitor_scan,
            noise,
        })
    }

    /// The stall escape's noise for robot `robot_id`, `goal_distance_m` (its own metres) from
    /// its goal `now`.
    fn escape_noise(
        &self,
        robot_id: &str,
        now: Instant,
        goal_distance_m: f64,
        state: &FootprintState,
    ) -> Result<Option<[f32; 2]>, ControllerError> {
        let radius_m = self.meta.bounding_radius() * state.mu;
        let escape = self.escapes.lock().unwrap_or_else(PoisonError::into_inner).touch(
            robot_id,
            now,
            || {
                let seed = robot_id
                    .bytes()
                    .fold(FNV_OFFSET, |h, b| (h ^ b as u64).wrapping_mul(FNV_PRIME));
                let e = StallEscape::for_radius(self.escape_after_s, radius_m, seed)
                    .expect("the delay was checked by with_stall_escape, the progress is > 0");
                Arc::new(Mutex::new(e))
            },
        )?;
        let mut escape = escape.lock().unwrap_or_else(PoisonError::into_inner);
        let t = now.duration_since(self.clock).as_secs_f64();
        escape.follow_goal(t, goal_distance_m, state.bounds.v_max);
        Ok(escape.noise(t, goal_distance_m))
    }

    /// `scan` (the robot's beams in its own metres) as it reads after the robot `moved`.
    fn carry_forward(&self, scan: &mut [f32], moved: Pose2) {
        // A 0 m reading stays an obstacle at the body (1 mm), not the "no return" that a
        // driver's 0.0 means to the resampling.
        let old: Vec<f32> = scan.iter().map(|r| r.max(1e-3)).collect();
        let layout = BeamLayout::new(self.beams, self.fov_deg);
        latency::predict_scan(&old, layout, [1e-3, MAX_RANGE_M], moved, scan);
    }

    /// The robot's route step, if it follows one: the subgoal as its goal, arrival at the
    /// route's goal, the rotation shim. A robot on a route must say where it is.
    fn follow_route(
        &self,
        input: &RobotInput,
        state: &FootprintState,
        scan: &[f32],
    ) -> Result<Option<RouteStep>, ControllerError> {
        let Some(route) = self.routes_table().seen(input.robot_id, Instant::now()) else {
            return Ok(None);
        };
        let pose = input.pose.ok_or_else(|| {
            ControllerError::invalid(
                "pose",
                format!(
                    "robot `{}` follows a route (SetRoute): send its pose in the route's frame \
                     with every Act, or clear the route",
                    input.robot_id
                ),
            )
        })?;
        let mut route = route.lock().unwrap_or_else(PoisonError::into_inner);
        // The scan's returns in the route's frame (its beams in the robot's own metres, before
        // DVST scales them), for a replan after a stall.
        let returns = || {
            let angles = BeamLayout::new(self.beams, self.fov_deg).angles();
            dvnav_sim::scan_points(pose, scan, &angles, self.scan_range[1] as f32)
        };
        let (status, shim) =
            route.step(pose, self.control_period_s, state.bounds.omega_max, returns);
        let goal = route.goal();
        let arrived = (pose.x - goal[0]).hypot(pose.y - goal[1]) <= state.goal_tolerance;
        let [x, y] = pose.to_local(status.subgoal);
        Ok(Some(RouteStep {
            status,
            goal_distance: x.hypot(y),
            goal_angle: y.atan2(x),
            arrived,
            shim: if arrived { None } else { shim },
        }))
    }

    /// Robot `robot_id` follows `points` (its own planner's path, in the frame its `Act` poses
    /// will be in) from now on, replacing any route it had. Refused, naming the field, when a
    /// pose is not finite or out of bounds, or the route is empty or too long.
    pub fn set_route(
        &self,
        robot_id: &str,
        points: Vec<[f64; 2]>,
    ) -> Result<RouteSet, ControllerError> {
        check_robot_id(robot_id)?;
        check_route(&points)?;
        let poses = points.len();
        let mu = self.footprint(robot_id).mu;
        let route = RobotRoute::new(self.subgoals.clone(), mu, points);
        let set = RouteSet { poses, length_m: route.length_m(), lookahead_m: route.lookahead_m() };
        self.routes_table().set(robot_id, Instant::now(), Arc::new(Mutex::new(route)))?;
        Ok(set)
    }

    /// The map `SetGoal` plans on from now on (a map_server YAML and its image's bytes);
    /// robots already on a planned route keep the map they were planned on. Returns it.
    pub fn set_map(&self, map_yaml: &str, image: &[u8]) -> Result<Arc<PlanMap>, ControllerError> {
        let map = Arc::new(PlanMap::from_bytes(map_yaml, image)?);
        *self.map.lock().unwrap_or_else(PoisonError::into_inner) = Some(map.clone());
        Ok(map)
    }

    /// Robot `robot_id`, at `start` on the map (`SetMap`), is sent to `goal`: the server plans
    /// for its footprint (bounding radius plus margin), it follows the path as a route, and
    /// the server replans when it strays or stalls. Refused naming `start` or `goal` when a
    /// point is off the map, in an obstacle or unreachable for the robot's size.
    pub fn set_goal(
        &self,
        robot_id: &str,
        start: Pose2,
        goal: [f64; 2],
    ) -> Result<RouteSet, ControllerError> {
        check_robot_id(robot_id)?;
        fn rename(r: RouteRefusal, field: &str) -> RouteRefusal {
            RouteRefusal { field: r.field.replacen("pose", field, 1), ..r }
        }
        check_pose(start).map_err(|r| rename(r, "start"))?;
        check_pose(Pose2::new(goal[0], goal[1], 0.0)).map_err(|r| rename(r, "goal"))?;
        let map = self.map.lock().unwrap_or_else(PoisonError::into_inner).clone();
        let map = map.ok_or(ControllerError::NoMap)?;
        let fp = self.footprint(robot_id);
        let radius = fp.robot.footprint.bounding_radius() + fp.robot.margin;
        let route =
            RobotRoute::planned(self.subgoals.clone(), fp.mu, map, radius, start.position(), goal)?;
        let set = RouteSet {
            poses: route.pose_count(),
            length_m: route.length_m(),
            lookahead_m: route.lookahead_m(),
        };
        self.routes_table().set(robot_id, Instant::now(), Arc::new(Mutex::new(route)))?;
        Ok(set)
    }

    /// Robot `robot_id` no longer follows a route; says whether it had one.
    pub fn clear_route(&self, robot_id: &str) -> Result<bool, ControllerError> {
        check_robot_id(robot_id)?;
        Ok(self.routes_table().remove(robot_id))
    }

    /// The subgoal rule's constants.
    pub fn subgoal_config(&self) -> &SubgoalConfig {
        &self.subgoals
    }

    fn routes_table(&self) -> MutexGuard<'_, RobotTable<Arc<Mutex<RobotRoute>>>> {
        self.routes.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The command from the meta agent's answer (`None`: arrived, no question asked).
    fn finish(&self, p: Prepared, reply: Option<Reply>) -> Result<Command, ControllerError> {
        let Prepared { state, filled_beams, route, shim, log, monitor_scan, .. } = p;
        let (v, omega, arrived) = match (reply, shim) {
            (None, Some((v, omega))) => (v, omega, false),
            (None, None) => (0.0, 0.0, true),
            (Some(reply), _) => {
                let (v_m, omega_m) =
                    reply.map_err(|e| ControllerError::Policy(anyhow::Error::msg(e)))?;
                if !(v_m.is_finite() && omega_m.is_finite()) {
                    return Err(ControllerError::Policy(anyhow::anyhow!(
                        "the meta policy answered a non-finite command ({v_m}, {omega_m})"
                    )));
                }
                let v_m = match &monitor_scan {
                    Some(scan) => safety::safe_speed(
                        scan,
                        BeamLayout::new(self.beams, self.fov_deg),
                        self.scan_range[1],
                        self.meta.bounding_radius(),
                        (v_m, omega_m),
                        self.safety_horizon_s,
                    ),
                    None => v_m,
                };
                let (v, omega) = transfer_policy(v_m, omega_m, state.mu, state.bounds);
                (v, omega, false)
            }
        };
        let t = Instant::now().duration_since(self.clock).as_secs_f64();
        log.lock().unwrap_or_else(PoisonError::into_inner).record(t, v, omega);
        self.commands.fetch_add(1, Ordering::Relaxed);
        Ok(Command {
            route,
            v,
            omega,
            arrived,
            goal_tolerance: state.goal_tolerance,
            filled_beams,
            mu: state.mu,
            footprint: state.robot.footprint.name.clone(),
            footprint_version: state.version,
        })
    }

    /// Replaces robot `robot_id`'s footprint with the one the footprint file `text` describes
    /// (all of it: keys the file leaves out take their defaults, as at start-up) and returns
    /// it with its new μ. A bad file changes nothing.
    pub fn set_footprint_toml(
        &self,
        robot_id: &str,
        text: &str,
    ) -> Result<FootprintState, ControllerError> {
        const FIELD: &str = "footprint_toml";
        check_robot_id(robot_id)?;
        if text.len() > MAX_FOOTPRINT_TOML {
            let why =
                format!("{} bytes; a footprint file has at most {MAX_FOOTPRINT_TOML}", text.len());
            return Err(ControllerError::invalid(FIELD, why));
        }
        let robot = robot_from_toml(text, FIELD, self.meta, self.margin).map_err(|e| {
            let reason = match e.downcast::<SpecFileError>() {
                Ok(e) => {
                    let line = e.line.map(|l| format!("line {l}: ")).unwrap_or_default();
                    let key =
                        if e.key.is_empty() { String::new() } else { format!("`{}`: ", e.key) };
                    format!("{line}{key}{}", e.reason)
                }
                Err(e) => format!("{e:#}"),
            };
            ControllerError::invalid(FIELD, reason)
        })?;
        let version = self.next_version.fetch_add(1, Ordering::Relaxed);
        let state = footprint_state(robot, version, self.meta_bounds, self.goal_tolerance)
            .map_err(|e| ControllerError::invalid(FIELD, format!("{e:#}")))?;
        let state = Arc::new(state);
        self.robots().set(robot_id, Instant::now(), state.clone())?;
        Ok((*state).clone())
    }

    /// Robot `robot_id`'s footprint now (the default for a robot without one).
    pub fn footprint(&self, robot_id: &str) -> FootprintState {
        let own = self.robots().get(robot_id, Instant::now());
        (*own.unwrap_or_else(|| self.default_robot.clone())).clone()
    }

    /// What this controller expects and drives with, for robot `robot_id`.
    pub fn info(&self, robot_id: &str) -> ControllerInfo {
        let footprint = self.footprint(robot_id);
        let mut robots = self.robots();
        let (max_robots, robot_idle) = robots.limits();
        ControllerInfo {
            beams: self.beams,
            fov_deg: self.fov_deg,
            scan_range: self.scan_range,
            control_period_s: self.control_period_s,
            meta_bounds: self.meta_bounds,
            footprint,
            model: self.model.clone(),
            commands: self.commands.load(Ordering::Relaxed),
            robots: robots.active(Instant::now()),
            max_robots,
            robot_idle,
            safety_horizon_s: self.safety_horizon_s,
            escape_after_s: self.escape_after_s,
        }
    }

    /// Nothing a panic could leave half-changed sits behind this lock (the table's entries
    /// are whole snapshots), so a poisoned lock is used on.
    fn robots(&self) -> MutexGuard<'_, RobotTable<Arc<FootprintState>>> {
        self.robots.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Checks every field of a request, in the order of the wire message.
    fn check(&self, input: &RobotInput) -> Result<(), ControllerError> {
        match input.scan {
            Scan::Meta(scan) => self.check_meta_scan(scan)?,
            Scan::Laser(scan) => scan.validate().map_err(|e| {
                ControllerError::invalid(format!("laser_scan.{}", e.field), e.reason)
            })?,
        }
        if let Some(pose) = input.pose {
            check_pose(pose)?;
        }
        let age = input.scan_age_s;
        if !(age.is_finite() && (0.0..=MAX_SCAN_AGE_S).contains(&age)) {
            return Err(ControllerError::invalid(
                "scan_age_s",
                format!("must be an age in [0, {MAX_SCAN_AGE_S}] s, got {age}"),
            ));
        }
        let d = input.goal_distance;
        if !(d.is_finite() && (0.0..=MAX_RANGE_M).contains(&d)) {
            return Err(ControllerError::invalid(
                "goal_distance",
                format!("must be a distance in [0, {MAX_RANGE_M}] m, got {d}"),
            ));
        }
        for (field, x, limit, unit) in [
            ("goal_angle", input.goal_angle, MAX_GOAL_ANGLE, "rad"),
            ("v", input.v, MAX_SPEED, "m/s"),
            ("omega", input.omega, MAX_SPEED, "rad/s"),
        ] {
            if !(x.is_finite() && x.abs() <= limit) {
                return Err(ControllerError::invalid(
                    field,
                    format!("must be finite and within ±{limit} {unit}, got {x}"),
                ));
            }
        }
        check_robot_id(input.robot_id)
    }

    fn check_meta_scan(&self, scan: &[f32]) -> Result<(), ControllerError> {
        let n = scan.len();
        if n != self.beams {
            return Err(ControllerError::invalid(
                "scan",
                format!(
                    "{n} ranges, the model's LiDAR has {} beams (send any other scan as \
                     `laser_scan`)",
                    self.beams
                ),
            ));
        }
        let bad = |r: &f32| !(r.is_finite() && *r >= 0.0 && f64::from(*r) <= MAX_RANGE_M);
        if let Some(i) = scan.iter().position(bad) {
            let r = scan[i];
            let others = scan[i + 1..].iter().filter(|r| bad(r)).count();
            let more = match others {
                0 => String::new(),
                k => format!(" ({k} more bad range{} after it)", if k == 1 { "" } else { "s" }),
            };
            let why = if !r.is_finite() {
                format!(
                    "{r} is not a range; send range_max ({} m) for a beam with no return, or \
                     send the scan as `laser_scan`, which reads ±inf and NaN as ROS does",
                    self.scan_range[1]
                )
            } else if r < 0.0 {
                format!("{r} m is negative")
            } else {
                format!("{r} m is beyond the longest range accepted, {MAX_RANGE_M} m")
            };
            return Err(ControllerError::invalid(format!("scan[{i}]"), format!("{why}{more}")));
        }
        Ok(())
    }
}

/// One route step of a request.
struct RouteStep {
    status: RouteStatus,
    /// The subgoal seen from the robot.
    goal_distance: f64,
    goal_angle: f64,
    /// At the route's goal.
    arrived: bool,
    shim: Option<(f64, f64)>,
}

/// A robot id within [`MAX_ROBOT_ID`] bytes, else the field's refusal.
pub fn check_robot_id(id: &str) -> Result<(), ControllerError> {
    if id.len() > MAX_ROBOT_ID {
        let why = format!("{} bytes; a robot id has at most {MAX_ROBOT_ID}", id.len());
        return Err(ControllerError::invalid("robot_id", why));
    }
    Ok(())
}

/// `robot` as a controller drives it: μ, the scaled robot, its bounds (its own, else
/// `meta_bounds`), its goal tolerance (the meta agent's `goal_tolerance` times μ).
fn footprint_state(
    robot: VariedRobot,
    version: u64,
    meta_bounds: VelocityBounds,
    goal_tolerance: f64,
) -> anyhow::Result<FootprintState> {
    robot.validate()?;
    let bounds = robot.velocity_bounds(meta_bounds);
    bounds.validate()?;
    let mu = robot.mu();
    Ok(FootprintState {
        mu,
        scaled: robot.meta.scaled(mu),
        bounds,
        goal_tolerance: goal_tolerance * mu,
        version,
        robot,
    })
}

/// A varied-robot file with the model's meta robot and the forced margin, if any.
fn robot_from_toml(
    text: &str,
    source: &str,
    meta: MetaRobot,
    margin: Option<f64>,
) -> anyhow::Result<VariedRobot> {
    let mut robot = VariedRobot::from_toml_str(text, source)?;
    // `from_toml_str` fills in the default meta robot when the file has none; only the file
    // tells whether it named one.
    let names_meta = text.parse::<toml::Table>().is_ok_and(|t| t.contains_key("meta"));
    if names_meta && !same_shape(&robot.meta, &meta) {
        return Err(SpecFileError {
            source: source.to_string(),
            line: None,
            key: "meta".into(),
            reason: format!(
                "the file's meta robot is a {}, but the model was trained as a {}; leave \
                 `[meta]` out to use the model's",
                robot.meta.describe(),
                meta.describe()
            ),
        }
        .into());
    }
    robot.meta = meta;
    if let Some(m) = margin {
        robot.margin = m;
    }
    robot.validate()?;
    Ok(robot)
}

/// Equal up to rounding (a file's 0.2 against a radius computed from a box).
fn same_shape(a: &MetaRobot, b: &MetaRobot) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9;
    match (*a, *b) {
        (MetaRobot::Circle { radius: r }, MetaRobot::Circle { radius: s }) => close(r, s),
        (
            MetaRobot::Rectangle { front, back, left, right },
            MetaRobot::Rectangle { front: f, back: k, left: l, right: r },
        ) => close(front, f) && close(back, k) && close(left, l) && close(right, r),
        _ => false,
    }
}

/// `a` in (−π, π]; angles already in [−π, π] pass unchanged, bit for bit.
fn wrap_angle(a: f64) -> f64 {
    if a.abs() <= PI {
        return a;
    }
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w <= -PI { w + TAU } else { w }
}

#[cfg(test)]
mod tests;
