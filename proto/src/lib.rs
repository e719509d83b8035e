//! dvnav's protobuf definitions, compiled once here (protox + tonic-prost-build, no system
//! `protoc`): the learner gRPC service (`dvnav.v1.Learner`) that actors talk to, the dvnav
//! messages written into MCAP episode logs, and the DVST controller service
//! (`dvnav.controller.v1.Controller`, [`controller::v1`]) that robots call. Both sides of the
//! wire and the log writer use these types, so `proto/` is the one source of truth.
//!
//! [`FILE_DESCRIPTOR_SET`] is the encoded `FileDescriptorSet` of the `dvnav/v1/` files; MCAP
//! schemas embed it so any protobuf-aware reader (Foxglove, Python `mcap-protobuf-support`)
//! decodes our messages without our code.

/// Version of the actor ⇄ learner protocol; a learner refuses actors that speak another one.
/// 2: each observation travels once (`TransitionBatch.next_obs_index`).
/// 3: `Register` returns a session credential (`RegisterReply.session`) that every
/// `Transitions` stream presents; batches follow the acknowledged sequence without gaps, and
/// an episode's report travels with its last transition.
pub const PROTOCOL_VERSION: u32 = 3;

/// Largest gRPC message either side of the learner service accepts or sends. Weights of the
/// default policy are about 1 MB and a default batch about 0.3 MB, over gRPC's 4 MiB default
/// only for much larger networks or batches; set deliberately so they never fail at run time.
pub const MAX_MESSAGE_BYTES: usize = 256 * 1024 * 1024;

/// Encoded `google.protobuf.FileDescriptorSet` of `dvnav/v1/*.proto`.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/dvnav_descriptor.bin"));

/// Generated types of package `dvnav.v1`.
#[allow(missing_docs, clippy::all)]
pub mod v1 {
    tonic::include_proto!("dvnav.v1");
}

pub use v1::*;

/// The DVST controller service (`dvnav serve`), package `dvnav.controller.v1`: a robot's
/// scan, goal and velocity in, a velocity command out.
pub mod controller {
    /// Generated types of package `dvnav.controller.v1`.
    #[allow(missing_docs, clippy::all)]
    pub mod v1 {
        tonic::include_proto!("dvnav.controller.v1");
    }
}
