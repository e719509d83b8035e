//! [`NavEnv`]: one navigation episode at a time for a robot of any footprint (design §2).

use super::grid::{GeodesicField, Reach};
use super::room::Body;
use super::sensor::MountedSensor;
use super::spec::Point;
use super::{Footprint, Lidar, Pose2, Room, advance, dist, wrap_angle};
use crate::EnvConfig;
use crate::Outcome;
use crate::laser_scan::{self, BeamLayout};
use crate::latency;
use crate::obs;
use crate::robustness::Perturbation;
use crate::transfer::{VelocityBounds, transfer_observation_in_place, transfer_policy};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;
use std::collections::VecDeque;
use std::sync::Arc;

mod route;
use route::RouteState;
pub use route::RouteStats;

/// No start and goal could be drawn for the robot in the room: the message says which room and
/// what was asked.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct NoTask(pub String);

/// What one control step produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutcome {
    /// r_s on success, r_c on collision, otherwise c1·(d_t − d_{t+1}) − c2.
    pub reward: f32,
    /// `Some` when the episode ended with this step (or had already ended).
    pub done: Option<Outcome>,
}

/// Tries per point before the sampler gives up on a room; the built-in rooms are mostly free
/// space, so a handful of tries suffices there.
const SAMPLE_TRIES: usize = 10_000;

/// Folded into an environment's seed for its robustness generator.
const ROBUSTNESS_STREAM: u64 = 0x0b05_7e55_d1ce_5eed;

/// One environment: a room, a robot (its footprint, unicycle kinematics, the LiDAR at the axle
/// centre), a goal, and the episode's bookkeeping. The robot is the circular meta robot of
/// `EnvConfig::robot_radius` unless `EnvConfig::footprint` or [`NavEnv::with_footprint`] gives
/// another footprint. With `EnvConfig::radius_range` (and no other footprint), each
/// [`NavEnv::reset`] draws the circle's radius uniformly from that range, and
/// [`NavEnv::reset_to`] (evaluation routes) drives `robot_radius`.
///
/// Starts and goals come from the environment's own generator, seeded at construction, so an
/// environment replays the same episodes for the same seed and actions. LiDAR noise (when
/// configured) draws from a second generator derived from the same seed, so turning noise on
/// does not change which starts and goals are drawn.
#[derive(Clone, Debug)]
pub struct NavEnv {
    cfg: EnvConfig,
    lidar: Lidar,
    /// `EnvConfig::sensor`: the real sensor the scan comes through, if any.
    sensor: Option<MountedSensor>,
    /// Meta beams the sensor did not see in the current scan (0 without a sensor).
    unseen_beams: usize,
    /// The scan in f64 for refilling dropped beams, kept to spare the hot path an allocation.
    dropout_ranges: Vec<f64>,
    room: Arc<Room>,
    /// The robot's shape, and the same as rapier shapes.
    footprint: Footprint,
    body: Body,
    /// [`Footprint::sweep_radius`]: how far (m) a footprint point moves per radian turned.
    sweep_radius: f64,
    /// The robot's radius (m): the circle's, or the footprint's bounding radius; the
    /// observation's radius input.
    radius: f64,
    /// `EnvConfig::radius_range` for the configured circular robot; `None` for a given
    /// footprint.
    radius_range: Option<[f64; 2]>,
    /// `EnvConfig::dvst` for the configured circular robot; `None` for a given footprint.
    dvst: Option<crate::DvstTrainingConfig>,
    /// This episode's DVST scale μ: 1 for the meta robot, R / `robot_radius` for a varied
    /// robot of `EnvConfig::dvst`, whose observations and commands go through DVST.
    mu: f64,
    /// Timed obstacles of the room present now (a prefix of the room's order).
    active: usize,
    /// Set by [`NavEnv::set_room`]; swapped in at the next reset.
    next_room: Option<Arc<Room>>,
    rng: Pcg64,
    noise_rng: Pcg64,
    pose: Pose2,
    start: Pose2,
    goal: [f64; 2],
    /// Last commanded (clamped) velocities.
    v: f64,
    omega: f64,
    steps: u32,
    /// This episode's step limit: `max_steps`, or more for a long planned route
    /// ([`crate::subgoal::SubgoalConfig::time_limit_factor`]).
    step_limit: u32,
    episode_return: f64,
    done: Option<Outcome>,
    /// Distance from the robot's centre to the goal at the current pose (d_t).
    goal_distance: f64,
    /// The scan at the current pose, computed once per step or reset.
    scan: Vec<f32>,
    /// Draws the robustness perturbations (dropout, actuation noise, jitter, per-episode
    /// ranges), apart from `rng` so they never change a seed's tasks.
    robust_rng: Pcg64,
    /// This episode's perturbations.
    perturb: Perturbation,
    /// With observation latency k: the last k + 1 observations, oldest first.
    history: VecDeque<Vec<f32>>,
    /// With observation latency k: the last k commands (real units), oldest first: what was
    /// sent since the observation the agent sees was made.
    commands: VecDeque<(f64, f64)>,
    /// `EnvConfig::subgoals`: this episode's planned path and subgoal rule.
    route: Option<RouteState>,
    /// `env.reward.geodesic_progress`, when the agent observes its final goal: the way to the
    /// goal for the robot's size from anywhere in the room, and that way's length (m) from the
    /// current pose, the reward's d_t.
    geodesic: Option<(GeodesicField, f64)>,
}

