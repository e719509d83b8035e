//! The tonic service: translates between wire types and [`LearnerState`] calls, and maps
//! [`LearnerError`] to status codes in one place. No training logic lives here.

use crate::state::{LearnerError, LearnerState, StatusSnapshot};
use dvnav_proto as pb;
use pb::learner_server::Learner;
use std::pin::Pin;
use std::sync::Arc;
use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

impl From<LearnerError> for Status {
    fn from(e: LearnerError) -> Self {
        let msg = e.to_string();
        match e {
            LearnerError::ProtocolMismatch { .. } => Status::failed_precondition(msg),
            LearnerError::Unauthenticated | LearnerError::ActorToken(_) => {
                Status::unauthenticated(msg)
            }
            LearnerError::UnknownActor(_) => Status::invalid_argument(msg),
            LearnerError::NoSession | LearnerError::UnknownSession => Status::unauthenticated(msg),
            LearnerError::WrongActor { .. } => Status::permission_denied(msg),
            LearnerError::SequenceGap { .. } => Status::failed_precondition(msg),
            LearnerError::Malformed(_) => Status::invalid_argument(msg),
            LearnerError::InvalidRequest(_) => Status::invalid_argument(msg),
            LearnerError::TooManyActors(_) | LearnerError::VariablesStreamOpen(_) => {
                Status::resource_exhausted(msg)
            }
            LearnerError::ShuttingDown => Status::unavailable(msg),
        }
    }
}

/// The gRPC face of a learner.
#[derive(Clone)]
pub struct LearnerService {
    state: Arc<LearnerState>,
}

impl LearnerService {
    /// Serves `state`; from here on the state reports itself ready to take actors
    /// ([`LearnerState::readiness`]).
    pub fn new(state: Arc<LearnerState>) -> Self {
        state.set_serving();
        Self { state }
    }

    /// The tonic server for `state`, with message-size limits set for weights and batches
    /// ([`dvnav_proto::MAX_MESSAGE_BYTES`]) instead of gRPC's 4 MiB default.
    pub fn server(state: Arc<LearnerState>) -> pb::learner_server::LearnerServer<Self> {
        Self::server_with_limit(state, dvnav_proto::MAX_MESSAGE_BYTES)
    }

    /// [`LearnerService::server`] with another message-size limit (tests use a small one to
    /// send an oversized message without allocating 256 MiB).
    pub fn server_with_limit(
        state: Arc<LearnerState>,
        max_message_bytes: usize,
    ) -> pb::learner_server::LearnerServer<Self> {
        pb::learner_server::LearnerServer::new(Self::new(state))
            .max_decoding_message_size(max_message_bytes)
            .max_encoding_message_size(max_message_bytes)
    }

    fn authorize<T>(&self, req: &Request<T>) -> Result<(), Status> {
        let presented = dvnav_tls::auth::bearer_token(req.metadata());
        self.state.authorize(presented).map_err(Status::from)
    }
}

/// The HTTP/2 server for the learner service, over TLS with `tls` (`--tls-cert`, see
/// [`dvnav_tls`]). Flow-control windows are sized for whole transition batches and weight
/// messages (with the 64 KiB defaults every 64 KiB of a message waits for a window update);
/// keepalive pings notice an actor whose machine vanished.
pub fn transport_server(
    tls: Option<tonic::transport::ServerTlsConfig>,
) -> anyhow::Result<tonic::transport::Server> {
    let server = tonic::transport::Server::builder()
        .initial_stream_window_size(Some(4 << 20))
        .initial_connection_window_size(Some(16 << 20))
        .http2_keepalive_interval(Some(std::time::Duration::from_secs(5)))
        .http2_keepalive_timeout(Some(std::time::Duration::from_secs(10)));
    match tls {
        Some(tls) => server
            .tls_config(tls)
            .map_err(|e| anyhow::anyhow!("cannot set up TLS for the learner service: {e}")),
        None => Ok(server),
    }
}

