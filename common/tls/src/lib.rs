//! # dvnav-tls
//!
//! Optional TLS for the gRPC services (the learner's and `dvnav serve`'s) when they are reached
//! across machines: rustls with the ring provider, through tonic.
//!
//! - [`ServerTlsFiles`]: a server's certificate and key (`--tls-cert`, `--tls-key`) and, for
//!   mutual TLS, the CA its clients' certificates must be signed by (`--tls-client-ca`).
//!   [`ServerTlsFiles::load`] reads and checks them and returns tonic's [`ServerTlsConfig`].
//! - [`ClientTlsFiles`]: what a client trusts (`--tls-ca`), the name it expects in the server's
//!   certificate (`--tls-domain`) and, for mutual TLS, its own certificate and key.
//!   [`ClientTlsFiles::load`] returns tonic's [`ClientTlsConfig`].
//! - [`endpoint`]: a URL and an optional client config as a tonic [`Endpoint`]; with TLS an
//!   `http://` URL is dialled as `https://`, so a TLS setting can never be dropped silently.
//!
//! Every file is read and checked when it is loaded (at start-up), so a missing file, a file
//! that is not PEM, a certificate given without its key or a key that belongs to another
//! certificate fails there, naming the file, not at the first connection.
//!
//! ```no_run
//! use dvnav_tls::{ClientTlsFiles, ServerTlsFiles};
//! let server = ServerTlsFiles::from_flags(Some("server.pem".into()), Some("server.key".into()), None)?
//!     .expect("both given");
//! let _config = server.load()?; // tonic::transport::ServerTlsConfig
//! let client = ClientTlsFiles { ca: Some("ca.pem".into()), ..Default::default() };
//! let tls = client.load()?;
//! let _endpoint = dvnav_tls::endpoint("http://10.0.0.5:50051", tls.as_ref())?; // https
//! # anyhow::Ok(())
//! ```
#![warn(missing_docs)]

pub mod auth;

use rustls::pki_types::pem::{PemObject, SectionKind};
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint, Identity, ServerTlsConfig};

/// A TLS handshake that has not finished after this long is dropped: a peer that opens a
/// connection and says nothing must not hold a task for ever.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// A server's TLS files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerTlsFiles {
    /// The server's certificate (PEM), optionally followed by intermediate certificates.
    pub cert: PathBuf,
    /// The certificate's private key (PEM: PKCS#8, PKCS#1 or SEC1).
    pub key: PathBuf,
    /// Mutual TLS: clients must present a certificate signed by a CA in this file (PEM).
    pub client_ca: Option<PathBuf>,
}

impl ServerTlsFiles {
    /// From the flags `--tls-cert`, `--tls-key` and `--tls-client-ca`: `None` without TLS;
    /// the certificate and the key come together or not at all.
    pub fn from_flags(
        cert: Option<PathBuf>,
        key: Option<PathBuf>,
        client_ca: Option<PathBuf>,
    ) -> anyhow::Result<Option<Self>> {
        match (cert, key) {
            (Some(cert), Some(key)) => Ok(Some(Self { cert, key, client_ca })),
            (Some(_), None) => anyhow::bail!("--tls-cert needs --tls-key (its private key)"),
            (None, Some(_)) => anyhow::bail!("--tls-key needs --tls-cert (its certificate)"),
            (None, None) if client_ca.is_some() => anyhow::bail!(
                "--tls-client-ca needs --tls-cert and --tls-key (mutual TLS is TLS first)"
            ),
            (None, None) => Ok(None),
        }
    }

