//! The learner's gRPC service over a real loopback socket: status codes for bad requests,
//! acknowledgements for good batches, and a shutdown through a oneshot, never a sleep.

use dvnav_config::Config;
use dvnav_link::wire::batch_to_proto;
use dvnav_proto::{PROTOCOL_VERSION, StatusRequest, VariablesRequest};
use support::{Server, batch, bound, bound_iter, register, start, start_limited, start_with};
use tonic::Code;

mod support;

#[tokio::test]
async fn wrong_protocol_version_is_a_failed_precondition() {
    let s = start(None).await;
    let err = s.client().await.register(register("a", PROTOCOL_VERSION + 1)).await.unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition, "{err}");
    s.shutdown().await;
}

#[tokio::test]
async fn a_missing_or_wrong_token_is_refused() {
    let s = start(Some("s3cret")).await;
    let mut c = s.client().await;
    assert_eq!(
        c.register(register("a", PROTOCOL_VERSION)).await.unwrap_err().code(),
        Code::Unauthenticated
    );
    let mut req = tonic::Request::new(register("a", PROTOCOL_VERSION));
    req.metadata_mut().insert("authorization", "Bearer wrong".parse().unwrap());
    assert_eq!(c.register(req).await.unwrap_err().code(), Code::Unauthenticated);
    let mut req = tonic::Request::new(register("a", PROTOCOL_VERSION));
    req.metadata_mut().insert("authorization", "Bearer s3cret".parse().unwrap());
    let reply = c.register(req).await.unwrap().into_inner();
    assert_eq!(reply.obs_spec.unwrap().obs_dim, 544);
    assert!(Config::from_toml_str(&reply.run_config_toml).is_ok());
    s.shutdown().await;
}

#[tokio::test]
async fn good_batches_are_acknowledged_and_malformed_ones_rejected_and_counted() {
    let s = start(None).await;
    let mut c = s.client().await;
    let reg = c.register(register("a", PROTOCOL_VERSION)).await.unwrap().into_inner();
    let id = reg.actor_id;
    let cfg = s.state.config().clone();
    let good = dvnav_link::wire::batch_to_proto(&batch(&cfg, 5), id, 0);
    let mut bad = dvnav_link::wire::batch_to_proto(&batch(&cfg, 3), id, 1);
    bad.observations[7] = f32::NAN;

    let mut acks =
        c.transitions(bound_iter(&reg.session, vec![good, bad])).await.unwrap().into_inner();
    let first = acks.message().await.unwrap().unwrap();
    assert_eq!((first.sequence, first.accepted), (0, 5));
    let err = acks.message().await.unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("observations"), "{}", err.message());

    let st = c.status(StatusRequest {}).await.unwrap().into_inner();
    assert_eq!((st.transitions_received, st.transitions_rejected), (5, 3));
    assert_eq!(st.replay_size, 5, "the malformed batch never reached the replay buffer");

    // A stream without a session, as from an actor that never registered.
    let stranger = dvnav_link::wire::batch_to_proto(&batch(&cfg, 1), 42, 0);
    let err = c.transitions(tokio_stream::iter(vec![stranger])).await.unwrap_err();
    assert_eq!(err.code(), Code::Unauthenticated, "{err}");
    s.shutdown().await;
}

#[tokio::test]
async fn variables_stream_delivers_weights_and_ends_at_shutdown() {
    let s = start(None).await;
    let mut c = s.client().await;
    let id = c.register(register("a", PROTOCOL_VERSION)).await.unwrap().into_inner().actor_id;
    let mut vars = c.variables(VariablesRequest { actor_id: id }).await.unwrap().into_inner();
    let first = vars.message().await.unwrap().unwrap();
    assert_eq!((first.version, &first.safetensors[..]), (1, &[1u8, 2, 3][..]));
    s.state.variables().publish_weights(vec![9; 5_000_000]);
    let second = vars.message().await.unwrap().unwrap();
    assert_eq!(
        (second.version, second.safetensors.len()),
        (2, 5_000_000),
        "over gRPC's 4 MiB default"
    );
    s.state.begin_shutdown();
    // The stop flag arrives, then the stream ends instead of holding shutdown up.
    while let Some(u) = vars.message().await.unwrap_or(None) {
        assert!(u.stop);
    }
    s.shutdown().await;
}

