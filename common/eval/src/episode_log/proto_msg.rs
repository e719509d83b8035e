//! [`foxglove::Encode`] for dvnav's own prost messages.
//!
//! The orphan rule forbids implementing a foreign trait (`Encode`) on a foreign type
//! (`dvnav_proto::StepRecord`), so messages travel in the [`Dvnav`] wrapper. The schema is the
//! message's full protobuf name plus the encoded `FileDescriptorSet` that `proto/` compiled, so
//! the bytes in the file are exactly the wire format and any protobuf-aware reader decodes them
//! without dvnav's code. We do not `#[derive(Encode)]`: its schema is generated from Rust field
//! order and is not stable across versions.

use foxglove::bytes::BufMut;
use foxglove::{Encode, Schema};

/// A prost message of package `dvnav.v1` whose descriptor is in
/// [`dvnav_proto::FILE_DESCRIPTOR_SET`].
pub(crate) trait DvnavMessage: prost::Message {
    /// Full protobuf name, e.g. `dvnav.v1.StepRecord`; the MCAP schema name.
    const FULL_NAME: &'static str;
}

impl DvnavMessage for dvnav_proto::StepRecord {
    const FULL_NAME: &'static str = "dvnav.v1.StepRecord";
}

impl DvnavMessage for dvnav_proto::EpisodeSummary {
    const FULL_NAME: &'static str = "dvnav.v1.EpisodeSummary";
}

/// A dvnav message on its way into an MCAP channel.
#[derive(Debug)]
pub(crate) struct Dvnav<T>(pub T);

impl<T: DvnavMessage> Encode for Dvnav<T> {
    type Error = prost::EncodeError;

    fn get_schema() -> Option<Schema> {
        Some(Schema::new(T::FULL_NAME, "protobuf", dvnav_proto::FILE_DESCRIPTOR_SET))
    }

    fn get_message_encoding() -> String {
        "protobuf".to_string()
    }

    fn encode(&self, buf: &mut impl BufMut) -> Result<(), Self::Error> {
        self.0.encode(buf)
    }

    fn encoded_len(&self) -> Option<usize> {
        Some(self.0.encoded_len())
    }
}
