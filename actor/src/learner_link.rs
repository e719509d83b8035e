//! The actor's connection to the learner: connect and register, follow the variables stream,
//! and stream batches in with acknowledgements, reconnecting by itself when the learner goes
//! away.
//!
//! Delivery: every batch gets a sequence number that keeps increasing over the actor's life and
//! stays in the [`Outbox`] until the learner acknowledges it, as the bytes the adder encoded
//! ([`EncodedBatch`]). After a reconnect the unacknowledged batches are sent again, the same
//! bytes under their numbers; a learner that had already inserted one answers
//! `duplicate` and does not insert it twice. A learner that does not know the batches pending
//! (a restarted learner expects sequence 0 from a name it has not seen) gets them renumbered
//! from the sequence it expects ([`Outbox::rebase`]): it refuses a number that skips ahead.
//! Every stream presents the session credential of the latest registration
//! ([`dvnav_link::wire::SESSION_METADATA`]). While the learner is unreachable the actor stops
//! taking batches from its adder, so the environment loop waits instead of buffering without
//! limit, and retries with exponential backoff (100 ms doubling to 5 s) for as long as it takes.

use crate::credits::Credits;
use dvnav_config::Config;
use dvnav_link::core::Variables;
use dvnav_link::wire::EncodedBatch;
use dvnav_proto as pb;
use dvnav_proto::MAX_MESSAGE_BYTES;
use pb::learner_client::LearnerClient;
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tokio_util::sync::CancellationToken;
use tonic::codec::{BufferSettings, Codec, EncodeBuf, Encoder};
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, ClientTlsConfig, Endpoint};

/// Longest wait between two reconnection attempts.
pub const MAX_BACKOFF: Duration = Duration::from_secs(5);
/// After a local stop (Ctrl-C), or once the learner has said stop, the actor gives up delivering
/// what is left after this long without a learner.
pub const GIVE_UP_AFTER_STOP: Duration = Duration::from_secs(10);

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

/// The channel to the learner, with the token on every call.
type Service = InterceptedService<Channel, AuthInterceptor>;

/// The learner client actors use: the generated stub for registration, status and the
/// variables stream (reached through `Deref`, so `client.register(..)` reads as on the stub),
/// and the same channel for the transition stream, whose batches go out as they were encoded
/// once ([`Client::transitions_encoded`]).
#[derive(Clone)]
pub struct Client {
    stub: LearnerClient<Service>,
    grpc: tonic::client::Grpc<Service>,
}

impl std::ops::Deref for Client {
    type Target = LearnerClient<Service>;
    fn deref(&self) -> &Self::Target {
        &self.stub
    }
}

impl std::ops::DerefMut for Client {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.stub
    }
}

impl Client {
    /// A client over `channel` that presents `token`.
    fn new(channel: Channel, token: Option<&str>) -> anyhow::Result<Self> {
        let service = InterceptedService::new(channel, AuthInterceptor::new(token)?);
        let stub = LearnerClient::new(service.clone())
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        let grpc = tonic::client::Grpc::new(service)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        Ok(Self { stub, grpc })
    }

    /// The `Transitions` call, as the generated stub makes it, but with [`OutgoingCodec`]: each
    /// batch's pre-encoded bytes are written as they are. The learner decodes the messages with
    /// prost like any `TransitionBatch`. The stream presents `session`, the credential of the
    /// registration it speaks for.
    pub async fn transitions_encoded(
        &mut self,
        session: &str,
        batches: impl Stream<Item = Outgoing> + Send + 'static,
    ) -> Result<tonic::Response<tonic::codec::Streaming<pb::BatchAck>>, tonic::Status> {
        let credential: MetadataValue<Ascii> = session.parse().map_err(|_| {
            tonic::Status::invalid_argument("the session credential is not a header value")
        })?;
        self.grpc
            .ready()
            .await
            .map_err(|e| tonic::Status::unknown(format!("Service was not ready: {e}")))?;
        let path =
            tonic::codegen::http::uri::PathAndQuery::from_static("/dvnav.v1.Learner/Transitions");
        let mut req = tonic::Request::new(batches);
        req.metadata_mut().insert(dvnav_link::wire::SESSION_METADATA, credential);
        req.extensions_mut().insert(tonic::GrpcMethod::new("dvnav.v1.Learner", "Transitions"));
        self.grpc.streaming(req, path, OutgoingCodec).await
    }
}

