//! # dvnav-config
//!
//! The run configuration: one TOML file holds every setting, each with a documented default.
//!
//! Loading is strict on purpose: an unknown key is almost always a typo that would otherwise
//! silently leave a default in force, so it is refused with the key, the line and the keys that
//! are valid there; a value out of range is refused naming its dotted key and the reason.
//! `dvnav train` writes the config it used into the run directory, and the learner ships the same
//! text to every actor at registration, so one file describes the whole run.
#![warn(missing_docs)]

use dvnav_sim::obs::ObsLayout;
use dvnav_sim::room_set::{Alternative, RoomSet};
pub use dvnav_sim::{EnvConfig, LidarConfig, RewardConfig};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::hash::Hasher;
use std::path::{Path, PathBuf};

/// Everything a run needs, section by section. See `configs/default.toml` for the annotated file.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Seed and step budget.
    pub run: RunConfig,
    /// Simulator, robot, LiDAR and reward constants (design §2).
    pub env: EnvConfig,
    /// Network sizes (design §3).
    pub network: NetConfig,
    /// Soft Actor-Critic hyper-parameters (design §4).
    pub sac: SacConfig,
    /// Replay buffer.
    pub replay: ReplayConfig,
    /// Learner process: publishing, checkpointing, throttling.
    pub learner: LearnerConfig,
    /// Actor processes: environments per actor and batching.
    pub actor: ActorConfig,
    /// PID warm-up episodes at the start of a run.
    pub warmup: WarmupConfig,
    /// Room curriculum.
    pub curriculum: CurriculumConfig,
    /// MCAP episode logging.
    pub logging: LoggingConfig,
}

/// Seed and budget of a run.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Root seed; actors, environments and the learner derive theirs from it.
    pub seed: u64,
    /// Environment steps (transitions received by the learner) after which the run stops.
    pub steps: u64,
    /// Wall-clock seconds after which the learner stops the run as Ctrl-C would (checkpoint,
    /// summaries, `best/` kept), counted from the learner's start (again from a resume's); 0:
    /// no limit. For runs whose agent is kept by its evaluation (`runs/NAME/best`), where the
    /// step budget is only an upper bound.
    pub max_wall_s: f64,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self { seed: 1, steps: 500_000, max_wall_s: 0.0 }
    }
}

impl RunConfig {
    /// The wall-clock budget, if any.
    pub fn wall_budget(&self) -> Option<std::time::Duration> {
        (self.max_wall_s > 0.0).then(|| std::time::Duration::from_secs_f64(self.max_wall_s))
    }
}

/// Sizes of the default 1D-CNN network (design §3).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct NetConfig {
    /// Output channels of the first convolution.
    pub conv1_channels: usize,
    /// Kernel size of the first convolution.
    pub conv1_kernel: usize,
    /// Stride of the first convolution.
    pub conv1_stride: usize,
    /// Output channels of the second convolution.
    pub conv2_channels: usize,
    /// Kernel size of the second convolution.
    pub conv2_kernel: usize,
    /// Stride of the second convolution.
    pub conv2_stride: usize,
    /// Width of the scan feature vector after the convolutions.
    pub scan_features: usize,
    /// Width of the two hidden fully-connected layers.
    pub hidden: usize,
    /// Lower bound of the policy's log standard deviation.
    pub log_std_min: f64,
    /// Upper bound of the policy's log standard deviation.
    pub log_std_max: f64,
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            conv1_channels: 32,
            conv1_kernel: 20,
            conv1_stride: 5,
            conv2_channels: 32,
            conv2_kernel: 10,
            conv2_stride: 3,
            scan_features: 128,
            hidden: 256,
            log_std_min: -5.0,
            log_std_max: 2.0,
        }
    }
}

/// Soft Actor-Critic (Haarnoja et al. 2018/2019) as in the paper's equations.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SacConfig {
    /// Discount γ.
    pub gamma: f64,
    /// Polyak averaging rate τ of the target critics.
    pub tau: f64,
    /// Minibatch size. Default 128 rather than 256: on a 2-core CPU an update at 128 takes
    /// 0.17 s against 0.28 s at 256 (`dvnav bench learner`), and the learner is the bottleneck.
    /// `configs/paper.toml` keeps 256.
    pub batch_size: usize,
    /// Adam learning rate of the policy.
    pub actor_lr: f64,
    /// Adam learning rate of the critics.
    pub critic_lr: f64,
    /// Adam learning rate of log α when the temperature is tuned.
    pub alpha_lr: f64,
    /// Tune α towards `target_entropy` (true) or keep it at `initial_alpha`.
    pub autotune_alpha: bool,
    /// α at the start (and for ever, when not tuned).
    pub initial_alpha: f64,
    /// Target entropy for tuning; default −|A| = −2.
    pub target_entropy: Option<f64>,
    /// The policy (and α) are updated once every this many critic updates.
    pub policy_delay: u64,
    /// Coefficient of the L2 regularization of the policy weights.
    pub policy_l2: f64,
    /// Learner updates per environment step (replay ratio), held whatever the number of actors.
    /// Algorithm 1 of the paper is 1.0 (`configs/paper.toml`); the default 0.25 lets a 2-core
    /// machine collect four steps per update while the learner is CPU-bound.
    pub updates_per_env_step: f64,
    /// Transitions in the replay buffer before the first update.
    pub learning_starts: u64,
    /// Steps summed into each critic target (n-step return): the target is
    /// r_t + γ r_t+1 + … + γ^(k−1) r_t+k−1 + γ^k (1 − d) V(s_t+k), with k = n unless the
    /// episode ends, or the stored steps of the episode do (an actor's batch boundary), first.
    /// 1 is the paper's one-step target. Larger n propagates the goal's reward back faster
    /// at the cost of bias from the off-policy steps in between (no correction, as in
    /// Rainbow and D4PG).
    pub n_step: usize,
    /// Weight λ_BC of a behaviour-cloning term in the policy loss on the transitions a
    /// controller chose (the PID warm-up, the planner expert of `warmup.expert_share`), kept
    /// only where the critics rate the controller's action above the policy's (the Q-filter of
    /// Nair et al. 2018): + λ_BC · mean(m · ‖tanh μ_θ(s) − a‖²). 0 (the default): the paper's
    /// loss.
    pub bc_weight: f64,
    /// Rate τ_π of a Polyak average of the policy's weights, θ̄ ← τ_π θ + (1 − τ_π) θ̄ after
    /// each policy update (`sac.policy_delay`), so θ̄ averages the last ~1/τ_π policies. When
    /// above 0, θ̄ is the run's agent: a checkpoint's `policy.safetensors` (what `dvnav eval`
    /// and `dvnav serve` load) and the training-time evaluation (`eval.csv`, `gate.csv`) are
    /// θ̄, while the actors keep exploring with the online θ (also saved, as
    /// `policy-online.safetensors`, and evaluated into `gate-online.csv`). For a policy that
    /// learns and unlearns a skill within a few thousand updates, so that a run's last
    /// checkpoint falls on either side by chance. 0 (the default): the online policy is the
    /// agent, as in the paper.
    pub policy_average_tau: f64,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            tau: 0.005,
            batch_size: 128,
            actor_lr: 3e-4,
            critic_lr: 3e-4,
            alpha_lr: 3e-4,
            autotune_alpha: true,
            initial_alpha: 0.2,
            target_entropy: None,
            policy_delay: 2,
            policy_l2: 1e-3,
            updates_per_env_step: 0.25,
            learning_starts: 2_000,
            n_step: 1,
            bc_weight: 0.0,
            policy_average_tau: 0.0,
        }
    }
}

