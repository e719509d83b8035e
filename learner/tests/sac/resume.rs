//! Exact resume: stopping at a checkpoint and resuming gives the same next update as not
//! stopping, bit for bit. First for the SAC learner alone (the same batch fed to both), then
//! for the learner process's whole state (replay buffer saved in the checkpoint, batch drawn
//! by the restored sampling generator, counters, curriculum, weight version), going through
//! the same `checkpoint::save` and `Checkpoint::resume` that `dvnav learner` uses.

use crate::golden::tiny_config;
use candle_core::Device;
use dvnav_config::Config;
use dvnav_learner::checkpoint::{self, Checkpoint, CheckpointMeta};
use dvnav_learner::replay::Batch;
use dvnav_learner::sac::{SacLearner, SacNetworks};
use dvnav_learner::state::LearnerState;
use dvnav_learner::trainer;
use dvnav_link::core::{EpisodeStats, TransitionBatch};
use dvnav_sim::Outcome;

fn learner(cfg: &Config, seed: u64) -> SacLearner {
    let nets = SacNetworks::new(cfg, seed, &Device::Cpu).unwrap();
    SacLearner::new(nets, cfg.sac.clone(), Device::Cpu, seed).unwrap()
}

/// Everything a learner holds (networks, targets, log α, Adam moments) as safetensors bytes.
fn everything(l: &SacLearner) -> Vec<u8> {
    safetensors::tensor::serialize(l.state_tensors().unwrap(), None).unwrap()
}

fn batch(cfg: &Config, k: usize) -> Batch {
    let d = cfg.obs_dim();
    let n = 5;
    let x = |i: usize, f: f64| (0.3 + 1.7 * (1.0 + (f * i as f64 + k as f64).sin())) as f32;
    Batch {
        size: n,
        obs_dim: d,
        obs: (0..n * d).map(|i| x(i, 0.37)).collect(),
        actions: (0..n * 2).map(|i| (0.9 * (1.3 * i as f64 + k as f64).sin()) as f32).collect(),
        rewards: (0..n).map(|i| (i as f32 - 2.0) * 0.5).collect(),
        next_obs: (0..n * d).map(|i| x(i, 0.41)).collect(),
        discounts: vec![0.99; n],
        terminated: (0..n).map(|i| if (i + k).is_multiple_of(4) { 1.0 } else { 0.0 }).collect(),
        demonstrated: vec![0.0; n],
    }
}

#[test]
fn a_restored_learner_makes_the_same_next_update() {
    let cfg = tiny_config();
    let dir = tempfile::tempdir().unwrap();
    let mut a = learner(&cfg, 5);
    // Three updates: the next one (the 4th, index 3) is a critic-only update and the one
    // after it a policy update, so both kinds run after the resume.
    for k in 0..3 {
        a.update(&batch(&cfg, k)).unwrap();
    }
    let meta = CheckpointMeta {
        updates: a.updates(),
        optimizer_steps: a.optimizer_steps(),
        noise_rng: Some(a.noise_rng().clone()),
        ..Default::default()
    };
    checkpoint::write(dir.path(), &a, &meta, &cfg.to_toml_string(), None).unwrap();
    let ckpt = Checkpoint::latest(dir.path()).unwrap();

    // Another seed: every bit of the next update must come from the checkpoint.
    let mut b = learner(&cfg, 99);
    ckpt.restore_learner(&mut b).unwrap();
    assert_eq!(everything(&b), everything(&a));
    for k in 3..5 {
        let ma = a.update(&batch(&cfg, k)).unwrap();
        let mb = b.update(&batch(&cfg, k)).unwrap();
        // Update 3 is critic-only: the policy metrics it reports are the last policy update's,
        // which only the learner that did it remembers (they are reports, not state).
        assert_eq!((ma.critic_loss, ma.q_mean, ma.alpha), (mb.critic_loss, mb.q_mean, mb.alpha));
        if k == 4 {
            assert_eq!(ma, mb, "update {k}");
        }
        assert_eq!(everything(&a), everything(&b), "weights after update {k}");
    }

    // Control: without the noise generator the same restore gives another update, so the
    // comparison above can fail.
    let mut c = learner(&cfg, 99);
    c.load_state(&ckpt.tensors, ckpt.meta.updates, ckpt.meta.optimizer_steps).unwrap();
    c.update(&batch(&cfg, 3)).unwrap();
    let mut a2 = learner(&cfg, 5);
    for k in 0..4 {
        a2.update(&batch(&cfg, k)).unwrap();
    }
    assert_ne!(everything(&c), everything(&a2));
}

/// A batch of `n` transitions as an actor sends it, with one finished episode of `outcome`.
fn wire_batch(cfg: &Config, n: usize, seq: u64, outcome: Outcome) -> dvnav_proto::TransitionBatch {
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, n);
    for i in 0..n {
        let v = |f: f64| -> Vec<f32> {
            (0..d)
                .map(|j| (0.5 + (f * (j + i) as f64 + seq as f64).sin().abs() * 3.0) as f32)
                .collect()
        };
        let a = [((i as f32) * 0.3).sin(), ((seq as f32) * 0.7).cos()];
        // The last transition ends the episode the batch reports.
        let last = i == n - 1;
        let (terminated, truncated) =
            (last && outcome.is_terminal(), last && !outcome.is_terminal());
        b.push(&v(0.3), a, i as f32 * 0.1 - 0.2, &v(0.5), terminated, truncated, 1);
    }
    b.episodes.push(EpisodeStats {
        env_index: 0,
        stage: 0,
        room: "env0".into(),
        outcome,
        steps: n as u32,
        episode_return: 1.0,
        policy_version: 1,
        warmup: false,
        varied: false,
    });
    dvnav_link::wire::batch_to_proto(&b, 0, seq)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 1)]