/// One batch as it goes out on a stream: its bytes ([`EncodedBatch`]) under this connection's
/// actor id and the batch's sequence number.
#[derive(Clone, Debug)]
pub struct Outgoing {
    /// The id this connection registered under.
    pub actor_id: u32,
    /// The batch's sequence number.
    pub sequence: u64,
    /// The batch, encoded once.
    pub batch: EncodedBatch,
}

/// The client's codec of the `Transitions` stream: [`Outgoing`] batches out, written from their
/// pre-encoded bytes; acknowledgements in, decoded by prost.
#[derive(Clone, Copy, Debug, Default)]
pub struct OutgoingCodec;

impl Codec for OutgoingCodec {
    type Encode = Outgoing;
    type Decode = pb::BatchAck;
    type Encoder = OutgoingEncoder;
    type Decoder = tonic_prost::ProstDecoder<pb::BatchAck>;

    fn encoder(&mut self) -> Self::Encoder {
        OutgoingEncoder
    }

    fn decoder(&mut self) -> Self::Decoder {
        tonic_prost::ProstCodec::<pb::TransitionBatch, pb::BatchAck>::raw_decoder(
            BufferSettings::default(),
        )
    }
}

/// Writes an [`Outgoing`] batch: its two header fields, then its bytes.
#[derive(Clone, Copy, Debug, Default)]
pub struct OutgoingEncoder;

impl Encoder for OutgoingEncoder {
    type Item = Outgoing;
    type Error = tonic::Status;

    fn encode(&mut self, item: Outgoing, dst: &mut EncodeBuf<'_>) -> Result<(), Self::Error> {
        // The two header fields take at most 2 + 5 + 1 + 10 bytes.
        dst.reserve(item.batch.body_len() + 18);
        item.batch.write(item.actor_id, item.sequence, dst);
        Ok(())
    }
}

/// The learner's endpoint; over TLS with `tls`, or for an `https://` URL (see
/// [`dvnav_tls::endpoint`]).
fn endpoint(url: &str, tls: Option<&ClientTlsConfig>) -> anyhow::Result<Endpoint> {
    Ok(dvnav_tls::endpoint(url, tls)
        .map_err(|e| anyhow::anyhow!("learner address {url:?}: {e:#}"))?
        .connect_timeout(Duration::from_secs(5))
        // Windows sized for ~0.3 MB batches and ~1 MB weights, as on the learner's side.
        .initial_stream_window_size(4 << 20)
        .initial_connection_window_size(16 << 20)
        .http2_keep_alive_interval(Duration::from_secs(5))
        .keep_alive_timeout(Duration::from_secs(10))
        .keep_alive_while_idle(true))
}

fn make_client(channel: Channel, token: Option<&str>) -> anyhow::Result<Client> {
    Client::new(channel, token)
}

/// Connects to the learner (over TLS with `tls`), retrying with exponential backoff until
/// `timeout`.
pub async fn connect(
    url: &str,
    tls: Option<&ClientTlsConfig>,
    token: Option<&str>,
    timeout: Duration,
) -> anyhow::Result<Client> {
    let endpoint = endpoint(url, tls)?;
    let deadline = Instant::now() + timeout;
    let mut backoff = Duration::from_millis(100);
    loop {
        match endpoint.connect().await {
            Ok(c) => return make_client(c, token),
            Err(e) if Instant::now() + backoff < deadline => {
                let error = dvnav_tls::error_chain(&e);
                tracing::debug!(%url, %error, ?backoff, "learner not reachable yet; retrying");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(MAX_BACKOFF);
            }
            Err(e) => anyhow::bail!(
                "cannot reach the learner at {} within {timeout:?}: {}",
                endpoint.uri(),
                dvnav_tls::error_chain(&e)
            ),
        }
    }
}