/// Wire form of a status snapshot.
pub fn status_to_proto(s: &StatusSnapshot) -> pb::StatusReply {
    pb::StatusReply {
        run_id: s.run_id.clone(),
        transitions_received: s.transitions_received,
        transitions_rejected: s.transitions_rejected,
        episodes: s.episodes,
        updates: s.updates,
        weight_version: s.weight_version,
        replay_size: s.replay_size,
        stage: s.stage,
        success_rate: s.success_rate as f32,
        critic_loss: s.critic_loss as f32,
        actor_loss: s.actor_loss as f32,
        alpha: s.alpha as f32,
        done: s.done,
        step_budget: s.step_budget,
        env_steps_per_s: s.live.env_steps_per_s,
        updates_per_s: s.live.updates_per_s,
        connected_actors: s.actors.iter().filter(|a| a.connected).count() as u32,
        policy_lag_mean: if s.live.recent_policy_lag.count > 0 {
            s.live.recent_policy_lag.mean()
        } else {
            0.0
        },
        policy_lag_max: s.live.recent_policy_lag.max,
        actors: s
            .actors
            .iter()
            .map(|a| pb::ActorCounters {
                actor_id: a.actor_id,
                actor_name: a.name.clone(),
                transitions_received: a.transitions_received,
                transitions_rejected: a.transitions_rejected,
                episodes: a.episodes,
                connected: a.connected,
                batches: a.batches,
            })
            .collect(),
    }
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

#[tonic::async_trait]
impl Learner for LearnerService {
    async fn register(
        &self,
        req: Request<pb::RegisterRequest>,
    ) -> Result<Response<pb::RegisterReply>, Status> {
        self.authorize(&req)?;
        let presented = dvnav_tls::auth::bearer_token(req.metadata()).map(str::to_string);
        let r = req.into_inner();
        let reg = self.state.register_presenting(
            &r.actor_name,
            r.protocol_version,
            presented.as_deref(),
        )?;
        let cfg = self.state.config();
        Ok(Response::new(pb::RegisterReply {
            actor_id: reg.actor_id,
            run_config_toml: self.state.config_toml().to_string(),
            obs_spec: Some(pb::ObservationSpec {
                scan_beams: cfg.env.lidar.beams as u32,
                obs_dim: cfg.obs_dim() as u32,
                action_dim: dvnav_sim::obs::ACTION_DIM as u32,
            }),
            actor_seed: reg.actor_seed,
            run_id: self.state.run_id().to_string(),
            next_sequence: reg.next_sequence,
            session: reg.session,
            batch_transitions: self.state.batch_transitions_advice(true),
        }))
    }

    type TransitionsStream = BoxStream<pb::BatchAck>;

    async fn transitions(
        &self,
        req: Request<Streaming<pb::TransitionBatch>>,
    ) -> Result<Response<Self::TransitionsStream>, Status> {
        self.authorize(&req)?;
        // The stream speaks for the actor whose session it presents, and for no other.
        let credential = req
            .metadata()
            .get(dvnav_link::wire::SESSION_METADATA)
            .map(|v| v.to_str().unwrap_or_default());
        let stream_actor = self.state.open_stream(credential)?;
        let mut inbound = req.into_inner();
        let state = self.state.clone();
        let (tx, rx) = mpsc::channel(16);
        tokio::spawn(async move {
            let shutdown = state.shutdown_signal();
            // Why the stream ended, and whether that was the actor's (or the learner's) plan.
            let (reason, expected) = loop {
                let next = tokio::select! {
                    m = inbound.message() => m,
                    () = shutdown.cancelled() => {
                        let _ = tx.send(Err(Status::unavailable("the learner is shutting down"))).await;
                        break ("learner shutdown".to_string(), true);
                    }
                };
                match next {
                    Ok(Some(batch)) => {
                        let sequence = batch.sequence;
                        let ingested = tokio::select! {
                            r = state.ingest(stream_actor, batch) => r,
                            // The actor vanished (killed, or its connection broke) while its
                            // batch waited for room in the replay buffer: it never learns the
                            // outcome, so the batch is dropped uncounted (`ingest` is cancel-safe
                            // until it inserts); a living actor resends it after reconnecting.
                            () = tx.closed() => break (
                                format!("the actor went away; its batch {sequence}, not yet inserted, was dropped"),
                                false,
                            ),
                        };
                        match ingested {
                            Ok(ack) => {
                                let ack = pb::BatchAck {
                                    sequence,
                                    accepted: ack.accepted,
                                    duplicate: ack.duplicate,
                                    batch_transitions: state.batch_transitions_advice(false),
                                };
                                if tx.send(Ok(ack)).await.is_err() {
                                    break ("the actor went away".to_string(), false);
                                }
                            }
                            Err(e) => {
                                // Counted by reason in `ingest`; the actor gets the status.
                                let reason = e.to_string();
                                let _ = tx.send(Err(e.into())).await;
                                break (reason, false);
                            }
                        }
                    }
                    Ok(None) => break ("stream closed by the actor".to_string(), true),
                    // Undecodable bytes or a message over the size limit: counted, and the
                    // actor is told why (tonic's status, e.g. OUT_OF_RANGE for the size) before
                    // the stream ends; the learner itself carries on.
                    Err(status) => {
                        let reason = format!("stream error: {}", status.message());
                        // Refused input (over the size limit) apart from a connection that
                        // broke (a killed actor, a cut link).
                        let kind = match status.code() {
                            tonic::Code::OutOfRange | tonic::Code::ResourceExhausted => {
                                "stream_oversized"
                            }
                            _ => "stream_broken",
                        };
                        state.count_rejection(Some(stream_actor), kind, &reason);
                        let _ = tx.send(Err(status)).await;
                        break (reason, false);
                    }
                }
            };
            if let Some(a) = state.set_connected(stream_actor, false) {
                let id = stream_actor;
                let (name, received, batches) = (&a.name, a.transitions_received, a.batches);
                if expected {
                    tracing::info!(actor = %name, actor_id = id, %reason, received, batches, "actor transition stream ended");
                } else {
                    // A killed actor process lands here as soon as its socket closes; one whose
                    // machine vanished once HTTP/2 keepalive gives up (see `transport_server`).
                    tracing::warn!(actor = %name, actor_id = id, %reason, received, batches, connected = a.connected, "actor transition stream ended abnormally");
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    type VariablesStream = BoxStream<pb::VariablesUpdate>;

    async fn variables(
        &self,
        req: Request<pb::VariablesRequest>,
    ) -> Result<Response<Self::VariablesStream>, Status> {
        self.authorize(&req)?;
        let actor_id = req.get_ref().actor_id;
        // One open stream per registered actor: what idle readers can pin stays bounded.
        self.state.open_variables_stream(actor_id)?;
        let mut rx = self.state.variables().subscribe();
        let state = self.state.clone();
        let shutdown = self.state.shutdown_signal();
        // Bounded: a slow actor holds at most one message in flight; `watch` coalesces the rest.
        let (tx, out) = mpsc::channel(1);
        tokio::spawn(async move {
            loop {
                let v = rx.borrow_and_update().clone();
                if tx.send(Ok(dvnav_link::wire::variables_to_proto(&v))).await.is_err() {
                    break;
                }
                tokio::select! {
                    changed = rx.changed() => if changed.is_err() { break },
                    () = shutdown.cancelled() => break,
                    // The reader went away: free the actor's stream now, not at the next version.
                    () = tx.closed() => break,
                }
            }
            state.close_variables_stream(actor_id);
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(out))))
    }

    async fn status(
        &self,
        req: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::StatusReply>, Status> {
        self.authorize(&req)?;
        Ok(Response::new(status_to_proto(&self.state.status())))
    }
}
