//! [`NavEnv`]: one navigation episode at a time for a robot of any footprint (design §2).

use super::room::Body;
use super::{Footprint, Lidar, Pose2, Room, wrap_angle};
use crate::EnvConfig;
use crate::Outcome;
use crate::obs;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

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
    episode_return: f64,
    done: Option<Outcome>,
    /// Distance from the robot's centre to the goal at the current pose (d_t).
    goal_distance: f64,
    /// The scan at the current pose, computed once per step or reset.
    scan: Vec<f32>,
}

impl NavEnv {
    /// An environment in `room`, seeded with `seed`, already reset to its first episode.
    ///
    /// # Panics
    /// If the room has no room for a start and a goal (see [`NavEnv::reset`]).
    pub fn new(room: Arc<Room>, cfg: &EnvConfig, seed: u64) -> NavEnv {
        let footprint =
            cfg.footprint.clone().unwrap_or_else(|| Footprint::circle(cfg.robot_radius));
        let range = if cfg.footprint.is_none() { cfg.radius_range } else { None };
        NavEnv::build(room, cfg, seed, footprint, range)
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
        NavEnv::build(room, cfg, seed, footprint, None)
    }

    fn build(
        room: Arc<Room>,
        cfg: &EnvConfig,
        seed: u64,
        footprint: Footprint,
        radius_range: Option<[f64; 2]>,
    ) -> NavEnv {
        if let Err(e) = footprint.validate() {
            panic!("invalid footprint: {e:#}");
        }
        let mut rng = Pcg64::seed_from_u64(seed);
        let noise_rng = Pcg64::from_rng(&mut rng);
        let lidar = Lidar::new(&cfg.lidar);
        let mut env = NavEnv {
            cfg: cfg.clone(),
            scan: vec![cfg.lidar.range_max as f32; lidar.beams()],
            lidar,
            room,
            body: Body::new(&footprint),
            sweep_radius: footprint.sweep_radius(),
            radius: footprint.bounding_radius(),
            radius_range,
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
            episode_return: 0.0,
            done: None,
            goal_distance: 0.0,
        };
        env.reset();
        env
    }

    /// Starts a new episode: a start (uniform position, uniform heading) and a goal drawn at
    /// random in free space, each with at least the footprint's bounding radius plus
    /// `spawn_clearance` to every wall and obstacle (timed obstacles included), at least
    /// `min_start_goal_distance` apart. When the room has spawn regions, starts come from the
    /// regions for starts and goals from those for goals (a region is picked in proportion to
    /// its area). A room set with [`NavEnv::set_room`] takes effect here. With a radius range
    /// the robot's radius is drawn first, from the same generator.
    ///
    /// # Panics
    /// If no such pair is found after many tries (a room without free space for the robot).
    pub fn reset(&mut self) {
        self.take_next_room();
        if let Some([lo, hi]) = self.radius_range {
            let r = if lo < hi { self.rng.random_range(lo..=hi) } else { lo };
            self.set_circle(r);
        }
        let need = self.footprint.bounding_radius() + self.cfg.spawn_clearance;
        for _ in 0..100 {
            let start = self.sample_free(need, true);
            for _ in 0..100 {
                let goal = self.sample_free(need, false);
                if dist(start, goal) >= self.cfg.min_start_goal_distance {
                    let yaw = self.rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
                    self.begin(Pose2::new(start[0], start[1], yaw), goal);
                    return;
                }
            }
        }
        panic!(
            "room `{}`: found no start and goal {} m apart with {need} m clearance",
            self.room.name(),
            self.cfg.min_start_goal_distance
        );
    }