/// Issue 27's bound on idle readers: a client that opens Variables streams and never reads
/// them pinned a weight message each (32 streams, 59.5 MiB). One stream per registered actor:
/// a second is refused with RESOURCE_EXHAUSTED, an unknown actor id with INVALID_ARGUMENT, the
/// field named and each counted; the actor's stream opens again once the first is dropped.
#[tokio::test]
async fn one_variables_stream_per_actor_bounds_what_idle_readers_pin() {
    let s = start(None).await;
    let mut c = s.client().await;
    let id = c.register(register("a", PROTOCOL_VERSION)).await.unwrap().into_inner().actor_id;
    let idle = c.variables(VariablesRequest { actor_id: id }).await.unwrap().into_inner();
    for _ in 0..31 {
        let err = c.variables(VariablesRequest { actor_id: id }).await.unwrap_err();
        assert_eq!(err.code(), Code::ResourceExhausted, "{err}");
        assert!(err.message().contains(&format!("actor id {id} already has a Variables stream")));
    }
    let err = c.variables(VariablesRequest { actor_id: id + 100 }).await.unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument, "{err}");
    assert!(err.message().contains(&format!("unknown actor id {}", id + 100)), "{err}");
    let st = s.state.status();
    assert_eq!(st.rejected_by_reason.get("variables_stream_open"), Some(&31));
    assert_eq!(st.rejected_by_reason.get("unknown_actor"), Some(&1));
    // The reader goes away (the client drops the stream): the server frees the actor's slot
    // when it sees the stream reset, without waiting for a new weight version.
    drop(idle);
    let mut again = None;
    for _ in 0..200 {
        match c.variables(VariablesRequest { actor_id: id }).await {
            Ok(r) => {
                again = Some(r.into_inner());
                break;
            }
            Err(e) => {
                assert_eq!(e.code(), Code::ResourceExhausted, "{e}");
                tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            }
        }
    }
    let mut again = again.expect("the actor's stream opens again within 2 s of the drop");
    assert_eq!(again.message().await.unwrap().unwrap().version, 1);
    s.shutdown().await;
}

/// Random and damaged batches thrown at the real service: each is refused with
/// INVALID_ARGUMENT (or accepted when it happens to be valid), the learner keeps serving, and
/// nothing malformed reaches the replay buffer.
#[tokio::test]
async fn random_batches_are_refused_and_the_learner_keeps_serving() {
    use rand::{Rng, SeedableRng};
    let s = start(None).await;
    let mut c = s.client().await;
    let reg = c.register(register("fuzz", PROTOCOL_VERSION)).await.unwrap().into_inner();
    let id = reg.actor_id;
    let cfg = s.state.config().clone();
    let d = cfg.obs_dim();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut refused = 0;
    let mut inserted = 0u64;
    // The sequence number moves on only when a batch is accepted.
    let mut seq = 0u64;
    for _ in 0..60 {
        let mut m = dvnav_link::wire::batch_to_proto(&batch(&cfg, 2), id, seq);
        match rng.random_range(0..6) {
            0 => m.count = rng.random(),
            1 => m.observations.truncate(rng.random_range(0..2 * d)),
            2 => m.actions[rng.random_range(0..4)] = rng.random_range(-5.0..5.0),
            3 => m.rewards[rng.random_range(0..2)] = f32::NEG_INFINITY,
            4 => {
                let k = rng.random_range(0..m.next_observations.len());
                m.next_observations[k] = f32::NAN
            }
            _ => m.terminated = vec![true; rng.random_range(0..5)],
        }
        let claimed = m.count as u64;
        let mut acks = c.transitions(bound_iter(&reg.session, vec![m])).await.unwrap().into_inner();
        match acks.message().await {
            Ok(Some(ack)) => {
                inserted += ack.accepted as u64;
                seq += 1;
            }
            Err(e) => {
                assert_eq!(e.code(), Code::InvalidArgument, "{e}");
                refused += 1;
                let _ = claimed;
            }
            Ok(None) => panic!("stream ended without an answer"),
        }
    }
    assert!(refused > 40, "most damaged batches are refused ({refused})");
    let st = c.status(StatusRequest {}).await.unwrap().into_inner();
    assert_eq!(st.replay_size, inserted, "only valid batches reached the replay buffer");
    assert_eq!(st.transitions_received, inserted);
    // Still serving.
    let ok = dvnav_link::wire::batch_to_proto(&batch(&cfg, 1), id, seq);
    let mut acks = c.transitions(bound_iter(&reg.session, vec![ok])).await.unwrap().into_inner();
    assert_eq!(acks.message().await.unwrap().unwrap().accepted, 1);
    s.shutdown().await;
}