/// What registration gives an actor.
#[derive(Clone, Debug)]
pub struct Registered {
    /// Id for this connection.
    pub actor_id: u32,
    /// The run's configuration, from the learner.
    pub config: Config,
    /// Seed for the environments.
    pub actor_seed: u64,
    /// Run id.
    pub run_id: String,
    /// Where a fresh actor process starts numbering its batches.
    pub next_sequence: u64,
    /// The credential its transition streams present.
    pub session: String,
    /// The learner's advice on batch size (0: none; see [`Credits`]).
    pub batch_transitions: u32,
}

/// Registers `name` with the learner; `tls`: whether the connection is TLS (for the hint a
/// plaintext client of a TLS learner needs).
pub async fn register(client: &mut Client, name: &str, tls: bool) -> anyhow::Result<Registered> {
    let reply = client
        .register(pb::RegisterRequest {
            actor_name: name.to_string(),
            protocol_version: dvnav_proto::PROTOCOL_VERSION,
            num_envs: 0,
        })
        .await
        .map_err(|s| {
            // A plaintext client of a server that speaks only TLS sees its connection fail
            // under the call, with one of these codes, never one from the learner's service.
            use tonic::Code::{Cancelled, Internal, Unknown};
            let hint = if !tls && matches!(s.code(), Cancelled | Internal | Unknown) {
                " (a learner that serves TLS drops plaintext connections: connect with --tls-ca)"
            } else {
                ""
            };
            anyhow::anyhow!("registration refused ({:?}): {}{hint}", s.code(), s.message())
        })?
        .into_inner();
    let config = Config::from_toml_str(&reply.run_config_toml)
        .map_err(|e| anyhow::anyhow!("the learner sent an unusable config: {e}"))?;
    Ok(Registered {
        actor_id: reply.actor_id,
        config,
        actor_seed: reply.actor_seed,
        run_id: reply.run_id,
        next_sequence: reply.next_sequence,
        session: reply.session,
        batch_transitions: reply.batch_transitions,
    })
}

/// Follows the variables stream into `tx` until it ends. The learner keeps one stream per
/// actor: after a reconnection it may still hold the old one open (until its keepalive
/// notices a vanished connection) and refuse the new one as RESOURCE_EXHAUSTED; that is
/// retried, with backoff, for as long as this task runs.
pub async fn follow_variables(
    mut client: Client,
    actor_id: u32,
    tx: watch::Sender<Option<Arc<Variables>>>,
) -> Option<String> {
    let mut backoff = Duration::from_millis(100);
    let mut stream = loop {
        match client.variables(pb::VariablesRequest { actor_id }).await {
            Ok(r) => break r.into_inner(),
            Err(s) if s.code() == tonic::Code::ResourceExhausted => {
                tracing::debug!(actor_id, error = %s.message(), "variables stream refused; retrying");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(2));
            }
            Err(s) => return Some(format!("{:?}: {}", s.code(), s.message())),
        }
    };
    loop {
        match stream.message().await {
            Ok(Some(u)) => {
                tx.send_replace(Some(Arc::new(dvnav_link::wire::variables_from_proto(u))));
            }
            Ok(None) => return None,
            Err(s) => return Some(format!("{:?}: {}", s.code(), s.message())),
        }
    }
}

/// Batches handed to the learner and not yet acknowledged, with their sequence numbers, kept
/// encoded.
#[derive(Debug)]
pub struct Outbox {
    pending: VecDeque<(u64, EncodedBatch)>,
    next_sequence: u64,
}

impl Outbox {
    /// An empty outbox numbering from `first_sequence`.
    pub fn new(first_sequence: u64) -> Self {
        Self { pending: VecDeque::new(), next_sequence: first_sequence }
    }

    /// Keeps `batch` until acknowledged; returns its sequence number.
    pub fn push(&mut self, batch: EncodedBatch) -> u64 {
        let seq = self.next_sequence;
        self.next_sequence += 1;
        self.pending.push_back((seq, batch));
        seq
    }

