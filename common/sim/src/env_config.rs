//! The simulated task's constants: the robot, its LiDAR and the reward (the `[env]` section of a
//! run's config file; `dvnav_config::Config` composes it with the other sections).

use crate::obs::ObsLayout;
use serde::{Deserialize, Serialize};

/// Constants of the simulated task (design §2; the paper's values are the defaults).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Control period ΔT in seconds.
    pub dt: f64,
    /// Radius of the circular meta robot in metres (the robot, unless `footprint` is set).
    pub robot_radius: f64,
    /// The robot's footprint when it is not the circular meta robot: `[env.footprint]` with
    /// `[[env.footprint.parts]]` as in a footprint file (README § Rooms). Absent: a disc of
    /// `robot_radius`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub footprint: Option<crate::Footprint>,
    /// Append the robot's radius (m) to the observation, after ω: the SAC_RI baseline's extra
    /// input (`configs/sac_ri.toml`). The policy's and the critics' first fully-connected layer
    /// take one input more. Needs the circular robot (no `footprint`). A policy trained so is
    /// driven on the gate with each robot's own radius as the input, not through DVST.
    pub radius_input: bool,
    /// `[min, max]` (m): every episode of `NavEnv::reset` draws the circular robot's radius
    /// uniformly from this range (spawn clearance follows the drawn radius); evaluation routes
    /// (`NavEnv::reset_to`) drive `robot_radius`. Absent: every episode is `robot_radius`.
    /// A range of more than one radius needs `radius_input`, so that a checkpoint without the
    /// radius input was always trained as one robot, the meta robot DVST assumes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_range: Option<[f64; 2]>,
    /// Linear velocity bound v_max (m/s); commands lie in [0, v_max].
    pub v_max: f64,
    /// Angular velocity bound ω_max (rad/s); commands lie in [-ω_max, ω_max].
    pub omega_max: f64,
    /// The goal is reached when the robot's centre is within this distance (m).
    pub goal_tolerance: f64,
    /// Episode length limit T_max in control steps (timeout, not a termination).
    pub max_steps: u32,
    /// Start and goal are drawn at least this far apart (m).
    pub min_start_goal_distance: f64,
    /// Extra free space (m) beyond the footprint required around sampled starts and goals.
    pub spawn_clearance: f64,
    /// Start and goal are drawn at most this far apart (m); 0: no bound.
    #[serde(skip_serializing_if = "is_zero")]
    pub max_start_goal_distance: f64,
    /// Sampled goals are reachable from the start for the robot's size: a disc of its bounding
    /// radius can drive from one to the other (a grid search, `dvnav_sim::grid`). Rooms that
    /// a gate or a door splits for big robots need it; in an open room it rejects nothing.
    #[serde(skip_serializing_if = "is_true")]
    pub reachable_tasks: bool,
    /// The shortest path from start to goal (for the robot's size) is at most this many times
    /// the straight line; 0: no bound. Local tasks in buildings use 1.5. Implies
    /// `reachable_tasks`.
    #[serde(skip_serializing_if = "is_zero")]
    pub max_path_ratio: f64,
    /// Longest translation (m) between two collision checks within one control step; keeps a
    /// fast robot from passing through a thin wall.
    pub collision_substep: f64,
    /// The LiDAR: the meta agent's beams, at the axle centre.
    pub lidar: LidarConfig,
    /// A real robot's LiDAR to observe through instead (`[env.sensor]`, or `dvnav eval --sensor
    /// FILE`): the environment simulates that sensor's `LaserScan` at its mounting and carries it
    /// over to `lidar`'s beams as `dvnav serve` would ([`crate::sensor`]). Absent: the meta
    /// agent's own LiDAR.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<crate::SensorSpec>,
    /// Long tasks along a planned path (`[env.subgoals]`, [`crate::subgoal`]): each episode
    /// plans a path for the robot's size and the agent observes the lookahead point on it as
    /// its goal; the reward's progress is the path left. Absent: the paper's mapless task.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subgoals: Option<crate::subgoal::SubgoalConfig>,
    /// Varied robots in training (`[env.dvst]`): a share of the episodes drive a bigger
    /// circular robot, observed and commanded through DVST ([`crate::transfer`]), so the meta
    /// agent learns the scaled worlds DVST shows it. Absent: every episode is the meta robot,
    /// as in the paper. Evaluations never draw them (`dvnav eval` drives the robots it names).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dvst: Option<DvstTrainingConfig>,
    /// The reward function.
    pub reward: RewardConfig,
    /// LiDAR dropout, observation latency, actuation noise and control-period jitter
    /// (`[env.robustness]`; none by default).
    #[serde(skip_serializing_if = "is_default")]
    pub robustness: crate::RobustnessConfig,
    /// With observation latency, carry the delayed scan and goal forward to the robot's pose
    /// now by the commands sent since ([`crate::latency`]), as a controller that knows its
    /// sensors' delay would. Off by default (the agent sees the delayed observation).
    #[serde(skip_serializing_if = "is_false")]
    pub latency_compensation: bool,
}

// Keys added after the first release stay out of a config's TOML (and its hash) while they
// hold their defaults, so older runs keep their config hashes.
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_true(b: &bool) -> bool {
    *b
}

