use super::*;
use dvnav_link::core::TransitionBatch;

fn small_config() -> Config {
    let mut cfg = Config::default();
    cfg.run.steps = 6;
    cfg.sac.batch_size = 2;
    cfg.sac.learning_starts = 2;
    cfg.replay.capacity = 16;
    cfg.actor.batch_transitions = 2;
    cfg.learner.max_steps_ahead = 1_000;
    cfg.warmup.pid_episodes = 1;
    cfg
}

fn batch(cfg: &Config, n: usize, actor_id: u32, seq: u64) -> pb::TransitionBatch {
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, n);
    // The last transition ends the (timed-out) episode the batch reports.
    for i in 0..n {
        b.push(&vec![1.0; d], [0.0, 0.0], 0.5, &vec![1.0; d], false, i == n - 1, 1);
    }
    b.episodes.push(dvnav_link::core::EpisodeStats {
        env_index: 0,
        stage: 0,
        room: "env0".into(),
        outcome: Outcome::Timeout,
        steps: 3,
        episode_return: 1.0,
        policy_version: 1,
        warmup: true,
        varied: false,
    });
    wire::batch_to_proto(&b, actor_id, seq)
}

#[tokio::test]
async fn counts_accepted_and_rejected_and_stops_at_the_budget() {
    let cfg = small_config();
    let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    assert!(matches!(
        s.ingest(id, batch(&cfg, 2, 9, 0)).await,
        Err(LearnerError::WrongActor { stream: 0, claimed: 9 })
    ));
    assert!(matches!(s.ingest(9, batch(&cfg, 2, 9, 0)).await, Err(LearnerError::UnknownActor(9))));
    assert_eq!(s.ingest(id, batch(&cfg, 3, id, 0)).await.unwrap().accepted, 3);
    assert!(!s.variables().current().warmup, "one warm-up episode was configured");
    let mut bad = batch(&cfg, 2, id, 1);
    bad.rewards[0] = f32::INFINITY;
    assert!(matches!(s.ingest(id, bad).await, Err(LearnerError::Malformed(_))));
    // Batch 1 was refused, so 2 would skip it.
    assert!(matches!(
        s.ingest(id, batch(&cfg, 3, id, 2)).await,
        Err(LearnerError::SequenceGap { got: 2, expected: 1 })
    ));
    assert!(!s.done_signal().is_cancelled());
    // A resend of batch 0 (after a reconnect) is acknowledged but not inserted again.
    let dup = s.ingest(id, batch(&cfg, 3, id, 0)).await.unwrap();
    assert_eq!(dup, Ack { accepted: 0, duplicate: true });
    s.ingest(id, batch(&cfg, 3, id, 1)).await.unwrap();
    // A restarted actor process is told where to continue its numbering.
    assert_eq!(s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().next_sequence, 2);
    let st = s.status();
    // Refused: 2 claiming actor 9, 2 malformed, 3 skipping ahead.
    assert_eq!((st.transitions_received, st.transitions_rejected, st.episodes), (6, 7, 2));
    assert_eq!(st.actors[0].transitions_received, 6);
    assert_eq!(st.actors[0].transitions_rejected, 7);
    assert_eq!(st.actors[0].duplicate_batches, 1);
    assert!(st.done && s.done_signal().is_cancelled());
    assert!(s.variables().current().stop);
}

/// Two streams of one actor id (a restarted process under the same name while the learner
/// has not yet seen the old stream end) both wait under backpressure with batch 1: it is
/// inserted once, the other copy is acknowledged as a duplicate.
#[tokio::test]
async fn a_sequence_number_is_inserted_once_across_streams_of_one_actor() {
    let mut cfg = small_config();
    cfg.run.steps = 1_000;
    cfg.sac.learning_starts = 0;
    cfg.learner.max_steps_ahead = 3;
    let s = Arc::new(LearnerState::new(cfg.clone(), "r".into(), None, vec![]));
    let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    assert_eq!(s.ingest(id, batch(&cfg, 3, id, 0)).await.unwrap().accepted, 3);
    // No updates: the next batches wait for room.
    let send = |seq| {
        let (s, b) = (s.clone(), batch(&cfg, 3, id, seq));
        tokio::spawn(async move { s.ingest(id, b).await.unwrap() })
    };
    let (first, second) = (send(1), send(1));
    for _ in 0..10 {
        tokio::task::yield_now().await;
    }
    assert!(!first.is_finished() && !second.is_finished(), "both wait under backpressure");
    assert_eq!(s.status().transitions_received, 3);
    s.limiter().close();
    let mut acks = [first.await.unwrap(), second.await.unwrap()];
    acks.sort_by_key(|a| a.duplicate);
    assert_eq!(acks, [Ack { accepted: 3, duplicate: false }, Ack { accepted: 0, duplicate: true }]);
    let st = s.status();
    assert_eq!((st.transitions_received, st.replay_size), (6, 6));
    assert_eq!(st.actors[0].duplicate_batches, 1);
}

