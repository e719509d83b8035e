//! The environment loop (Acme's EnvironmentLoop): step K environments with one batched policy
//! forward pass, hand every transition to an [`Adder`], report finished episodes, follow the
//! learner's variables (weights, stage, warm-up, stop), and log selected episodes to MCAP.
//!
//! It knows nothing about the network: the actor process plugs in the gRPC adder and variable
//! client; tests plug in in-process ones.

use crate::episode_logger::EpisodeSelector;
use candle_core::{Device, Tensor};
use dvnav_config::Config;
use dvnav_link::core::{Adder, EpisodeStats, VariableSource};
use dvnav_nav::control::{action_to_velocity, pid_velocity, velocity_to_action};
use dvnav_nav::weights::PolicyHandle;
use dvnav_sim::obs::{ACTION_DIM, GOAL_ANGLE, GOAL_DISTANCE};
use dvnav_sim::{Outcome, score};
use dvnav_sim::{Room, VecEnv};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use std::collections::HashMap;
use std::sync::Arc;

/// Who drives an episode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Driver {
    Pid,
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
    /// Episodes driven by the PID controller.
    pub warmup_episodes: u64,
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
    rooms: HashMap<String, Arc<Room>>,
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

impl<A: Adder, V: VariableSource> EnvironmentLoop<A, V> {
    /// A loop over `cfg.actor.envs` environments seeded from `seed`, in the first room of the
    /// curriculum until the learner assigns another.
    pub fn new(
        cfg: Config,
        actor_name: String,
        actor_id: u32,
        seed: u64,
        adder: A,
        source: V,
        logger: Option<EpisodeSelector>,
    ) -> anyhow::Result<Self> {
        let first_room = cfg.curriculum.rooms[0].clone();
        let room = Room::builtin(&first_room)?;
        let n = cfg.actor.envs;
        let seeds: Vec<u64> =
            (0..n as u64).map(|i| seed.wrapping_mul(7919).wrapping_add(i)).collect();
        let envs = VecEnv::new(vec![room.clone(); n], &cfg.env, &seeds);
        let d = cfg.obs_dim();
        let mut this = Self {
            actor_name,
            actor_id,
            envs,
            adder,
            source,
            policy: PolicyHandle::default(),
            rooms: HashMap::from([(first_room, room)]),
            stage: 0,
            episodes: Vec::with_capacity(n),
            next_episode_id: 0,
            obs: vec![0.0; n * d],
            next_obs: vec![0.0; n * d],
            actions: vec![[0.0; ACTION_DIM]; n],
            rng: rand_pcg::Pcg64::seed_from_u64(seed ^ 0x000a_c70e),
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

    fn room(&mut self, name: &str) -> anyhow::Result<Arc<Room>> {
        if let Some(r) = self.rooms.get(name) {
            return Ok(r.clone());
        }
        let r = Room::builtin(name)?;
        self.rooms.insert(name.to_string(), r.clone());
        Ok(r)
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
        let driver = if warmup { Driver::Pid } else { Driver::Policy };
        let mut logged = false;
        if let Some(l) = self.logger.as_mut() {
            let env = &self.envs.envs()[i];
            logged = l.maybe_begin(i, id, env, &self.cfg)?;
        }
        Ok(EpisodeInfo { id, stage, driver, logged })
    }

    /// One step of every environment. Returns false when the learner says stop.
    pub fn step(&mut self) -> anyhow::Result<bool> {
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
                let room = self.room(&v.room)?;
                tracing::info!(actor = %self.actor_name, stage = v.stage, room = %v.room, "switching stage");
                self.stage = v.stage;
                for env in self.envs.envs_mut() {
                    env.set_room(room.clone());
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
            let acted_version = if info.driver == Driver::Pid { 0 } else { version };
            let terminated = out.done.is_some_and(|o| o.is_terminal());
            let truncated = out.done == Some(Outcome::Timeout);
            self.adder.add(
                &self.obs[i * d..(i + 1) * d],
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
                    warmup: info.driver == Driver::Pid,
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
                        mu: 1.0,
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
                self.adder.add_episode(stats)?;
                let stage = self.pick_stage();
                let name = self.cfg.curriculum.rooms[stage as usize].clone();
                let room = self.room(&name)?;
                self.envs.envs_mut()[i].set_room(room);
                self.envs.envs_mut()[i].reset();
                self.episodes[i] = self.new_episode_in(i, warmup, stage)?;
                self.envs.envs()[i].write_obs(&mut self.next_obs[i * d..(i + 1) * d]);
            }
        }
        std::mem::swap(&mut self.obs, &mut self.next_obs);
        Ok(true)
    }

    /// Fills `self.actions`: the PID controller for warm-up episodes, a sample from the policy
    /// (one batched forward pass) for the others.
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
mod tests {
    use super::*;
    use dvnav_link::core::{TransitionBatch, Variables};
    use dvnav_nav::nets::{Actor, init_seeded, varmap_to_safetensors};

    /// Collects everything in memory.
    #[derive(Default)]
    struct VecAdder {
        batch: TransitionBatch,
    }

    impl Adder for VecAdder {
        fn add(
            &mut self,
            obs: &[f32],
            action: [f32; ACTION_DIM],
            reward: f32,
            next_obs: &[f32],
            terminated: bool,
            truncated: bool,
            policy_version: u64,
        ) -> anyhow::Result<()> {
            self.batch.obs_dim = obs.len();
            self.batch.push(obs, action, reward, next_obs, terminated, truncated, policy_version);
            Ok(())
        }
        fn add_episode(&mut self, stats: EpisodeStats) -> anyhow::Result<()> {
            self.batch.episodes.push(stats);
            Ok(())
        }
        fn flush(&mut self) -> anyhow::Result<()> {
            Ok(())
        }
    }

    struct Fixed(Arc<Variables>);

    impl VariableSource for Fixed {
        fn latest(&self) -> Option<Arc<Variables>> {
            Some(self.0.clone())
        }
    }

    fn policy_bytes(cfg: &Config) -> Vec<u8> {
        let vm = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&vm, candle_core::DType::F32, &Device::Cpu);
        Actor::new(vb, &cfg.network, cfg.obs_layout()).unwrap();
        init_seeded(&vm, 5).unwrap();
        varmap_to_safetensors(&vm).unwrap()
    }

    fn run(warmup: bool, steps: usize, seed: u64) -> (TransitionBatch, LoopCounters) {
        run_at(warmup, steps, seed, 0, 0.0)
    }

    fn run_at(
        warmup: bool,
        steps: usize,
        seed: u64,
        stage: u32,
        earlier_share: f64,
    ) -> (TransitionBatch, LoopCounters) {
        let mut cfg = Config::default();
        cfg.actor.envs = 3;
        cfg.env.max_steps = 60;
        cfg.curriculum.earlier_share = earlier_share;
        let vars = Variables {
            version: 3,
            policy: Arc::new(policy_bytes(&cfg)),
            stage,
            room: cfg.curriculum.rooms[stage as usize].clone(),
            warmup,
            stop: false,
        };
        let mut el = EnvironmentLoop::new(
            cfg,
            "t".into(),
            0,
            seed,
            VecAdder::default(),
            Fixed(Arc::new(vars)),
            None,
        )
        .unwrap();
        let mut n = 0;
        el.run(|_| {
            n += 1;
            n <= steps
        })
        .unwrap();
        let (adder, counters) = el.finish().unwrap();
        (adder.batch, counters)
    }

    /// The episode log's directory becomes unwritable mid-run: the loop goes on, the failures
    /// are counted, and logging resumes in new files once the directory is back. As root no
    /// permission bit stops a write, so the directory is replaced by a regular file: creating a
    /// file "inside" it fails with ENOTDIR for root too.
    #[test]
    fn an_unwritable_log_directory_is_survived_and_retried() {
        let mut cfg = Config::default();
        cfg.actor.envs = 2;
        cfg.env.max_steps = 20;
        cfg.logging.every_nth_episode = 1;
        cfg.logging.episodes_per_file = 1;
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("mcap");
        let meta = dvnav_eval::episode_log::LogMetadata::default();
        let selector = EpisodeSelector::create(&dir, "t", meta, &cfg).unwrap().unwrap();
        // Before the first episode begins: the directory is now a file.
        std::fs::remove_dir_all(&dir).unwrap();
        std::fs::write(&dir, b"not a directory").unwrap();
        let vars = Variables {
            version: 3,
            policy: Arc::new(policy_bytes(&cfg)),
            stage: 0,
            room: cfg.curriculum.rooms[0].clone(),
            warmup: true,
            stop: false,
        };
        let mut el = EnvironmentLoop::new(
            cfg,
            "t".into(),
            0,
            1,
            VecAdder::default(),
            Fixed(Arc::new(vars)),
            Some(selector),
        )
        .unwrap();
        let mut n = 0;
        el.run(|_| {
            n += 1;
            n <= 100
        })
        .unwrap();
        let c = el.counters();
        assert!(c.episodes >= 5, "{c:?}");
        assert_eq!(c.logged_episodes, 0, "{c:?}");
        assert!(c.log_write_failures >= 5, "every selected episode tried and failed: {c:?}");
        let failures = c.log_write_failures;
        // The directory is back: the next selected episodes are written again.
        std::fs::remove_file(&dir).unwrap();
        std::fs::create_dir(&dir).unwrap();
        let mut n = 0;
        el.run(|_| {
            n += 1;
            n <= 100
        })
        .unwrap();
        let (adder, c) = el.finish().unwrap();
        assert_eq!(c.log_write_failures, failures, "{c:?}");
        assert!(c.logged_episodes >= 5, "{c:?}");
        assert_eq!(adder.batch.len() as u64, c.env_steps);
        let files = std::fs::read_dir(&dir).unwrap().count();
        assert!(files >= 5, "{files} files");
    }

    #[test]
    fn transitions_chain_and_episodes_are_reported() {
        let (b, c) = run(false, 150, 11);
        let d = b.obs_dim;
        assert_eq!(b.len(), 450);
        assert_eq!(c.env_steps, 450);
        assert!(c.episodes > 0 && b.episodes.len() as u64 == c.episodes);
        assert!(b.policy_versions.iter().all(|&v| v == 3));
        // Per environment (transitions interleave env 0, 1, 2, 0, …), the next observation of a
        // step is the observation of the following step unless the episode ended.
        for i in 0..b.len() - 3 {
            if b.terminated[i] || b.truncated[i] {
                continue;
            }
            assert_eq!(
                &b.next_observations[i * d..(i + 1) * d],
                &b.observations[(i + 3) * d..(i + 4) * d],
                "transition {i}"
            );
        }
        // Timeouts are truncations, never terminations; episode lengths respect T_max.
        assert!(b.episodes.iter().all(|e| e.steps <= 60));
        let ends = b.terminated.iter().zip(&b.truncated).filter(|(t, u)| **t || **u).count();
        assert_eq!(ends as u64, c.episodes);
    }

    #[test]
    fn a_share_of_episodes_runs_in_earlier_rooms() {
        // Stage 2 with half the episodes in earlier rooms: after the first episodes (which
        // start in the assigned room), every stage up to 2 shows up, each in its own room.
        let (b, _) = run_at(false, 600, 3, 2, 0.5);
        let stages: std::collections::BTreeSet<u32> = b.episodes.iter().map(|e| e.stage).collect();
        assert_eq!(stages.into_iter().collect::<Vec<_>>(), vec![0, 1, 2], "{}", b.episodes.len());
        for e in &b.episodes {
            assert_eq!(e.room, format!("env{}", e.stage));
        }
        // Without a share, everything after each environment's first episode (begun before
        // the loop heard of stage 2) runs in the assigned room.
        let (b, _) = run_at(false, 300, 3, 2, 0.0);
        let mut seen = std::collections::HashSet::new();
        let later: Vec<_> = b.episodes.iter().filter(|e| !seen.insert(e.env_index)).collect();
        assert!(!later.is_empty());
        assert!(later.iter().all(|e| e.stage == 2 && e.room == "env2"));
    }

    #[test]
    fn radius_input_transitions_carry_each_episodes_drawn_radius() {
        let mut cfg = Config::from_toml_str(include_str!("../../configs/sac_ri.toml")).unwrap();
        cfg.actor.envs = 3;
        cfg.env.max_steps = 40;
        let vars = Variables {
            version: 1,
            policy: Arc::new(policy_bytes(&cfg)),
            stage: 0,
            room: "sac_ri".into(),
            warmup: false,
            stop: false,
        };
        let mut el = EnvironmentLoop::new(
            cfg.clone(),
            "t".into(),
            0,
            5,
            VecAdder::default(),
            Fixed(Arc::new(vars)),
            None,
        )
        .unwrap();
        let mut n = 0;
        el.run(|_| {
            n += 1;
            n <= 200
        })
        .unwrap();
        let (adder, _) = el.finish().unwrap();
        let b = adder.batch;
        let d = b.obs_dim;
        assert_eq!(d, 545);
        let radius = |obs: &[f32], i: usize| obs[i * d + 544];
        let mut seen = std::collections::BTreeSet::new();
        for i in 0..b.len() {
            let r = radius(&b.observations, i);
            assert!((0.2..=0.5).contains(&r), "{r}");
            seen.insert(r.to_bits());
            if !(b.terminated[i] || b.truncated[i]) {
                assert_eq!(radius(&b.next_observations, i), r, "one radius per episode");
            }
        }
        // A radius of its own for every episode (the finished ones and up to 3 still open).
        let episodes = b.episodes.len();
        assert!(episodes >= 10, "{episodes}");
        assert!((episodes..=episodes + 3).contains(&seen.len()), "{} radii", seen.len());
        // The learner's wire validation takes these observations at the config's length.
        let msg = dvnav_link::wire::batch_to_proto(&b, 0, 0);
        let back = dvnav_link::wire::batch_from_proto(msg.clone(), cfg.obs_dim()).unwrap();
        assert_eq!(back.observations, b.observations);
        assert!(dvnav_link::wire::batch_from_proto(msg, 544).is_err());
    }

    #[test]
    fn warmup_episodes_use_the_pid_controller() {
        let (b, c) = run(true, 40, 11);
        assert!(b.policy_versions.iter().all(|&v| v == 0));
        assert_eq!(c.episodes, c.warmup_episodes);
        assert!(b.episodes.iter().all(|e| e.warmup));
    }

    #[test]
    fn same_seed_gives_identical_transitions() {
        let (a, _) = run(false, 80, 21);
        let (b, _) = run(false, 80, 21);
        let (c, _) = run(false, 80, 22);
        let enc = |x: &TransitionBatch| {
            use prost::Message;
            dvnav_link::wire::batch_to_proto(x, 0, 0).encode_to_vec()
        };
        assert_eq!(enc(&a), enc(&b));
        assert_ne!(enc(&a), enc(&c));
    }
}