/// The radius a room's cached grids ([`Room::reach`], [`Room::centre_reach`]) are built for: the
/// robot's rounded up to whole centimetres, so a drawn radius range shares a few grids per room.
fn grid_radius(r: f64) -> f64 {
    (r * 100.0).ceil() / 100.0
}

impl NavEnv {
    /// An environment in `room`, seeded with `seed`, already reset to its first episode.
    ///
    /// # Panics
    /// If the room has no room for a start and a goal (see [`NavEnv::reset`]).
    pub fn new(room: Arc<Room>, cfg: &EnvConfig, seed: u64) -> NavEnv {
        let mut env = NavEnv::unreset(room, cfg, seed, None);
        env.reset();
        env
    }

    /// An environment for a robot of `footprint` (robot frame, LiDAR at the origin), whatever
    /// `cfg.footprint` says; otherwise like [`NavEnv::new`].
    ///
    /// # Panics
    /// If the room has no room for a start and a goal, or the footprint is invalid (see
    /// [`Footprint::validate`]).
    pub fn with_footprint(
        room: Arc<Room>,
        cfg: &EnvConfig,
        seed: u64,
        footprint: Footprint,
    ) -> NavEnv {
        let mut env = NavEnv::unreset(room, cfg, seed, Some(footprint));
        env.reset();
        env
    }

    /// [`NavEnv::new`] (`footprint` `None`) or [`NavEnv::with_footprint`], with an error instead
    /// of a panic when the room has no task for the robot (evaluations skip such a room and
    /// robot, saying so).
    pub fn try_new(
        room: Arc<Room>,
        cfg: &EnvConfig,
        seed: u64,
        footprint: Option<Footprint>,
    ) -> Result<NavEnv, NoTask> {
        let mut env = NavEnv::unreset(room, cfg, seed, footprint);
        env.try_reset()?;
        Ok(env)
    }

    /// The environment before its first reset, for a `named` footprint or (`None`) the
    /// configured robot: only the configured circle draws its radius per episode
    /// (`EnvConfig::radius_range`, `EnvConfig::dvst`).
    fn unreset(room: Arc<Room>, cfg: &EnvConfig, seed: u64, named: Option<Footprint>) -> NavEnv {
        let own_circle = named.is_none() && cfg.footprint.is_none();
        let footprint = named
            .or_else(|| cfg.footprint.clone())
            .unwrap_or_else(|| Footprint::circle(cfg.robot_radius));
        if let Err(e) = footprint.validate() {
            panic!("invalid footprint: {e:#}");
        }
        let mut rng = Pcg64::seed_from_u64(seed);
        let noise_rng = Pcg64::from_rng(&mut rng);
        let lidar = Lidar::new(&cfg.lidar);
        NavEnv {
            cfg: cfg.clone(),
            scan: vec![cfg.lidar.range_max as f32; lidar.beams()],
            lidar,
            sensor: cfg.sensor.as_ref().map(MountedSensor::new),
            unseen_beams: 0,
            dropout_ranges: Vec::new(),
            room,
            body: Body::new(&footprint),
            sweep_radius: footprint.sweep_radius(),
            radius: footprint.bounding_radius(),
            radius_range: cfg.radius_range.filter(|_| own_circle),
            dvst: cfg.dvst.filter(|_| own_circle),
            mu: 1.0,
            footprint,
            active: 0,
            next_room: None,
            rng,
            noise_rng,
            pose: Pose2::default(),
            start: Pose2::default(),
            goal: [0.0, 0.0],
            v: 0.0,
            omega: 0.0,
            steps: 0,
            step_limit: cfg.max_steps,
            episode_return: 0.0,
            done: None,
            goal_distance: 0.0,
            robust_rng: Pcg64::seed_from_u64(seed ^ ROBUSTNESS_STREAM),
            perturb: Perturbation::default(),
            history: VecDeque::new(),
            commands: VecDeque::new(),
            route: None,
            geodesic: None,
        }
    }