/// Bad input, fuzzed: thousands of well-formed but invalid batches (unknown actor, wrong
/// sizes, NaN/Inf, rewards and actions out of bounds, huge declared counts, contradictory
/// flags, unknown outcomes) and registrations with wrong protocol versions, mixed with valid
/// batches. Each invalid one is refused with the status code the service returns and
/// counted under its reason; the replay buffer grows by exactly the valid ones.
#[tokio::test]
async fn random_invalid_batches_are_refused_by_reason_and_never_reach_the_replay_buffer() {
    use rand::{Rng, SeedableRng};
    use tonic::Code;
    let mut cfg = small_config();
    cfg.run.steps = 1 << 40;
    cfg.replay.capacity = 1 << 14;
    cfg.sac.learning_starts = 1 << 40;
    let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
    let (mut seq, mut replay, mut rejected) = (0u64, 0u64, 0u64);
    let mut by_reason: BTreeMap<String, u64> = BTreeMap::new();
    let d = cfg.obs_dim();
    let bad = |rng: &mut rand_pcg::Pcg64| match rng.random_range(0..3) {
        0 => f32::NAN,
        1 => f32::INFINITY,
        _ => f32::NEG_INFINITY,
    };
    for i in 0..6_000 {
        let n = rng.random_range(1..5usize);
        let mut m = batch(&cfg, n, id, seq);
        let sign = if rng.random() { 1.0 } else { -1.0 };
        let expect: Option<(&str, Code)> = match i % 15 {
            0 => {
                m.actor_id = rng.random_range(id + 1..=u32::MAX);
                Some(("actor_mismatch", Code::PermissionDenied))
            }
            1 => {
                let k = rng.random_range(1..=d);
                if rng.random() {
                    m.observations.truncate(n * d - k)
                } else {
                    m.observations.extend(std::iter::repeat_n(0.0, k))
                }
                Some(("observations", Code::InvalidArgument))
            }
            2 => {
                m.next_observations.pop();
                Some(("next_observations", Code::InvalidArgument))
            }
            3 => {
                let j = rng.random_range(0..n * d);
                m.observations[j] = bad(&mut rng);
                Some(("observations", Code::InvalidArgument))
            }
            4 => {
                m.rewards[rng.random_range(0..n)] = bad(&mut rng);
                Some(("rewards", Code::InvalidArgument))
            }
            5 => {
                m.rewards[rng.random_range(0..n)] =
                    sign * wire::MAX_ABS_REWARD * rng.random_range(1.001..1e6f32);
                Some(("rewards", Code::InvalidArgument))
            }
            6 => {
                m.actions[rng.random_range(0..2 * n)] = sign * rng.random_range(1.0001..1e6f32);
                Some(("actions", Code::InvalidArgument))
            }
            7 => {
                m.count = rng.random_range(wire::MAX_BATCH_TRANSITIONS as u32 + 1..=u32::MAX);
                Some(("count", Code::InvalidArgument))
            }
            8 => {
                m.count += rng.random_range(1..1000);
                Some(("observations", Code::InvalidArgument))
            }
            9 => {
                let j = rng.random_range(0..n);
                (m.terminated[j], m.truncated[j]) = (true, true);
                Some(("truncated", Code::InvalidArgument))
            }
            10 => {
                m.episodes[0].outcome = rng.random_range(3..i32::MAX);
                Some(("episodes", Code::InvalidArgument))
            }
            11 => {
                let v = rng.random_range(0..u32::MAX);
                let v = if v == dvnav_proto::PROTOCOL_VERSION { v + 1 } else { v };
                let e = s.register("b", v).unwrap_err();
                assert_eq!(tonic::Status::from(e).code(), Code::FailedPrecondition);
                *by_reason.entry("protocol_version".into()).or_default() += 1;
                None
            }
            12 => {
                m.sequence = seq + rng.random_range(1..=u64::MAX - seq);
                Some(("sequence_gap", Code::FailedPrecondition))
            }
            13 => {
                let fake = m.episodes[0].clone();
                m.episodes.extend(std::iter::repeat_n(fake, rng.random_range(1..100)));
                Some(("episode_count", Code::InvalidArgument))
            }
            _ => None,
        };
        if i % 15 == 11 {
            continue;
        }
        let claimed = (m.count as u64).min(wire::MAX_BATCH_TRANSITIONS as u64);
        match (s.ingest(id, m).await, expect) {
            (Ok(ack), None) => {
                assert_eq!(ack, Ack { accepted: n as u32, duplicate: false });
                seq += 1;
                replay += n as u64;
            }
            (Err(e), Some((reason, code))) => {
                assert_eq!(e.reason(), reason, "case {i}: {e}");
                assert_eq!(tonic::Status::from(e).code(), code, "case {i}");
                *by_reason.entry(reason.into()).or_default() += 1;
                rejected += claimed;
            }
            (r, expect) => panic!("case {i}: got {r:?}, expected {expect:?}"),
        }
        let st = s.status();
        assert_eq!(st.replay_size, replay, "case {i}");
        assert_eq!(st.transitions_received, replay, "case {i}");
    }
    let st = s.status();
    assert_eq!(st.rejected_by_reason, by_reason);
    assert_eq!(st.transitions_rejected, rejected);
    assert_eq!(st.actors[0].transitions_rejected, rejected);
    assert!(st.actors[0].last_error.as_deref().unwrap().contains("malformed"));
    assert_eq!(by_reason.len(), 11, "every reason was exercised: {by_reason:?}");
    let text = crate::metrics::render_prometheus(&crate::metrics::Sample {
        elapsed_s: 0.0,
        status: st,
        rooms: vec![],
        memory: Default::default(),
    });
    assert!(text.contains("dvnav_requests_rejected_total{reason=\"rewards\"} "), "{text}");
}

