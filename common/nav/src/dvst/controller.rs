//! [`DvstController`]: what `dvnav serve` does, without the network. A robot sends its scan,
//! goal and velocity each control cycle ([`RobotInput`]) and gets the meta agent's command
//! through DVST back ([`Command`]); its footprint can change at run time
//! ([`DvstController::set_footprint_toml`]).
//!
//! The controller owns a [`Dvst`] behind a mutex: a request is checked before the lock is
//! taken (a malformed one never reaches the policy), and a footprint change swaps robot, μ and
//! bounds under the same lock that [`act`](DvstController::act) holds, so every command is
//! computed wholly with the old footprint or wholly with the new one, and says which
//! ([`Command::footprint_version`]).
//!
//! The meta robot is the one the model was trained as (its run configuration's
//! `env.robot_radius` or `env.footprint`): a footprint file that leaves `[meta]` out gets it,
//! one whose `[meta]` says otherwise is refused, since DVST's μ would then be computed for a
//! robot the agent never was.
//!
//! ```no_run
//! use dvnav_nav::dvst::controller::{DvstController, ModelId, RobotInput};
//! use dvnav_nav::policy::MetaAgent;
//! # fn main() -> anyhow::Result<()> {
//! let (agent, cfg) = MetaAgent::load("models/meta-r0.2".as_ref())?;
//! let toml = std::fs::read_to_string("footprints/paper-medium.toml")?;
//! let model = ModelId { name: "meta-r0.2".into(), version: "unversioned".into() };
//! let ctl = DvstController::new(agent, &cfg, model, &toml, "paper-medium.toml", None)?;
//! let scan = vec![10.0; ctl.beams()];
//! let input = RobotInput { scan: &scan, goal_distance: 2.0, goal_angle: 0.3, v: 0.0, omega: 0.0 };
//! let command = ctl.act(&input)?;
//! println!("v = {:.3} m/s, ω = {:.3} rad/s at μ = {}", command.v, command.omega, command.mu);
//! # Ok(())
//! # }
//! ```

use super::agent::Dvst;
use super::footprint_file::VariedRobot;
use super::scale::MetaRobot;
use super::transfer::VelocityBounds;
use crate::policy::NavPolicy;
use dvnav_config::Config;
use dvnav_sim::obs::{ANGULAR_VELOCITY, GOAL_ANGLE, GOAL_DISTANCE, LINEAR_VELOCITY, obs_dim};
use dvnav_sim::{Footprint, SpecFileError};
use std::f64::consts::{PI, TAU};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};

/// The model a controller drives with, as it reports it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelId {
    /// A name for people: the model or checkpoint directory.
    pub name: String,
    /// What tells two models apart: a fingerprint of the weights.
    pub version: String,
}

/// One control cycle's observation, as the robot measures it (physical units, robot frame).
#[derive(Clone, Copy, Debug)]
pub struct RobotInput<'a> {
    /// LiDAR ranges (m) in the meta agent's beam layout ([`dvnav_sim::Lidar`]), finite, ≥ 0.
    pub scan: &'a [f32],
    /// Distance to the goal (m), ≥ 0.
    pub goal_distance: f64,
    /// Bearing of the goal (rad, left positive); an angle outside [−π, π] is wrapped into it.
    pub goal_angle: f64,
    /// Current linear velocity (m/s).
    pub v: f64,
    /// Current angular velocity (rad/s).
    pub omega: f64,
}

/// The answer to one [`RobotInput`].
#[derive(Clone, Debug, PartialEq)]
pub struct Command {
    /// Linear velocity (m/s), within the robot's bounds.
    pub v: f64,
    /// Angular velocity (rad/s), within the robot's bounds.
    pub omega: f64,
    /// The μ it was computed with.
    pub mu: f64,
    /// The footprint's name.
    pub footprint: String,
    /// Which footprint it was computed with: 1 at start-up, +1 per footprint change.
    pub footprint_version: u64,
}

/// The robot a controller drives now.
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
    /// 1 at start-up, +1 per footprint change.
    pub version: u64,
}

