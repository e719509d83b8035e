use super::*;
use dvnav_link::core::{BatchWriter, TransitionBatch, Variables};
use dvnav_nav::nets::{Actor, init_seeded, varmap_to_safetensors};

/// Collects everything in memory, in one batch handed over at the end.
#[derive(Default)]
struct VecAdder {
    writer: Option<BatchWriter>,
    batch: TransitionBatch,
    /// Called with the step's number (from 1) when the loop asks whether the adder is ready:
    /// what happens while a step waits for the learner.
    on_ready: Option<Box<dyn FnMut(usize)>>,
    readies: usize,
}

impl Adder for VecAdder {
    fn add_first(&mut self, env: usize, obs: &[f32]) -> anyhow::Result<()> {
        self.writer.get_or_insert_with(|| BatchWriter::new(obs.len(), 0)).add_first(env, obs)
    }
    fn add(
        &mut self,
        env: usize,
        action: [f32; ACTION_DIM],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
        truncated: bool,
        policy_version: u64,
    ) -> anyhow::Result<()> {
        let w = self.writer.as_mut().ok_or_else(|| anyhow::anyhow!("a step before add_first"))?;
        w.add(env, action, reward, next_obs, terminated, truncated, policy_version)
    }
    fn add_episode(&mut self, stats: EpisodeStats) -> anyhow::Result<()> {
        self.writer.as_mut().expect("episodes come after steps").add_episode(stats);
        Ok(())
    }
    /// Called once, by `EnvironmentLoop::finish`.
    fn flush(&mut self) -> anyhow::Result<()> {
        if let Some(w) = self.writer.as_mut() {
            anyhow::ensure!(self.batch.is_empty(), "flushed twice");
            self.batch = w.take();
        }
        Ok(())
    }
    fn ready(&mut self) -> anyhow::Result<()> {
        self.readies += 1;
        if let Some(f) = self.on_ready.as_mut() {
            f(self.readies);
        }
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

/// A loop over `cfg`'s environments whose learner always says `version`, `stage` and
/// `warmup` (no network).
fn fixed_loop(
    cfg: Config,
    version: u64,
    stage: u32,
    warmup: bool,
    seed: u64,
) -> EnvironmentLoop<VecAdder, Fixed> {
    let vars = Variables {
        version,
        policy: Arc::new(policy_bytes(&cfg)),
        stage,
        room: cfg.curriculum.rooms[stage as usize].clone(),
        warmup,
        stop: false,
    };
    EnvironmentLoop::new(cfg, "t".into(), 0, seed, VecAdder::default(), Fixed(Arc::new(vars)), None)
        .unwrap()
}

/// Steps every environment of `el` `steps` times (unless the learner says stop first).
fn run_steps<V: VariableSource>(el: &mut EnvironmentLoop<VecAdder, V>, steps: usize) {
    let mut n = 0;
    el.run(|_| {
        n += 1;
        n <= steps
    })
    .unwrap();
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
    let mut el = fixed_loop(cfg, 3, stage, warmup, seed);
    run_steps(&mut el, steps);
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
    run_steps(&mut el, 100);
    let c = el.counters();
    assert!(c.episodes >= 5, "{c:?}");
    assert_eq!(c.logged_episodes, 0, "{c:?}");
    assert!(c.log_write_failures >= 5, "every selected episode tried and failed: {c:?}");
    let failures = c.log_write_failures;
    // The directory is back: the next selected episodes are written again.
    std::fs::remove_file(&dir).unwrap();
    std::fs::create_dir(&dir).unwrap();
    run_steps(&mut el, 100);
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
        assert_eq!(b.next_obs(i), &b.observations[(i + 3) * d..(i + 4) * d], "transition {i}");
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
    let mut cfg = Config::from_toml_str(include_str!("../../../configs/sac_ri.toml")).unwrap();
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
    run_steps(&mut el, 200);
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
            assert_eq!(radius(b.next_obs(i), 0), r, "one radius per episode");
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

/// `warmup.expert_share`: the planner expert drives that share of the policy's episodes (all
/// of them at 1, none at 0), acting as the PID does (weight version 0, not counted towards
/// the curriculum), and reaches goals behind walls the untrained policy does not.
#[test]
fn the_planner_expert_drives_its_share_of_episodes() {
    let run_with = |share: f64| {
        let mut cfg = Config::default();
        cfg.actor.envs = 3;
        cfg.curriculum.rooms = vec!["generated:walls:0..10".into()];
        cfg.env.subgoals =
            Some(dvnav_sim::subgoal::SubgoalConfig { follow_share: 0.0, ..Default::default() });
        cfg.warmup.expert_share = share;
        let mut el = fixed_loop(cfg, 3, 0, false, 4);
        run_steps(&mut el, 1500);
        let (adder, c) = el.finish().unwrap();
        (adder.batch, c)
    };
    let (b, c) = run_with(1.0);
    assert!(c.episodes >= 6, "{c:?}");
    assert_eq!((c.expert_episodes, c.warmup_episodes), (c.episodes, c.episodes));
    assert!(b.policy_versions.iter().all(|&v| v == 0));
    assert!(b.episodes.iter().all(|e| e.warmup));
    let expert_rate = c.successes as f64 / c.episodes as f64;
    let (b, c) = run_with(0.0);
    assert_eq!((c.expert_episodes, c.warmup_episodes), (0, 0));
    assert!(b.policy_versions.iter().all(|&v| v == 3));
    let policy_rate = c.successes as f64 / c.episodes.max(1) as f64;
    assert!(expert_rate >= 0.8 && expert_rate > policy_rate, "{expert_rate} {policy_rate}");
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

/// A source whose weights can change between steps, as the learner's stream changes them.
struct Swappable(Arc<std::sync::Mutex<Arc<Variables>>>);

impl VariableSource for Swappable {
    fn latest(&self) -> Option<Arc<Variables>> {
        Some(self.0.lock().unwrap().clone())
    }
}

#[test]
fn a_step_that_waits_for_the_learner_acts_with_the_weights_published_meanwhile() {
    let mut cfg = Config::default();
    cfg.actor.envs = 3;
    let vars = Arc::new(std::sync::Mutex::new(Arc::new(Variables {
        version: 3,
        policy: Arc::new(policy_bytes(&cfg)),
        stage: 0,
        room: cfg.curriculum.rooms[0].clone(),
        warmup: false,
        stop: false,
    })));
    // The third step waits, and the learner publishes version 4 meanwhile.
    let published = vars.clone();
    let adder = VecAdder {
        on_ready: Some(Box::new(move |step| {
            if step == 3 {
                let mut v = published.lock().unwrap();
                *v = Arc::new(Variables { version: 4, ..(**v).clone() });
            }
        })),
        ..VecAdder::default()
    };
    let mut el = EnvironmentLoop::new(cfg, "t".into(), 0, 1, adder, Swappable(vars), None).unwrap();
    for _ in 0..5 {
        assert!(el.step().unwrap());
    }
    let (adder, _) = el.finish().unwrap();
    let versions = &adder.batch.policy_versions;
    assert_eq!(versions.len(), 15);
    assert_eq!(versions[..6], [3; 6], "steps 1 and 2");
    assert_eq!(versions[6..], [4; 9], "step 3 waited, then acted with version 4");
}

/// The loop of `run_at` over `rooms`, at `stage`, with PID episodes (no weights needed).
fn run_rooms(rooms: &[&str], stage: u32, steps: usize, seed: u64) -> TransitionBatch {
    let mut cfg = Config::default();
    cfg.actor.envs = 3;
    cfg.env.max_steps = 25;
    cfg.curriculum.rooms = rooms.iter().map(|r| r.to_string()).collect();
    let mut el = fixed_loop(cfg, 1, stage, true, seed);
    run_steps(&mut el, steps);
    el.finish().unwrap().0.batch
}

#[test]
fn a_set_stage_runs_its_episodes_in_many_rooms_of_the_set_and_a_single_stage_in_its_room() {
    let set = "generated:clutter:0..5:size=5|env0";
    let allowed: std::collections::BTreeSet<String> = (0..5)
        .map(|s| format!("generated:clutter:{s}:size=5"))
        .chain(["env0".to_string()])
        .collect();
    let b = run_rooms(&[set, "env1"], 0, 300, 4);
    assert!(b.episodes.len() >= 20, "{}", b.episodes.len());
    assert!(b.episodes.iter().all(|e| e.stage == 0 && allowed.contains(&e.room)));
    let seen: std::collections::BTreeSet<&str> =
        b.episodes.iter().map(|e| e.room.as_str()).collect();
    assert!(seen.len() >= 4, "rooms drawn: {seen:?}");
    assert!(seen.contains("env0"), "{seen:?}");
    // The same seed draws the same rooms.
    let again = run_rooms(&[set, "env1"], 0, 300, 4);
    let rooms = |b: &TransitionBatch| b.episodes.iter().map(|e| e.room.clone()).collect::<Vec<_>>();
    assert_eq!(rooms(&b), rooms(&again));
    // Assigned stage 1 (one room): every episode after each environment's first (begun in
    // stage 0's set, before the loop heard of stage 1) runs in `env1`.
    let b = run_rooms(&[set, "env1"], 1, 200, 4);
    let mut firsts = std::collections::HashSet::new();
    let later: Vec<_> = b.episodes.iter().filter(|e| !firsts.insert(e.env_index)).collect();
    assert!(later.len() >= 10, "{}", later.len());
    assert!(later.iter().all(|e| e.stage == 1 && e.room == "env1"));
}

#[test]
fn the_room_cache_keeps_at_most_its_capacity_and_never_drops_a_room_in_use() {
    let mut cache = RoomCache::default();
    let in_use = cache.get("env0").unwrap();
    for seed in 0..ROOM_CACHE_CAPACITY as u64 + 3 {
        // Cheap rooms: a few obstacles in a small square.
        cache.get(&format!("generated:clutter:{seed}:size=3,density=0.02")).unwrap();
        assert!(cache.rooms.len() <= ROOM_CACHE_CAPACITY);
    }
    assert_eq!(cache.rooms.len(), ROOM_CACHE_CAPACITY);
    assert_eq!(cache.order.len(), ROOM_CACHE_CAPACITY);
    assert!(Arc::ptr_eq(&cache.get("env0").unwrap()[0], &in_use[0]), "env0 was kept");
    assert!(!cache.rooms.contains_key("generated:clutter:0:density=0.02,size=3"), "oldest out");
}

/// `curriculum.robust_from_stage`: a run before that stage draws clean episodes, one at or
/// past it draws the configured perturbations (here a fixed dropout, so every such episode's
/// draw shows it), whatever the stage of the room an episode revisits.
#[test]
fn robustness_starts_at_its_stage() {
    let episodes_at = |stage: u32| {
        let mut cfg = Config::default();
        cfg.actor.envs = 2;
        cfg.env.max_steps = 15;
        cfg.env.robustness.beam_dropout = 0.1;
        cfg.curriculum.robust_from_stage = Some(2);
        cfg.curriculum.earlier_share = 0.5;
        let mut el = fixed_loop(cfg, 3, stage, true, 7);
        // Every environment finishes at least two episodes (timeouts at 15 steps at most).
        let mut dropouts = Vec::new();
        for _ in 0..40 {
            assert!(el.step().unwrap());
            dropouts.extend(el.envs.envs().iter().map(|e| e.perturbation().beam_dropout));
        }
        let first = el.envs.envs()[0].perturbation().beam_dropout;
        (first, dropouts)
    };
    let (_, before) = episodes_at(1);
    assert!(before.iter().all(|&d| d == 0.0), "{before:?}");
    let (last, after) = episodes_at(2);
    assert_eq!(last, 0.1, "episodes begun at stage 2 are perturbed");
    // The first episodes began before the learner's stage arrived (clean); the later ones
    // are perturbed, earlier rooms included (earlier_share = 0.5).
    assert!(after.contains(&0.0) && after.contains(&0.1), "{after:?}");
}