    /// Follows a (re)registration that expects `expected` next. Pending batches numbered from
    /// below `expected` up to it were inserted and their acknowledgements lost: they keep
    /// their numbers and are acknowledged as duplicates. Otherwise the learner does not know
    /// them (a restarted learner, which expects 0 from a new name, or one that expects more
    /// than was ever sent): they are renumbered from `expected`, as is what comes after.
    pub fn rebase(&mut self, expected: u64) {
        let first = self.pending.front().map_or(self.next_sequence, |(s, _)| *s);
        if (first..=self.next_sequence).contains(&expected) {
            return;
        }
        for (i, (s, _)) in self.pending.iter_mut().enumerate() {
            *s = expected + i as u64;
        }
        self.next_sequence = expected + self.pending.len() as u64;
    }

    /// Forgets every batch up to and including `sequence` (acknowledgements come in order);
    /// returns how many.
    pub fn ack(&mut self, sequence: u64) -> usize {
        let before = self.pending.len();
        while self.pending.front().is_some_and(|(s, _)| *s <= sequence) {
            self.pending.pop_front();
        }
        before - self.pending.len()
    }

    /// Batches waiting for an acknowledgement.
    pub fn len(&self) -> usize {
        self.pending.len()
    }

    /// True when everything was acknowledged.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Transitions waiting for an acknowledgement.
    pub fn pending_transitions(&self) -> u64 {
        self.pending.iter().map(|(_, b)| b.len() as u64).sum()
    }

    /// Every pending batch, for a resend under `actor_id`: the same bytes, shared.
    fn resend(&self, actor_id: u32) -> Vec<Outgoing> {
        self.pending
            .iter()
            .map(|(s, b)| Outgoing { actor_id, sequence: *s, batch: b.clone() })
            .collect()
    }
}

/// Delivery counters of a link.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct LinkCounters {
    /// Batches handed to the learner (each counted once, however often resent).
    pub batches_sent: u64,
    /// Transitions handed to the learner (each counted once).
    pub transitions_sent: u64,
    /// Batches acknowledged.
    pub batches_acked: u64,
    /// Transitions the learner inserted.
    pub transitions_acked: u64,
    /// Batches the learner recognised as already inserted.
    pub duplicate_acks: u64,
    /// Batches sent again after a reconnect.
    pub batches_resent: u64,
    /// Successful reconnections.
    pub reconnects: u64,
    /// Transitions still unacknowledged when the link gave up (0 after a clean end).
    pub transitions_undelivered: u64,
}

/// Shared between the send and receive halves of a stream, which run in one task: the locks
/// are never contended, they only make the future `Send`.
struct Session<'a> {
    outbox: &'a Mutex<Outbox>,
    credits: &'a Credits,
    counters: &'a Mutex<LinkCounters>,
    input_closed: &'a Mutex<bool>,
}