    /// Starts a new episode: a start (uniform position, uniform heading) and a goal drawn at
    /// random in free space, each with at least the footprint's bounding radius plus
    /// `spawn_clearance` to every wall and obstacle (timed obstacles included), at least
    /// `min_start_goal_distance` apart (and at most `max_start_goal_distance` when set), the
    /// goal reachable from the start for a disc of the footprint's bounding radius
    /// (`reachable_tasks`) by a path at most `max_path_ratio` times the straight line (when
    /// set). When the room has spawn regions, starts come from the
    /// regions for starts and goals from those for goals (a region is picked in proportion to
    /// its area). A room set with [`NavEnv::set_room`] takes effect here. With a radius range
    /// the robot's radius is drawn first, from the same generator.
    ///
    /// # Panics
    /// If no such pair is found after many tries (a room without free space for the robot);
    /// [`NavEnv::try_reset`] says so instead.
    pub fn reset(&mut self) {
        if let Err(e) = self.try_reset() {
            panic!("{e}");
        }
    }

    /// [`NavEnv::reset`], with an error when no start and goal are found.
    pub fn try_reset(&mut self) -> Result<(), NoTask> {
        self.take_next_room();
        if let Some([lo, hi]) = self.radius_range {
            let r = if lo < hi { self.rng.random_range(lo..=hi) } else { lo };
            self.set_circle(r);
        }
        if let Some(d) = self.dvst {
            let varied = d.share >= 1.0 || (d.share > 0.0 && self.rng.random::<f64>() < d.share);
            let [lo, hi] = d.radius_range;
            let r = match varied {
                true if lo < hi => self.rng.random_range(lo..=hi),
                true => lo,
                false => self.cfg.robot_radius,
            };
            self.set_circle(r);
            self.mu = r / self.cfg.robot_radius;
            if self.mu != 1.0 {
                match self.draw_task() {
                    Ok(()) => return Ok(()),
                    // A room too tight for the varied robot: the meta robot drives this one.
                    Err(_) => {
                        self.set_circle(self.cfg.robot_radius);
                        self.mu = 1.0;
                    }
                }
            }
        }
        self.draw_task()
    }

    /// Draws this episode's start and goal for the robot as it is now, and begins it.
    fn draw_task(&mut self) -> Result<(), NoTask> {
        let need = self.footprint.bounding_radius() + self.cfg.spawn_clearance;
        // The rounding of `grid_radius` comes out of the join slack.
        let r = self.footprint.bounding_radius();
        let r_grid = grid_radius(r);
        // Long tasks (a route, any way round) are the planner's: a goal is reachable when it
        // can plan there, on its finer raster (in a building, through doors the sampling
        // raster's conservative cells call shut).
        let long = self.cfg.subgoals.is_some() && self.cfg.max_path_ratio <= 0.0;
        let reach = (self.cfg.reachable_tasks || self.cfg.max_path_ratio > 0.0)
            .then(|| if long { self.room.planning_reach(r_grid) } else { self.room.reach(r_grid) });
        let slack = self.cfg.spawn_clearance - (r_grid - r);
        for _ in 0..100 {
            let start = self.sample_free(need, true)?;
            if reach.as_ref().is_some_and(|r| r.component_at(start, slack).is_none()) {
                continue;
            }
            for _ in 0..100 {
                let goal = self.sample_free(need, false)?;
                let d = dist(start, goal);
                let far_enough = d >= self.cfg.min_start_goal_distance;
                let near_enough = self.cfg.max_start_goal_distance <= 0.0
                    || d <= self.cfg.max_start_goal_distance;
                if far_enough
                    && near_enough
                    && self.task_ok(reach.as_deref(), slack, start, goal, d)
                {
                    let yaw = self.rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
                    self.begin(Pose2::new(start[0], start[1], yaw), goal);
                    return Ok(());
                }
            }
        }
        Err(NoTask(format!(
            "room `{}`: found no start and goal {} m apart with {need} m clearance that the \
             robot can drive between (env.reachable_tasks, max_start_goal_distance {}, \
             max_path_ratio {})",
            self.room.name(),
            self.cfg.min_start_goal_distance,
            self.cfg.max_start_goal_distance,
            self.cfg.max_path_ratio
        )))
    }