/// An actor that dies while its batch waits under backpressure: the learner notices the broken
/// stream at once (not when room frees up), drops the waiting batch uncounted, and a process
/// that registers again under the name continues at the first batch never inserted.
#[tokio::test]
async fn a_batch_waiting_when_its_actor_dies_is_dropped_uncounted() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000;
    cfg.sac.learning_starts = 0;
    // No trainer runs: after 5 transitions ingestion waits for updates that never come.
    cfg.learner.max_steps_ahead = 5;
    let s = start_with(cfg.clone(), None).await;
    let mut c = s.client().await;
    let reg = c.register(register("doomed", PROTOCOL_VERSION)).await.unwrap().into_inner();
    let id = reg.actor_id;
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    let mut acks = c
        .transitions(bound(&reg.session, tokio_stream::wrappers::ReceiverStream::new(rx)))
        .await
        .unwrap()
        .into_inner();
    let proto = |n, seq| dvnav_link::wire::batch_to_proto(&batch(&cfg, n), id, seq);
    tx.send(proto(5, 0)).await.unwrap();
    assert_eq!(acks.message().await.unwrap().unwrap().accepted, 5);
    tx.send(proto(4, 1)).await.unwrap();
    // Give the learner time to read batch 1 and park it in the rate limiter (if it has not,
    // the test still holds, it just does not exercise the wait).
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    assert!(s.state.status().actors[0].connected);
    // The "process" dies: its stream is reset and its connection dropped.
    drop((acks, tx, c));
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    while s.state.status().actors[0].connected {
        assert!(std::time::Instant::now() < deadline, "the learner never noticed the dead actor");
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    // Room frees up: nothing of the dead stream is left to insert.
    s.state.limiter().close();
    tokio::task::yield_now().await;
    let st = s.state.status();
    assert_eq!((st.transitions_received, st.replay_size), (5, 5), "{st:?}");

    // The restarted process continues at batch 1, which is new data, not a duplicate.
    let mut c = s.client().await;
    let again = c.register(register("doomed", PROTOCOL_VERSION)).await.unwrap().into_inner();
    assert_eq!((again.actor_id, again.next_sequence), (id, 1));
    let mut acks =
        c.transitions(bound_iter(&again.session, vec![proto(3, 1)])).await.unwrap().into_inner();
    let ack = acks.message().await.unwrap().unwrap();
    assert_eq!((ack.accepted, ack.duplicate), (3, false));
    assert_eq!(s.state.status().transitions_received, 8);
    s.shutdown().await;
}