/// What a controller expects and drives with.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerInfo {
    /// Scan length a request must carry.
    pub beams: usize,
    /// The meta agent's LiDAR field of view (degrees).
    pub fov_deg: f64,
    /// The meta agent's LiDAR range `[min, max]` (m): transferred scans are clamped to it.
    pub scan_range: [f64; 2],
    /// The control period the meta agent was trained at (s).
    pub control_period_s: f64,
    /// The meta agent's velocity bounds.
    pub meta_bounds: VelocityBounds,
    /// The current robot.
    pub footprint: FootprintState,
    /// The model.
    pub model: ModelId,
    /// Commands answered so far.
    pub commands: u64,
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
    /// The policy failed on a valid request.
    #[error("the policy failed: {0:#}")]
    Policy(anyhow::Error),
}

impl ControllerError {
    fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        ControllerError::InvalidArgument { field: field.into(), reason: reason.into() }
    }
}

/// What the lock guards: the policy, the observation buffer it is fed from, and the version
/// of the footprint it drives.
#[derive(Debug)]
struct Inner<P> {
    dvst: Dvst<P>,
    obs: Vec<f32>,
    footprint_version: u64,
}

/// A meta agent driving one varied robot through DVST, shared by the requests of a service.
#[derive(Debug)]
pub struct DvstController<P> {
    inner: Mutex<Inner<P>>,
    beams: usize,
    fov_deg: f64,
    scan_range: [f64; 2],
    control_period_s: f64,
    /// The model's meta robot: every footprint gets it.
    meta: MetaRobot,
    /// A margin forced on every footprint (`dvnav serve --margin`), else each file's own.
    margin: Option<f64>,
    model: ModelId,
    commands: AtomicU64,
}

impl<P: NavPolicy> DvstController<P> {
    /// Drives `policy`, trained with the run configuration `cfg`, for the varied robot of the
    /// footprint file `robot_toml` (`source` names it in errors). `margin` replaces the file's
    /// margin, here and in every later footprint.
    pub fn new(
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
        if let Some(m) = margin {
            anyhow::ensure!(m.is_finite() && m >= 0.0, "the margin must be ≥ 0 m, got {m}");
        }
        let trained =
            cfg.env.footprint.clone().unwrap_or_else(|| Footprint::circle(cfg.env.robot_radius));
        let meta = MetaRobot::from_footprint(&trained).ok_or_else(|| {
            anyhow::anyhow!(
                "DVST needs a circular or rectangular meta robot; the model was trained as `{}`",
                trained.name
            )
        })?;
        let robot = robot_from_toml(robot_toml, source, meta, margin)?;
        let scan_range = [lidar.range_min, lidar.range_max];
        let dvst = Dvst::new(policy, robot)?.with_scan_range(Some(scan_range))?;
        Ok(Self {
            inner: Mutex::new(Inner {
                dvst,
                obs: vec![0.0; obs_dim(lidar.beams)],
                footprint_version: 1,
            }),
            beams: lidar.beams,
            fov_deg: lidar.fov_deg,
            scan_range,
            control_period_s: cfg.env.dt,
            meta,
            margin,
            model,
            commands: AtomicU64::new(0),
        })
    }

    /// Scan length a request must carry.
    pub fn beams(&self) -> usize {
        self.beams
    }

    /// The model it drives with.
    pub fn model(&self) -> &ModelId {
        &self.model
    }

    /// The command for one control cycle. A malformed input is refused, naming the field,
    /// before the policy sees it.
    pub fn act(&self, input: &RobotInput) -> Result<Command, ControllerError> {
        self.check(input)?;
        let mut inner = self.lock();
        let Inner { dvst, obs, footprint_version } = &mut *inner;
        let b = self.beams;
        obs[..b].copy_from_slice(input.scan);
        obs[b + GOAL_DISTANCE] = input.goal_distance as f32;
        obs[b + GOAL_ANGLE] = wrap_angle(input.goal_angle) as f32;
        obs[b + LINEAR_VELOCITY] = input.v as f32;
        obs[b + ANGULAR_VELOCITY] = input.omega as f32;
        let (v, omega) = dvst.act(obs).map_err(ControllerError::Policy)?;
        self.commands.fetch_add(1, Ordering::Relaxed);
        Ok(Command {
            v,
            omega,
            mu: dvst.mu(),
            footprint: dvst.robot().footprint.name.clone(),
            footprint_version: *footprint_version,
        })
    }

