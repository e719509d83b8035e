//! What the service tests share: a learner's gRPC service on a loopback socket with a
//! shutdown through a oneshot (never a sleep), registration, and batches on a stream bound
//! to a session.
// Each test binary compiles this module and uses a part of it.
#![allow(dead_code)]

use dvnav_config::Config;
use dvnav_learner::service::LearnerService;
use dvnav_learner::state::LearnerState;
use dvnav_link::core::TransitionBatch;
use dvnav_proto::RegisterRequest;
use dvnav_proto::learner_client::LearnerClient;
use std::sync::Arc;
use tonic::transport::Channel;

/// A learner service being served.
pub struct Server {
    pub state: Arc<LearnerState>,
    pub url: String,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
}

/// The default config with a 1,000-step budget, with the shared `token` if any.
pub async fn start(token: Option<&str>) -> Server {
    let mut cfg = Config::default();
    cfg.run.steps = 1_000;
    start_with(cfg, token).await
}

/// Serves a fresh state for `cfg`.
pub async fn start_with(cfg: Config, token: Option<&str>) -> Server {
    start_limited(cfg, token, dvnav_proto::MAX_MESSAGE_BYTES).await
}

/// Serves a fresh state for `cfg` with a message-size limit.
pub async fn start_limited(cfg: Config, token: Option<&str>, max_message_bytes: usize) -> Server {
    let state = LearnerState::new(cfg, "t".into(), token.map(String::from), vec![1, 2, 3]);
    serve(state, max_message_bytes).await
}

/// Serves `state`.
pub async fn serve(state: LearnerState, max_message_bytes: usize) -> Server {
    let state = Arc::new(state);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(LearnerService::server_with_limit(state.clone(), max_message_bytes))
            .serve_with_incoming_shutdown(
                tokio_stream::wrappers::TcpListenerStream::new(listener),
                async {
                    let _ = rx.await;
                },
            ),
    );
    Server { state, url, stop: Some(tx), task }
}

impl Server {
    pub async fn client(&self) -> LearnerClient<Channel> {
        LearnerClient::connect(self.url.clone())
            .await
            .unwrap()
            .max_decoding_message_size(dvnav_proto::MAX_MESSAGE_BYTES)
    }

    pub async fn shutdown(mut self) {
        self.state.begin_shutdown();
        self.stop.take().unwrap().send(()).unwrap();
        self.task.await.unwrap().unwrap();
    }
}

pub fn register(name: &str, version: u32) -> RegisterRequest {
    RegisterRequest { actor_name: name.into(), protocol_version: version, num_envs: 1 }
}

/// `n` transitions that end no episode.
pub fn batch(cfg: &Config, n: usize) -> TransitionBatch {
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, n);
    for _ in 0..n {
        b.push(&vec![1.0; d], [0.5, 0.0], 0.1, &vec![1.0; d], false, false, 1);
    }
    b
}

/// A `Transitions` request of `batches` that presents `session`.
pub fn bound<S>(session: &str, batches: S) -> tonic::Request<S> {
    let mut req = tonic::Request::new(batches);
    req.metadata_mut().insert(dvnav_link::wire::SESSION_METADATA, session.parse().unwrap());
    req
}

/// A `Transitions` request of these batches that presents `session`.
pub fn bound_iter(
    session: &str,
    batches: Vec<dvnav_proto::TransitionBatch>,
) -> tonic::Request<tokio_stream::Iter<std::vec::IntoIter<dvnav_proto::TransitionBatch>>> {
    bound(session, tokio_stream::iter(batches))
}
