//! A whole actor process: connect and register, run the environment loop on a blocking
//! thread, deliver its batches through the [`crate::learner_link`], write a summary.

use crate::adder::BatchingAdder;
use crate::credits::Credits;
use crate::environment_loop::{EnvironmentLoop, LoopCounters};
use crate::episode_logger::EpisodeSelector;
pub use crate::learner_link::connect;
use crate::learner_link::{LinkCounters, LinkOptions, register, run_link};
use crate::variable_client::VariableClient;
use dvnav_eval::episode_log::LogMetadata;
use serde::Serialize;
use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

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
    /// TLS for the learner connection (`--tls-ca`; see [`dvnav_tls`]): with it an
    /// `http://` URL is dialled as `https://`.
    pub tls: Option<tonic::transport::ClientTlsConfig>,
    /// How long to keep trying to reach the learner at start-up.
    pub connect_timeout: Duration,
}

/// What an actor reports at the end (`actors/<name>/summary.json`); `dvnav train` reads it
/// back as this type.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
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
    /// Delivery details: duplicates, resends, reconnects, undelivered.
    pub link: LinkCounters,
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

/// Runs an actor until the learner says stop or `shutdown` resolves. The learner going away
/// does not end it: the link reconnects and resends what was not acknowledged.
pub async fn run(
    opts: ActorOptions,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<ActorSummary> {
    let started = Instant::now();
    let mut client =
        connect(&opts.learner_url, opts.tls.as_ref(), opts.token.as_deref(), opts.connect_timeout)
            .await?;
    let tls = dvnav_tls::dials_tls(&opts.learner_url, opts.tls.as_ref());
    let reg = register(&mut client, &opts.name, tls).await?;
    let cfg = reg.config.clone();
    let actor_id = reg.actor_id;
    tracing::info!(name = %opts.name, actor_id, run = %reg.run_id, "registered with the learner");

    let stop = CancellationToken::new();
    {
        let stop = stop.clone();
        tokio::spawn(async move {
            shutdown.await;
            stop.cancel();
        });
    }
    let (mut variables, var_tx) = VariableClient::new();
    // A bounded queue between the loop thread and the link: when the learner pushes back or is
    // away, the loop blocks here.
    let (batch_tx, batch_rx) = mpsc::channel(cfg.actor.send_queue_batches);
    // Batches awaiting an acknowledgement: the loop blocks before starting one more.
    let credits = Arc::new(Credits::new(cfg.actor.max_batches_in_flight));
    let link = run_link(
        LinkOptions {
            url: opts.learner_url.clone(),
            name: opts.name.clone(),
            token: opts.token.clone(),
            tls: opts.tls.clone(),
        },
        client,
        reg.clone(),
        batch_rx,
        credits.clone(),
        var_tx,
        stop.clone(),
    );

    let actor_dir = opts.out_dir.join("actors").join(&opts.name);
    std::fs::create_dir_all(&actor_dir)?;
    let logger = EpisodeSelector::create(
        &opts.out_dir.join("mcap").join(&opts.name),
        &opts.name,
        LogMetadata {
            run_id: reg.run_id.clone(),
            actor: opts.name.clone(),
            actor_id,
            config_hash: cfg.hash_hex(),
            seed: reg.actor_seed,
        },
        &cfg,
    )?;
    let name = opts.name.clone();
    let loop_stop = stop.clone();
    let environment = async move {
        variables.wait_first().await?;
        tokio::task::spawn_blocking(move || -> anyhow::Result<(LoopCounters, String)> {
            // A quarter heartbeat: the learner's watchdog sees a live actor move well inside the
            // 0.6 heartbeat that makes a stall (learner/src/watchdog.rs).
            let max_delay = Duration::from_secs_f64(cfg.learner.heartbeat_s / 4.0);
            let adder =
                BatchingAdder::new(cfg.obs_dim(), cfg.actor.batch_transitions, max_delay, batch_tx)
                    .with_credits(credits);
            let mut el = EnvironmentLoop::new(
                cfg,
                name,
                actor_id,
                reg.actor_seed,
                adder,
                variables,
                logger,
            )?;
            let mut last_log = Instant::now();
            let ran = el.run(|c| {
                if last_log.elapsed() > Duration::from_secs(30) {
                    tracing::info!(
                        env_steps = c.env_steps,
                        episodes = c.episodes,
                        "actor progress"
                    );
                    last_log = Instant::now();
                }
                !loop_stop.is_cancelled()
            });
            let interrupted = loop_stop.is_cancelled();
            let reason = match (&ran, interrupted) {
                (Ok(()), false) => "learner said stop".to_string(),
                (Ok(()), true) => "interrupted".to_string(),
                // The link gave up after a local stop: the adder's queue is closed.
                (Err(e), true) => format!("interrupted while the learner was away ({e})"),
                (Err(_), false) => String::new(),
            };
            if let (Err(e), false) = (&ran, interrupted) {
                anyhow::bail!("environment loop failed: {e:#}");
            }
            // The adder (and its sender) is dropped with the loop: the link drains and closes.
            let counters = match el.finish() {
                Ok((_adder, c)) => c,
                Err(e) if interrupted => {
                    tracing::warn!(error = %e, "final flush failed after a local stop");
                    LoopCounters::default()
                }
                Err(e) => return Err(e),
            };
            Ok((counters, reason))
        })
        .await?
    };
    let (link, loop_result) = tokio::join!(link, environment);
    let (loop_counters, stop_reason) = loop_result?;
    let wall = started.elapsed().as_secs_f64();
    let summary = ActorSummary {
        name: opts.name.clone(),
        actor_id,
        transitions_sent: link.transitions_sent,
        transitions_acked: link.transitions_acked,
        batches_sent: link.batches_sent,
        batches_acked: link.batches_acked,
        env_steps_per_s: loop_counters.env_steps as f64 / wall,
        link,
        loop_counters,
        wall_time_s: wall,
        stop_reason,
    };
    std::fs::write(actor_dir.join("summary.json"), serde_json::to_vec_pretty(&summary)?)?;
    tracing::info!(
        name = %summary.name,
        sent = summary.transitions_sent,
        acked = summary.transitions_acked,
        reconnects = summary.link.reconnects,
        "actor finished"
    );
    Ok(summary)
}