async fn a_resumed_learner_process_continues_exactly() {
    let mut cfg = tiny_config();
    cfg.replay.save_in_checkpoint = true;
    cfg.replay.capacity = 32;
    cfg.sac.batch_size = 8;
    cfg.sac.learning_starts = 8;
    cfg.sac.updates_per_env_step = 1.0;
    cfg.warmup.pid_episodes = 2;
    cfg.curriculum.window = 4;
    cfg.actor.batch_transitions = 6;
    cfg.learner.max_steps_ahead = 10_000;
    let dir = tempfile::tempdir().unwrap();

    // The run before the stop: 7 batches (42 transitions, the ring wraps), 6 updates.
    let state = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    state.register("actor-0", dvnav_proto::PROTOCOL_VERSION).unwrap();
    let outcomes = [Outcome::Success, Outcome::Collision, Outcome::Success, Outcome::Timeout];
    for seq in 0..7 {
        state.ingest(0, wire_batch(&cfg, 6, seq, outcomes[seq as usize % 4])).await.unwrap();
    }
    let mut a = learner(&cfg, 1);
    let mut rng = trainer::sample_rng(cfg.run.seed);
    let mut scratch = Batch::default();
    for _ in 0..6 {
        trainer::train_step(&state, &mut a, &mut rng, &mut scratch).unwrap();
    }
    state.variables().publish_weights(a.policy_safetensors().unwrap());
    checkpoint::save(dir.path(), &state, &a, &rng).unwrap();
    let before = state.status();
    // What it does next without stopping.
    let next_a = trainer::train_step(&state, &mut a, &mut rng, &mut scratch).unwrap();
    let batch_a = scratch.clone();

    // Resume into a fresh process: another seed for everything the checkpoint must replace.
    let resumed = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let mut b = learner(&cfg, 77);
    let ckpt = Checkpoint::latest(dir.path()).unwrap();
    assert!(ckpt.dir.join(checkpoint::REPLAY_FILE).exists());
    let mut rng_b = ckpt.resume(&mut b, &resumed).unwrap().expect("the sampling generator");
    let after = resumed.status();
    assert_eq!(
        (after.transitions_received, after.episodes, after.updates, after.weight_version),
        (before.transitions_received, before.episodes, before.updates, before.weight_version)
    );
    assert_eq!(after.replay_size, before.replay_size);
    assert_eq!(resumed.curriculum_state(), state.curriculum_state());
    assert_eq!(after.success_rate, before.success_rate);
    assert!(!resumed.variables().current().warmup, "warm-up episodes were already done");

    let next_b = trainer::train_step(&resumed, &mut b, &mut rng_b, &mut scratch).unwrap();
    assert_eq!(scratch, batch_a, "the same batch is sampled");
    assert_eq!(next_a, next_b);
    assert_eq!(everything(&a), everything(&b), "bit-identical weights after the next update");
}

#[test]
fn without_a_saved_replay_training_waits_for_fresh_transitions() {
    let mut cfg = tiny_config();
    cfg.sac.learning_starts = 10;
    cfg.sac.batch_size = 4;
    cfg.sac.updates_per_env_step = 0.5;
    let dir = tempfile::tempdir().unwrap();
    let a = learner(&cfg, 1);
    let meta =
        CheckpointMeta { updates: 40, env_steps: 95, weight_version: 9, ..Default::default() };
    checkpoint::write(dir.path(), &a, &meta, "", None).unwrap();
    let state = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let mut b = learner(&cfg, 2);
    let ckpt = Checkpoint::latest(dir.path()).unwrap();
    assert!(ckpt.resume(&mut b, &state).unwrap().is_none(), "an old checkpoint has no generator");
    assert_eq!(b.updates(), 40);
    assert_eq!(state.variables().current().version, 9);
    let limiter = state.limiter();
    let (inserted, updates) = limiter.counters();
    assert_eq!(updates, 40);
    // No update until `learning_starts` new transitions are in, then the replay ratio again.
    let allowed = |fresh: u64| limiter.updates_allowed(inserted + fresh);
    assert!(allowed(9) < 40, "no update with 9 fresh transitions");
    assert_eq!((allowed(10), allowed(12)), (40, 41));
}

/// With `curriculum.replay_ratios` the count of transitions behind the updates cannot be read
/// back through one ratio: a resumed run goes on from its updates at its stage's ratio, once
/// `learning_starts` fresh transitions have refilled the emptied buffer.
#[test]
fn a_run_with_stage_ratios_resumes_at_its_stages_ratio() {
    let mut cfg = tiny_config();
    cfg.sac.learning_starts = 10;
    cfg.sac.batch_size = 4;
    cfg.curriculum.replay_ratios = vec![0.25, 0.5];
    let dir = tempfile::tempdir().unwrap();
    let a = learner(&cfg, 1);
    let meta =
        CheckpointMeta { updates: 40, env_steps: 300, weight_version: 9, ..Default::default() };
    checkpoint::write(dir.path(), &a, &meta, "", None).unwrap();
    let state = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    assert_eq!(state.limiter().ratio(), 0.25);
    let mut b = learner(&cfg, 2);
    let ckpt = Checkpoint::latest(dir.path()).unwrap();
    ckpt.resume(&mut b, &state).unwrap();
    let limiter = state.limiter();
    let (inserted, updates) = limiter.counters();
    assert_eq!((updates, limiter.ratio()), (40, 0.25), "stage 0's ratio");
    let allowed = |fresh: u64| limiter.updates_allowed(inserted + fresh);
    assert_eq!((allowed(9), allowed(10), allowed(13)), (40, 40, 41));
}