    /// Whether the robot can drive from `start` to `goal` (`d` apart), within the path-ratio
    /// bound when there is one.
    fn task_ok(
        &self,
        reach: Option<&Reach>,
        slack: f64,
        start: [f64; 2],
        goal: [f64; 2],
        d: f64,
    ) -> bool {
        let Some(reach) = reach else { return true };
        if self.cfg.max_path_ratio > 0.0 {
            reach
                .path_length(start, goal, slack)
                .is_some_and(|len| len <= self.cfg.max_path_ratio * d)
        } else {
            reach.connected(start, goal, slack)
        }
    }

    /// Starts a new episode from `start` towards `goal` (evaluation routes). Neither is checked
    /// for clearance; a start in contact ends the first step with a collision. With a radius
    /// range the robot is the circle of `robot_radius`, so every route drives the same robot.
    pub fn reset_to(&mut self, start: Pose2, goal: [f64; 2]) {
        self.take_next_room();
        if (self.radius_range.is_some() || self.dvst.is_some())
            && self.radius != self.cfg.robot_radius
        {
            self.set_circle(self.cfg.robot_radius);
        }
        self.mu = 1.0;
        self.begin(start, goal);
    }

    /// Makes the robot a circle of radius `r` (m) about the axle.
    fn set_circle(&mut self, r: f64) {
        self.footprint = Footprint::circle(r);
        self.body = Body::new(&self.footprint);
        self.sweep_radius = self.footprint.sweep_radius();
        self.radius = r;
    }

    /// Runs the next episodes in `room` (from the next reset on).
    pub fn set_room(&mut self, room: Arc<Room>) {
        self.next_room = Some(room);
    }

    /// Runs the next episodes with `robustness` in place of the configured `[env.robustness]`
    /// (from the next reset on; the episode under way keeps its perturbations). The actors'
    /// curriculum switches it per stage (`curriculum.robust_from_stage`).
    pub fn set_robustness(&mut self, robustness: crate::RobustnessConfig) {
        self.cfg.robustness = robustness;
    }

    /// The `[env.robustness]` the next episodes draw their perturbations from.
    pub fn robustness(&self) -> &crate::RobustnessConfig {
        &self.cfg.robustness
    }

    fn take_next_room(&mut self) {
        if let Some(room) = self.next_room.take() {
            self.room = room;
        }
    }

    /// A uniformly drawn point whose disc of radius `need` touches nothing, from the room's
    /// spawn regions for starts (`starts`) or goals, or anywhere in its square without regions.
    fn sample_free(&mut self, need: f64, starts: bool) -> Result<[f64; 2], NoTask> {
        let room = self.room.clone();
        let regions: Vec<_> = room
            .spec()
            .spawn_regions
            .iter()
            .filter(|r| if starts { r.starts } else { r.goals })
            .collect();
        let h = room.side() / 2.0 - need;
        if h <= 0.0 {
            return Err(NoTask(format!("room `{}` is too small for the robot", room.name())));
        }
        let area = |r: &&crate::SpawnRegion| (r.max[0] - r.min[0]) * (r.max[1] - r.min[1]);
        let total: f64 = regions.iter().map(area).sum();
        for _ in 0..SAMPLE_TRIES {
            let p = if regions.is_empty() {
                [self.rng.random_range(-h..=h), self.rng.random_range(-h..=h)]
            } else {
                let mut u = self.rng.random_range(0.0..total);
                let mut pick = regions[regions.len() - 1];
                for r in &regions {
                    if u < area(r) {
                        pick = r;
                        break;
                    }
                    u -= area(r);
                }
                [
                    self.rng.random_range(pick.min[0]..=pick.max[0]),
                    self.rng.random_range(pick.min[1]..=pick.max[1]),
                ]
            };
            if !room.circle_collides_any_time(p, need) {
                return Ok(p);
            }
        }
        Err(NoTask(format!(
            "room `{}`: no free point with {need} m clearance found",
            self.room.name()
        )))
    }