    /// Reads and checks the files: PEM, a certificate, a private key that belongs to it, and
    /// usable client CA certificates. Returns the config for tonic's server.
    pub fn load(&self) -> anyhow::Result<ServerTlsConfig> {
        let cert_pem = read(&self.cert, "TLS certificate")?;
        let key_pem = read(&self.key, "TLS private key")?;
        let certs = certificates(&cert_pem, &self.cert, "TLS certificate")?;
        let key = private_key(&key_pem, &self.key)?;
        // What tonic builds per server, built once here to see that it can be.
        rustls::ServerConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .expect("ring supports the default protocol versions")
            .with_no_client_auth()
            .with_single_cert(certs, key)
            .map_err(|e| {
                anyhow::anyhow!(
                    "TLS private key {} cannot serve the certificate {}: {e}",
                    self.key.display(),
                    self.cert.display()
                )
            })?;
        let mut config = ServerTlsConfig::new()
            .identity(Identity::from_pem(cert_pem, key_pem))
            .timeout(HANDSHAKE_TIMEOUT);
        if let Some(ca) = &self.client_ca {
            let pem = read(ca, "TLS client CA")?;
            roots(&pem, ca, "TLS client CA")?;
            config = config.client_ca_root(Certificate::from_pem(pem));
        }
        Ok(config)
    }
}

/// A client's TLS settings; TLS is on when any is set.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ClientTlsFiles {
    /// CA certificates to trust (PEM); without it, the system's.
    pub ca: Option<PathBuf>,
    /// The name to verify in the server's certificate when the URL's host differs (connecting
    /// by IP address to a certificate issued for a name, say).
    pub domain: Option<String>,
    /// Mutual TLS: this client's certificate (PEM)...
    pub cert: Option<PathBuf>,
    /// ...and its private key (PEM).
    pub key: Option<PathBuf>,
}

impl ClientTlsFiles {
    /// True when TLS is asked for.
    pub fn is_set(&self) -> bool {
        self.ca.is_some() || self.domain.is_some() || self.cert.is_some() || self.key.is_some()
    }

    /// Reads and checks the files: `None` when no TLS setting is given, else the config for
    /// tonic's client (with [`endpoint`]).
    pub fn load(&self) -> anyhow::Result<Option<ClientTlsConfig>> {
        if !self.is_set() {
            return Ok(None);
        }
        let mut config = ClientTlsConfig::new().timeout(HANDSHAKE_TIMEOUT);
        match &self.ca {
            Some(ca) => {
                let pem = read(ca, "TLS CA")?;
                roots(&pem, ca, "TLS CA")?;
                config = config.ca_certificate(Certificate::from_pem(pem));
            }
            None => config = config.with_native_roots(),
        }
        if let Some(d) = &self.domain {
            check_server_name(d).map_err(|e| anyhow::anyhow!("--tls-domain {e}"))?;
            config = config.domain_name(d.clone());
        }
        match (&self.cert, &self.key) {
            (Some(cert), Some(key)) => {
                let cert_pem = read(cert, "TLS client certificate")?;
                let key_pem = read(key, "TLS client private key")?;
                let certs = certificates(&cert_pem, cert, "TLS client certificate")?;
                let der = private_key(&key_pem, key)?;
                rustls::ClientConfig::builder_with_provider(provider())
                    .with_safe_default_protocol_versions()
                    .expect("ring supports the default protocol versions")
                    .with_root_certificates(rustls::RootCertStore::empty())
                    .with_client_auth_cert(certs, der)
                    .map_err(|e| {
                        anyhow::anyhow!(
                            "TLS client private key {} cannot serve the certificate {}: {e}",
                            key.display(),
                            cert.display()
                        )
                    })?;
                config = config.identity(Identity::from_pem(cert_pem, key_pem));
            }
            (Some(_), None) => anyhow::bail!("--tls-cert needs --tls-key (its private key)"),
            (None, Some(_)) => anyhow::bail!("--tls-key needs --tls-cert (its certificate)"),
            (None, None) => {}
        }
        Ok(Some(config))
    }
}

/// The URL a client dials: `https://` whenever it uses TLS (`tls`), else `url` as given.
pub fn dial_url(url: &str, tls: bool) -> String {
    match url.strip_prefix("http://") {
        Some(rest) if tls => format!("https://{rest}"),
        _ if tls && !url.contains("://") => format!("https://{url}"),
        _ => url.to_string(),
    }
}

/// Whether dialling `url` with `tls` speaks TLS: with a client config, or for an `https://`
/// URL (see [`endpoint`]).
pub fn dials_tls(url: &str, tls: Option<&ClientTlsConfig>) -> bool {
    tls.is_some() || url.starts_with("https://")
}