fn is_default(r: &crate::RobustnessConfig) -> bool {
    *r == crate::RobustnessConfig::default()
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            dt: 0.2,
            robot_radius: 0.2,
            footprint: None,
            radius_input: false,
            radius_range: None,
            v_max: 0.5,
            omega_max: std::f64::consts::FRAC_PI_2,
            goal_tolerance: 0.2,
            max_steps: 400,
            min_start_goal_distance: 1.0,
            spawn_clearance: 0.1,
            max_start_goal_distance: 0.0,
            reachable_tasks: true,
            max_path_ratio: 0.0,
            collision_substep: 0.02,
            lidar: LidarConfig::default(),
            sensor: None,
            subgoals: None,
            dvst: None,
            reward: RewardConfig::default(),
            robustness: crate::RobustnessConfig::default(),
            latency_compensation: false,
        }
    }
}

/// `[env.dvst]`: which episodes of a training run drive a varied robot through DVST.
///
/// Such an episode draws a circle of radius R uniformly from `radius_range` and simulates it
/// in the room at its own size; the agent observes what DVST would show the meta agent for it
/// (lengths divided by μ = R / `robot_radius`, scans clamped to the meta LiDAR's range) and
/// its command goes through DVST's policy transfer within `v_max` and `omega_max`. The
/// reward's progress term is divided by μ, so that returns stay in the meta robot's units.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DvstTrainingConfig {
    /// `[min, max]` radius (m) of the varied robots, `robot_radius ≤ min ≤ max ≤ 2 m`.
    pub radius_range: [f64; 2],
    /// Share of episodes that drive a varied robot (the rest the meta robot), in [0, 1].
    pub share: f64,
}

impl DvstTrainingConfig {
    /// Checks the range against the meta robot's radius and the share; the key and the reason
    /// when wrong.
    pub fn check(&self, robot_radius: f64) -> Result<(), (String, String)> {
        let [lo, hi] = self.radius_range;
        if !(lo.is_finite() && hi.is_finite() && robot_radius <= lo && lo <= hi && hi <= 2.0) {
            return Err((
                "radius_range".into(),
                format!(
                    "needs robot_radius ({robot_radius} m) ≤ min ≤ max ≤ 2 m, got [{lo}, {hi}]"
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.share) {
            return Err(("share".into(), format!("must lie in [0, 1], got {}", self.share)));
        }
        Ok(())
    }
}

/// A planar LiDAR at the robot's axle centre.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    /// Number of beams, spread evenly over the field of view.
    pub beams: usize,
    /// Field of view in degrees, centred straight ahead.
    pub fov_deg: f64,
    /// Shortest range reported (m).
    pub range_min: f64,
    /// Longest range (m); a beam with no return reads this.
    pub range_max: f64,
    /// Standard deviation of Gaussian range noise (m); 0 for exact geometry.
    pub noise_std: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self { beams: 540, fov_deg: 270.0, range_min: 0.02, range_max: 10.0, noise_std: 0.0 }
    }
}

/// r_s on success, r_c on collision, otherwise c1·(d_t − d_{t+1}) − c2.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RewardConfig {
    /// r_s.
    pub success: f64,
    /// r_c.
    pub collision: f64,
    /// c1: weight of progress towards the goal (per metre).
    pub progress: f64,
    /// c2: time penalty per step.
    pub time_penalty: f64,
    /// c3: penalty per rad/s of change in the angular command from one step to the next,
    /// c3·|ω_t − ω_{t−1}| (not in the paper; 0 keeps its reward). Against the ω chatter real
    /// motors suffer (`dvnav eval`'s `reversal_rate`); the first step after a reset is free.
    #[serde(skip_serializing_if = "is_zero")]
    pub omega_change: f64,
    /// d_t is the length of the robot's shortest way to the goal (through the cells a disc of
    /// its radius can be at, on the planner's raster) instead of the straight line, when the
    /// agent observes its final goal (a followed route's d_t is already its path left). Not in
    /// the paper: the reward Habitat's PointNav pays, so that going round a wall is progress
    /// and pressing against it is not. Training only: evaluations ([`EnvConfig::clean`]) keep
    /// the straight line.
    #[serde(skip_serializing_if = "is_false")]
    pub geodesic_progress: bool,
}

impl Default for RewardConfig {
    fn default() -> Self {
        Self {
            success: 10.0,
            collision: -10.0,
            progress: 2.0,
            time_penalty: 0.01,
            omega_change: 0.0,
            geodesic_progress: false,
        }
    }
}

impl EnvConfig {
    /// The observation layout of environments with these constants.
    pub fn obs_layout(&self) -> ObsLayout {
        ObsLayout { beams: self.lidar.beams, radius_input: self.radius_input }
    }

    /// These constants without what only training draws, as evaluations drive an agent: no
    /// LiDAR noise, no robustness perturbations, no varied training robots (`dvst`), no
    /// subgoals (`dvnav eval` adds back what its command line asks for) and the paper's
    /// straight-line progress reward (a geodesic field per episode would slow evaluations, and
    /// their scores stay comparable with earlier ones).
    pub fn clean(&self) -> EnvConfig {
        EnvConfig {
            dvst: None,
            subgoals: None,
            robustness: Default::default(),
            lidar: LidarConfig { noise_std: 0.0, ..self.lidar.clone() },
            reward: RewardConfig { geodesic_progress: false, ..self.reward.clone() },
            ..self.clone()
        }
    }
}