    fn begin(&mut self, start: Pose2, goal: [f64; 2]) {
        let p = Perturbation::draw(
            &self.cfg.robustness,
            self.cfg.lidar.noise_std,
            &mut self.robust_rng,
        );
        self.lidar.set_noise_std(p.noise_std);
        self.perturb = p;
        let start = Pose2 { yaw: wrap_angle(start.yaw), ..start };
        self.start = start;
        self.pose = start;
        self.goal = goal;
        self.v = 0.0;
        self.omega = 0.0;
        self.steps = 0;
        self.episode_return = 0.0;
        self.done = None;
        self.active = self.room.timed_active(0);
        self.goal_distance = dist(start.position(), goal);
        let robust_rng = &mut self.robust_rng;
        self.route = self.cfg.subgoals.as_ref().map(|c| {
            let scale = self.radius / self.cfg.robot_radius;
            // Drawn only for a share below 1, so every seed's runs stay as they were; from the
            // robustness stream so the draw never changes a seed's tasks.
            let follow =
                c.follow && (c.follow_share >= 1.0 || robust_rng.random::<f64>() < c.follow_share);
            RouteState::begin(c, follow, &self.room, self.radius, scale, start, goal)
        });
        self.geodesic = self.geodesic_field(start.position(), goal);
        self.step_limit = self.cfg.max_steps;
        if let (Some(c), Some(len)) =
            (&self.cfg.subgoals, self.route.as_ref().and_then(|r| r.stats().planned_length_m))
            && c.time_limit_factor > 0.0
        {
            // The planned path driven at v_max, times the factor.
            let steps = c.time_limit_factor * len / (self.cfg.v_max * self.cfg.dt);
            self.step_limit = self.step_limit.max(steps.ceil() as u32);
        }
        self.update_scan();
        self.history.clear();
        self.commands.clear();
        if self.perturb.latency_steps > 0 {
            let mut o = vec![0.0; self.obs_dim()];
            self.compose_obs(&mut o);
            let k = self.perturb.latency_steps as usize;
            self.history.extend(std::iter::repeat_n(o, k + 1));
            // The robot stood still before its first command.
            self.commands.extend(std::iter::repeat_n((0.0, 0.0), k));
        }
    }

    /// Keeps the observation just made for the latency buffer.
    fn remember_obs(&mut self) {
        if self.perturb.latency_steps == 0 {
            return;
        }
        let mut o = self.history.pop_front().unwrap_or_else(|| vec![0.0; self.obs_dim()]);
        self.compose_obs(&mut o);
        self.history.push_back(o);
        self.commands.pop_front();
        self.commands.push_back((self.v, self.omega));
    }

    fn update_scan(&mut self) {
        if let Some(sensor) = &mut self.sensor {
            // The sensor's own noise, not the meta LiDAR's.
            let noise = (sensor.spec().noise_std > 0.0).then_some(&mut self.noise_rng);
            self.unseen_beams = sensor.meta_scan(
                &self.room,
                self.pose,
                self.active,
                noise,
                &self.cfg.lidar,
                &mut self.scan,
            );
        } else {
            let noise = (self.perturb.noise_std > 0.0).then_some(&mut self.noise_rng);
            self.lidar.scan_active(&self.room, self.pose, self.active, noise, &mut self.scan);
        }
        let p = self.perturb.beam_dropout;
        if p > 0.0 {
            self.drop_beams(p);
        }
    }

    /// Drops each beam with probability `p` and shows the loss as the deployed pipeline
    /// (`dvnav serve`, [`laser_scan`]) reads a driver's lost return, half each: +inf or 0
    /// reads `range_max`; NaN is no reading, and its meta beam reads the nearer of its seen
    /// neighbours. Training on losses read as 0 m would teach the agent about obstacles that
    /// no deployed scan ever shows it.
    fn drop_beams(&mut self, p: f64) {
        let max = self.cfg.lidar.range_max as f32;
        let mut unseen = false;
        for r in self.scan.iter_mut() {
            if self.robust_rng.random_bool(p) {
                let no_return = self.robust_rng.random_bool(0.5);
                *r = if no_return { max } else { f32::INFINITY };
                unseen |= !no_return;
            }
        }
        if unseen {
            let layout = laser_scan::BeamLayout::new(self.cfg.lidar.beams, self.cfg.lidar.fov_deg);
            let ranges = &mut self.dropout_ranges;
            ranges.clear();
            ranges.extend(self.scan.iter().map(|&r| f64::from(r)));
            laser_scan::fill_from_neighbours(ranges, layout.wraps());
            for (o, &r) in self.scan.iter_mut().zip(ranges.iter()) {
                *o = r as f32;
            }
        }
    }