impl Session<'_> {
    /// One `Transitions` stream: resend what is pending, then forward new batches, reading
    /// acknowledgements concurrently. Ok when the adder closed and everything is acknowledged.
    async fn run(
        &self,
        client: &mut Client,
        reg: &Registered,
        batches: &mut mpsc::Receiver<EncodedBatch>,
    ) -> Result<(), String> {
        let actor_id = reg.actor_id;
        let (out_tx, out_rx) = mpsc::channel::<Outgoing>(2);
        let status = |s: tonic::Status| format!("{:?}: {}", s.code(), s.message());
        let mut acks = client
            .transitions_encoded(&reg.session, ReceiverStream::new(out_rx))
            .await
            .map_err(status)?
            .into_inner();
        let resend = self.outbox.lock().expect("link lock").resend(actor_id);
        self.counters.lock().expect("link lock").batches_resent += resend.len() as u64;
        let send = async move {
            for m in resend {
                out_tx.send(m).await.map_err(|_| "the request stream closed".to_string())?;
            }
            while !*self.input_closed.lock().expect("link lock") {
                let Some(b) = batches.recv().await else {
                    *self.input_closed.lock().expect("link lock") = true;
                    break;
                };
                let n = b.len() as u64;
                // In the outbox before the first send: if the stream breaks, it is resent.
                let sequence = self.outbox.lock().expect("link lock").push(b.clone());
                let msg = Outgoing { actor_id, sequence, batch: b };
                {
                    let mut c = self.counters.lock().expect("link lock");
                    c.batches_sent += 1;
                    c.transitions_sent += n;
                }
                out_tx.send(msg).await.map_err(|_| "the request stream closed".to_string())?;
            }
            Ok::<(), String>(())
        };
        let receive = async {
            while let Some(ack) = acks.message().await.map_err(status)? {
                let done = self.outbox.lock().expect("link lock").ack(ack.sequence);
                // The advice first: the batch this credit starts follows it.
                self.credits.advise(ack.batch_transitions);
                self.credits.give(done);
                let mut c = self.counters.lock().expect("link lock");
                c.batches_acked += 1;
                c.transitions_acked += ack.accepted as u64;
                c.duplicate_acks += ack.duplicate as u64;
            }
            Ok::<(), String>(())
        };
        tokio::pin!(send, receive);
        let mut sent_all = false;
        loop {
            tokio::select! {
                r = &mut send, if !sent_all => { r?; sent_all = true; }
                r = &mut receive => {
                    r?;
                    return if sent_all && self.outbox.lock().expect("link lock").is_empty() {
                        Ok(())
                    } else {
                        Err("the learner ended the stream early".into())
                    };
                }
            }
        }
    }
}

/// Connection settings.
#[derive(Clone, Debug)]
pub struct LinkOptions {
    /// Learner address.
    pub url: String,
    /// Actor name.
    pub name: String,
    /// Shared token.
    pub token: Option<String>,
    /// TLS for the connection (`--tls-ca`), kept for every reconnection.
    pub tls: Option<ClientTlsConfig>,
}