    /// Replaces the robot with the one the footprint file `text` describes (all of it: keys
    /// the file leaves out take their defaults, as at start-up) and returns it with its new μ.
    /// A bad file changes nothing.
    pub fn set_footprint_toml(&self, text: &str) -> Result<FootprintState, ControllerError> {
        const FIELD: &str = "footprint_toml";
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
        let mut inner = self.lock();
        inner
            .dvst
            .set_robot(robot)
            .map_err(|e| ControllerError::invalid(FIELD, format!("{e:#}")))?;
        inner.footprint_version += 1;
        Ok(Self::state(&inner))
    }

    /// The current robot.
    pub fn footprint(&self) -> FootprintState {
        Self::state(&self.lock())
    }

    /// What this controller expects and drives with.
    pub fn info(&self) -> ControllerInfo {
        let inner = self.lock();
        let (v_max, omega_max) = inner.dvst.meta_policy().velocity_bounds();
        ControllerInfo {
            beams: self.beams,
            fov_deg: self.fov_deg,
            scan_range: self.scan_range,
            control_period_s: self.control_period_s,
            meta_bounds: VelocityBounds { v_max, omega_max },
            footprint: Self::state(&inner),
            model: self.model.clone(),
            commands: self.commands.load(Ordering::Relaxed),
        }
    }

    fn state(inner: &Inner<P>) -> FootprintState {
        let (v_max, omega_max) = inner.dvst.velocity_bounds();
        FootprintState {
            robot: inner.dvst.robot().clone(),
            mu: inner.dvst.mu(),
            scaled: inner.dvst.scaled_robot(),
            bounds: VelocityBounds { v_max, omega_max },
            version: inner.footprint_version,
        }
    }

    /// A panic inside the policy leaves nothing half-changed that a later request could see
    /// (the observation buffer is rewritten whole every call), so a poisoned lock is used on.
    fn lock(&self) -> MutexGuard<'_, Inner<P>> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Checks every field of a request, in the order of the wire message.
    fn check(&self, input: &RobotInput) -> Result<(), ControllerError> {
        let n = input.scan.len();
        if n != self.beams {
            return Err(ControllerError::invalid(
                "scan",
                format!("{n} ranges, the model's LiDAR has {} beams", self.beams),
            ));
        }
        let bad = |r: &f32| !(r.is_finite() && *r >= 0.0);
        if let Some(i) = input.scan.iter().position(bad) {
            let r = input.scan[i];
            let others = input.scan[i + 1..].iter().filter(|r| bad(r)).count();
            let more = match others {
                0 => String::new(),
                k => format!(" ({k} more bad range{} after it)", if k == 1 { "" } else { "s" }),
            };
            let why = if r.is_finite() {
                format!("{r} m is negative")
            } else {
                format!(
                    "{r} is not a range; send range_max ({} m) for a beam with no return",
                    self.scan_range[1]
                )
            };
            return Err(ControllerError::invalid(format!("scan[{i}]"), format!("{why}{more}")));
        }
        let d = input.goal_distance;
        if !(d.is_finite() && d >= 0.0) {
            return Err(ControllerError::invalid(
                "goal_distance",
                format!("must be a finite distance ≥ 0 m, got {d}"),
            ));
        }
        for (field, x, unit) in [
            ("goal_angle", input.goal_angle, "rad"),
            ("v", input.v, "m/s"),
            ("omega", input.omega, "rad/s"),
        ] {
            if !x.is_finite() {
                return Err(ControllerError::invalid(
                    field,
                    format!("must be finite ({unit}), got {x}"),
                ));
            }
        }
        Ok(())
    }
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