    /// Applies the command `(v, ω)` for one control period `dt`.
    ///
    /// The command is clamped to `[0, v_max] × [−ω_max, ω_max]` (NaN counts as 0), and the
    /// unicycle moves exactly along the arc (a straight line when ω = 0). The footprint is
    /// checked for contact at sub-steps so close that no point of it moves more than
    /// `collision_substep` between two checks (v·dt for the axle plus |ω|·dt times the
    /// footprint's sweep radius for turning: a long robot turning in place sweeps its corners);
    /// at the first contact the robot stops there and the episode ends in
    /// [`Outcome::Collision`] with r_c. Timed obstacles that appear when this step ends are
    /// added then; one that appears on the robot is a collision.
    /// Otherwise the episode ends in [`Outcome::Success`] (r_s) when the centre is within
    /// `goal_tolerance` of the goal, and the reward is c1·(d_t − d_{t+1}) − c2; the step that
    /// reaches `max_steps` ends in [`Outcome::Timeout`] with that ordinary reward.
    ///
    /// After the episode has ended the robot stays put: every further step returns reward 0
    /// and the same outcome until [`NavEnv::reset`].
    pub fn step(&mut self, v: f64, omega: f64) -> StepOutcome {
        if let Some(outcome) = self.done {
            return StepOutcome { reward: 0.0, done: Some(outcome) };
        }
        let clamp = |x: f64, lo: f64, hi: f64| if x.is_nan() { 0.0 } else { x.clamp(lo, hi) };
        let omega_prev = (self.steps > 0).then_some(self.omega);
        let v = clamp(v, 0.0, self.cfg.v_max);
        let omega = clamp(omega, -self.cfg.omega_max, self.cfg.omega_max);
        let (v, omega) = if self.mu != 1.0 {
            let bounds = VelocityBounds { v_max: self.cfg.v_max, omega_max: self.cfg.omega_max };
            transfer_policy(v, omega, self.mu, bounds)
        } else {
            (v, omega)
        };
        self.v = v;
        self.omega = omega;
        // What the motors do: the command plus actuation noise, within the bounds again.
        let [sv, sw] = self.perturb.actuation_noise_std;
        let mut gauss = |s: f64| {
            if s > 0.0 {
                Normal::new(0.0, s).map_or(0.0, |n| n.sample(&mut self.robust_rng))
            } else {
                0.0
            }
        };
        let (v, omega) = (
            clamp(v + gauss(sv), 0.0, self.cfg.v_max),
            clamp(omega + gauss(sw), -self.cfg.omega_max, self.cfg.omega_max),
        );
        let j = self.perturb.dt_jitter;
        let dt = if j > 0.0 {
            self.cfg.dt * (1.0 + self.robust_rng.random_range(-j..=j))
        } else {
            self.cfg.dt
        };
        let from = self.pose;
        let travel = (v + omega.abs() * self.sweep_radius) * dt;
        let substeps = ((travel / self.cfg.collision_substep).ceil() as usize).max(1);
        let mut collided = false;
        for k in 1..=substeps {
            // Each sub-step pose from the step's start, so rounding never accumulates.
            let t = if k == substeps { dt } else { dt * k as f64 / substeps as f64 };
            self.pose = advance(from, v, omega, t);
            if self.room.body_collides(&self.body, self.pose, self.active) {
                collided = true;
                break;
            }
        }
        self.pose.yaw = wrap_angle(self.pose.yaw);
        self.steps += 1;
        let active = self.room.timed_active(self.steps);
        if active > self.active {
            self.active = active;
            collided = collided || self.room.body_collides(&self.body, self.pose, active);
        }

        let d_prev = self.progress_distance();
        self.goal_distance = dist(self.pose.position(), self.goal);
        self.update_scan();
        let d_next = match self.route.as_mut() {
            Some(route) => {
                let (pose, scan, angles) = (self.pose, &self.scan, self.lidar.beam_angles());
                let max = self.cfg.lidar.range_max as f32;
                let left = route.step(&self.room, pose, self.cfg.dt, || {
                    crate::lidar::scan_points(pose, scan, angles, max)
                });
                if route.follow() { left } else { self.straight_or_geodesic() }
            }
            None => self.straight_or_geodesic(),
        };
        let rw = &self.cfg.reward;
        let (reward, done) = if collided {
            (rw.collision, Some(Outcome::Collision))
        } else if self.goal_distance <= self.cfg.goal_tolerance {
            (rw.success, Some(Outcome::Success))
        } else {
            let change = omega_prev.map_or(0.0, |w| (self.omega - w).abs());
            // In the meta robot's units, as the agent observes distances.
            let progress = (d_prev - d_next) / self.mu;
            let r = rw.progress * progress - rw.time_penalty - rw.omega_change * change;
            (r, (self.steps >= self.step_limit).then_some(Outcome::Timeout))
        };
        let reward = reward as f32;
        self.episode_return += reward as f64;
        self.done = done;
        self.remember_obs();
        StepOutcome { reward, done }
    }

    /// Length of [`NavEnv::write_obs`]'s output: beams + 4, one more with the radius input.
    pub fn obs_dim(&self) -> usize {
        self.cfg.obs_layout().dim()
    }