/// Runs the link until the adder closes `batches` and the learner has acknowledged everything,
/// reconnecting whenever the learner goes away. Gives up only after a stop (local, `stop`, or
/// from the learner) with no learner for [`GIVE_UP_AFTER_STOP`].
/// `credits` go back to the adder as the learner acknowledges batches, and are closed when the
/// link ends.
#[allow(clippy::too_many_arguments)]
pub async fn run_link(
    opts: LinkOptions,
    mut client: Client,
    first: Registered,
    mut batches: mpsc::Receiver<EncodedBatch>,
    credits: Arc<Credits>,
    variables: watch::Sender<Option<Arc<Variables>>>,
    stop: CancellationToken,
) -> LinkCounters {
    // Whatever ends the link, a loop waiting for a credit is released.
    struct CloseOnDrop<'a>(&'a Credits);
    impl Drop for CloseOnDrop<'_> {
        fn drop(&mut self) {
            self.0.close();
        }
    }
    let _close = CloseOnDrop(&credits);
    let outbox = Mutex::new(Outbox::new(first.next_sequence));
    let counters = Mutex::new(LinkCounters::default());
    let input_closed = Mutex::new(false);
    let session = Session {
        outbox: &outbox,
        credits: &credits,
        counters: &counters,
        input_closed: &input_closed,
    };
    let mut reg = first;
    loop {
        credits.advise(reg.batch_transitions);
        let follower =
            tokio::spawn(follow_variables(client.clone(), reg.actor_id, variables.clone()));
        let end = session.run(&mut client, &reg, &mut batches).await;
        follower.abort();
        let error = match end {
            Ok(()) => break,
            Err(e) => e,
        };
        tracing::warn!(
            name = %opts.name,
            error = %error,
            pending_batches = outbox.lock().expect("link lock").len(),
            "lost the learner; reconnecting"
        );
        let lost_at = Instant::now();
        let mut backoff = Duration::from_millis(100);
        let reconnected = loop {
            // A learner that already said stop is finishing its run and will not come back;
            // neither will one this actor was told locally to leave.
            let learner_said_stop = variables.borrow().as_ref().is_some_and(|v| v.stop);
            if (stop.is_cancelled() || learner_said_stop) && lost_at.elapsed() > GIVE_UP_AFTER_STOP
            {
                break None;
            }
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(MAX_BACKOFF);
            let Ok(ep) = endpoint(&opts.url, opts.tls.as_ref()) else { break None };
            let channel = match ep.connect().await {
                Ok(c) => c,
                Err(e) => {
                    tracing::debug!(error = %dvnav_tls::error_chain(&e), "learner not reachable; retrying");
                    continue;
                }
            };
            let Ok(mut c) = make_client(channel, opts.token.as_deref()) else { break None };
            let tls = dvnav_tls::dials_tls(&opts.url, opts.tls.as_ref());
            match register(&mut c, &opts.name, tls).await {
                Ok(reg) => break Some((c, reg)),
                Err(e) => tracing::debug!(error = %e, "re-registration failed; retrying"),
            }
        };
        let Some((c, again)) = reconnected else {
            tracing::error!(
                name = %opts.name,
                undelivered = outbox.lock().expect("link lock").pending_transitions(),
                "giving up on the learner after a stop"
            );
            break;
        };
        tracing::info!(name = %opts.name, actor_id = again.actor_id, "reconnected to the learner");
        outbox.lock().expect("link lock").rebase(again.next_sequence);
        client = c;
        reg = again;
        counters.lock().expect("link lock").reconnects += 1;
    }
    let mut c = counters.into_inner().expect("link lock");
    c.transitions_undelivered = outbox.lock().expect("link lock").pending_transitions();
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_link::core::TransitionBatch;
    use prost::Message;

    fn batch(n: usize) -> EncodedBatch {
        let mut b = TransitionBatch::with_capacity(1, n);
        for _ in 0..n {
            b.push(&[0.0], [0.0, 0.0], 0.0, &[0.0], false, false, 1);
        }
        EncodedBatch::new(&b)
    }

    /// The message the learner decodes from an outgoing batch.
    fn on_the_wire(o: &Outgoing) -> pb::TransitionBatch {
        let mut buf = Vec::new();
        o.batch.write(o.actor_id, o.sequence, &mut buf);
        pb::TransitionBatch::decode(buf.as_slice()).unwrap()
    }

    #[test]
    fn outbox_keeps_batches_until_acknowledged_in_order() {
        let mut o = Outbox::new(7);
        assert_eq!(o.push(batch(2)), 7);
        assert_eq!(o.push(batch(3)), 8);
        assert_eq!(o.push(batch(4)), 9);
        assert_eq!(o.pending_transitions(), 9);
        o.ack(8);
        assert_eq!(o.len(), 1);
        let resend: Vec<_> = o.resend(3).iter().map(on_the_wire).collect();
        assert_eq!((resend[0].sequence, resend[0].actor_id, resend[0].count), (9, 3, 4));
        o.ack(9);
        assert!(o.is_empty());
        assert_eq!(o.push(batch(1)), 10, "numbering continues");
    }

    #[test]
    fn rebase_keeps_numbers_the_learner_knows_and_renumbers_the_rest() {
        let mut o = Outbox::new(5);
        for n in 1..=3 {
            o.push(batch(n));
        }
        // Pending 5, 6, 7; the learner inserted 5 and 6 (their acks lost): unchanged.
        o.rebase(7);
        assert_eq!(o.resend(0).iter().map(|m| m.sequence).collect::<Vec<_>>(), [5, 6, 7]);
        o.rebase(8);
        assert_eq!(o.resend(0)[0].sequence, 5, "all inserted: resent as duplicates");
        // A restarted learner expects 0 from this name: renumbered, and so is what follows.
        o.rebase(0);
        assert_eq!(o.resend(0).iter().map(|m| m.sequence).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(o.push(batch(1)), 3);
        // One that expects more than was ever sent.
        o.rebase(100);
        assert_eq!(
            o.resend(0).iter().map(|m| m.sequence).collect::<Vec<_>>(),
            [100, 101, 102, 103]
        );
        let mut empty = Outbox::new(9);
        empty.rebase(0);
        assert_eq!(empty.push(batch(1)), 0);
    }
}