/// Random and truncated bytes through the prost decoder and into ingestion: nothing
/// panics, and the replay buffer grows by exactly what was acknowledged as accepted.
#[tokio::test]
async fn random_bytes_through_the_decoder_and_ingestion_never_panic() {
    use prost::Message;
    use rand::{Rng, SeedableRng};
    let mut cfg = small_config();
    cfg.run.steps = 1 << 40;
    cfg.replay.capacity = 1 << 14;
    cfg.sac.learning_starts = 1 << 40;
    let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    let valid = batch(&cfg, 2, id, 0).encode_to_vec();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let (mut decoded, mut accepted_total) = (0, 0u64);
    for i in 0..6_000 {
        let bytes: Vec<u8> = match i % 3 {
            0 => (0..rng.random_range(0..300)).map(|_| rng.random()).collect(),
            1 => valid[..rng.random_range(0..valid.len())].to_vec(),
            _ => {
                let mut v = valid.clone();
                for _ in 0..rng.random_range(1..4) {
                    let j = rng.random_range(0..v.len());
                    v[j] = rng.random();
                }
                v
            }
        };
        let Ok(mut msg) = pb::TransitionBatch::decode(bytes.as_slice()) else { continue };
        decoded += 1;
        // Mostly the registered actor at its next sequence number, so that validation (not
        // the unknown-actor or duplicate check) sees the damage.
        if rng.random_range(0..4) > 0 {
            msg.actor_id = id;
            msg.sequence = s.status().actors[0].next_sequence;
        }
        let before = s.status().replay_size;
        let accepted = match s.ingest(id, msg).await {
            Ok(ack) => ack.accepted as u64,
            Err(e) => {
                let _ = tonic::Status::from(e);
                0
            }
        };
        accepted_total += accepted;
        assert_eq!(s.status().replay_size, before + accepted, "case {i}");
    }
    assert!(decoded > 1_000, "{decoded} decoded");
    let st = s.status();
    assert_eq!(st.transitions_received, accepted_total);
    assert!(st.rejected_by_reason.values().sum::<u64>() > 10, "{:?}", st.rejected_by_reason);
}