    /// Writes the observation at the current pose in the layout of [`crate::obs`]: the scan
    /// (m), goal distance (m), goal bearing in the robot frame (rad, (−π, π], left positive),
    /// and the last commanded v (m/s) and ω (rad/s), both 0 after a reset; with
    /// `EnvConfig::radius_input`, then the robot's radius ([`NavEnv::robot_radius`]).
    ///
    /// # Panics
    /// If `out` is not [`NavEnv::obs_dim`] long.
    ///
    /// With observation latency (`env.robustness.latency_steps` = k) it writes the scan and
    /// goal of k steps ago instead (the reset's while the episode is younger), and the last
    /// command as it is now: a controller knows what it sent, only its sensors and odometry
    /// lag (`dvnav serve` fills v, ω from the robot's last command).
    pub fn write_obs(&self, out: &mut [f32]) {
        assert_eq!(out.len(), self.obs_dim(), "observation buffer length");
        match self.history.front() {
            Some(old) => {
                out.copy_from_slice(old);
                let beams = self.scan.len();
                if self.cfg.latency_compensation {
                    let moved = latency::motion_since(self.commands.iter().copied(), self.cfg.dt);
                    let lidar = &self.cfg.lidar;
                    let layout = BeamLayout::new(lidar.beams, lidar.fov_deg);
                    let range = [lidar.range_min, lidar.range_max];
                    latency::carry_observation(old, layout, range, moved, out);
                }
                out[beams + obs::LINEAR_VELOCITY] = self.v as f32;
                out[beams + obs::ANGULAR_VELOCITY] = self.omega as f32;
            }
            None => self.compose_obs(out),
        }
        if self.mu != 1.0 {
            let range = [self.cfg.lidar.range_min, self.cfg.lidar.range_max];
            transfer_observation_in_place(out, self.scan.len(), self.mu, Some(range));
        }
    }

    /// This episode's DVST scale μ (`EnvConfig::dvst`): 1 for the meta robot.
    pub fn dvst_scale(&self) -> f64 {
        self.mu
    }

    /// This episode's robustness perturbations ([`crate::robustness`]).
    pub fn perturbation(&self) -> Perturbation {
        self.perturb
    }

    /// The observation at the current pose (see [`NavEnv::write_obs`]).
    fn compose_obs(&self, out: &mut [f32]) {
        let beams = self.scan.len();
        out[..beams].copy_from_slice(&self.scan);
        let extra = &mut out[beams..];
        let goal = self.observed_goal();
        extra[obs::GOAL_DISTANCE] = dist(self.pose.position(), goal) as f32;
        extra[obs::GOAL_ANGLE] = self.pose.bearing_to(goal) as f32;
        extra[obs::LINEAR_VELOCITY] = self.v as f32;
        extra[obs::ANGULAR_VELOCITY] = self.omega as f32;
        if self.cfg.radius_input {
            extra[obs::RADIUS] = self.radius as f32;
        }
    }

    /// The robot's radius (m): the circle's (drawn per episode with a radius range), or a
    /// footprint's bounding radius (the smallest circle about the axle that covers it, which
    /// is how a policy with the radius input sees a robot that is not a circle).
    pub fn robot_radius(&self) -> f64 {
        self.radius
    }

    /// Bearing of the goal in the robot frame (rad, (−π, π], left positive).
    pub fn goal_angle(&self) -> f64 {
        self.pose.bearing_to(self.goal)
    }

    /// The goal the agent observes: the subgoal when following a planned path
    /// (`env.subgoals`), else the goal.
    pub fn observed_goal(&self) -> [f64; 2] {
        match &self.route {
            Some(r) if r.follow() => r.subgoal(),
            _ => self.goal,
        }
    }

    /// The subgoal the agent observes when this episode follows a planned path
    /// (`env.subgoals`); `None` when it observes the final goal.
    pub fn subgoal(&self) -> Option<[f64; 2]> {
        self.route.as_ref().filter(|r| r.follow()).map(RouteState::subgoal)
    }

    /// The lookahead point on this episode's planned path (`env.subgoals`), whether or not the
    /// agent observes it: what the planner expert steers for. `None` without subgoals, or when
    /// no path was found (the robot can only head for the final goal).
    pub fn planned_subgoal(&self) -> Option<[f64; 2]> {
        self.route.as_ref().filter(|r| r.path().is_some()).map(RouteState::subgoal)
    }

    /// The reward's d_t: the path left along the plan when following one, else the shortest
    /// way's length with `env.reward.geodesic_progress`, else the straight distance to the goal.
    fn progress_distance(&self) -> f64 {
        match (&self.route, &self.geodesic) {
            (Some(r), _) if r.follow() => r.remaining_m(),
            (_, Some((_, d))) => *d,
            _ => self.goal_distance,
        }
    }