/// Longest n-step return (`sac.n_step`): an environment's steps are linked only inside one of
/// its actor's batches (`actor.batch_transitions` shared by `actor.envs`), so longer chains
/// would rarely be whole.
pub const MAX_N_STEP: usize = 32;

/// The replay buffer.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// Transitions kept; the oldest is overwritten first.
    pub capacity: usize,
    /// Write the whole buffer into every checkpoint (`replay.safetensors`), so a resumed run
    /// samples exactly what it would have sampled. Off by default: a full buffer of the
    /// default size is about 2 GB per checkpoint; without it a resumed learner waits for
    /// `sac.learning_starts` fresh transitions before it trains again.
    pub save_in_checkpoint: bool,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self { capacity: 500_000, save_in_checkpoint: false }
    }
}

/// The learner process.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// A new weight version is published to actors every this many updates.
    pub publish_every_updates: u64,
    /// A checkpoint is written every this many updates (and at the end of the run).
    pub checkpoint_every_updates: u64,
    /// Distinct actor names the learner registers over a run; one more is refused
    /// (RESOURCE_EXHAUSTED). Bounds the per-actor counters and the `actor` label values of
    /// `/metrics` against a caller that registers name after name. `dvnav train` uses one name
    /// per process, restarts included.
    pub max_actor_names: usize,
    /// A checkpoint is also written once this many seconds have passed since the last one
    /// (or the start) and training has moved since, so a learner killed early in a run, long
    /// before `checkpoint_every_updates`, resumes from one at most this old. 0: by updates
    /// only.
    pub checkpoint_every_s: f64,
    /// How many environment steps ingestion may run ahead of what the replay ratio allows
    /// before the learner stops reading transitions (backpressure to the actors).
    pub max_steps_ahead: u64,
    /// About how many transitions all actors' unacknowledged batches hold together: each
    /// actor is told to fill batches of this divided by the connected actors (at most its own
    /// `actor.batch_transitions`, at least 8). What waits in flight was acted by an old policy:
    /// inserted data was acted about this many environment steps ago, about this ×
    /// `sac.updates_per_env_step` / `publish_every_updates` weight versions (128 × 0.25 / 50 ≈
    /// 0.6 by default) whatever the number of actors (measured: docs/results.md, issue 16).
    pub transitions_in_flight: usize,
    /// Threads for the learner's update (0: one per core): the minibatch is cut into row
    /// shards that run side by side, candle single-threaded in each (its own pool's spin
    /// barriers made two threads slower than one). Default 2: two make an update 1.5-1.8x
    /// faster on an idle 2-core machine, and the default run reach its skill 1.37x sooner
    /// (docs/results.md, "Learner threads" and "Two threads by default").
    pub threads: usize,
    /// The arithmetic of the networks' matrix products in training: fp32, or bf16 operands
    /// with fp32 sums (master weights, Adam moments and losses stay fp32), or `auto` (the
    /// default): the learner times both at its start and trains in bf16 only where bf16 was
    /// faster (a Zen 4 with AVX512-BF16 reached the skill in 105 s against 131 s; a Zen 5,
    /// with twice as wide fp32 FMAs, runs bf16 updates slower than fp32: docs/results.md,
    /// "bf16 mixed precision"); fp32 untimed on CPUs without AVX512-BF16 and on GPUs.
    /// Actors always act in fp32.
    pub precision: Precision,
    /// On a CUDA device (`--device cuda`), capture the update once as a CUDA graph and
    /// replay it, instead of launching its kernels one by one. Off by default until measured
    /// on a GPU (docs/results.md, "CUDA graphs"); a capture the driver refuses falls back to
    /// op by op by itself.
    #[serde(skip_serializing_if = "is_false")]
    pub cuda_graph: bool,
    /// Every this many updates, evaluate the deterministic policy on the evaluation route of
    /// every curriculum room plus `eval_episodes` random episodes per room, and append the
    /// results to `eval.csv` in the run directory (design §4). 0: no evaluation.
    pub eval_every_updates: u64,
    /// Random episodes per room in each evaluation during training (0: the routes only); a
    /// stage that is a set of rooms spreads them over the set's first rooms (up to 4).
    /// The same seeded starts and goals every time, so the rows of `eval.csv` compare.
    pub eval_episodes: usize,
    /// With each evaluation, also run the paper's gate test (the twelve robots R = 0.20–0.75 m
    /// through DVST, clean, as `dvnav eval --scenario gate`) and append a row per robot to
    /// `gate.csv`: a run's behaviour at the trap is known while it trains. It is the paper's
    /// own test, not a held-out room. Off by default (it costs about as much as the rooms).
    #[serde(skip_serializing_if = "is_false")]
    pub eval_gate: bool,
    /// The best agent's own evaluation (`[learner.selection]`): with each evaluation, local
    /// tasks for robots of several sizes in rooms of the training distribution, and the run
    /// keeps its best agent by them (`RUN/best`). Absent: the best agent is picked by the
    /// evaluation rows themselves (the meta robot in the curriculum's rooms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub selection: Option<SelectionConfig>,
    /// The heartbeat interval (s). Actors deliver what they have at least every quarter
    /// interval, even a part batch, and the learner's watchdog names a component that made
    /// no progress for a whole interval (ingest, trainer, rate limiter, each actor) within one
    /// interval of its last progress.
    pub heartbeat_s: f64,
    /// `GET /healthz` answers 503 once the trainer or the rate limiter has been stalled this
    /// long (s), so a supervisor restarts a wedged learner (which resumes from its newest
    /// checkpoint). 0: never.
    pub liveness_stall_s: f64,
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            publish_every_updates: 50,
            checkpoint_every_updates: 10_000,
            checkpoint_every_s: 300.0,
            max_actor_names: 1024,
            max_steps_ahead: 2_000,
            transitions_in_flight: 128,
            threads: 2,
            precision: Precision::Auto,
            cuda_graph: false,
            eval_every_updates: 2_000,
            eval_episodes: 10,
            eval_gate: false,
            selection: None,
            heartbeat_s: 10.0,
            liveness_stall_s: 300.0,
        }
    }
}

/// What the best agent of a run is picked by (`[learner.selection]`, issue 29): the issue's local
/// tasks (start and goal 2-5 m apart, a collision-free path at most 1.5x the straight line),
/// clean, for a circular robot of each of `radii` through DVST, in `room_count` rooms of the room
/// set `rooms` (the curriculum's syntax; drawn round-robin over its alternatives, the first
/// seeds of each). The training-time evaluation's own rooms test the meta robot alone with a
/// few episodes per stage, a noisy score that knows nothing of big robots; this one is sized
/// to tell two agents apart. Its rooms must be training rooms (generated seeds below 9000):
/// the held-out suite stays held out.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SelectionConfig {
    /// Room set, e.g. `generated:clutter:0..2000|generated:corridors:0..2000`.
    pub rooms: String,
    /// Rooms drawn from the set.
    pub room_count: usize,
    /// Robot radii (m), each through DVST from the meta robot.
    pub radii: Vec<f64>,
    /// Episodes per room and robot, the same seeded starts and goals at every evaluation.
    pub episodes: usize,
    /// With `learner.eval_gate`: the gate test as a bar instead of half the score. An agent
    /// whose gate test passes at least this many of its twelve robots ranks above every agent
    /// that passes fewer, and among those the selection's rows alone decide; agents below the
    /// bar rank among themselves as without one (a run that never reaches it ranked by the
    /// selection alone kept a gate-7 agent over its gate-11 ones, g40). 0 (the default):
    /// the score is the mean of the rows' success and the gate's share, as g28-g32 ran, which
    /// let a 12-of-12 agent with weaker local skill win over an 11-of-12 one (g32).
    #[serde(skip_serializing_if = "is_zero")]
    pub gate_min_passed: usize,
}

