//! The environment loop (Acme's EnvironmentLoop): step K environments with one batched policy
//! forward pass, hand every observation once to an [`Adder`] (an episode's first with
//! `add_first`, each step's result with `add`), report finished episodes, follow the
//! learner's variables (weights, stage, warm-up, stop), and log selected episodes to MCAP.
//!
//! It knows nothing about the network: the actor process plugs in the gRPC adder and variable
//! client; tests plug in in-process ones.
//!
//! **Rooms.** Each curriculum stage is a [`RoomSet`]; every episode draws its room from its
//! stage's set with the loop's random stream (a stage of one room draws nothing, so seeded runs
//! of single-room curricula are unchanged). Rooms are built on first use and kept, at most
//! [`ROOM_CACHE_CAPACITY`] of them: building a generated room (its layout, then a grid search
//! that checks its free space is connected) costs far more than an episode's first step.

use crate::episode_logger::EpisodeSelector;
use candle_core::{Device, Tensor};
use dvnav_config::Config;
use dvnav_link::core::{Adder, EpisodeStats, VariableSource};
use dvnav_nav::control::{action_to_velocity, expert_command, pid_velocity, velocity_to_action};
use dvnav_nav::weights::PolicyHandle;
use dvnav_sim::obs::{ACTION_DIM, GOAL_ANGLE, GOAL_DISTANCE};
use dvnav_sim::room_set::RoomSet;
use dvnav_sim::{Outcome, score};
use dvnav_sim::{Room, VecEnv};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

/// Rooms an actor keeps built (names, each one room or a room file's rooms). A generated room
/// is slow to build and holds its clearance grid (up to 400 x 400 cells) once episodes have
/// sampled tasks in it, so with sets of thousands of rooms the cache keeps the recent ones.
pub const ROOM_CACHE_CAPACITY: usize = 256;

/// Draws a new room of a set this many times when a drawn room fails to build, before giving
/// up: one bad seed of a generator should not end a long run.
const ROOM_TRIES: usize = 8;

/// Rooms built so far, by name; at most [`ROOM_CACHE_CAPACITY`], the oldest that no
/// environment uses evicted first.
#[derive(Default)]
struct RoomCache {
    rooms: HashMap<String, Vec<Arc<Room>>>,
    /// Names, oldest first.
    order: VecDeque<String>,
}

impl RoomCache {
    /// The rooms of `name` (`Room::load`): one, or every room of a room file.
    fn get(&mut self, name: &str) -> anyhow::Result<Vec<Arc<Room>>> {
        if let Some(r) = self.rooms.get(name) {
            return Ok(r.clone());
        }
        let rooms = Room::load(name)?;
        anyhow::ensure!(!rooms.is_empty(), "`{name}` holds no room");
        if self.rooms.len() >= ROOM_CACHE_CAPACITY {
            // An environment holds its room (and its next) itself; an entry only the cache
            // holds is free to go.
            let unused = |rooms: &[Arc<Room>]| rooms.iter().all(|r| Arc::strong_count(r) == 1);
            let at = self.order.iter().position(|n| unused(&self.rooms[n])).unwrap_or(0);
            if let Some(old) = self.order.remove(at) {
                self.rooms.remove(&old);
            }
        }
        self.rooms.insert(name.to_string(), rooms.clone());
        self.order.push_back(name.to_string());
        Ok(rooms)
    }

    /// A room of `set`, drawn with `rng` ([`RoomSet::pick`], then one of a room file's rooms
    /// when it holds several). A room of a set that fails to build is reported and another
    /// drawn, up to [`ROOM_TRIES`] times.
    fn pick(&mut self, set: &RoomSet, rng: &mut impl Rng) -> anyhow::Result<Arc<Room>> {
        let tries = if set.is_single() { 1 } else { ROOM_TRIES };
        let mut failure = None;
        for _ in 0..tries {
            let name = set.pick(rng);
            match self.get(&name) {
                Ok(rooms) if rooms.len() == 1 => return Ok(rooms[0].clone()),
                Ok(rooms) => return Ok(rooms[rng.random_range(0..rooms.len())].clone()),
                Err(e) => {
                    if tries > 1 {
                        let error = format!("{e:#}");
                        tracing::warn!(room = %name, stage = %set, %error, "cannot build a room; drawing another");
                    }
                    failure = Some(e);
                }
            }
        }
        let e = failure.unwrap_or_else(|| anyhow::anyhow!("no room drawn"));
        Err(e.context(format!("stage `{set}`: {tries} drawn rooms in a row failed to build")))
    }
}