    /// Starts a new episode from `start` towards `goal` (evaluation routes). Neither is checked
    /// for clearance; a start in contact ends the first step with a collision. With a radius
    /// range the robot is the circle of `robot_radius`, so every route drives the same robot.
    pub fn reset_to(&mut self, start: Pose2, goal: [f64; 2]) {
        self.take_next_room();
        if self.radius_range.is_some() && self.radius != self.cfg.robot_radius {
            self.set_circle(self.cfg.robot_radius);
        }
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

    fn take_next_room(&mut self) {
        if let Some(room) = self.next_room.take() {
            self.room = room;
        }
    }

    /// A uniformly drawn point whose disc of radius `need` touches nothing, from the room's
    /// spawn regions for starts (`starts`) or goals, or anywhere in its square without regions.
    fn sample_free(&mut self, need: f64, starts: bool) -> [f64; 2] {
        let room = self.room.clone();
        let regions: Vec<_> = room
            .spec()
            .spawn_regions
            .iter()
            .filter(|r| if starts { r.starts } else { r.goals })
            .collect();
        let h = room.side() / 2.0 - need;
        assert!(h > 0.0, "room `{}` is too small for the robot", room.name());
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
                return p;
            }
        }
        panic!("room `{}`: no free point with {need} m clearance found", self.room.name());
    }

    fn begin(&mut self, start: Pose2, goal: [f64; 2]) {
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
        self.update_scan();
    }

    fn update_scan(&mut self) {
        let noise = (self.cfg.lidar.noise_std > 0.0).then_some(&mut self.noise_rng);
        self.lidar.scan_active(&self.room, self.pose, self.active, noise, &mut self.scan);
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
        let v = clamp(v, 0.0, self.cfg.v_max);
        let omega = clamp(omega, -self.cfg.omega_max, self.cfg.omega_max);
        self.v = v;
        self.omega = omega;

        let dt = self.cfg.dt;
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

        let rw = &self.cfg.reward;
        let d_prev = self.goal_distance;
        self.goal_distance = dist(self.pose.position(), self.goal);
        let (reward, done) = if collided {
            (rw.collision, Some(Outcome::Collision))
        } else if self.goal_distance <= self.cfg.goal_tolerance {
            (rw.success, Some(Outcome::Success))
        } else {
            let r = rw.progress * (d_prev - self.goal_distance) - rw.time_penalty;
            (r, (self.steps >= self.cfg.max_steps).then_some(Outcome::Timeout))
        };
        let reward = reward as f32;
        self.episode_return += reward as f64;
        self.done = done;
        self.update_scan();
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
    pub fn write_obs(&self, out: &mut [f32]) {
        assert_eq!(out.len(), self.obs_dim(), "observation buffer length");
        let beams = self.scan.len();
        out[..beams].copy_from_slice(&self.scan);
        let extra = &mut out[beams..];
        extra[obs::GOAL_DISTANCE] = self.goal_distance as f32;
        extra[obs::GOAL_ANGLE] = self.goal_angle() as f32;
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
        let [x, y] = self.pose.to_local(self.goal);
        let a = y.atan2(x);
        if a <= -std::f64::consts::PI { std::f64::consts::PI } else { a }
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

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The unicycle's pose after driving `(v, ω)` for `t` seconds from `p`, in closed form.
///
/// The arc's chord has length v·t·sinc(ω·t/2) and points along the mean heading
/// yaw + ω·t/2; written this way it needs no separate straight-line case and stays accurate as
/// ω → 0.
fn advance(p: Pose2, v: f64, omega: f64, t: f64) -> Pose2 {
    let half = 0.5 * omega * t;
    let sinc = if half.abs() < 1e-4 { 1.0 - half * half / 6.0 } else { half.sin() / half };
    let chord = v * t * sinc;
    let (s, c) = (p.yaw + half).sin_cos();
    Pose2 { x: p.x + chord * c, y: p.y + chord * s, yaw: p.yaw + omega * t }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Footprint, ObstacleSpec, RoomSpec};
    use std::f64::consts::{FRAC_PI_2, PI};

    fn empty_room(side: f64) -> Arc<Room> {
        Arc::new(Room::new(RoomSpec::empty("empty", side)))
    }

    fn cfg() -> EnvConfig {
        EnvConfig::default()
    }

    #[test]
    fn arc_and_straight_kinematics_are_exact() {
        let p = advance(Pose2::default(), 0.5, FRAC_PI_2, 0.2);
        let r = 0.5 / FRAC_PI_2;
        let th = FRAC_PI_2 * 0.2;
        assert!((p.x - r * th.sin()).abs() < 1e-12);
        assert!((p.y - r * (1.0 - th.cos())).abs() < 1e-12);
        assert!((p.yaw - th).abs() < 1e-12);
        let q = advance(Pose2::new(1.0, 2.0, 0.3), 0.5, 0.0, 0.2);
        assert!((q.x - (1.0 + 0.1 * 0.3f64.cos())).abs() < 1e-12);
        assert!((q.y - (2.0 + 0.1 * 0.3f64.sin())).abs() < 1e-12);
        // Tiny ω is continuous with the straight line.
        let e = advance(Pose2::new(1.0, 2.0, 0.3), 0.5, 1e-9, 0.2);
        assert!((e.x - q.x).abs() < 1e-10 && (e.y - q.y).abs() < 1e-10);
        // A full circle returns home.
        let f = advance(Pose2::default(), 0.5, FRAC_PI_2, 4.0);
        assert!(f.x.abs() < 1e-12 && f.y.abs() < 1e-12);
    }

    #[test]
    fn free_step_rewards_progress() {
        let cfg = cfg();
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
        env.reset_to(Pose2::new(-2.0, 0.0, 0.0), [2.0, 0.0]);
        let out = env.step(0.5, 0.0);
        // 0.1 m straight at the goal: 2·0.1 − 0.01.
        assert!((out.reward - 0.19).abs() < 1e-6, "{}", out.reward);
        assert_eq!(out.done, None);
        // A turning, clamped step: the reward is c1·(d_t − d_{t+1}) − c2 with the real poses.
        let d0 = env.goal_distance();
        let out = env.step(3.0, -5.0);
        assert_eq!(env.velocity(), (0.5, -FRAC_PI_2));
        let d1 = dist(env.pose().position(), env.goal());
        let expect = 2.0 * (d0 - d1) - 0.01;
        assert!((out.reward as f64 - expect).abs() < 1e-6, "{} vs {expect}", out.reward);
        assert!((env.pose().yaw + FRAC_PI_2 * 0.2).abs() < 1e-12);
        assert_eq!(env.steps(), 2);
        assert!((env.sim_time() - 0.4).abs() < 1e-12);
        assert!((env.episode_return() - (0.19f32 as f64 + out.reward as f64)).abs() < 1e-9);
        // Reversing is not possible: v clamps to 0, and the robot only turns.
        let before = env.pose();
        let out = env.step(-1.0, 0.0);
        assert_eq!(env.pose().position(), before.position());
        assert!((out.reward + 0.01).abs() < 1e-7);
    }

    #[test]
    fn success_pays_r_s_and_the_env_stays_done() {
        let cfg = cfg();
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [0.29, 0.0]);
        let out = env.step(0.5, 0.0);
        assert_eq!(out, StepOutcome { reward: 10.0, done: Some(Outcome::Success) });
        let pose = env.pose();
        let again = env.step(0.5, 1.0);
        assert_eq!(again, StepOutcome { reward: 0.0, done: Some(Outcome::Success) });
        assert_eq!(env.pose(), pose);
        assert_eq!(env.steps(), 1);
        env.reset();
        assert_eq!((env.done(), env.steps(), env.velocity()), (None, 0, (0.0, 0.0)));
    }

    #[test]
    fn collision_pays_r_c_and_stops_at_contact() {
        let cfg = cfg();
        let mut env = NavEnv::new(empty_room(4.0), &cfg, 1);
        // 0.05 m between the disc and the wall at x = 2.
        env.reset_to(Pose2::new(1.75, 0.0, 0.0), [-1.0, 0.0]);
        let out = env.step(0.5, 0.0);
        assert_eq!(out, StepOutcome { reward: -10.0, done: Some(Outcome::Collision) });
        let x = env.pose().x;
        assert!(x > 1.8 - 1e-9 && x <= 1.8 + 0.02 + 1e-9, "stopped at the first contact: {x}");
        assert_eq!(env.step(0.0, 0.0).done, Some(Outcome::Collision));
    }

    #[test]
    fn timeout_after_max_steps() {
        let cfg = EnvConfig { max_steps: 5, ..cfg() };
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 0.0]);
        for i in 1..=5 {
            let out = env.step(0.0, 0.5);
            assert!((out.reward + 0.01).abs() < 1e-7, "ordinary reward at step {i}");
            assert_eq!(out.done, (i == 5).then_some(Outcome::Timeout), "step {i}");
        }
        assert_eq!(env.done(), Some(Outcome::Timeout));
    }

    #[test]
    fn no_tunneling_through_a_thin_wall() {
        // A 2 cm wall 1 m ahead, the goal behind it; 5 m per control step without sub-steps
        // would jump clean over it.
        let mut spec = RoomSpec::empty("thin", 12.0);
        spec.obstacles.push(ObstacleSpec::Box {
            center: [1.0, 0.0],
            half_extents: [0.01, 3.0],
            angle: 0.0,
        });
        let room = Arc::new(Room::new(spec));
        for (v_max, dt) in [(0.5, 1.0), (5.0, 1.0)] {
            let cfg = EnvConfig { v_max, dt, ..cfg() };
            let mut env = NavEnv::new(room.clone(), &cfg, 1);
            env.reset_to(Pose2::new(0.0, 0.0, 0.0), [3.0, 0.0]);
            let mut done = None;
            for _ in 0..10 {
                done = env.step(v_max, 0.0).done;
                assert!(env.pose().x < 1.0, "centre stays in front of the wall");
                if done.is_some() {
                    break;
                }
            }
            assert_eq!(done, Some(Outcome::Collision), "v_max {v_max}");
            assert!(env.pose().x >= 0.79 - 0.02, "{}", env.pose().x);
        }
    }

    #[test]
    fn observation_layout_and_goal_angle() {
        let cfg = cfg();
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
        env.reset_to(Pose2::new(1.0, 1.0, FRAC_PI_2), [0.0, 1.0]);
        let mut o = vec![0.0; env.obs_dim()];
        env.write_obs(&mut o);
        let b = 540;
        assert_eq!(o.len(), 544);
        assert_eq!(&o[..b], env.scan());
        assert!((o[b + obs::GOAL_DISTANCE] - 1.0).abs() < 1e-6);
        assert!((o[b + obs::GOAL_ANGLE] - FRAC_PI_2 as f32).abs() < 1e-6, "goal to the left");
        assert_eq!((o[b + obs::LINEAR_VELOCITY], o[b + obs::ANGULAR_VELOCITY]), (0.0, 0.0));
        // Straight behind: +π, never −π.
        env.reset_to(Pose2::new(1.0, 0.0, 0.0), [0.0, 0.0]);
        assert_eq!(env.goal_angle(), PI);
        env.reset_to(Pose2::new(0.0, 0.0, PI), [-1.0, -1.0]);
        assert!((env.goal_angle() - PI / 4.0).abs() < 1e-12, "{}", env.goal_angle());
        env.step(0.3, -0.2);
        env.write_obs(&mut o);
        assert_eq!((o[b + obs::LINEAR_VELOCITY], o[b + obs::ANGULAR_VELOCITY]), (0.3, -0.2));
        // Straight ahead, the scan reads the wall at x = −4 seen from the robot.
        let (x, yaw) = (env.pose().x, env.pose().yaw);
        let theta = env.lidar().beam_angles()[270] + yaw;
        let expect = (-4.0 - x) / theta.cos();
        assert!((o[270] as f64 - expect).abs() < 1e-3, "{} vs {expect}", o[270]);
    }

    #[test]
    fn the_radius_input_adds_the_episodes_radius_after_omega() {
        let standard = NavEnv::new(empty_room(8.0), &cfg(), 1);
        assert_eq!(standard.obs_dim(), 544, "the meta agent's layout is unchanged");
        let cfg = EnvConfig { radius_input: true, robot_radius: 0.3, ..cfg() };
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
        assert_eq!(env.obs_dim(), 545);
        let mut o = vec![0.0; 545];
        env.write_obs(&mut o);
        assert_eq!(o[540 + obs::RADIUS], 0.3);
        // The standard part is what an environment without the radius input writes.
        let plain_cfg = EnvConfig { radius_input: false, ..cfg.clone() };
        let mut plain = NavEnv::new(empty_room(8.0), &plain_cfg, 1);
        let mut p = vec![0.0; 544];
        for _ in 0..5 {
            env.step(0.4, 0.3);
            plain.step(0.4, 0.3);
            env.write_obs(&mut o);
            plain.write_obs(&mut p);
            assert_eq!(o[..544], p[..]);
            assert_eq!(o[544], 0.3);
        }
        // A given footprint's radius input is its bounding radius.
        let fp = Footprint::rectangle(0.6, 0.8);
        let env = NavEnv::with_footprint(empty_room(8.0), &cfg, 1, fp);
        env.write_obs(&mut o);
        assert!((o[544] as f64 - 0.5).abs() < 1e-6, "{}", o[544]);
    }

    #[test]
    fn radii_are_drawn_per_episode_within_the_range_and_replay_for_a_seed() {
        let cfg = EnvConfig { radius_input: true, radius_range: Some([0.2, 0.5]), ..cfg() };
        let room = Room::builtin("sac_ri").unwrap();
        let radii = |seed: u64| -> Vec<f64> {
            let mut env = NavEnv::new(room.clone(), &cfg, seed);
            let mut o = vec![0.0; env.obs_dim()];
            (0..200)
                .map(|_| {
                    env.reset();
                    let r = env.robot_radius();
                    env.write_obs(&mut o);
                    assert_eq!(o[540 + obs::RADIUS], r as f32, "the observation holds it");
                    assert_eq!(env.footprint().as_circle(), Some(r), "the robot is that circle");
                    // Spawn clearance follows the drawn radius.
                    let need = r + cfg.spawn_clearance;
                    assert!(!room.circle_collides_any_time(env.start().position(), need));
                    assert!(!room.circle_collides_any_time(env.goal(), need));
                    r
                })
                .collect()
        };
        let a = radii(4);
        assert!(a.iter().all(|r| (0.2..=0.5).contains(r)), "{a:?}");
        let (lo, hi) = a.iter().fold((1.0f64, 0.0f64), |(l, h), &r| (l.min(r), h.max(r)));
        assert!(lo < 0.25 && hi > 0.45, "spread over the range: {lo} .. {hi}");
        assert_eq!(a, radii(4), "the same seed draws the same radii");
        assert_ne!(a, radii(5));
        // The robot collides as the drawn circle: driving into a wall, it stops r from it.
        let mut env = NavEnv::new(empty_room(8.0), &cfg, 9);
        let r = env.robot_radius();
        env.reset_to(Pose2::new(3.0, 0.0, 0.0), [-3.0, 0.0]);
        assert_eq!(env.robot_radius(), 0.2, "a route drives robot_radius");
        env.reset();
        assert_ne!(env.robot_radius(), r, "the next random episode draws again");
        let r = env.robot_radius();
        env.begin(Pose2::new(0.0, 0.0, 0.0), [-3.0, 0.0]); // as reset left the robot
        while env.done().is_none() {
            env.step(0.5, 0.0);
        }
        assert_eq!(env.done(), Some(Outcome::Collision));
        assert!((env.pose().x - (4.0 - r)).abs() < 0.03, "{} vs r = {r}", env.pose().x);
        // A given footprint is that robot in every episode; a one-value range draws nothing.
        let mut fixed = NavEnv::with_footprint(room.clone(), &cfg, 4, Footprint::circle(0.35));
        let one = EnvConfig { radius_range: Some([0.3, 0.3]), ..cfg.clone() };
        let mut single = NavEnv::new(room.clone(), &one, 4);
        let fixed_cfg = EnvConfig { radius_range: None, robot_radius: 0.3, ..one.clone() };
        let mut none = NavEnv::new(room.clone(), &fixed_cfg, 4);
        for _ in 0..20 {
            fixed.reset();
            single.reset();
            none.reset();
            assert_eq!(fixed.robot_radius(), 0.35);
            assert_eq!(single.robot_radius(), 0.3);
            assert_eq!((single.start(), single.goal()), (none.start(), none.goal()));
        }
    }

    fn run_episode(env: &mut NavEnv, actions: &mut Pcg64) -> (Vec<u32>, Vec<u32>) {
        let mut obs_bits = Vec::new();
        let mut reward_bits = Vec::new();
        let mut o = vec![0.0f32; env.obs_dim()];
        env.write_obs(&mut o);
        obs_bits.extend(o.iter().map(|x| x.to_bits()));
        loop {
            let (v, w) = (actions.random_range(0.0..0.5), actions.random_range(-1.5..1.5));
            let out = env.step(v, w);
            env.write_obs(&mut o);
            obs_bits.extend(o.iter().map(|x| x.to_bits()));
            reward_bits.push(out.reward.to_bits());
            if out.done.is_some() {
                return (obs_bits, reward_bits);
            }
        }
    }

    #[test]
    fn same_seed_same_episodes_different_seed_different() {
        let room = Room::builtin("env3").unwrap();
        let cfg = EnvConfig { max_steps: 60, ..cfg() };
        let mut a = NavEnv::new(room.clone(), &cfg, 42);
        let mut b = NavEnv::new(room.clone(), &cfg, 42);
        for episode in 0..3 {
            let ea = run_episode(&mut a, &mut Pcg64::seed_from_u64(episode));
            let eb = run_episode(&mut b, &mut Pcg64::seed_from_u64(episode));
            assert_eq!(ea, eb, "episode {episode}");
            a.reset();
            b.reset();
        }
        let c = NavEnv::new(room, &cfg, 43);
        assert_ne!((a.start(), a.goal()), (c.start(), c.goal()));
    }

    #[test]
    fn lidar_noise_is_seeded_and_leaves_the_episodes_alone() {
        let room = Room::builtin("env1").unwrap();
        let noisy_cfg = EnvConfig {
            lidar: crate::LidarConfig { noise_std: 0.01, ..Default::default() },
            ..cfg()
        };
        let exact = NavEnv::new(room.clone(), &cfg(), 11);
        let mut a = NavEnv::new(room.clone(), &noisy_cfg, 11);
        let mut b = NavEnv::new(room, &noisy_cfg, 11);
        assert_eq!((a.start(), a.goal()), (exact.start(), exact.goal()), "same episodes");
        assert_ne!(a.scan(), exact.scan(), "noisy");
        assert_eq!(a.scan(), b.scan(), "deterministic");
        a.step(0.2, 0.1);
        b.step(0.2, 0.1);
        assert_eq!(a.scan(), b.scan());
    }

    #[test]
    fn set_room_takes_effect_at_reset() {
        let mut env = NavEnv::new(Room::builtin("env0").unwrap(), &cfg(), 5);
        env.set_room(Room::builtin("env3").unwrap());
        assert_eq!(env.room().name(), "env0");
        env.reset();
        assert_eq!(env.room().name(), "env3");
    }

    #[test]
    fn builtin_rooms_sample_valid_starts_and_goals() {
        let cfg = cfg();
        let need = cfg.robot_radius + cfg.spawn_clearance;
        for name in Room::builtin_names() {
            let room = Room::builtin(&name).unwrap();
            if Room::training_names().contains(&name.as_str()) {
                assert!(!room.circle_collides([0.0, 0.0], cfg.robot_radius), "{name}: origin");
                assert!(room.clearance([0.0, 0.0], 1.0) >= 0.4 + cfg.robot_radius);
            }
            let half = room.side() / 2.0;
            let mut env = NavEnv::new(room.clone(), &cfg, 9);
            for _ in 0..200 {
                env.reset();
                let (s, g) = (env.start().position(), env.goal());
                for p in [s, g] {
                    assert!(p[0].abs() < half && p[1].abs() < half, "{name}: {p:?} inside");
                    assert!(room.clearance(p, 1.0) >= need - 1e-5, "{name}: {p:?} free");
                }
                assert!(dist(s, g) >= cfg.min_start_goal_distance);
                assert!(env.start().yaw > -PI && env.start().yaw <= PI);
                assert_eq!(env.pose(), env.start());
                assert!(env.scan().iter().all(|&r| r as f64 >= cfg.robot_radius));
            }
        }
    }

    /// A 2 cm wall across the room 1 m ahead at full speed (and at 10x the speed with a 1 s
    /// control period): the circle and the rectangle footprints both stop in front of it.
    #[test]
    fn no_tunneling_at_full_speed_for_circle_and_rectangle() {
        let mut spec = RoomSpec::empty("thin", 12.0);
        spec.obstacles.push(ObstacleSpec::Box {
            center: [1.0, 0.0],
            half_extents: [0.01, 5.0],
            angle: 0.0,
        });
        let room = Arc::new(Room::new(spec));
        let rect = Footprint::rectangle(0.5, 0.3);
        for fp in [
            Footprint::circle(0.2),
            rect.clone(),
            rect.with_cargo([ObstacleSpec::Circle { center: [-0.4, 0.0], radius: 0.1 }]),
        ] {
            let front = fp.parts.iter().map(|p| p.aabb()[1][0]).fold(f64::MIN, f64::max);
            for (v_max, dt) in [(0.5, 0.2), (5.0, 1.0)] {
                let cfg = EnvConfig { v_max, dt, ..cfg() };
                let mut env = NavEnv::with_footprint(room.clone(), &cfg, 1, fp.clone());
                env.reset_to(Pose2::new(0.0, 0.0, 0.0), [3.0, 0.0]);
                let mut done = None;
                for _ in 0..40 {
                    done = env.step(v_max, 0.0).done;
                    if done.is_some() {
                        break;
                    }
                }
                assert_eq!(done, Some(Outcome::Collision), "{} at {v_max} m/s", fp.name);
                let nose = env.pose().x + front;
                assert!(
                    (0.99 - 1e-6..=0.99 + 0.02 + 1e-6).contains(&nose),
                    "{}: nose at {nose}",
                    fp.name
                );
            }
        }
    }

    /// A 1 m x 0.1 m rectangle turning in place beside a wall 0.3 m from its axle: it starts
    /// and (after half a turn) would end parallel to the wall, clear of it, but its corners
    /// sweep through the wall on the way. Checking only the end pose misses the contact.
    #[test]
    fn a_long_rectangle_turning_beside_a_wall_hits_it() {
        let mut spec = RoomSpec::empty("wall", 6.0);
        spec.obstacles.push(ObstacleSpec::Box {
            center: [0.0, 0.35],
            half_extents: [2.0, 0.05],
            angle: 0.0,
        });
        let room = Arc::new(Room::new(spec));
        let fp = Footprint::rectangle(1.0, 0.1);
        // ω_max·dt = π: one control step is half a turn.
        let cfg = EnvConfig { dt: 2.0, ..cfg() };
        let mut env = NavEnv::with_footprint(room.clone(), &cfg, 1, fp.clone());
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, -2.0]);
        assert!(!room.footprint_collides(&fp, Pose2::new(0.0, 0.0, PI)), "end pose is clear");
        let out = env.step(0.0, cfg.omega_max);
        assert_eq!(out.done, Some(Outcome::Collision));
        // Stopped at the first contact: a corner reaches y = 0.3 at yaw ≈ asin(0.25/0.51)−atan(0.1).
        let yaw = env.pose().yaw;
        let contact = (0.3f64 / 0.5f64.hypot(0.05)).asin() - (0.05f64 / 0.5).atan();
        assert!(
            yaw >= contact - 1e-9 && yaw <= contact + 0.02 / 0.5 + 1e-9,
            "yaw {yaw} vs {contact}"
        );
        assert!(env.pose().position() == [0.0, 0.0]);
        // The same turn the other way is free (the wall is only on the left).
        let mut env = NavEnv::with_footprint(room, &cfg, 1, fp);
        env.reset_to(Pose2::new(0.0, -1.0, 0.0), [2.0, -2.0]);
        assert_eq!(env.step(0.0, -cfg.omega_max).done, None);
    }

    #[test]
    fn footprints_sample_starts_with_their_clearance_and_stay_seeded() {
        let room = Room::builtin("env2").unwrap();
        let fp = Footprint::rectangle(0.8, 0.4)
            .with_cargo([ObstacleSpec::Circle { center: [-0.5, 0.0], radius: 0.15 }]);
        let cfg = cfg();
        let need = fp.bounding_radius() + cfg.spawn_clearance;
        let mut a = NavEnv::with_footprint(room.clone(), &cfg, 4, fp.clone());
        let mut b = NavEnv::with_footprint(room.clone(), &cfg, 4, fp.clone());
        for _ in 0..100 {
            for p in [a.start().position(), a.goal()] {
                assert!(room.clearance(p, 2.0) >= need - 1e-5, "{p:?}");
            }
            assert!(!room.footprint_collides(&fp, a.start()));
            assert_eq!((a.start(), a.goal()), (b.start(), b.goal()));
            a.reset();
            b.reset();
        }
        // Through the config as well.
        let via_cfg = EnvConfig { footprint: Some(fp.clone()), ..cfg.clone() };
        let c = NavEnv::new(room, &via_cfg, 4);
        assert_eq!(c.footprint(), &fp);
    }

    #[test]
    fn spawn_regions_hold_starts_and_goals() {
        let mut spec = RoomSpec::empty("regions", 6.0);
        spec.spawn_regions = vec![
            crate::SpawnRegion {
                name: "west".into(),
                min: [-2.5, -2.5],
                max: [-1.5, 2.5],
                starts: true,
                goals: false,
            },
            crate::SpawnRegion {
                name: "east".into(),
                min: [1.5, -2.5],
                max: [2.5, 2.5],
                starts: false,
                goals: true,
            },
        ];
        let mut env = NavEnv::new(Arc::new(Room::new(spec)), &cfg(), 2);
        for _ in 0..100 {
            let (s, g) = (env.start().position(), env.goal());
            assert!((-2.5..=-1.5).contains(&s[0]) && (1.5..=2.5).contains(&g[0]), "{s:?} {g:?}");
            env.reset();
        }
    }

    /// The dynamic room's route driven straight at full speed: the first timed obstacle is in
    /// the scan from step 8 on (not before), the rapier reference sees it too, and the robot
    /// runs into it; the same seed and actions give byte-identical episodes.
    #[test]
    fn timed_obstacles_appear_in_scan_and_collision() {
        let room = Room::builtin("dynamic").unwrap();
        let route = room.spec().route("dynamic").unwrap().clone();
        let mut env = NavEnv::new(room.clone(), &cfg(), 1);
        env.reset_to(route.start_pose(), route.goals[0]);
        let ahead = |env: &NavEnv| env.scan()[270] as f64;
        let mut reference = vec![0.0f32; env.lidar().beams()];
        let mut hit = None;
        for k in 1..=40 {
            let before = ahead(&env);
            let out = env.step(0.5, 0.0);
            let y = env.pose().y;
            if k < 8 {
                assert_eq!(env.timed_active(), 0);
                assert!(
                    ahead(&env) > 2.0 && (ahead(&env) - (before - 0.1)).abs() < 1e-3,
                    "step {k}"
                );
            } else if out.done.is_none() {
                assert!(env.timed_active() >= 1);
                // The disc at (0, −1), r 0.3: the beam just left of ahead meets it near y = −1.3.
                assert!(
                    (ahead(&env) - (-1.3 - y)).abs() < 1e-3,
                    "step {k}: {} at y {y}",
                    ahead(&env)
                );
            }
            env.lidar().scan_reference_active(
                &room,
                env.pose(),
                env.timed_active(),
                None::<&mut Pcg64>,
                &mut reference,
            );
            for (i, (&f, &r)) in env.scan().iter().zip(&reference).enumerate() {
                assert!((f - r).abs() < 1e-4, "step {k}, beam {i}: {f} vs rapier {r}");
            }
            if out.done.is_some() {
                hit = Some((k, out.done));
                break;
            }
        }
        // The robot's front (y + 0.2) reaches the disc (y = −1.3) after 1.5 m: step 15.
        assert_eq!(hit, Some((15, Some(Outcome::Collision))));
        // Reset: the obstacles are gone again.
        env.reset_to(route.start_pose(), route.goals[0]);
        assert_eq!(env.timed_active(), 0);
        // Determinism in the dynamic room, with random starts and actions.
        let mut a = NavEnv::new(room.clone(), &cfg(), 8);
        let mut b = NavEnv::new(room, &cfg(), 8);
        for episode in 0..3 {
            let ea = run_episode(&mut a, &mut Pcg64::seed_from_u64(episode));
            let eb = run_episode(&mut b, &mut Pcg64::seed_from_u64(episode));
            assert_eq!(ea, eb, "episode {episode}");
            a.reset();
            b.reset();
        }
    }

    #[test]
    fn an_obstacle_appearing_on_the_robot_is_a_collision() {
        let mut spec = RoomSpec::empty("drop", 6.0);
        spec.timed_obstacles.push(crate::TimedObstacle {
            at_step: 2,
            obstacle: ObstacleSpec::Circle { center: [0.5, 0.0], radius: 0.3 },
        });
        let mut env = NavEnv::new(Arc::new(Room::new(spec)), &cfg(), 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 2.0]);
        assert_eq!(env.step(0.0, 0.0).done, None);
        assert_eq!(env.step(0.0, 0.0).done, Some(Outcome::Collision), "appears at step 2");
    }

    #[test]
    #[ignore = "benchmark; run with --release -- --ignored --nocapture"]
    fn steps_per_second() {
        let room = Room::builtin("env2").unwrap();
        let mut env = NavEnv::new(room, &cfg(), 1);
        let mut obs = vec![0.0f32; env.obs_dim()];
        let mut actions = Pcg64::seed_from_u64(0);
        let n = 20_000;
        let t = std::time::Instant::now();
        for _ in 0..n {
            let out = env.step(actions.random_range(0.0..0.5), actions.random_range(-1.5..1.5));
            env.write_obs(&mut obs);
            if out.done.is_some() {
                env.reset();
            }
        }
        let s = t.elapsed().as_secs_f64();
        println!("single env: {:.0} steps/s ({:.1} µs/step)", n as f64 / s, s / n as f64 * 1e6);
        let (lidar, room, pose) = (env.lidar().clone(), env.room().clone(), env.pose());
        let mut scan = vec![0.0f32; lidar.beams()];
        let t = std::time::Instant::now();
        for _ in 0..n {
            lidar.scan(&room, pose, None::<&mut Pcg64>, &mut scan);
        }
        let s = t.elapsed().as_secs_f64();
        println!(
            "scan alone: {:.1} µs ({:.0} ns/beam)",
            s / n as f64 * 1e6,
            s / n as f64 * 1e9 / 540.0
        );
        let m = n / 10;
        let t = std::time::Instant::now();
        for _ in 0..m {
            lidar.scan_reference(&room, pose, None::<&mut Pcg64>, &mut scan);
        }
        let s = t.elapsed().as_secs_f64();
        println!("rapier reference scan: {:.1} µs", s / m as f64 * 1e6);
    }
}