impl Default for SelectionConfig {
    fn default() -> Self {
        Self {
            rooms: String::new(),
            room_count: 12,
            radii: vec![0.2, 0.4, 0.6],
            episodes: 16,
            gate_min_passed: 0,
        }
    }
}

/// The robots of the paper's gate test (`dvnav_eval::GATE_RADII`, R = 0.20-0.75 m by 0.05).
pub const GATE_ROBOTS: usize = 12;

// Keys added after their section was first released stay out of a config's TOML (and its hash)
// while off, so older runs keep their config hashes.
fn is_false(b: &bool) -> bool {
    !*b
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The arithmetic of the learner's matrix products (`learner.precision`).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// fp32 operands and sums.
    Fp32,
    /// bfloat16 operands (rounded to nearest even), fp32 sums: twice the multiply rate on CPUs
    /// with AVX512-BF16, the same arithmetic at the fp32 rate elsewhere.
    Bf16,
    /// Chosen where the learner runs: bf16 where it timed bf16 updates faster than fp32,
    /// fp32 elsewhere (`dvnav_learner::bench::precision`).
    #[default]
    Auto,
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fp32" => Ok(Precision::Fp32),
            "bf16" => Ok(Precision::Bf16),
            "auto" => Ok(Precision::Auto),
            other => Err(format!("unknown precision `{other}`: expected `fp32`, `bf16` or `auto`")),
        }
    }
}

impl fmt::Display for Precision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Precision::Fp32 => "fp32",
            Precision::Bf16 => "bf16",
            Precision::Auto => "auto",
        })
    }
}

/// An actor process.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ActorConfig {
    /// Environments each actor steps side by side (one policy forward pass for all of them).
    pub envs: usize,
    /// Transitions per batch sent to the learner.
    pub batch_transitions: usize,
    /// Batches that may wait for the network before the environment loop blocks.
    pub send_queue_batches: usize,
    /// Batches handed to the learner and not yet acknowledged before the environment loop
    /// blocks, before it starts the next one: fresh data (the policy lag of what the learner
    /// inserts) against actor idle time. 1: an actor acts its next batch once the learner has
    /// taken the last.
    pub max_batches_in_flight: usize,
}

impl Default for ActorConfig {
    fn default() -> Self {
        Self { envs: 4, batch_transitions: 128, send_queue_batches: 4, max_batches_in_flight: 1 }
    }
}

/// The PID controller that acts during the first episodes of a run (design §4).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct WarmupConfig {
    /// Episodes of the run (all actors together) driven by the PID controller.
    pub pid_episodes: u64,
    /// v = clip(kp_linear · x_g, 0, v_max).
    pub kp_linear: f64,
    /// ω = clip(kp_angular · y_g, −ω_max, ω_max).
    pub kp_angular: f64,
    /// Share of the episodes after the warm-up (drawn per episode) driven by the planner
    /// expert: the PID controller aimed at the subgoal on the episode's planned path
    /// (`[env.subgoals]`, which it needs), while the agent observes what it would observe (the
    /// final goal in a mapless episode). Its transitions go to the replay buffer like the
    /// warm-up's, so the critics see detours round walls that the policy itself has not found.
    /// 0 (the default): none.
    pub expert_share: f64,
    /// The planner expert turns in place while its subgoal is more than this many degrees off
    /// its heading.
    pub expert_turn_deg: f64,
}

impl Default for WarmupConfig {
    fn default() -> Self {
        Self {
            pid_episodes: 100,
            kp_linear: 1.0,
            kp_angular: 10.0,
            expert_share: 0.0,
            expert_turn_deg: 45.0,
        }
    }
}

/// Rooms of shrinking size; the learner moves the run on when the success rate is high enough.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CurriculumConfig {
    /// The stages' rooms, easiest first. Each stage is a room name or path as `Room::load`
    /// takes it (a built-in room, a room file, `generated:KIND:SEED[:PARAMS]`, a map), or a
    /// set of rooms drawn per episode: alternatives separated by `|`, each a name or a range of
    /// generated seeds `generated:KIND:A..B[:PARAMS]` (`dvnav_sim::room_set`).
    pub rooms: Vec<String>,
    /// Episodes of the current stage over which the success rate is measured.
    pub window: usize,
    /// Success rate over the window that moves the run to the next stage.
    pub threshold: f64,
    /// Share of episodes an actor runs in an earlier room (drawn uniformly among them) once
    /// the run is past the first stage, so skills of the bigger rooms are not forgotten.
    pub earlier_share: f64,
    /// End the run (a clean stop with a final checkpoint) once the last room's success rate
    /// over a full window reaches the threshold: the "time to skill" runs of the seed sweep.
    pub stop_when_skilled: bool,
    /// The first stage (0-based) whose episodes get `[env.robustness]`; the stages before it
    /// run clean. `None` (the default): every stage. Noise from the start kept the generalist
    /// from learning the clean skill (docs/results.md, "Experiment log"), so a late stage can
    /// add it once that skill is there. Decided by the run's stage, so the earlier rooms
    /// revisited through `earlier_share` get it too once the run is there.
    pub robust_from_stage: Option<u32>,
    /// The replay ratio (updates per environment step) of each stage, in order; stages past
    /// the list's end keep its last value. Empty (the default): `sac.updates_per_env_step` in
    /// every stage. Environment steps are nearly free and the learner sets the pace, so a
    /// later stage that only has to show the skill in a smaller room may need fewer updates
    /// per episode than the first, where the skill is learned (docs/results.md, "Time to
    /// skill").
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub replay_ratios: Vec<f64>,
}

impl CurriculumConfig {
    /// The replay ratio of `stage`: its entry of [`Self::replay_ratios`], the last entry past
    /// the list's end, or `default` (`sac.updates_per_env_step`) when the list is empty.
    pub fn replay_ratio(&self, stage: usize, default: f64) -> f64 {
        self.replay_ratios.get(stage).or(self.replay_ratios.last()).copied().unwrap_or(default)
    }
}

impl Default for CurriculumConfig {
    fn default() -> Self {
        Self {
            rooms: ["env0", "env1", "env2", "env3"].map(String::from).to_vec(),
            window: 50,
            threshold: 0.9,
            earlier_share: 0.0,
            stop_when_skilled: false,
            robust_from_stage: None,
            replay_ratios: Vec::new(),
        }
    }
}

/// Which episodes actors write to MCAP, and how files are cut.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LoggingConfig {
    /// Log every Nth training episode of each actor (1: all, 0: none).
    pub every_nth_episode: u64,
    /// Start a new MCAP file after this many logged episodes, so a killed actor loses at most
    /// the open file's tail.
    pub episodes_per_file: u64,
    /// Also start a new file once one reaches this size (MiB; 0: no size limit). Episodes never
    /// straddle files, so a file may pass it by one episode.
    pub max_file_mb: u64,
}

impl Default for LoggingConfig {
    fn default() -> Self {
        Self { every_nth_episode: 10, episodes_per_file: 20, max_file_mb: 64 }
    }
}

/// A configuration value that cannot be used, named by its dotted key.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    /// The file the value came from, when it came from a file.
    pub file: Option<PathBuf>,
    /// Dotted key, e.g. `sac.gamma`; empty for a syntax error.
    pub key: String,
    /// What is wrong and what would be right.
    pub reason: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (&self.file, self.key.is_empty()) {
            (Some(p), false) => write!(f, "{}: `{}`: {}", p.display(), self.key, self.reason),
            (Some(p), true) => write!(f, "{}: {}", p.display(), self.reason),
            (None, false) => write!(f, "`{}`: {}", self.key, self.reason),
            (None, true) => write!(f, "{}", self.reason),
        }
    }
}