/// An error with its sources: tonic's transport errors say only "transport error" at the top;
/// a refused TLS handshake (unknown CA, wrong name) is a few levels down.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(inner) = source {
        // Some errors' messages already hold their source's.
        let text = inner.to_string();
        if !s.contains(&text) {
            s.push_str(": ");
            s.push_str(&text);
        }
        source = inner.source();
    }
    s
}

/// The endpoint for `url`: TLS with `tls` when given (an `http://` URL is dialled as
/// `https://`); an `https://` URL without it trusts the system's CA certificates; plain
/// HTTP/2 otherwise.
pub fn endpoint(url: &str, tls: Option<&ClientTlsConfig>) -> anyhow::Result<Endpoint> {
    let https = url.starts_with("https://");
    let dial = dial_url(url, tls.is_some());
    let ep = Endpoint::from_shared(dial.clone())
        .map_err(|e| anyhow::anyhow!("bad server address {url:?}: {e}"))?;
    let config = match tls {
        Some(c) => c.clone(),
        None if https => ClientTlsConfig::new().with_native_roots().timeout(HANDSHAKE_TIMEOUT),
        None => return Ok(ep),
    };
    ep.tls_config(config).map_err(|e| {
        let hint = if tls.is_none() {
            " (no --tls-ca given: the system's CA certificates are used)"
        } else {
            ""
        };
        anyhow::anyhow!("cannot set up TLS for {dial}: {e}{hint}")
    })
}

/// Checks that `name` can stand in a certificate and be verified: a DNS name or an IP address.
pub fn check_server_name(name: &str) -> anyhow::Result<()> {
    ServerName::try_from(name.to_string())
        .map(drop)
        .map_err(|e| anyhow::anyhow!("{name:?} is not a host name or IP address: {e}"))
}

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

fn read(path: &Path, what: &str) -> anyhow::Result<Vec<u8>> {
    std::fs::read(path)
        .map_err(|e| anyhow::anyhow!("{what} {}: cannot read it: {e}", path.display()))
}

/// The PEM sections of a file, each with its kind.
fn sections(pem: &[u8], path: &Path, what: &str) -> anyhow::Result<Vec<(SectionKind, Vec<u8>)>> {
    let all = <(SectionKind, Vec<u8>)>::pem_slice_iter(pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("{what} {}: not valid PEM: {e}", path.display()))?;
    anyhow::ensure!(
        !all.is_empty(),
        "{what} {}: not a PEM file (no -----BEGIN ...----- block in it)",
        path.display()
    );
    Ok(all)
}

fn kinds(sections: &[(SectionKind, Vec<u8>)]) -> String {
    let names: Vec<String> = sections.iter().map(|(k, _)| format!("{k:?}")).collect();
    names.join(", ")
}

fn certificates(
    pem: &[u8],
    path: &Path,
    what: &str,
) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let all = sections(pem, path, what)?;
    let certs: Vec<CertificateDer<'static>> = all
        .iter()
        .filter(|(k, _)| *k == SectionKind::Certificate)
        .map(|(_, der)| CertificateDer::from(der.clone()))
        .collect();
    anyhow::ensure!(
        !certs.is_empty(),
        "{what} {}: no certificate in it (no -----BEGIN CERTIFICATE----- block; it holds {}{})",
        path.display(),
        kinds(&all),
        if all.iter().any(|(k, _)| is_key(*k)) { ": a key given for the certificate?" } else { "" }
    );
    Ok(certs)
}

fn is_key(kind: SectionKind) -> bool {
    matches!(kind, SectionKind::PrivateKey | SectionKind::RsaPrivateKey | SectionKind::EcPrivateKey)
}