#[test]
fn refuses_other_protocol_versions_and_wrong_tokens() {
    let s = LearnerState::new(small_config(), "r".into(), Some("t0k".into()), vec![]);
    assert!(matches!(s.register("a", 999), Err(LearnerError::ProtocolMismatch { .. })));
    assert!(matches!(s.authorize(None), Err(LearnerError::Unauthenticated)));
    assert!(matches!(s.authorize(Some("x")), Err(LearnerError::Unauthenticated)));
    assert!(s.authorize(Some("t0k")).is_ok());
    // Same name, same id.
    let a = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    let b = s.register("b", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    assert_ne!(a, b);
    assert_eq!(s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id, a);
}

#[test]
fn new_actor_names_stop_at_the_limit_and_known_ones_come_back() {
    let mut cfg = small_config();
    cfg.learner.max_actor_names = 2;
    let s = LearnerState::new(cfg, "r".into(), None, vec![]);
    let v = dvnav_proto::PROTOCOL_VERSION;
    let a = s.register("a", v).unwrap().actor_id;
    s.register("b", v).unwrap();
    let e = s.register("c", v).unwrap_err();
    assert!(matches!(e, LearnerError::TooManyActors(2)), "{e}");
    assert_eq!(tonic::Status::from(e).code(), tonic::Code::ResourceExhausted);
    assert_eq!(s.register("a", v).unwrap().actor_id, a, "a known name still registers");
    let st = s.status();
    assert_eq!((st.actors.len(), st.rejected_by_reason.get("too_many_actors")), (2, Some(&1)));
}

#[test]
fn actors_share_the_transitions_in_flight() {
    assert_eq!(share_of_in_flight(256, 0), 256);
    assert_eq!(share_of_in_flight(256, 2), 128);
    assert_eq!(share_of_in_flight(256, 3), 86, "rounded up: the shares cover the budget");
    assert_eq!(share_of_in_flight(256, 8), 32);
    assert_eq!(share_of_in_flight(256, 100), MIN_ADVISED_BATCH);
    let mut cfg = small_config();
    cfg.learner.transitions_in_flight = 64;
    let s = LearnerState::new(cfg, "r".into(), None, vec![]);
    let v = dvnav_proto::PROTOCOL_VERSION;
    assert_eq!(s.batch_transitions_advice(true), 64, "the first actor to join gets it all");
    let regs: Vec<Registration> = ["a", "b", "c", "d"].map(|n| s.register(n, v).unwrap()).into();
    // Registered is not connected: only open streams count.
    assert_eq!(s.batch_transitions_advice(false), 64);
    for r in &regs {
        s.open_stream(Some(&r.session)).unwrap();
    }
    assert_eq!(s.batch_transitions_advice(false), 16);
    assert_eq!(s.batch_transitions_advice(true), 13, "a fifth joining");
    s.set_connected(regs[0].actor_id, false);
    assert_eq!(s.batch_transitions_advice(false), 22);
}

/// A batch of one successful episode of `n` transitions in curriculum stage `stage`.
fn success_batch(
    cfg: &Config,
    n: usize,
    actor_id: u32,
    seq: u64,
    stage: u32,
) -> pb::TransitionBatch {
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, n);
    for i in 0..n {
        b.push(&vec![1.0; d], [0.0, 0.0], 0.5, &vec![1.0; d], i == n - 1, false, 1);
    }
    b.episodes.push(dvnav_link::core::EpisodeStats {
        env_index: 0,
        stage,
        room: cfg.curriculum.rooms[stage as usize].clone(),
        outcome: Outcome::Success,
        steps: n as u32,
        episode_return: 10.0,
        policy_version: 1,
        warmup: false,
        varied: false,
    });
    wire::batch_to_proto(&b, actor_id, seq)
}

/// `curriculum.replay_ratios`: the limiter runs at the first stage's ratio, and at the next
/// stage's from the batch that moves the run on.
#[tokio::test]
async fn each_curriculum_stage_runs_at_its_own_replay_ratio() {
    let mut cfg = small_config();
    cfg.run.steps = 10_000;
    cfg.warmup.pid_episodes = 0;
    cfg.curriculum.window = 2;
    cfg.curriculum.threshold = 0.5;
    cfg.curriculum.replay_ratios = vec![0.5, 0.125];
    let s = LearnerState::new(cfg.clone(), "r".into(), None, vec![]);
    let id = s.register("a", dvnav_proto::PROTOCOL_VERSION).unwrap().actor_id;
    assert_eq!(s.limiter().ratio(), 0.5);
    s.ingest(id, success_batch(&cfg, 20, id, 0, 0)).await.unwrap();
    assert_eq!(s.limiter().ratio(), 0.5, "one episode of a window of two");
    s.ingest(id, success_batch(&cfg, 20, id, 1, 0)).await.unwrap();
    assert_eq!(s.curriculum_state().stage, 1);
    assert_eq!(s.limiter().ratio(), 0.125);
    // 40 in at 0.5 from learning_starts (2): 19 updates allowed; then 0.125 per transition.
    assert_eq!(s.limiter().updates_allowed(40), 19);
    assert_eq!(s.limiter().updates_allowed(48), 20);
    // The last stage's ratio holds for the stages past the list.
    s.ingest(id, success_batch(&cfg, 20, id, 2, 1)).await.unwrap();
    s.ingest(id, success_batch(&cfg, 20, id, 3, 1)).await.unwrap();
    assert_eq!(s.curriculum_state().stage, 2);
    assert_eq!(s.limiter().ratio(), 0.125);
}
