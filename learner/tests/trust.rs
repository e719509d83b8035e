//! Bad traffic from a client that holds the shared token, over the real gRPC service (issue
//! 16): a stream that speaks for another actor, a sequence number that skips ahead, episode
//! reports no transition backs, stages outside the curriculum, and refused tokens. Each is
//! refused with its status code and counted by reason; nothing of it reaches the replay
//! buffer, the curriculum or the metric labels, and the real actor's data is not lost.

use dvnav_config::Config;
use dvnav_learner::actor_tokens::ActorTokens;
use dvnav_learner::metrics::{Sampler, render_prometheus};
use dvnav_learner::state::LearnerState;
use dvnav_link::core::{EpisodeStats, TransitionBatch};
use dvnav_link::wire::batch_to_proto;
use dvnav_proto::{PROTOCOL_VERSION, RegisterReply, StatusRequest, VariablesRequest};
use dvnav_sim::Outcome;
use support::{Server, batch, bound_iter, register, serve, start, start_with};
use tonic::Code;

mod support;

async fn join(s: &Server, name: &str) -> RegisterReply {
    s.client().await.register(register(name, PROTOCOL_VERSION)).await.unwrap().into_inner()
}

/// Sends `m` on a stream bound to `session`: the acknowledgement or the refusal.
async fn send(
    s: &Server,
    session: &str,
    m: dvnav_proto::TransitionBatch,
) -> Result<dvnav_proto::BatchAck, tonic::Status> {
    let mut acks = s.client().await.transitions(bound_iter(session, vec![m])).await?.into_inner();
    acks.message().await.map(|a| a.expect("an answer"))
}

fn reason(s: &Server, r: &str) -> u64 {
    s.state.status().rejected_by_reason.get(r).copied().unwrap_or(0)
}

/// One transition that ends an episode in `outcome`, and `reports` copies of its report.
fn one_episode(
    cfg: &Config,
    outcome: Outcome,
    steps: u32,
    ret: f32,
    stage: u32,
    reports: usize,
) -> TransitionBatch {
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, 1);
    let (terminated, truncated) = (outcome.is_terminal(), outcome == Outcome::Timeout);
    b.push(&vec![1.0; d], [0.5, 0.0], 10.0, &vec![2.0; d], terminated, truncated, 1);
    let e = EpisodeStats {
        env_index: 0,
        stage,
        room: "env0".into(),
        outcome,
        steps,
        episode_return: ret,
        policy_version: 1,
        warmup: false,
        varied: false,
    };
    b.episodes = vec![e; reports];
    b
}

#[tokio::test]
async fn a_stream_cannot_speak_for_another_actor() {
    let s = start(None).await;
    let cfg = s.state.config().clone();
    let a = join(&s, "a").await;
    let b = join(&s, "b").await;
    // A's stream, B's id: refused, nothing inserted, B credited nothing.
    let forged = batch_to_proto(&batch(&cfg, 8), b.actor_id, 0);
    let err = send(&s, &a.session, forged).await.unwrap_err();
    assert_eq!(err.code(), Code::PermissionDenied, "{err}");
    let st = s.state.status();
    assert_eq!((st.transitions_received, st.replay_size), (0, 0));
    assert_eq!(st.actors[b.actor_id as usize].transitions_received, 0);
    assert_eq!(reason(&s, "actor_mismatch"), 1);
    assert_eq!(st.actors[a.actor_id as usize].transitions_rejected, 8, "counted against A");

    // No session, a made-up one, and A's previous one after A registered again.
    let mine = batch_to_proto(&batch(&cfg, 8), a.actor_id, 0);
    let mut c = s.client().await;
    let err = c.transitions(tokio_stream::iter(vec![mine.clone()])).await.unwrap_err();
    assert_eq!(err.code(), Code::Unauthenticated, "{err}");
    assert_eq!(send(&s, "0123abcd", mine.clone()).await.unwrap_err().code(), Code::Unauthenticated);
    let a2 = join(&s, "a").await;
    assert_eq!(a2.actor_id, a.actor_id);
    assert_eq!(send(&s, &a.session, mine.clone()).await.unwrap_err().code(), Code::Unauthenticated);
    assert_eq!((reason(&s, "session_missing"), reason(&s, "session_unknown")), (1, 2));
    assert_eq!(s.state.status().replay_size, 0);

    // B's own stream still delivers B's batch 0.
    let real = batch_to_proto(&batch(&cfg, 8), b.actor_id, 0);
    let ack = send(&s, &b.session, real).await.unwrap();
    assert_eq!((ack.accepted, ack.duplicate), (8, false));
    assert_eq!(s.state.status().actors[b.actor_id as usize].transitions_received, 8);
    s.shutdown().await;
}

