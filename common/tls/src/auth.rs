//! The shared-token rule of every dvnav gRPC service (the learner's and `dvnav serve`'s): with
//! a token configured, each call must carry `authorization: Bearer TOKEN`. The token is never
//! logged; it is compared in constant time, so a caller cannot find it byte by byte from how
//! long a refusal takes.

/// The token a call presents in `authorization: Bearer …`, if any.
pub fn bearer_token(metadata: &tonic::metadata::MetadataMap) -> Option<&str> {
    metadata.get("authorization")?.to_str().ok()?.strip_prefix("Bearer ")
}

/// Whether `presented` passes when `expected` is configured (anything passes without one).
pub fn token_accepted(expected: Option<&str>, presented: Option<&str>) -> bool {
    match (expected, presented) {
        (None, _) => true,
        (Some(e), Some(p)) => constant_time_eq(e.as_bytes(), p.as_bytes()),
        (Some(_), None) => false,
    }
}

/// Equal in time independent of where the bytes differ (the length is not secret).
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    subtle::ConstantTimeEq::ct_eq(a, b).into()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_compare_whole() {
        assert!(constant_time_eq(b"secret", b"secret"));
        assert!(!constant_time_eq(b"secret", b"secreT"));
        assert!(!constant_time_eq(b"secret", b"secret2"));
        assert!(!constant_time_eq(b"", b"x"));
        assert!(token_accepted(None, None) && token_accepted(None, Some("x")));
        assert!(!token_accepted(Some("t"), None) && !token_accepted(Some("t"), Some("u")));
        assert!(token_accepted(Some("t"), Some("t")));
    }

    #[test]
    fn the_token_is_read_from_a_bearer_header_only() {
        let mut m = tonic::metadata::MetadataMap::new();
        assert_eq!(bearer_token(&m), None);
        m.insert("authorization", "Basic abc".parse().unwrap());
        assert_eq!(bearer_token(&m), None);
        m.insert("authorization", "Bearer abc".parse().unwrap());
        assert_eq!(bearer_token(&m), Some("abc"));
    }
}
