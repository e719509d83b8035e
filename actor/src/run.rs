//! A whole actor process: connect and register, follow the variables stream, stream
//! transitions, run the environment loop on a blocking thread, and write a summary.

use crate::adder::BatchingAdder;
use crate::environment_loop::{EnvironmentLoop, LoopCounters};
use crate::episode_logger::EpisodeSelector;
use crate::variable_client::{VariableClient, variables_from_proto};
use dvnav_common::config::Config;
use dvnav_common::core::TransitionBatch;
use dvnav_common::episode_log::LogMetadata;
use dvnav_common::wire::batch_to_proto;
use dvnav_proto as pb;
use pb::learner_client::LearnerClient;
use serde::Serialize;
use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};

use dvnav_proto::MAX_MESSAGE_BYTES;

/// Options of an actor process.
#[derive(Clone, Debug)]
pub struct ActorOptions {
    /// Learner address, e.g. `http://127.0.0.1:50051`.
    pub learner_url: String,
    /// Actor name, unique within the run.
    pub name: String,
    /// Run directory; the actor writes under `actors/<name>/`.
    pub out_dir: PathBuf,
    /// Shared token, if the learner requires one.
    pub token: Option<String>,
    /// How long to keep trying to reach the learner at start-up.
    pub connect_timeout: Duration,
}

/// What an actor reports at the end (`actors/<name>/summary.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct ActorSummary {
    /// Actor name.
    pub name: String,
    /// Id the learner gave it.
    pub actor_id: u32,
    /// Transitions written into the stream to the learner.
    pub transitions_sent: u64,
    /// Transitions the learner acknowledged.
    pub transitions_acked: u64,
    /// Batches written into the stream.
    pub batches_sent: u64,
    /// Batches acknowledged.
    pub batches_acked: u64,
    /// The environment loop's counters.
    #[serde(flatten)]
    pub loop_counters: LoopCounters,
    /// Wall time (s).
    pub wall_time_s: f64,
    /// Environment steps per second of wall time.
    pub env_steps_per_s: f64,
    /// Why the actor stopped.
    pub stop_reason: String,
}

/// Adds `authorization: Bearer <token>` to every call when a token is set.
#[derive(Clone)]
pub struct AuthInterceptor {
    header: Option<MetadataValue<Ascii>>,
}

impl AuthInterceptor {
    /// An interceptor for `token`.
    pub fn new(token: Option<&str>) -> anyhow::Result<Self> {
        let header = token.map(|t| format!("Bearer {t}").parse()).transpose().map_err(|_| {
            anyhow::anyhow!("the access token contains characters not allowed in a header")
        })?;
        Ok(Self { header })
    }
}

impl tonic::service::Interceptor for AuthInterceptor {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(h) = &self.header {
            req.metadata_mut().insert("authorization", h.clone());
        }
        Ok(req)
    }
}

/// The learner client type actors use.
pub type Client = LearnerClient<InterceptedService<Channel, AuthInterceptor>>;

/// Connects to the learner, retrying with exponential backoff until `timeout`.
pub async fn connect(url: &str, token: Option<&str>, timeout: Duration) -> anyhow::Result<Client> {
    let endpoint = Endpoint::from_shared(url.to_string())
        .map_err(|e| anyhow::anyhow!("bad learner address {url:?}: {e}"))?
        .connect_timeout(Duration::from_secs(5))
        .http2_keep_alive_interval(Duration::from_secs(10))
        .keep_alive_while_idle(true);
    let deadline = Instant::now() + timeout;
    let mut backoff = Duration::from_millis(100);
    let channel = loop {
        match endpoint.connect().await {
            Ok(c) => break c,
            Err(e) if Instant::now() + backoff < deadline => {
                tracing::debug!(%url, error = %e, ?backoff, "learner not reachable yet; retrying");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(5));
            }
            Err(e) => anyhow::bail!("cannot reach the learner at {url} within {timeout:?}: {e}"),
        }
    };
    Ok(LearnerClient::with_interceptor(channel, AuthInterceptor::new(token)?)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES))
}

#[derive(Debug, Default)]
struct StreamCounters {
    batches_sent: u64,
    transitions_sent: u64,
    batches_acked: u64,
    transitions_acked: u64,
}

/// Writes batches from `batches` into a `Transitions` stream and counts the acknowledgements,
/// until `batches` closes and the learner has acknowledged everything (or the stream fails).
async fn stream_transitions(
    mut client: Client,
    actor_id: u32,
    mut batches: mpsc::Receiver<TransitionBatch>,
) -> (StreamCounters, Option<String>) {
    let (out_tx, out_rx) = mpsc::channel::<pb::TransitionBatch>(2);
    let sender = tokio::spawn(async move {
        let (mut seq, mut sent) = (0u64, 0u64);
        while let Some(b) = batches.recv().await {
            let n = b.len() as u64;
            if out_tx.send(batch_to_proto(&b, actor_id, seq)).await.is_err() {
                break;
            }
            seq += 1;
            sent += n;
        }
        (seq, sent)
    });
    let mut c = StreamCounters::default();
    let mut error = None;
    match client.transitions(ReceiverStream::new(out_rx)).await {
        Ok(resp) => {
            let mut acks = resp.into_inner();
            loop {
                match acks.message().await {
                    Ok(Some(ack)) => {
                        c.batches_acked += 1;
                        c.transitions_acked += ack.accepted as u64;
                    }
                    Ok(None) => break,
                    Err(s) => {
                        error = Some(format!("{:?}: {}", s.code(), s.message()));
                        break;
                    }
                }
            }
        }
        Err(s) => error = Some(format!("{:?}: {}", s.code(), s.message())),
    }
    let (seq, sent) = sender.await.unwrap_or((0, 0));
    c.batches_sent = seq;
    c.transitions_sent = sent;
    (c, error)
}