    /// With `env.reward.geodesic_progress`, when the agent observes its final goal: the field
    /// of ways to `goal` for the robot's size, on the planner's raster, and its value at
    /// `start`. `None` otherwise, and when the field has no value there (the reward then
    /// measures the straight line, as the paper's does).
    fn geodesic_field(&self, start: Point, goal: Point) -> Option<(GeodesicField, f64)> {
        let follows = self.route.as_ref().is_some_and(RouteState::follow);
        if !self.cfg.reward.geodesic_progress || follows {
            return None;
        }
        // The room's cached cells for the radius on the task draw's grid (building them again
        // would cost more than the field), where the disc's centre fits exactly:
        // the planner's conservative reach shuts gaps the robot drives through, and the reward
        // would then pay the way round them. No slack: `Reach::entries` still joins the goal
        // through the cells within 1.5 of its own, which a goal drawn with the robot's
        // clearance always has.
        let field = self.room.centre_reach(grid_radius(self.radius)).field_to(goal, 0.0)?;
        let d = field.distance(start)?;
        Some((field, d))
    }

    /// The reward's d_{t+1} when the agent observes its final goal: the geodesic way's length
    /// with `env.reward.geodesic_progress` (the straight line where the field has no value
    /// near the robot), else the straight line; keeps it as the next step's d_t.
    fn straight_or_geodesic(&mut self) -> f64 {
        let pose = self.pose.position();
        match &mut self.geodesic {
            Some((field, d)) => {
                // Off the field (a robot pressed into a corner the raster calls too tight for
                // it, farther than the search looks) counts no progress rather than jumping
                // to the straight line.
                if let Some(now) = field.distance(pose) {
                    *d = now;
                }
                *d
            }
            None => self.goal_distance,
        }
    }

    /// The rotation shim's command (`env.subgoals.rotation_shim`): after each plan, turn in
    /// place towards the subgoal until it is within the shim's angle; `None` while the agent
    /// drives (and always without subgoals). Callers use it instead of the policy's command.
    pub fn shim_command(&self) -> Option<(f64, f64)> {
        match &self.route {
            Some(r) if r.follow() && self.done.is_none() => {
                r.shim_command(self.pose, self.cfg.omega_max)
            }
            _ => None,
        }
    }

    /// What this episode's route came to (`env.subgoals`); `None` without subgoals.
    pub fn route_stats(&self) -> Option<RouteStats> {
        self.route.as_ref().map(RouteState::stats)
    }

    /// The current plan (`env.subgoals`), when there is one.
    pub fn planned_path(&self) -> Option<&crate::planner::PlannedPath> {
        self.route.as_ref().and_then(RouteState::path)
    }

    /// Distance from the robot's centre to the goal (m).
    pub fn goal_distance(&self) -> f64 {
        self.goal_distance
    }

    /// The robot's pose.
    pub fn pose(&self) -> Pose2 {
        self.pose
    }

    /// The goal position (m).
    pub fn goal(&self) -> [f64; 2] {
        self.goal
    }

    /// The pose the episode started from.
    pub fn start(&self) -> Pose2 {
        self.start
    }

    /// Control steps since the reset.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// Sum of the rewards since the reset (of the `f32` rewards returned, summed in `f64`).
    pub fn episode_return(&self) -> f64 {
        self.episode_return
    }

    /// Simulated seconds since the reset.
    pub fn sim_time(&self) -> f64 {
        self.steps as f64 * self.cfg.dt
    }

    /// How the episode ended, or `None` while it runs.
    pub fn done(&self) -> Option<Outcome> {
        self.done
    }

    /// The LiDAR ranges at the current pose (m).
    pub fn scan(&self) -> &[f32] {
        &self.scan
    }

    /// Meta beams of the current scan that the configured sensor (`EnvConfig::sensor`) did not
    /// see and the resampling filled; 0 without a sensor.
    pub fn unseen_beams(&self) -> usize {
        self.unseen_beams
    }

    /// The room of the current episode.
    pub fn room(&self) -> &Arc<Room> {
        &self.room
    }

    /// Last commanded (clamped) linear and angular velocity, (m/s, rad/s).
    pub fn velocity(&self) -> (f64, f64) {
        (self.v, self.omega)
    }

    /// The environment's constants.
    pub fn config(&self) -> &EnvConfig {
        &self.cfg
    }

    /// The LiDAR.
    pub fn lidar(&self) -> &Lidar {
        &self.lidar
    }

    /// The robot's footprint.
    pub fn footprint(&self) -> &Footprint {
        &self.footprint
    }

    /// How many of the room's timed obstacles are present now.
    pub fn timed_active(&self) -> usize {
        self.active
    }
}

#[cfg(test)]
mod tests;
