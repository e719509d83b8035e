//! The TLS flags of the gRPC servers (`dvnav learner`, `dvnav serve`) and their clients
//! (`dvnav actor`); the files are read and checked by [`dvnav_tls`].

use clap::Args;
use dvnav_tls::{ClientTlsFiles, ServerTlsFiles};
use std::path::PathBuf;
use tonic::transport::{ClientTlsConfig, ServerTlsConfig};

/// TLS for a gRPC server (`dvnav certs` writes the files).
#[derive(Args, Debug, Clone, Default)]
pub struct ServerTlsArgs {
    /// Serve gRPC over TLS with this certificate (PEM, with --tls-key). Clients then connect
    /// with `--tls-ca` and the CA that signed it. `dvnav certs` writes both.
    #[arg(long, value_name = "FILE")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM).
    #[arg(long, value_name = "FILE")]
    pub tls_key: Option<PathBuf>,
    /// Mutual TLS: accept only clients that present a certificate signed by a CA in this file
    /// (PEM; with --tls-cert and --tls-key).
    #[arg(long, value_name = "FILE")]
    pub tls_client_ca: Option<PathBuf>,
}

impl ServerTlsArgs {
    /// The checked server config; `None` without TLS.
    pub fn load(&self) -> anyhow::Result<Option<ServerTlsConfig>> {
        ServerTlsFiles::from_flags(
            self.tls_cert.clone(),
            self.tls_key.clone(),
            self.tls_client_ca.clone(),
        )?
        .map(|f| f.load())
        .transpose()
    }
}

/// TLS for a gRPC client.
#[derive(Args, Debug, Clone, Default)]
pub struct ClientTlsArgs {
    /// Connect over TLS (an http:// URL is dialled as https://), trusting the CA
    /// certificate(s) in this file (PEM: `ca.pem` from `dvnav certs`). An https:// URL without
    /// it trusts the system's CA certificates.
    #[arg(long, value_name = "FILE")]
    pub tls_ca: Option<PathBuf>,
    /// The name to verify in the server's certificate when the URL's host is not in it, e.g.
    /// when connecting by IP address to a certificate issued for a name. Implies TLS.
    #[arg(long, value_name = "NAME")]
    pub tls_domain: Option<String>,
    /// Mutual TLS: this client's certificate (PEM, with --tls-key), for a server run with
    /// --tls-client-ca (`client.pem` from `dvnav certs`). Implies TLS.
    #[arg(long, value_name = "FILE")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM).
    #[arg(long, value_name = "FILE")]
    pub tls_key: Option<PathBuf>,
}

impl ClientTlsArgs {
    /// The checked client config; `None` without TLS.
    pub fn load(&self) -> anyhow::Result<Option<ClientTlsConfig>> {
        ClientTlsFiles {
            ca: self.tls_ca.clone(),
            domain: self.tls_domain.clone(),
            cert: self.tls_cert.clone(),
            key: self.tls_key.clone(),
        }
        .load()
    }
}