#[tokio::test]
async fn a_sequence_jump_is_refused_and_the_next_real_batch_is_not_a_duplicate() {
    let s = start(None).await;
    let cfg = s.state.config().clone();
    let a = join(&s, "a").await;
    let ok = send(&s, &a.session, batch_to_proto(&batch(&cfg, 4), a.actor_id, 0)).await.unwrap();
    assert_eq!(ok.accepted, 4);
    let jump = batch_to_proto(&batch(&cfg, 4), a.actor_id, 1_000_000_000);
    let err = send(&s, &a.session, jump).await.unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition, "{err}");
    assert!(err.message().contains("next expected is 1"), "{}", err.message());
    assert_eq!(reason(&s, "sequence_gap"), 1);
    // The actor's real batch 1: new data, inserted.
    let ack = send(&s, &a.session, batch_to_proto(&batch(&cfg, 4), a.actor_id, 1)).await.unwrap();
    assert_eq!((ack.accepted, ack.duplicate), (4, false));
    let st = s.state.status();
    assert_eq!((st.transitions_received, st.replay_size), (8, 8));
    assert_eq!(st.actors[0].duplicate_batches, 0);
    assert_eq!(st.actors[0].next_sequence, 2);
    s.shutdown().await;
}

#[tokio::test]
async fn episode_reports_no_transition_backs_do_not_move_the_curriculum() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000_000;
    cfg.warmup.pid_episodes = 0;
    let s = start_with(cfg.clone(), None).await;
    let a = join(&s, "a").await;
    // Every batch here is refused, so each one is the actor's batch 0.
    let seq = 0;
    let cases = [
        // One transition, sixty successes.
        (one_episode(&cfg, Outcome::Success, 30, 10.0, 0, 60), "episode_count"),
        // A success reported for a timed-out transition.
        (one_episode(&cfg, Outcome::Timeout, 400, 1.0, 0, 0), "episode_count"),
        (one_episode(&cfg, Outcome::Success, 401, 10.0, 0, 1), "episode_steps"),
        (one_episode(&cfg, Outcome::Success, 0, 10.0, 0, 1), "episode_steps"),
        // A success quicker than the robot can drive from the closest start allowed.
        (one_episode(&cfg, Outcome::Success, 1, 10.0, 0, 1), "episode_steps"),
        (one_episode(&cfg, Outcome::Success, 5, 500.0, 0, 1), "episode_return"),
    ];
    for (mut b, why) in cases {
        if why == "episode_count" && b.episodes.is_empty() {
            b.episodes = one_episode(&cfg, Outcome::Success, 30, 10.0, 0, 1).episodes;
        }
        let err = send(&s, &a.session, batch_to_proto(&b, a.actor_id, seq)).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{why}: {err}");
        assert!(err.message().contains(why), "{why}: {}", err.message());
    }
    assert_eq!(reason(&s, "episode_count"), 2);
    assert_eq!((reason(&s, "episode_steps"), reason(&s, "episode_return")), (3, 1));
    let st = s.state.status();
    assert_eq!((st.episodes, st.stage, st.replay_size), (0, 0, 0));
    assert!(s.state.curriculum_state().changes.is_empty());

    // An honest report in the same shape is accepted and counted.
    let honest = one_episode(&cfg, Outcome::Success, 30, 10.0, 0, 1);
    let ack = send(&s, &a.session, batch_to_proto(&honest, a.actor_id, seq)).await.unwrap();
    assert_eq!(ack.accepted, 1);
    assert_eq!(s.state.status().episodes, 1);
    s.shutdown().await;
}