/// Who drives an episode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Driver {
    Pid,
    /// The planner expert (`warmup.expert_share`): the PID controller on the planned path's
    /// subgoal.
    Expert,
    Policy,
}

#[derive(Clone, Debug)]
struct EpisodeInfo {
    id: u64,
    stage: u32,
    driver: Driver,
    logged: bool,
}

/// Counters of one actor's loop.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LoopCounters {
    /// Environment steps taken (all environments).
    pub env_steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Episodes driven by the PID controller or the planner expert (not the policy).
    pub warmup_episodes: u64,
    /// Of those, episodes driven by the planner expert (`warmup.expert_share`).
    #[serde(default)]
    pub expert_episodes: u64,
    /// Episodes written to MCAP.
    pub logged_episodes: u64,
    /// MCAP write errors survived (disk full, unwritable directory); the actor goes on.
    pub log_write_failures: u64,
    /// Smallest weight version that chose an action (0 if only PID acted).
    pub min_policy_version: u64,
    /// Largest weight version that chose an action.
    pub max_policy_version: u64,
    /// Distinct weight versions loaded.
    pub weight_updates: u64,
    /// Episodes by outcome.
    pub successes: u64,
    /// Collisions.
    pub collisions: u64,
    /// Timeouts.
    pub timeouts: u64,
}

/// Steps environments until the learner says stop.
pub struct EnvironmentLoop<A: Adder, V: VariableSource> {
    cfg: Config,
    actor_name: String,
    actor_id: u32,
    envs: VecEnv,
    adder: A,
    source: V,
    policy: PolicyHandle,
    /// The curriculum's stages (`curriculum.rooms`), parsed.
    sets: Vec<RoomSet>,
    rooms: RoomCache,
    stage: u32,
    episodes: Vec<EpisodeInfo>,
    next_episode_id: u64,
    obs: Vec<f32>,
    next_obs: Vec<f32>,
    actions: Vec<[f32; ACTION_DIM]>,
    rng: rand_pcg::Pcg64,
    seed: u64,
    logger: Option<EpisodeSelector>,
    counters: LoopCounters,
}

/// The `[env.robustness]` of episodes while the run is in `stage`: the configured one from
/// `curriculum.robust_from_stage` on (every stage when unset), none before.
fn stage_robustness(cfg: &Config, stage: u32) -> dvnav_sim::RobustnessConfig {
    match cfg.curriculum.robust_from_stage {
        Some(from) if stage < from => dvnav_sim::RobustnessConfig::default(),
        _ => cfg.env.robustness.clone(),
    }
}

