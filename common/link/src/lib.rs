//! # dvnav-link
//!
//! What connects an actor to the learner, as plain types testable without a network:
//!
//! - [`core`]: Acme-style seams: [`core::TransitionBatch`] (each observation once, paired by
//!   position), [`core::Adder`] (`add_first`, then `add` per step) with [`core::BatchWriter`]
//!   that pairs for it, [`core::Variables`] and [`core::VariableSource`], so an environment loop
//!   runs against an in-process learner in tests and against the gRPC one in production.
//! - [`wire`]: every conversion between these domain types and the wire types of
//!   `dvnav-proto`, validating untrusted input in one place (each error names its field), and
//!   [`wire::EncodedBatch`], a batch encoded once and sent as such however often.
//! - [`consistency`]: whether a batch's episode reports can be true of its transitions and of
//!   the run (counts, lengths, returns, stages), so fabricated episodes never move the
//!   curriculum.
//!
//! It sits on [`dvnav_sim`] (observation layout, [`dvnav_sim::Outcome`]) and `dvnav-proto`
//! only; the transport's security (TLS, tokens) is `dvnav-tls`.
//!
//! ```
//! use dvnav_link::core::TransitionBatch;
//! use dvnav_link::wire::{batch_from_proto, batch_to_proto};
//! let mut batch = TransitionBatch::with_capacity(3, 1);
//! batch.push(&[1.0, 2.0, 3.0], [0.5, -0.5], 0.1, &[1.0, 2.0, 4.0], false, false, 7);
//! let msg = batch_to_proto(&batch, 1, 0);
//! assert_eq!(batch_from_proto(msg, 3).unwrap(), batch);
//! ```
#![warn(missing_docs)]

pub mod consistency;
pub mod core;
pub mod wire;