#[tokio::test]
async fn stages_outside_the_curriculum_are_refused_and_make_no_metric_series() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000_000;
    let s = start_with(cfg.clone(), None).await;
    let a = join(&s, "a").await;
    for stage in [4, 300, u32::MAX] {
        let b = one_episode(&cfg, Outcome::Success, 30, 10.0, stage, 1);
        let err = send(&s, &a.session, batch_to_proto(&b, a.actor_id, 0)).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{err}");
    }
    assert_eq!(reason(&s, "episode_stage"), 3);
    // Stage 3, the last room, is in the curriculum.
    let b = one_episode(&cfg, Outcome::Success, 30, 10.0, 3, 1);
    assert_eq!(send(&s, &a.session, batch_to_proto(&b, a.actor_id, 0)).await.unwrap().accepted, 1);
    let text = render_prometheus(&Sampler::new().sample(&s.state));
    let series: Vec<&str> =
        text.lines().filter(|l| l.starts_with("dvnav_stage_episodes_total{")).collect();
    assert_eq!(series.len(), 1, "{series:?}");
    assert!(series[0].starts_with("dvnav_stage_episodes_total{stage=\"3\""), "{series:?}");
    s.shutdown().await;
}

/// `req` with `authorization: Bearer token` when a token is given.
fn with<T>(token: Option<&str>, req: T) -> tonic::Request<T> {
    let mut r = tonic::Request::new(req);
    if let Some(t) = token {
        r.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    r
}

#[tokio::test]
async fn refused_tokens_are_counted_as_unauthenticated() {
    let s = start(Some("s3cret")).await;
    let mut c = s.client().await;
    for token in [None, Some("wrong"), Some("s3cre"), Some("s3cret ")] {
        let r = c.register(with(token, register("a", PROTOCOL_VERSION))).await;
        assert_eq!(r.unwrap_err().code(), Code::Unauthenticated);
        let r = c.status(with(token, StatusRequest {})).await;
        assert_eq!(r.unwrap_err().code(), Code::Unauthenticated);
        let r = c.variables(with(token, VariablesRequest { actor_id: 0 })).await;
        assert_eq!(r.unwrap_err().code(), Code::Unauthenticated);
        let r = c.transitions(with(token, tokio_stream::iter(Vec::new()))).await;
        assert_eq!(r.unwrap_err().code(), Code::Unauthenticated);
    }
    assert_eq!(reason(&s, "unauthenticated"), 16);
    let text = render_prometheus(&Sampler::new().sample(&s.state));
    assert!(
        text.lines().any(|l| l == "dvnav_requests_rejected_total{reason=\"unauthenticated\"} 16"),
        "{text}"
    );
    // The right token still works.
    let ok = c.register(with(Some("s3cret"), register("a", PROTOCOL_VERSION))).await;
    assert!(ok.is_ok());
    s.shutdown().await;
}

#[tokio::test]
async fn with_per_actor_tokens_a_name_registers_only_with_its_own() {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000;
    let tokens = ActorTokens::parse("a ta\nb tb\n").unwrap();
    let state =
        LearnerState::new(cfg, "t".into(), None, vec![1, 2, 3]).with_actor_tokens(Some(tokens));
    let s = serve(state, dvnav_proto::MAX_MESSAGE_BYTES).await;
    let mut c = s.client().await;
    let code = |r: Result<tonic::Response<RegisterReply>, tonic::Status>| r.unwrap_err().code();
    // B's token for A; a listed token for an unlisted name (no shared token); no token at all.
    assert_eq!(
        code(c.register(with(Some("tb"), register("a", PROTOCOL_VERSION))).await),
        Code::Unauthenticated
    );
    assert_eq!(
        code(c.register(with(Some("ta"), register("c", PROTOCOL_VERSION))).await),
        Code::Unauthenticated
    );
    assert_eq!(
        code(c.register(with(None, register("a", PROTOCOL_VERSION))).await),
        Code::Unauthenticated
    );
    assert_eq!((reason(&s, "actor_token"), reason(&s, "unauthenticated")), (2, 1));
    assert!(s.state.status().actors.is_empty(), "no refused name was registered");
    // Each with its own.
    let a =
        c.register(with(Some("ta"), register("a", PROTOCOL_VERSION))).await.unwrap().into_inner();
    let b =
        c.register(with(Some("tb"), register("b", PROTOCOL_VERSION))).await.unwrap().into_inner();
    assert_ne!(a.actor_id, b.actor_id);
    assert!(c.status(with(Some("tb"), StatusRequest {})).await.is_ok());
    s.shutdown().await;
}