/// Runs an actor until the learner says stop or `shutdown` resolves.
pub async fn run(
    opts: ActorOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<ActorSummary> {
    let started = Instant::now();
    let mut client =
        connect(&opts.learner_url, opts.token.as_deref(), opts.connect_timeout).await?;
    let reply = client
        .register(pb::RegisterRequest {
            actor_name: opts.name.clone(),
            protocol_version: dvnav_proto::PROTOCOL_VERSION,
            num_envs: 0,
        })
        .await
        .map_err(|s| anyhow::anyhow!("registration refused ({:?}): {}", s.code(), s.message()))?
        .into_inner();
    let cfg = Config::from_toml_str(&reply.run_config_toml)
        .map_err(|e| anyhow::anyhow!("the learner sent an unusable config: {e}"))?;
    let actor_id = reply.actor_id;
    tracing::info!(name = %opts.name, actor_id, run = %reply.run_id, "registered with the learner");

    // Variables: follow the stream into a watch channel.
    let (mut variables, var_tx) = VariableClient::new();
    let mut var_stream = client
        .variables(pb::VariablesRequest { actor_id })
        .await
        .map_err(|s| anyhow::anyhow!("variables stream refused: {}", s.message()))?
        .into_inner();
    let var_task = tokio::spawn(async move {
        loop {
            match var_stream.message().await {
                Ok(Some(u)) => {
                    var_tx.send_replace(Some(Arc::new(variables_from_proto(u))));
                }
                Ok(None) => break None,
                Err(s) => break Some(format!("{:?}: {}", s.code(), s.message())),
            }
        }
    });
    variables.wait_first().await?;

    // Transitions: a bounded queue between the loop thread and the stream.
    let (batch_tx, batch_rx) = mpsc::channel(cfg.actor.send_queue_batches);
    let stream_task = tokio::spawn(stream_transitions(client.clone(), actor_id, batch_rx));

    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        tokio::spawn(async move {
            shutdown.await;
            stop.store(true, Ordering::Relaxed);
        });
    }

    let actor_dir = opts.out_dir.join("actors").join(&opts.name);
    std::fs::create_dir_all(&actor_dir)?;
    let logger = EpisodeSelector::create(
        &opts.out_dir.join("mcap").join(&opts.name),
        &opts.name,
        LogMetadata {
            run_id: reply.run_id.clone(),
            actor: opts.name.clone(),
            actor_id,
            config_hash: cfg.hash_hex(),
            seed: reply.actor_seed,
        },
        &cfg,
    )?;
    let name = opts.name.clone();
    let loop_stop = stop.clone();
    let loop_source = variables.clone();
    let loop_result =
        tokio::task::spawn_blocking(move || -> anyhow::Result<(LoopCounters, String)> {
            let adder = BatchingAdder::new(cfg.obs_dim(), cfg.actor.batch_transitions, batch_tx);
            let mut el = EnvironmentLoop::new(
                cfg,
                name,
                actor_id,
                reply.actor_seed,
                adder,
                loop_source,
                logger,
            )?;
            let mut last_log = Instant::now();
            el.run(|c| {
                if last_log.elapsed() > Duration::from_secs(30) {
                    tracing::info!(
                        env_steps = c.env_steps,
                        episodes = c.episodes,
                        "actor progress"
                    );
                    last_log = Instant::now();
                }
                !loop_stop.load(Ordering::Relaxed)
            })?;
            let reason =
                if loop_stop.load(Ordering::Relaxed) { "interrupted" } else { "learner said stop" };
            let (_adder, counters) = el.finish()?;
            Ok((counters, reason.to_string()))
        })
        .await?;
    // The adder (and its sender) is dropped: the stream drains and closes.
    let (stream, stream_error) = stream_task.await?;
    var_task.abort();
    let (loop_counters, mut stop_reason) = loop_result?;
    if let Some(e) = stream_error {
        tracing::warn!(error = %e, "transition stream ended with an error");
        stop_reason = format!("{stop_reason}; stream error: {e}");
    }
    let wall = started.elapsed().as_secs_f64();
    let summary = ActorSummary {
        name: opts.name.clone(),
        actor_id,
        transitions_sent: stream.transitions_sent,
        transitions_acked: stream.transitions_acked,
        batches_sent: stream.batches_sent,
        batches_acked: stream.batches_acked,
        env_steps_per_s: loop_counters.env_steps as f64 / wall,
        loop_counters,
        wall_time_s: wall,
        stop_reason,
    };
    std::fs::write(actor_dir.join("summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    tracing::info!(
        name = %summary.name,
        sent = summary.transitions_sent,
        acked = summary.transitions_acked,
        "actor finished"
    );
    Ok(summary)
}