fn private_key(pem: &[u8], path: &Path) -> anyhow::Result<PrivateKeyDer<'static>> {
    let what = "TLS private key";
    let all = sections(pem, path, what)?;
    let key = all.iter().find(|(k, _)| is_key(*k)).map(|(k, der)| match k {
        SectionKind::RsaPrivateKey => PrivateKeyDer::Pkcs1(der.clone().into()),
        SectionKind::EcPrivateKey => PrivateKeyDer::Sec1(der.clone().into()),
        _ => PrivateKeyDer::Pkcs8(der.clone().into()),
    });
    key.ok_or_else(|| {
        anyhow::anyhow!(
            "{what} {}: no private key in it (no -----BEGIN PRIVATE KEY----- block; it holds \
             {}{})",
            path.display(),
            kinds(&all),
            if all.iter().any(|(k, _)| *k == SectionKind::Certificate) {
                ": a certificate given for the key?"
            } else {
                ""
            }
        )
    })
}

/// Checks that every certificate of a CA file can be a trust anchor.
fn roots(pem: &[u8], path: &Path, what: &str) -> anyhow::Result<()> {
    let mut store = rustls::RootCertStore::empty();
    for (i, cert) in certificates(pem, path, what)?.into_iter().enumerate() {
        store.add(cert).map_err(|e| {
            anyhow::anyhow!("{what} {}: certificate {} is not usable: {e}", path.display(), i + 1)
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Files {
        dir: tempfile::TempDir,
    }

    impl Files {
        /// A self-signed certificate for `localhost` and its key, and a second pair.
        fn new() -> Files {
            let dir = tempfile::tempdir().unwrap();
            for name in ["a", "b"] {
                let c = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
                std::fs::write(dir.path().join(format!("{name}.pem")), c.cert.pem()).unwrap();
                std::fs::write(
                    dir.path().join(format!("{name}.key")),
                    c.signing_key.serialize_pem(),
                )
                .unwrap();
            }
            std::fs::write(dir.path().join("junk.txt"), "not a certificate\n").unwrap();
            std::fs::write(
                dir.path().join("broken.pem"),
                "-----BEGIN CERTIFICATE-----\nMIIB!!!\n-----END CERTIFICATE-----\n",
            )
            .unwrap();
            Files { dir }
        }

        fn path(&self, name: &str) -> PathBuf {
            self.dir.path().join(name)
        }

        fn server(&self, cert: &str, key: &str) -> ServerTlsFiles {
            ServerTlsFiles { cert: self.path(cert), key: self.path(key), client_ca: None }
        }
    }

    fn err(r: anyhow::Result<impl std::fmt::Debug>) -> String {
        format!("{:#}", r.expect_err("an error"))
    }

    #[test]
    fn a_matching_certificate_and_key_load() {
        let f = Files::new();
        f.server("a.pem", "a.key").load().unwrap();
        let mtls =
            ServerTlsFiles { client_ca: Some(f.path("b.pem")), ..f.server("a.pem", "a.key") };
        mtls.load().unwrap();
        let client = ClientTlsFiles {
            ca: Some(f.path("a.pem")),
            domain: Some("localhost".into()),
            cert: Some(f.path("b.pem")),
            key: Some(f.path("b.key")),
        };
        assert!(client.load().unwrap().is_some());
        assert!(ClientTlsFiles::default().load().unwrap().is_none(), "no TLS without settings");
    }

    #[test]
    fn certificate_and_key_come_together() {
        let p = |s: &str| Some(PathBuf::from(s));
        assert_eq!(ServerTlsFiles::from_flags(None, None, None).unwrap(), None);
        let both = ServerTlsFiles::from_flags(p("c.pem"), p("k.pem"), None).unwrap().unwrap();
        assert_eq!((both.cert, both.key), ("c.pem".into(), "k.pem".into()));
        let e = err(ServerTlsFiles::from_flags(p("c.pem"), None, None));
        assert!(e.contains("--tls-cert needs --tls-key"), "{e}");
        let e = err(ServerTlsFiles::from_flags(None, p("k.pem"), None));
        assert!(e.contains("--tls-key needs --tls-cert"), "{e}");
        let e = err(ServerTlsFiles::from_flags(None, None, p("ca.pem")));
        assert!(e.contains("--tls-client-ca needs --tls-cert and --tls-key"), "{e}");
        let client = ClientTlsFiles { cert: p("c.pem"), ..Default::default() };
        let e = err(client.load());
        assert!(e.contains("--tls-cert needs --tls-key"), "{e}");
    }

    #[test]
    fn a_missing_file_is_named() {
        let f = Files::new();
        let e = err(f.server("missing.pem", "a.key").load());
        assert!(e.starts_with("TLS certificate "), "{e}");
        assert!(e.contains("missing.pem: cannot read it: No such file"), "{e}");
        let e = err(f.server("a.pem", "missing.key").load());
        assert!(e.contains("TLS private key ") && e.contains("missing.key: cannot read"), "{e}");
        let client = ClientTlsFiles { ca: Some(f.path("nope.pem")), ..Default::default() };
        let e = err(client.load());
        assert!(e.starts_with("TLS CA ") && e.contains("nope.pem: cannot read it"), "{e}");
    }

    #[test]
    fn a_file_that_is_not_pem_is_named() {
        let f = Files::new();
        let e = err(f.server("junk.txt", "a.key").load());
        assert!(e.contains("junk.txt: not a PEM file"), "{e}");
        let e = err(f.server("a.pem", "junk.txt").load());
        assert!(e.contains("TLS private key") && e.contains("junk.txt: not a PEM file"), "{e}");
        let e = err(f.server("broken.pem", "a.key").load());
        assert!(e.contains("broken.pem: not valid PEM: base64 decode error"), "{e}");
        let ca = ClientTlsFiles { ca: Some(f.path("junk.txt")), ..Default::default() };
        assert!(err(ca.load()).contains("junk.txt: not a PEM file"));
    }

    #[test]
    fn a_certificate_without_its_key_is_refused() {
        let f = Files::new();
        // The certificate where the key belongs, and the other way round.
        let e = err(f.server("a.pem", "a.pem").load());
        assert!(e.contains("a.pem: no private key in it"), "{e}");
        assert!(e.contains("a certificate given for the key?"), "{e}");
        let e = err(f.server("a.key", "a.key").load());
        assert!(e.contains("a.key: no certificate in it") && e.contains("a key given"), "{e}");
        // Another certificate's key.
        let e = err(f.server("a.pem", "b.key").load());
        assert!(e.contains("b.key cannot serve the certificate"), "{e}");
        assert!(e.contains("a.pem"), "{e}");
        let client = ClientTlsFiles {
            ca: Some(f.path("a.pem")),
            cert: Some(f.path("a.pem")),
            key: Some(f.path("b.key")),
            ..Default::default()
        };
        assert!(err(client.load()).contains("b.key cannot serve the certificate"));
    }

    #[test]
    fn a_bad_domain_is_refused() {
        let f = Files::new();
        let client = ClientTlsFiles {
            ca: Some(f.path("a.pem")),
            domain: Some("not a name".into()),
            ..Default::default()
        };
        let e = err(client.load());
        assert!(e.contains("--tls-domain \"not a name\" is not a host name or IP"), "{e}");
        check_server_name("learner.example").unwrap();
        check_server_name("10.77.1.1").unwrap();
        check_server_name("::1").unwrap();
    }

    #[test]
    fn tls_is_always_dialled_as_https() {
        assert_eq!(dial_url("http://10.0.0.5:50051", true), "https://10.0.0.5:50051");
        assert_eq!(dial_url("10.0.0.5:50051", true), "https://10.0.0.5:50051");
        assert_eq!(dial_url("https://h:1", true), "https://h:1");
        assert_eq!(dial_url("http://h:1", false), "http://h:1");
        assert_eq!(dial_url("https://h:1", false), "https://h:1");
        let f = Files::new();
        let tls = ClientTlsFiles { ca: Some(f.path("a.pem")), ..Default::default() };
        let ep = endpoint("http://127.0.0.1:1", tls.load().unwrap().as_ref()).unwrap();
        assert_eq!(ep.uri().scheme_str(), Some("https"));
        assert_eq!(endpoint("http://127.0.0.1:1", None).unwrap().uri().scheme_str(), Some("http"));
    }
}
