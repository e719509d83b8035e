//! Session credentials: what binds a `Transitions` stream to the one actor that registered.
//!
//! The shared token says a caller may talk to the learner at all; it does not say *which*
//! actor it is, and a batch's `actor_id` field is whatever the sender wrote. So each
//! registration gets a fresh random credential, and a stream is bound to the actor whose
//! credential it presents. A later registration of the same actor (a reconnect, a restarted
//! process under the same name) replaces the credential: whoever registered last speaks for
//! the name.

use rand::RngCore;
use std::collections::HashMap;

/// Bytes of randomness in a credential (128 bits, hex-encoded).
const CREDENTIAL_BYTES: usize = 16;

/// The current credential of every registered actor.
#[derive(Debug, Default)]
pub struct Sessions {
    by_credential: HashMap<String, u32>,
    by_actor: HashMap<u32, String>,
}

impl Sessions {
    /// A fresh credential for `actor_id`, replacing its previous one.
    pub fn issue(&mut self, actor_id: u32) -> String {
        let mut bytes = [0u8; CREDENTIAL_BYTES];
        // The thread generator is a CSPRNG seeded from the OS.
        rand::rng().fill_bytes(&mut bytes);
        let credential: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        if let Some(old) = self.by_actor.insert(actor_id, credential.clone()) {
            self.by_credential.remove(&old);
        }
        self.by_credential.insert(credential.clone(), actor_id);
        credential
    }

    /// The actor `credential` is current for.
    pub fn actor(&self, credential: &str) -> Option<u32> {
        self.by_credential.get(credential).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_credential_names_its_actor_until_replaced() {
        let mut s = Sessions::default();
        let a = s.issue(0);
        let b = s.issue(1);
        assert_ne!(a, b);
        assert_eq!(a.len(), 2 * CREDENTIAL_BYTES);
        assert_eq!((s.actor(&a), s.actor(&b)), (Some(0), Some(1)));
        let a2 = s.issue(0);
        assert_eq!((s.actor(&a), s.actor(&a2)), (None, Some(0)), "the old one is void");
        assert_eq!(s.actor(""), None);
        assert_eq!(s.actor("not-a-credential"), None);
    }
}
