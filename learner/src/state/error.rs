//! Why the learner refuses a request: [`LearnerError`], mapped to a gRPC status in one place
//! (the service's `From<LearnerError> for Status`).

use dvnav_link::wire::WireError;

/// Why the learner refused a request; mapped to a gRPC status in one place.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// The actor speaks another protocol version.
    #[error("protocol version {got} is not supported; this learner speaks {expected}")]
    ProtocolMismatch {
        /// What the actor sent.
        got: u32,
        /// What the learner speaks.
        expected: u32,
    },
    /// Missing or wrong shared token.
    #[error("missing or wrong access token")]
    Unauthenticated,
    /// With per-actor tokens: a name registered without its own token (or, for a name the
    /// file does not list, without the shared one).
    #[error("actor {0:?} must present its own token (--actor-tokens)")]
    ActorToken(String),
    /// A batch from an actor id that never registered.
    #[error("unknown actor id {0}; register first")]
    UnknownActor(u32),
    /// A second `Variables` stream of an actor whose first is still open.
    #[error(
        "actor id {0} already has a Variables stream open (one per actor; it closes when its \
         reader goes away)"
    )]
    VariablesStreamOpen(u32),
    /// A `Transitions` stream without a session credential.
    #[error("no session credential (metadata `x-dvnav-session`); register first")]
    NoSession,
    /// A session credential that is not (or no longer) current.
    #[error("unknown or replaced session credential; register again")]
    UnknownSession,
    /// A batch that claims another actor than the one its stream's session belongs to.
    #[error("this stream speaks for actor {stream}, not actor {claimed}")]
    WrongActor {
        /// The actor the stream's session belongs to.
        stream: u32,
        /// The actor the batch claims.
        claimed: u32,
    },
    /// A sequence number beyond the next one expected: a batch the learner never received
    /// would have to have been sent before it.
    #[error("batch sequence {got} skips ahead; the next expected is {expected}")]
    SequenceGap {
        /// What the batch carried.
        got: u64,
        /// The next sequence number of this actor.
        expected: u64,
    },
    /// A malformed batch.
    #[error("malformed transition batch: {0}")]
    Malformed(#[from] WireError),
    /// An invalid request field.
    #[error("invalid request: {0}")]
    InvalidRequest(String),
    /// A new actor name past `learner.max_actor_names`.
    #[error("{0} actor names are registered already (learner.max_actor_names)")]
    TooManyActors(usize),
    /// The learner is shutting down.
    #[error("the learner is shutting down")]
    ShuttingDown,
}

impl LearnerError {
    /// The `reason` label this refusal is counted under (`dvnav_requests_rejected_total`):
    /// the offending field for a malformed batch, else the kind of refusal.
    pub fn reason(&self) -> &'static str {
        match self {
            LearnerError::ProtocolMismatch { .. } => "protocol_version",
            LearnerError::Unauthenticated => "unauthenticated",
            LearnerError::ActorToken(_) => "actor_token",
            LearnerError::UnknownActor(_) => "unknown_actor",
            LearnerError::VariablesStreamOpen(_) => "variables_stream_open",
            LearnerError::NoSession => "session_missing",
            LearnerError::UnknownSession => "session_unknown",
            LearnerError::WrongActor { .. } => "actor_mismatch",
            LearnerError::SequenceGap { .. } => "sequence_gap",
            LearnerError::Malformed(e) => e.field,
            LearnerError::InvalidRequest(_) => "invalid_request",
            LearnerError::TooManyActors(_) => "too_many_actors",
            LearnerError::ShuttingDown => "shutting_down",
        }
    }
}