impl std::error::Error for ConfigError {}

fn bad(key: &str, reason: impl Into<String>) -> ConfigError {
    ConfigError { file: None, key: key.to_string(), reason: reason.into() }
}

impl Config {
    /// Parses TOML text, refusing unknown keys, and validates every value.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let cfg: Config = toml::from_str(text).map_err(|e| ConfigError {
            file: None,
            key: String::new(),
            reason: e.to_string().trim_end().to_string(),
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads and validates a config file; errors name the file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            file: Some(path.to_path_buf()),
            key: String::new(),
            reason: format!("cannot read config file: {e}"),
        })?;
        Self::from_toml_str(&text).map_err(|mut e| {
            e.file = Some(path.to_path_buf());
            e
        })
    }

    /// The config as TOML, every key written out (what `dvnav train` stores in the run).
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("config serializes to TOML")
    }

    /// A short stable fingerprint of the config (FNV-1a 64 of its TOML), for log metadata.
    pub fn hash_hex(&self) -> String {
        let mut h = fnv::FnvHasher::default();
        h.write(self.to_toml_string().as_bytes());
        let h = h.finish();
        format!("{h:016x}")
    }

    /// The observation layout: the scan, goal (distance, angle), velocity (v, ω), and the
    /// robot's radius with `env.radius_input`.
    pub fn obs_layout(&self) -> ObsLayout {
        self.env.obs_layout()
    }

    /// Scalars after the scan: 4, or 5 with `env.radius_input`.
    pub fn obs_extra(&self) -> usize {
        self.obs_layout().extra()
    }

    /// Length of the flat observation vector (544 by default).
    pub fn obs_dim(&self) -> usize {
        self.obs_layout().dim()
    }

    /// Checks every value for range and consistency.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let e = &self.env;
        positive("env.dt", e.dt)?;
        positive("env.robot_radius", e.robot_radius)?;
        if let Some(f) = &e.footprint {
            f.validate().map_err(|err| bad("env.footprint", format!("{err:#}")))?;
        }
        if let Some(s) = &e.sensor {
            s.validate().map_err(|(k, r)| bad(&format!("env.sensor.{k}"), r))?;
        }
        self.validate_radius_range()?;
        positive("env.v_max", e.v_max)?;
        positive("env.omega_max", e.omega_max)?;
        positive("env.goal_tolerance", e.goal_tolerance)?;
        positive("env.collision_substep", e.collision_substep)?;
        non_negative("env.min_start_goal_distance", e.min_start_goal_distance)?;
        non_negative("env.spawn_clearance", e.spawn_clearance)?;
        non_negative("env.max_start_goal_distance", e.max_start_goal_distance)?;
        e.robustness.check().map_err(|(k, r)| bad(&format!("env.robustness.{k}"), r))?;
        if let Some(sg) = &e.subgoals {
            sg.check().map_err(|(k, r)| bad(&k, r))?;
        }
        if let Some(d) = &e.dvst {
            d.check(e.robot_radius).map_err(|(k, r)| bad(&format!("env.dvst.{k}"), r))?;
            if e.footprint.is_some() || e.radius_input || e.radius_range.is_some() {
                return Err(bad(
                    "env.dvst",
                    "drives the circular meta robot's varied robots through DVST; it cannot be \
                     combined with env.footprint, env.radius_input or env.radius_range",
                ));
            }
        }
        if e.max_start_goal_distance > 0.0 && e.max_start_goal_distance < e.min_start_goal_distance
        {
            return Err(bad(
                "env.max_start_goal_distance",
                format!(
                    "{} is below env.min_start_goal_distance ({}); set it higher, or 0 for no bound",
                    e.max_start_goal_distance, e.min_start_goal_distance
                ),
            ));
        }
        if e.max_path_ratio != 0.0 && !(e.max_path_ratio >= 1.0 && e.max_path_ratio.is_finite()) {
            return Err(bad(
                "env.max_path_ratio",
                format!(
                    "must be 0 (no bound) or at least 1 (a path is never shorter than the \
                     straight line), got {}",
                    e.max_path_ratio
                ),
            ));
        }
        if e.max_steps == 0 {
            return Err(bad("env.max_steps", "must be at least 1"));
        }
        let l = &e.lidar;
        if l.beams < 2 {
            return Err(bad("env.lidar.beams", "must be at least 2"));
        }
        if !(l.fov_deg > 0.0 && l.fov_deg <= 360.0) {
            return Err(bad(
                "env.lidar.fov_deg",
                format!("must be in (0, 360], got {}", l.fov_deg),
            ));
        }
        non_negative("env.lidar.range_min", l.range_min)?;
        if !(l.range_max.is_finite() && l.range_max > l.range_min) {
            return Err(bad("env.lidar.range_max", "must be finite and greater than range_min"));
        }
        non_negative("env.lidar.noise_std", l.noise_std)?;
        for (k, v) in [
            ("env.reward.success", e.reward.success),
            ("env.reward.collision", e.reward.collision),
            ("env.reward.progress", e.reward.progress),
            ("env.reward.time_penalty", e.reward.time_penalty),
        ] {
            finite(k, v)?;
        }

        let n = &self.network;
        for (k, v) in [
            ("network.conv1_channels", n.conv1_channels),
            ("network.conv1_kernel", n.conv1_kernel),
            ("network.conv1_stride", n.conv1_stride),
            ("network.conv2_channels", n.conv2_channels),
            ("network.conv2_kernel", n.conv2_kernel),
            ("network.conv2_stride", n.conv2_stride),
            ("network.scan_features", n.scan_features),
            ("network.hidden", n.hidden),
        ] {
            if v == 0 {
                return Err(bad(k, "must be at least 1"));
            }
        }
        if n.conv_output_len(l.beams).is_none() {
            return Err(bad(
                "network.conv1_kernel",
                format!("the convolutions do not fit a scan of {} beams", l.beams),
            ));
        }
        let log_std_ok =
            n.log_std_min.is_finite() && n.log_std_max.is_finite() && n.log_std_min < n.log_std_max;
        if !log_std_ok {
            return Err(bad("network.log_std_min", "must be below network.log_std_max"));
        }

        let s = &self.sac;
        if !(s.gamma > 0.0 && s.gamma < 1.0) {
            return Err(bad("sac.gamma", format!("must be in (0, 1), got {}", s.gamma)));
        }
        if !(s.tau > 0.0 && s.tau <= 1.0) {
            return Err(bad("sac.tau", format!("must be in (0, 1], got {}", s.tau)));
        }
        if s.batch_size == 0 {
            return Err(bad("sac.batch_size", "must be at least 1"));
        }
        positive("sac.actor_lr", s.actor_lr)?;
        positive("sac.critic_lr", s.critic_lr)?;
        positive("sac.alpha_lr", s.alpha_lr)?;
        positive("sac.initial_alpha", s.initial_alpha)?;
        if let Some(t) = s.target_entropy {
            finite("sac.target_entropy", t)?;
        }
        if s.policy_delay == 0 {
            return Err(bad("sac.policy_delay", "must be at least 1"));
        }
        non_negative("sac.policy_l2", s.policy_l2)?;
        non_negative("sac.bc_weight", s.bc_weight)?;
        if !(0.0..=1.0).contains(&s.policy_average_tau) {
            return Err(bad(
                "sac.policy_average_tau",
                format!("must be in [0, 1] (0: off), got {}", s.policy_average_tau),
            ));
        }
        positive("sac.updates_per_env_step", s.updates_per_env_step)?;
        if !(1..=MAX_N_STEP).contains(&s.n_step) {
            return Err(bad(
                "sac.n_step",
                format!("must be in 1..={MAX_N_STEP} (1: one-step targets), got {}", s.n_step),
            ));
        }
        if self.replay.capacity < s.batch_size {
            return Err(bad("replay.capacity", "must hold at least one batch (sac.batch_size)"));
        }
        if s.learning_starts < s.batch_size as u64 {
            return Err(bad("sac.learning_starts", "must be at least sac.batch_size"));
        }

        let le = &self.learner;
        if le.publish_every_updates == 0 {
            return Err(bad("learner.publish_every_updates", "must be at least 1"));
        }
        if le.checkpoint_every_updates == 0 {
            return Err(bad("learner.checkpoint_every_updates", "must be at least 1"));
        }
        if le.max_actor_names == 0 {
            return Err(bad("learner.max_actor_names", "must be at least 1"));
        }
        if !(le.checkpoint_every_s.is_finite() && le.checkpoint_every_s >= 0.0) {
            return Err(bad("learner.checkpoint_every_s", "must be 0 (off) or a positive time"));
        }
        // Below 0.1 s the watchdog's sampling (a fifth of it) would cost more than it tells.
        if !(le.heartbeat_s.is_finite() && le.heartbeat_s >= 0.1) {
            return Err(bad(
                "learner.heartbeat_s",
                format!("must be a finite number of seconds ≥ 0.1, got {}", le.heartbeat_s),
            ));
        }
        non_negative("learner.liveness_stall_s", le.liveness_stall_s)?;
        if le.transitions_in_flight == 0 {
            return Err(bad("learner.transitions_in_flight", "must be at least 1"));
        }
        if let Some(sel) = &le.selection {
            self.validate_selection(sel)?;
        }
        let a = &self.actor;
        if a.envs == 0 {
            return Err(bad("actor.envs", "must be at least 1"));
        }
        if a.batch_transitions == 0 {
            return Err(bad("actor.batch_transitions", "must be at least 1"));
        }
        if a.send_queue_batches == 0 {
            return Err(bad("actor.send_queue_batches", "must be at least 1"));
        }
        if a.max_batches_in_flight == 0 {
            return Err(bad("actor.max_batches_in_flight", "must be at least 1"));
        }
        if le.max_steps_ahead < a.batch_transitions as u64 {
            return Err(bad(
                "learner.max_steps_ahead",
                "must be at least actor.batch_transitions, or ingestion could never proceed",
            ));
        }
        positive("warmup.kp_linear", self.warmup.kp_linear)?;
        positive("warmup.kp_angular", self.warmup.kp_angular)?;
        let w = &self.warmup;
        if !(0.0..=1.0).contains(&w.expert_share) {
            return Err(bad(
                "warmup.expert_share",
                format!("must be in [0, 1], not {}", w.expert_share),
            ));
        }
        if w.expert_share > 0.0 && self.env.subgoals.is_none() {
            return Err(bad(
                "warmup.expert_share",
                "the planner expert follows each episode's planned path: add an [env.subgoals] \
                 table (follow_share = 0 keeps every episode mapless)",
            ));
        }
        if !(w.expert_turn_deg > 0.0 && w.expert_turn_deg < 180.0) {
            return Err(bad(
                "warmup.expert_turn_deg",
                format!("must lie in (0, 180), not {}", w.expert_turn_deg),
            ));
        }
        let c = &self.curriculum;
        if c.rooms.is_empty() {
            return Err(bad("curriculum.rooms", "needs at least one room"));
        }
        for (i, stage) in c.rooms.iter().enumerate() {
            validate_stage(stage).map_err(|e| bad(&format!("curriculum.rooms[{i}]"), e))?;
        }
        if c.window == 0 {
            return Err(bad("curriculum.window", "must be at least 1"));
        }
        if !(c.threshold > 0.0 && c.threshold <= 1.0) {
            return Err(bad("curriculum.threshold", "must be in (0, 1]"));
        }
        if let Some(from) = c.robust_from_stage
            && from as usize >= c.rooms.len()
        {
            return Err(bad(
                "curriculum.robust_from_stage",
                format!(
                    "is {from}, but the curriculum has {} stages (0-based: at most {})",
                    c.rooms.len(),
                    c.rooms.len().saturating_sub(1)
                ),
            ));
        }
        if !(0.0..=1.0).contains(&c.earlier_share) {
            return Err(bad("curriculum.earlier_share", "must be in [0, 1]"));
        }
        if c.replay_ratios.len() > c.rooms.len() {
            return Err(bad(
                "curriculum.replay_ratios",
                format!(
                    "has {} entries, but the curriculum has {} stages (one ratio per stage)",
                    c.replay_ratios.len(),
                    c.rooms.len()
                ),
            ));
        }
        for (i, &r) in c.replay_ratios.iter().enumerate() {
            positive(&format!("curriculum.replay_ratios[{i}]"), r)?;
        }
        if self.logging.episodes_per_file == 0 {
            return Err(bad("logging.episodes_per_file", "must be at least 1"));
        }
        if self.run.steps == 0 {
            return Err(bad("run.steps", "must be at least 1"));
        }
        non_negative("run.max_wall_s", self.run.max_wall_s)?;
        Ok(())
    }
}