/// An oversized message (over the server's decoding limit; 1 MiB here instead of the
/// production 256 MiB, the same tonic mechanism) is refused with tonic's status for it
/// (OUT_OF_RANGE), counted under `stream_oversized`, never reaches the replay buffer, and the
/// learner goes on serving the same actor.
#[tokio::test]
async fn an_oversized_message_is_refused_and_the_learner_keeps_serving() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000_000;
    let s = start_limited(cfg.clone(), None, 1 << 20).await;
    let mut c = s.client().await;
    let reg = c.register(register("a", PROTOCOL_VERSION)).await.unwrap().into_inner();
    let id = reg.actor_id;
    // Just over 1 MiB: n transitions of one obs_dim-long observation of four-byte floats each
    // (the next observation of one is the observation of the following one).
    let n = 1 + (1 << 20) / (4 * cfg.obs_dim());
    let huge = dvnav_link::wire::batch_to_proto(&batch(&cfg, n), id, 0);
    let mut acks = c.transitions(bound_iter(&reg.session, vec![huge])).await.unwrap().into_inner();
    let err = acks.message().await.unwrap_err();
    assert_eq!(err.code(), Code::OutOfRange, "{err}");
    let st = s.state.status();
    assert_eq!((st.transitions_received, st.replay_size), (0, 0));
    assert_eq!(
        st.rejected_by_reason.get("stream_oversized"),
        Some(&1),
        "{:?}",
        st.rejected_by_reason
    );
    // The learner still serves: a normal batch on a new stream is accepted.
    let ok = dvnav_link::wire::batch_to_proto(&batch(&cfg, 4), id, 0);
    let mut acks = c.transitions(bound_iter(&reg.session, vec![ok])).await.unwrap().into_inner();
    assert_eq!(acks.message().await.unwrap().unwrap().accepted, 4);
    let status = c.status(StatusRequest {}).await.unwrap().into_inner();
    assert_eq!(status.transitions_received, 4);
    s.shutdown().await;
}

/// An open transition stream of one actor: batches in, acknowledgements out.
struct OpenStream {
    tx: tokio::sync::mpsc::Sender<dvnav_proto::TransitionBatch>,
    acks: tonic::Streaming<dvnav_proto::BatchAck>,
}

impl OpenStream {
    async fn open(s: &Server, session: &str) -> Self {
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let req = bound(session, tokio_stream::wrappers::ReceiverStream::new(rx));
        let acks = s.client().await.transitions(req).await.unwrap().into_inner();
        Self { tx, acks }
    }

    async fn send(&mut self, m: dvnav_proto::TransitionBatch) -> dvnav_proto::BatchAck {
        self.tx.send(m).await.unwrap();
        self.acks.message().await.unwrap().expect("an acknowledgement")
    }
}

#[tokio::test]
async fn each_actor_is_advised_its_share_of_the_transitions_in_flight() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000;
    cfg.learner.transitions_in_flight = 64;
    let s = start_with(cfg.clone(), None).await;
    let mut c = s.client().await;
    let a = c.register(register("a", PROTOCOL_VERSION)).await.unwrap().into_inner();
    assert_eq!(a.batch_transitions, 64, "alone");
    let mut sa = OpenStream::open(&s, &a.session).await;
    let ack = sa.send(batch_to_proto(&batch(&cfg, 4), a.actor_id, 0)).await;
    assert_eq!((ack.accepted, ack.batch_transitions), (4, 64));
    let b = c.register(register("b", PROTOCOL_VERSION)).await.unwrap().into_inner();
    assert_eq!(b.batch_transitions, 32, "a connected, b joining");
    let mut sb = OpenStream::open(&s, &b.session).await;
    assert_eq!(sb.send(batch_to_proto(&batch(&cfg, 4), b.actor_id, 0)).await.batch_transitions, 32);
    assert_eq!(sa.send(batch_to_proto(&batch(&cfg, 4), a.actor_id, 1)).await.batch_transitions, 32);
    // B goes away: A gets the whole budget back.
    drop(sb);
    let gone = std::time::Instant::now();
    while s.state.status().actors[b.actor_id as usize].connected {
        assert!(gone.elapsed().as_secs() < 10, "b's stream never ended");
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    assert_eq!(sa.send(batch_to_proto(&batch(&cfg, 4), a.actor_id, 2)).await.batch_transitions, 64);
    drop(sa);
    s.shutdown().await;
}