impl<A: Adder, V: VariableSource> EnvironmentLoop<A, V> {
    /// A loop over `cfg.actor.envs` environments seeded from `seed`, in rooms of the first
    /// stage of the curriculum until the learner assigns another.
    pub fn new(
        cfg: Config,
        actor_name: String,
        actor_id: u32,
        seed: u64,
        adder: A,
        source: V,
        logger: Option<EpisodeSelector>,
    ) -> anyhow::Result<Self> {
        let sets = cfg
            .curriculum
            .rooms
            .iter()
            .map(|s| RoomSet::parse(s))
            .collect::<anyhow::Result<Vec<_>>>()?;
        anyhow::ensure!(!sets.is_empty(), "curriculum.rooms: needs at least one room");
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x000a_c70e);
        let mut rooms = RoomCache::default();
        let n = cfg.actor.envs;
        // Each environment's first episode: a room of stage 0 (one room: the same for all,
        // and nothing drawn).
        let first: Vec<Arc<Room>> =
            (0..n).map(|_| rooms.pick(&sets[0], &mut rng)).collect::<anyhow::Result<_>>()?;
        let seeds: Vec<u64> =
            (0..n as u64).map(|i| seed.wrapping_mul(7919).wrapping_add(i)).collect();
        let mut env_cfg = cfg.env.clone();
        env_cfg.robustness = stage_robustness(&cfg, 0);
        let envs = VecEnv::new(first, &env_cfg, &seeds);
        let d = cfg.obs_dim();
        let mut this = Self {
            actor_name,
            actor_id,
            envs,
            adder,
            source,
            policy: PolicyHandle::default(),
            sets,
            rooms,
            stage: 0,
            episodes: Vec::with_capacity(n),
            next_episode_id: 0,
            obs: vec![0.0; n * d],
            next_obs: vec![0.0; n * d],
            actions: vec![[0.0; ACTION_DIM]; n],
            rng,
            seed,
            logger,
            counters: LoopCounters { min_policy_version: u64::MAX, ..Default::default() },
            cfg,
        };
        let warmup = this.source.latest().is_none_or(|v| v.warmup);
        for i in 0..n {
            let info = this.new_episode(i, warmup)?;
            this.episodes.push(info);
        }
        this.envs.write_obs(&mut this.obs);
        for i in 0..n {
            this.adder.add_first(i, &this.obs[i * d..(i + 1) * d])?;
        }
        Ok(this)
    }

    /// Counters so far.
    pub fn counters(&self) -> LoopCounters {
        let mut c = self.counters.clone();
        c.log_write_failures = self.logger.as_ref().map_or(0, |l| l.write_failures());
        if c.min_policy_version == u64::MAX {
            c.min_policy_version = 0;
        }
        c
    }

    /// The adder (to flush or inspect it).
    pub fn adder_mut(&mut self) -> &mut A {
        &mut self.adder
    }

    /// Finishes: flushes the adder and closes the episode log.
    pub fn finish(mut self) -> anyhow::Result<(A, LoopCounters)> {
        self.adder.flush()?;
        let c = self.counters();
        if let Some(l) = self.logger.take() {
            l.close()?;
        }
        Ok((self.adder, c))
    }

    /// Runs until the variables say stop or `keep_going` returns false.
    pub fn run(&mut self, mut keep_going: impl FnMut(&LoopCounters) -> bool) -> anyhow::Result<()> {
        while keep_going(&self.counters) {
            if !self.step()? {
                break;
            }
        }
        Ok(())
    }

    /// A room for the next episode of `stage`, drawn from its set.
    fn stage_room(&mut self, stage: u32) -> anyhow::Result<Arc<Room>> {
        let set = self.sets.get(stage as usize).ok_or_else(|| {
            anyhow::anyhow!("stage {stage}: the curriculum has {} stages", self.sets.len())
        })?;
        self.rooms.pick(set, &mut self.rng)
    }

    /// Starts a new episode in environment `i` (already reset or fresh) and logs its start.
    /// The stage of the next episode: the learner's, or with probability
    /// `curriculum.earlier_share` a uniformly drawn earlier one.
    fn pick_stage(&mut self) -> u32 {
        let share = self.cfg.curriculum.earlier_share;
        if self.stage > 0 && share > 0.0 && self.rng.random_bool(share) {
            self.rng.random_range(0..self.stage)
        } else {
            self.stage
        }
    }

    fn new_episode(&mut self, i: usize, warmup: bool) -> anyhow::Result<EpisodeInfo> {
        self.new_episode_in(i, warmup, self.stage)
    }

    fn new_episode_in(
        &mut self,
        i: usize,
        warmup: bool,
        stage: u32,
    ) -> anyhow::Result<EpisodeInfo> {
        let id = self.next_episode_id;
        self.next_episode_id += 1;
        let driver = self.driver(i, warmup);
        let mut logged = false;
        if let Some(l) = self.logger.as_mut() {
            let env = &self.envs.envs()[i];
            logged = l.maybe_begin(i, id, env, &self.cfg)?;
        }
        Ok(EpisodeInfo { id, stage, driver, logged })
    }

    /// Who drives environment `i`'s new episode. With `warmup.expert_share` > 0 the planner
    /// expert drives the warm-up (where a path was planned) and that share of the later
    /// episodes; drawn only then, so runs without an expert keep their seeds' streams.
    fn driver(&mut self, i: usize, warmup: bool) -> Driver {
        let share = self.cfg.warmup.expert_share;
        if share <= 0.0 {
            return if warmup { Driver::Pid } else { Driver::Policy };
        }
        let planned = self.envs.envs()[i].planned_subgoal().is_some();
        match (warmup, planned) {
            (true, true) => Driver::Expert,
            (true, false) => Driver::Pid,
            (false, true) if self.rng.random_bool(share) => Driver::Expert,
            (false, _) => Driver::Policy,
        }
    }

    /// One step of every environment. Returns false when the learner says stop.
    pub fn step(&mut self) -> anyhow::Result<bool> {
        // Before the weights are read: a step whose transitions must wait for the learner
        // waits here, and then acts with what the learner published meanwhile.
        self.adder.ready()?;
        let vars = self.source.latest();
        if let Some(v) = &vars {
            if v.stop {
                return Ok(false);
            }
            if v.version > self.policy.version()
                && self.policy.update(
                    v.version,
                    &v.policy,
                    &self.cfg.network,
                    self.cfg.obs_layout(),
                )?
            {
                self.counters.weight_updates += 1;
            }
            if v.stage != self.stage {
                tracing::info!(actor = %self.actor_name, stage = v.stage, room = %v.room, "switching stage");
                self.stage = v.stage;
                let robustness = stage_robustness(&self.cfg, self.stage);
                for env in self.envs.envs_mut() {
                    env.set_robustness(robustness.clone());
                }
                // A stage of one room is every environment's next room. A set draws each
                // episode's room when the episode begins (below), so nothing is drawn here.
                let set = RoomSet::parse(&v.room)?;
                if set.is_single() {
                    let room = self.rooms.pick(&set, &mut self.rng)?;
                    for env in self.envs.envs_mut() {
                        env.set_room(room.clone());
                    }
                }
            }
        }
        let warmup = vars.as_ref().is_none_or(|v| v.warmup);
        let version = self.policy.version();
        self.choose_actions()?;

        let commands: Vec<(f64, f64)> =
            self.actions.iter().map(|a| action_to_velocity(*a, &self.cfg.env)).collect();
        let outcomes = self.envs.step(&commands);
        self.envs.write_obs(&mut self.next_obs);
        let d = self.cfg.obs_dim();
        for (i, out) in outcomes.iter().enumerate() {
            let info = self.episodes[i].clone();
            let acted_version = if info.driver == Driver::Policy { version } else { 0 };
            let terminated = out.done.is_some_and(|o| o.is_terminal());
            let truncated = out.done == Some(Outcome::Timeout);
            self.adder.add(
                i,
                self.actions[i],
                out.reward,
                &self.next_obs[i * d..(i + 1) * d],
                terminated,
                truncated,
                acted_version,
            )?;
            self.counters.env_steps += 1;
            if info.driver == Driver::Policy {
                self.counters.min_policy_version =
                    self.counters.min_policy_version.min(acted_version);
                self.counters.max_policy_version =
                    self.counters.max_policy_version.max(acted_version);
            }
            if info.logged {
                let env = &self.envs.envs()[i];
                if let Some(l) = self.logger.as_mut() {
                    l.log_step(i, env, commands[i], self.actions[i], out.reward)?;
                }
            }
            if let Some(outcome) = out.done {
                let env = &self.envs.envs()[i];
                let stats = EpisodeStats {
                    env_index: i as u32,
                    stage: info.stage,
                    room: env.room().name().to_string(),
                    outcome,
                    steps: env.steps(),
                    episode_return: env.episode_return() as f32,
                    policy_version: acted_version,
                    // Not the policy's episode: kept out of the curriculum's success rate.
                    warmup: info.driver != Driver::Policy,
                    varied: env.dvst_scale() != 1.0,
                };
                if info.logged {
                    let summary = dvnav_proto::EpisodeSummary {
                        episode_id: info.id,
                        actor: self.actor_name.clone(),
                        actor_id: self.actor_id,
                        stage: info.stage,
                        room: stats.room.clone(),
                        seed: self.seed,
                        footprint: format!("circle r={}", env.robot_radius()),
                        mu: env.dvst_scale(),
                        outcome: dvnav_link::wire::outcome_to_proto(outcome) as i32,
                        steps: stats.steps,
                        episode_return: env.episode_return(),
                        score: score(outcome, stats.steps, self.cfg.env.max_steps),
                        policy_version: acted_version,
                        warmup: stats.warmup,
                        start_x: env.start().x,
                        start_y: env.start().y,
                        goal_x: env.goal()[0],
                        goal_y: env.goal()[1],
                        env_index: i as u32,
                        ..Default::default()
                    };
                    if let Some(l) = self.logger.as_mut()
                        && l.end(i, summary)?
                    {
                        self.counters.logged_episodes += 1;
                    }
                }
                self.counters.episodes += 1;
                match outcome {
                    Outcome::Success => self.counters.successes += 1,
                    Outcome::Collision => self.counters.collisions += 1,
                    Outcome::Timeout => self.counters.timeouts += 1,
                }
                if stats.warmup {
                    self.counters.warmup_episodes += 1;
                }
                if info.driver == Driver::Expert {
                    self.counters.expert_episodes += 1;
                }
                self.adder.add_episode(stats)?;
                let stage = self.pick_stage();
                let room = self.stage_room(stage)?;
                self.envs.envs_mut()[i].set_room(room);
                self.envs.envs_mut()[i].reset();
                self.episodes[i] = self.new_episode_in(i, warmup, stage)?;
                self.envs.envs()[i].write_obs(&mut self.next_obs[i * d..(i + 1) * d]);
                self.adder.add_first(i, &self.next_obs[i * d..(i + 1) * d])?;
            }
        }
        std::mem::swap(&mut self.obs, &mut self.next_obs);
        Ok(true)
    }

    /// Fills `self.actions`: the PID controller for warm-up episodes, the planner expert for
    /// its episodes, a sample from the policy (one batched forward pass) for the others.
    fn choose_actions(&mut self) -> anyhow::Result<()> {
        let d = self.cfg.obs_dim();
        let beams = self.cfg.env.lidar.beams;
        let n = self.envs.len();
        let any_policy = self.episodes.iter().any(|e| e.driver == Driver::Policy);
        let policy_actions = match (any_policy, self.policy.actor()) {
            (true, Some(actor)) => {
                let obs = Tensor::from_slice(&self.obs, (n, d), &Device::Cpu)?;
                let eps: Vec<f32> =
                    (0..n * ACTION_DIM).map(|_| StandardNormal.sample(&mut self.rng)).collect();
                let eps = Tensor::from_vec(eps, (n, ACTION_DIM), &Device::Cpu)?;
                let s = actor.sample_with_noise(&obs, &eps)?;
                Some(s.action.to_vec2::<f32>()?)
            }
            _ => None,
        };
        for i in 0..n {
            let o = &self.obs[i * d..(i + 1) * d];
            self.actions[i] = match (self.episodes[i].driver, &policy_actions) {
                (Driver::Policy, Some(acts)) => [acts[i][0], acts[i][1]],
                (Driver::Expert, _) => {
                    let env = &self.envs.envs()[i];
                    // Without a path (it had one when the episode began) the PID on the goal.
                    let (v, w) = expert_command(env, &self.cfg.warmup).unwrap_or_else(|| {
                        let (d, a) = (o[beams + GOAL_DISTANCE], o[beams + GOAL_ANGLE]);
                        pid_velocity(d as f64, a as f64, &self.cfg.warmup, &self.cfg.env)
                    });
                    velocity_to_action(v, w, &self.cfg.env)
                }
                // PID episodes, and policy episodes before any weights arrived.
                _ => {
                    let (v, w) = pid_velocity(
                        o[beams + GOAL_DISTANCE] as f64,
                        o[beams + GOAL_ANGLE] as f64,
                        &self.cfg.warmup,
                        &self.cfg.env,
                    );
                    velocity_to_action(v, w, &self.cfg.env)
                }
            };
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