impl Config {
    /// `env.radius_input` and `env.radius_range`: a circular robot, a range of positive radii
    /// that fits every built-in curriculum room, and the radius input when the range holds
    /// more than one radius.
    /// `[learner.selection]`: a room set of rooms that exist, at least one room, episode and
    /// robot, and a meta robot DVST can scale (circular, no radius input).
    fn validate_selection(&self, sel: &SelectionConfig) -> Result<(), ConfigError> {
        let key = "learner.selection";
        if sel.rooms.is_empty() {
            return Err(bad(
                &format!("{key}.rooms"),
                "must name the rooms to select in (a room set, as a curriculum stage)",
            ));
        }
        validate_stage(&sel.rooms).map_err(|e| bad(&format!("{key}.rooms"), e))?;
        if sel.room_count == 0 {
            return Err(bad(&format!("{key}.room_count"), "must be at least 1"));
        }
        if sel.episodes == 0 {
            return Err(bad(&format!("{key}.episodes"), "must be at least 1"));
        }
        if sel.radii.is_empty() || sel.radii.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(bad(
                &format!("{key}.radii"),
                format!("must be one or more positive radii (m), got {:?}", sel.radii),
            ));
        }
        if sel.gate_min_passed > 0 && !self.learner.eval_gate {
            return Err(bad(
                &format!("{key}.gate_min_passed"),
                "is a bar on the gate test: set learner.eval_gate = true, or remove it",
            ));
        }
        if sel.gate_min_passed > GATE_ROBOTS {
            return Err(bad(
                &format!("{key}.gate_min_passed"),
                format!(
                    "must be at most {GATE_ROBOTS}, the gate test's robots, got {}",
                    sel.gate_min_passed
                ),
            ));
        }
        let e = &self.env;
        if e.footprint.is_some() || e.radius_input || e.radius_range.is_some() {
            return Err(bad(
                &format!("{key}.radii"),
                "drive the circular meta robot's scaled robots through DVST; it cannot be \
                 combined with env.footprint, env.radius_input or env.radius_range",
            ));
        }
        Ok(())
    }

    fn validate_radius_range(&self) -> Result<(), ConfigError> {
        let e = &self.env;
        if e.radius_input && e.footprint.is_some() {
            return Err(bad(
                "env.radius_input",
                "the radius input describes the circular robot; remove env.footprint",
            ));
        }
        let Some([lo, hi]) = e.radius_range else { return Ok(()) };
        if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi) {
            return Err(bad(
                "env.radius_range",
                format!("must be [min, max] with 0 < min ≤ max (m), got [{lo}, {hi}]"),
            ));
        }
        if e.footprint.is_some() {
            return Err(bad(
                "env.radius_range",
                "draws circular robots; it cannot be combined with env.footprint",
            ));
        }
        if lo < hi && !e.radius_input {
            return Err(bad(
                "env.radius_range",
                format!(
                    "robots of radius {lo} to {hi} m need env.radius_input = true (a policy \
                     that cannot see the radius); for one robot size set env.robot_radius"
                ),
            ));
        }
        let need = hi + e.spawn_clearance;
        // Built-in rooms named in any stage (alone or in a set); other rooms are checked when
        // they are loaded, and stages that do not parse are reported by `validate`.
        let named: Vec<String> = self
            .curriculum
            .rooms
            .iter()
            .filter_map(|stage| RoomSet::parse(stage).ok())
            .flat_map(|set| set.alternatives().to_vec())
            .filter_map(|a| match a {
                Alternative::Name(n) => Some(n),
                Alternative::Generated { .. } => None,
            })
            .collect();
        for spec in dvnav_sim::room_file::builtin_specs() {
            if named.contains(&spec.name) && need >= spec.side / 2.0 {
                return Err(bad(
                    "env.radius_range",
                    format!(
                        "a robot of radius {hi} m (+ env.spawn_clearance {c}) does not fit \
                         room `{name}` ({side}x{side} m)",
                        c = e.spawn_clearance,
                        name = spec.name,
                        side = spec.side
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl NetConfig {
    /// Length and channel count of the second convolution's output for a scan of `beams`, or
    /// `None` when a kernel is longer than its input.
    pub fn conv_output_len(&self, beams: usize) -> Option<(usize, usize)> {
        let l1 = conv_len(beams, self.conv1_kernel, self.conv1_stride)?;
        let l2 = conv_len(l1, self.conv2_kernel, self.conv2_stride)?;
        Some((l2, self.conv2_channels))
    }
}

fn conv_len(input: usize, kernel: usize, stride: usize) -> Option<usize> {
    (input >= kernel && stride > 0).then(|| (input - kernel) / stride + 1)
}

/// One `curriculum.rooms` entry: a room set whose names are built-in rooms, generated rooms
/// (checked by parsing; built when loaded), or files that exist (a map image may carry
/// `:resolution=…` after its path).
fn validate_stage(stage: &str) -> Result<(), String> {
    let set = RoomSet::parse(stage).map_err(|e| format!("{e:#}"))?;
    let builtin = dvnav_sim::Room::builtin_names();
    for alt in set.alternatives() {
        let Alternative::Name(name) = alt else { continue };
        let is_file = |p: &str| Path::new(p).is_file();
        let known = builtin.contains(name)
            || name.starts_with(dvnav_sim::generate::PREFIX)
            || is_file(name)
            || (dvnav_sim::grid_map::is_map_name(name)
                && name.rsplit_once(':').is_some_and(|(path, _)| is_file(path)));
        if !known {
            return Err(format!(
                "room `{name}` is neither a built-in room ({}), a generated room \
                 (generated:KIND:SEED or generated:KIND:A..B), nor an existing file",
                builtin.join(", ")
            ));
        }
    }
    Ok(())
}

fn finite(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() { Ok(()) } else { Err(bad(key, format!("must be a finite number, got {v}"))) }
}

fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(bad(key, format!("must be a finite number above 0, got {v}")))
    }
}

fn non_negative(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(bad(key, format!("must be a finite number ≥ 0, got {v}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_round_trip() {
        let cfg = Config::default();
        cfg.validate().unwrap();
        let text = cfg.to_toml_string();
        assert_eq!(Config::from_toml_str(&text).unwrap(), cfg);
        assert_eq!(cfg.network.conv_output_len(540), Some((32, 32)));
    }

    #[test]
    fn the_wall_budget_is_off_by_default_and_refuses_a_negative_or_endless_one() {
        assert_eq!(Config::default().run.wall_budget(), None);
        let cfg = Config::from_toml_str("[run]\nmax_wall_s = 1800\n").unwrap();
        assert_eq!(cfg.run.wall_budget(), Some(std::time::Duration::from_secs(1800)));
        for bad in ["-1", "inf", "nan"] {
            let text = format!("[run]\nmax_wall_s = {bad}\n");
            let err = Config::from_toml_str(&text).unwrap_err().to_string();
            assert!(err.contains("run.max_wall_s"), "{bad}: {err}");
        }
    }

    #[test]
    fn shipped_config_files_parse_and_default_toml_matches_the_defaults() {
        let default = include_str!("../../../configs/default.toml");
        assert_eq!(Config::from_toml_str(default).unwrap(), Config::default());
        let paper = Config::from_toml_str(include_str!("../../../configs/paper.toml")).unwrap();
        assert_eq!((paper.sac.batch_size, paper.sac.updates_per_env_step), (256, 1.0));
    }

    #[test]
    fn the_default_precision_is_auto_and_each_precision_parses() {
        let cfg = Config::default();
        assert_eq!(cfg.learner.precision, Precision::Auto);
        for p in [Precision::Fp32, Precision::Bf16, Precision::Auto] {
            assert_eq!(p.to_string().parse::<Precision>(), Ok(p));
            let text = format!("[learner]\nprecision = \"{p}\"\n");
            assert_eq!(Config::from_toml_str(&text).unwrap().learner.precision, p);
        }
        let err = "fp16".parse::<Precision>().unwrap_err();
        assert!(err.contains("`fp16`") && err.contains("`auto`"), "{err}");
        assert!(Config::from_toml_str("[learner]\nprecision = \"fp16\"\n").is_err());
    }

    #[test]
    fn the_default_observation_is_the_meta_agents_544() {
        let cfg = Config::default();
        assert_eq!((cfg.obs_dim(), cfg.obs_extra()), (544, 4));
        assert!(!cfg.env.radius_input && cfg.env.radius_range.is_none());
        // A run config written before the radius keys existed (the shipped meta agent's)
        // loads with the same layout.
        let old = Config::from_toml_str("[env]\nrobot_radius = 0.2\n").unwrap();
        assert_eq!(old, cfg);
        assert!(!cfg.to_toml_string().contains("radius_range"), "absent stays absent");
    }

    #[test]
    fn the_sac_ri_config_is_the_defaults_with_the_radius_input_in_the_12_m_room() {
        let ri = Config::from_toml_str(include_str!("../../../configs/sac_ri.toml")).unwrap();
        assert_eq!(ri.curriculum.rooms, ["sac_ri"]);
        assert!(ri.env.radius_input);
        assert_eq!(ri.env.radius_range, Some([0.2, 0.5]));
        assert_eq!((ri.obs_dim(), ri.obs_extra()), (545, 5));
        let mut back = ri.clone();
        (back.env.radius_input, back.env.radius_range) = (false, None);
        back.curriculum.rooms = CurriculumConfig::default().rooms;
        assert_eq!(back, Config::default(), "everything else is the default");
        assert_eq!(Config::from_toml_str(&ri.to_toml_string()).unwrap(), ri);
    }

    #[test]
    fn the_subgoals_config_is_the_defaults_with_subgoals_and_no_shim() {
        let c = Config::from_toml_str(include_str!("../../../configs/subgoals.toml")).unwrap();
        c.validate().unwrap();
        let sg = c.env.subgoals.clone().unwrap();
        assert!(sg.follow && !sg.rotation_shim);
        let without = Config { env: EnvConfig { subgoals: None, ..c.env.clone() }, ..c };
        assert_eq!(without, Config::default());
    }

    #[test]
    fn the_generalist_config_is_the_defaults_with_room_sets_robustness_and_smoothness() {
        let g = Config::from_toml_str(include_str!("../../../configs/generalist.toml")).unwrap();
        g.validate().unwrap();
        assert_eq!(g.curriculum.rooms.len(), 4);
        assert!(
            g.curriculum.rooms[3].split('|').any(|r| r == "env3"),
            "the last stage keeps the paper's Env_3"
        );
        // Training draws perturbations from ranges; the fixed values (what evaluation uses
        // unless asked) stay clean apart from the actuation σ the ranges scale.
        let r = &g.env.robustness;
        assert!(r.randomize.is_some());
        assert_eq!((r.beam_dropout, r.latency_steps, r.dt_jitter), (0.0, 0, 0.0));
        assert_eq!(g.env.lidar.noise_std, 0.0);
        assert!(g.env.reward.omega_change > 0.0);
        let mut back = g.clone();
        back.curriculum.rooms = CurriculumConfig::default().rooms;
        back.curriculum.earlier_share = CurriculumConfig::default().earlier_share;
        back.env.robustness = Default::default();
        back.env.reward.omega_change = Config::default().env.reward.omega_change;
        assert_eq!(back, Config::default(), "everything else is the default");
        for stage in &g.curriculum.rooms {
            let set = RoomSet::parse(stage).unwrap();
            assert!(!set.is_single(), "{stage}");
            // Training seeds only: every range ends at or below 9000 (the held-out seeds).
            for alt in set.alternatives() {
                if let Alternative::Generated { seeds, .. } = alt {
                    assert!(seeds.end <= 9000, "{stage}");
                }
            }
            // The first rooms of each stage build.
            for name in set.sample(3) {
                let rooms = dvnav_sim::Room::load(&name).unwrap();
                assert_eq!(rooms[0].name(), name);
            }
        }
    }

    #[test]
    fn curriculum_stages_must_be_room_sets_of_known_rooms() {
        let refused = |rooms: &str, key: &str, words: &str| {
            let e = Config::from_toml_str(&format!("[curriculum]\nrooms = {rooms}\n")).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.reason.contains(words), "{e}");
        };
        refused(r#"["env0", "env9"]"#, "curriculum.rooms[1]", "room `env9` is neither a built-in");
        refused(r#"["env0|nowhere.toml"]"#, "curriculum.rooms[0]", "`nowhere.toml`");
        refused(r#"["env0", "env1||env2"]"#, "curriculum.rooms[1]", "is empty");
        refused(r#"["generated:clutter:7..7"]"#, "curriculum.rooms[0]", "`7..7` is empty");
        refused(r#"["generated:maze:0..9"]"#, "curriculum.rooms[0]", "unknown generator kind");
        // Room files are found from the working directory (the crate's, in tests).
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../../rooms/training.toml");
        let ok = format!(r#"["env0|generated:rooms:0..10", "generated:paper:3", "{file}"]"#);
        Config::from_toml_str(&format!("[curriculum]\nrooms = {ok}\n")).unwrap();
        // The radius check reaches built-in rooms inside sets.
        let e = Config::from_toml_str(
            "[env]\nradius_input = true\nradius_range = [0.2, 2.45]\n\
             [curriculum]\nrooms = [\"generated:rooms:0..10|env3\"]\n",
        )
        .unwrap_err();
        assert!(e.key == "env.radius_range" && e.reason.contains("`env3`"), "{e}");
    }

    #[test]
    fn bad_radius_settings_are_refused_with_the_reason() {
        let refused = |text: &str, key: &str, words: &str| {
            let e = Config::from_toml_str(text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.reason.contains(words), "{e}");
        };
        let ri = "[env]\nradius_input = true\n";
        refused(&format!("{ri}radius_range = [0.5, 0.2]\n"), "env.radius_range", "0 < min ≤ max");
        refused(&format!("{ri}radius_range = [0.0, 0.2]\n"), "env.radius_range", "0 < min ≤ max");
        refused(&format!("{ri}radius_range = [0.2, nan]\n"), "env.radius_range", "0 < min ≤ max");
        refused("[env]\nradius_range = [0.2, 0.5]\n", "env.radius_range", "radius_input = true");
        refused(
            "[env.dvst]\nradius_range = [0.1, 0.6]\nshare = 0.5\n",
            "env.dvst.radius_range",
            "≤ min",
        );
        refused("[env.dvst]\nradius_range = [0.2, 0.6]\nshare = 1.5\n", "env.dvst.share", "[0, 1]");
        refused(
            &format!("{ri}[env.dvst]\nradius_range = [0.2, 0.6]\nshare = 0.5\n"),
            "env.dvst",
            "env.radius_input",
        );
        let dvst = Config::from_toml_str("[env.dvst]\nradius_range = [0.2, 0.6]\nshare = 0.5\n");
        assert_eq!(dvst.unwrap().env.dvst.map(|d| d.radius_range), Some([0.2, 0.6]));
        // The largest robot must fit every curriculum room (env3 is 5 m).
        refused(&format!("{ri}radius_range = [0.2, 2.45]\n"), "env.radius_range", "`env3`");
        let fp = "[env.footprint]\nname = \"c\"\n[[env.footprint.parts]]\nshape = \"circle\"\n\
                  center = [0.0, 0.0]\nradius = 0.2\n";
        refused(&format!("{ri}{fp}"), "env.radius_input", "circular robot");
        refused(
            &format!("[env]\nradius_range = [0.3, 0.3]\n{fp}"),
            "env.radius_range",
            "env.footprint",
        );
        // Accepted: one radius without the input, the input without a range, a big robot in
        // a big room.
        let one = Config::from_toml_str("[env]\nradius_range = [0.3, 0.3]\n").unwrap();
        assert_eq!(one.obs_dim(), 544);
        assert_eq!(Config::from_toml_str(ri).unwrap().obs_dim(), 545);
        let big = "[env]\nradius_input = true\nradius_range = [0.2, 2.45]\n\
                   [curriculum]\nrooms = [\"sac_ri\"]\n";
        Config::from_toml_str(big).unwrap();
    }

    #[test]
    fn the_planner_expert_needs_subgoals_and_a_share_in_range() {
        let refused = |text: &str, key: &str, words: &str| {
            let e = Config::from_toml_str(text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().contains(words), "{e}");
        };
        refused("[warmup]\nexpert_share = 0.2\n", "warmup.expert_share", "[env.subgoals]");
        let sub = "[env.subgoals]\nfollow_share = 0.0\n";
        refused(&format!("[warmup]\nexpert_share = 1.5\n{sub}"), "warmup.expert_share", "[0, 1]");
        refused(
            &format!("[warmup]\nexpert_share = 0.2\nexpert_turn_deg = 0\n{sub}"),
            "warmup.expert_turn_deg",
            "(0, 180)",
        );
        let ok = Config::from_toml_str(&format!("[warmup]\nexpert_share = 0.2\n{sub}")).unwrap();
        assert_eq!(ok.warmup.expert_share, 0.2);
    }

    #[test]
    fn unknown_key_is_refused_with_its_name() {
        let err = Config::from_toml_str("[sac]\ngama = 0.9\n").unwrap_err();
        assert!(err.reason.contains("gama"), "{err}");
    }

    #[test]
    fn bad_value_names_the_key() {
        let err = Config::from_toml_str("[sac]\ngamma = 1.5\n").unwrap_err();
        assert_eq!(err.key, "sac.gamma");
        let err = Config::from_toml_str("[env.lidar]\nbeams = 10\n").unwrap_err();
        assert_eq!(err.key, "network.conv1_kernel");
        for n in [0, MAX_N_STEP + 1] {
            let err = Config::from_toml_str(&format!("[sac]\nn_step = {n}\n")).unwrap_err();
            assert_eq!(err.key, "sac.n_step", "{n}");
        }
        let three = Config::from_toml_str("[sac]\nn_step = 3\n").unwrap();
        assert_eq!(three.sac.n_step, 3);
        for tau in ["-0.1", "1.5", "nan"] {
            let err =
                Config::from_toml_str(&format!("[sac]\npolicy_average_tau = {tau}\n")).unwrap_err();
            assert_eq!(err.key, "sac.policy_average_tau", "{tau}");
        }
        let avg = Config::from_toml_str("[sac]\npolicy_average_tau = 0.001\n").unwrap();
        assert_eq!(avg.sac.policy_average_tau, 0.001);
    }

    #[test]
    fn subgoals_round_trip_and_bad_ones_name_the_key() {
        let cfg = Config::from_toml_str("[env.subgoals]\nlookahead_m = 2.0\n").unwrap();
        let sg = cfg.env.subgoals.clone().unwrap();
        assert_eq!(sg.lookahead_m, 2.0);
        assert!(sg.follow && sg.rotation_shim);
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        let err = Config::from_toml_str("[env.subgoals]\nstall_s = -1\n").unwrap_err();
        assert_eq!(err.key, "env.subgoals.stall_s");
        let err =
            Config::from_toml_str("[env.subgoals.planner]\nclearance_decay_m = 0\n").unwrap_err();
        assert_eq!(err.key, "env.subgoals.planner.clearance_decay_m");
        // Without the table, the paper's mapless task (and no key in the config's hash).
        assert!(!Config::default().to_toml_string().contains("subgoals"));
    }

    #[test]
    fn cuda_graph_stays_out_of_the_toml_while_off_and_round_trips_on() {
        // Off, the key is not written, so the config hashes of earlier runs do not move.
        assert!(!Config::default().to_toml_string().contains("cuda_graph"));
        let cfg = Config::from_toml_str("[learner]\ncuda_graph = true\n").unwrap();
        assert!(cfg.learner.cuda_graph);
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
    }

    #[test]
    fn the_selection_stays_out_of_the_toml_while_absent_and_bad_ones_name_the_key() {
        assert!(!Config::default().to_toml_string().contains("selection"));
        let sel = "[learner.selection]\nrooms = \"generated:clutter:0..20|env3\"\n";
        let cfg = Config::from_toml_str(sel).unwrap();
        let got = cfg.learner.selection.clone().unwrap();
        assert_eq!(
            (got.room_count, got.radii.as_slice(), got.episodes),
            (12, &[0.2, 0.4, 0.6][..], 16)
        );
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        let refused = |text: &str, key: &str, words: &str| {
            let e = Config::from_toml_str(text).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().contains(words), "{e}");
        };
        refused("[learner.selection]\nepisodes = 4\n", "learner.selection.rooms", "must name");
        refused(
            "[learner.selection]\nrooms = \"nowhere\"\n",
            "learner.selection.rooms",
            "neither a built-in room",
        );
        refused(&format!("{sel}radii = [0.2, -0.4]\n"), "learner.selection.radii", "positive");
        refused(&format!("{sel}radii = []\n"), "learner.selection.radii", "positive");
        refused(&format!("{sel}episodes = 0\n"), "learner.selection.episodes", "at least 1");
        refused(&format!("{sel}room_count = 0\n"), "learner.selection.room_count", "at least 1");
        refused(&format!("[env]\nradius_input = true\n{sel}"), "learner.selection.radii", "DVST");
        // The gate bar: off by default (not in the TOML), needs the gate test, at most 12.
        assert!(!cfg.to_toml_string().contains("gate_min_passed"));
        let bar = |n: usize| format!("[learner]\neval_gate = true\n{sel}gate_min_passed = {n}\n");
        let cfg = Config::from_toml_str(&bar(11)).unwrap();
        assert_eq!(cfg.learner.selection.as_ref().unwrap().gate_min_passed, 11);
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        refused(&bar(13), "learner.selection.gate_min_passed", "at most 12");
        refused(
            &format!("{sel}gate_min_passed = 11\n"),
            "learner.selection.gate_min_passed",
            "eval_gate = true",
        );
    }

    /// The experiment log's configs (docs/results.md) stay runnable as the keys evolve.
    #[test]
    fn every_experiment_config_parses_and_validates() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/experiments");
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let text = std::fs::read_to_string(&path).unwrap();
                Config::from_toml_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                n += 1;
            }
        }
        assert!(n >= 3, "{n} configs in {}", dir.display());
    }

    #[test]
    fn replay_ratios_name_each_stage_and_the_last_holds() {
        let cfg = Config::from_toml_str("[curriculum]\nreplay_ratios = [0.25, 0.0625]\n").unwrap();
        let c = &cfg.curriculum;
        assert_eq!([0, 1, 3].map(|s| c.replay_ratio(s, 1.0)), [0.25, 0.0625, 0.0625]);
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        assert_eq!(Config::default().curriculum.replay_ratio(2, 0.25), 0.25);
        assert!(!Config::default().to_toml_string().contains("replay_ratios"));
        let err = Config::from_toml_str("[curriculum]\nreplay_ratios = [0.25, 0]\n").unwrap_err();
        assert_eq!(err.key, "curriculum.replay_ratios[1]");
        let err =
            Config::from_toml_str("[curriculum]\nreplay_ratios = [1, 1, 1, 1, 1]\n").unwrap_err();
        assert_eq!(err.key, "curriculum.replay_ratios");
    }

    #[test]
    fn robust_from_stage_round_trips_and_must_name_a_stage() {
        let cfg = Config::from_toml_str("[curriculum]\nrobust_from_stage = 3\n").unwrap();
        assert_eq!(cfg.curriculum.robust_from_stage, Some(3));
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        // The paper's curriculum has stages 0..=3.
        let err = Config::from_toml_str("[curriculum]\nrobust_from_stage = 4\n").unwrap_err();
        assert_eq!(err.key, "curriculum.robust_from_stage");
        assert!(err.reason.contains("4 stages"), "{err}");
        // Unset, the key stays out of the written config (and of its hash).
        assert!(!Config::default().to_toml_string().contains("robust_from_stage"));
    }

    #[test]
    fn partial_file_keeps_other_defaults() {
        let cfg = Config::from_toml_str("[run]\nsteps = 10\n").unwrap();
        assert_eq!(cfg.run.steps, 10);
        assert_eq!(cfg.sac, SacConfig::default());
    }

    #[test]
    fn a_footprint_in_the_run_config_round_trips_and_bad_ones_name_the_key() {
        let text = "[env.footprint]\nname = \"cart\"\n[[env.footprint.parts]]\nshape = \"box\"\n\
                    center = [0.1, 0.0]\nhalf_extents = [0.3, 0.2]\n";
        let cfg = Config::from_toml_str(text).unwrap();
        let fp = cfg.env.footprint.clone().unwrap();
        assert!((fp.bounding_radius() - 0.4f64.hypot(0.2)).abs() < 1e-12);
        assert_eq!(Config::from_toml_str(&cfg.to_toml_string()).unwrap(), cfg);
        let bad = text.replace("[0.3, 0.2]", "[0.3, -0.2]");
        assert_eq!(Config::from_toml_str(&bad).unwrap_err().key, "env.footprint");
    }
}
