//! `dvnav certs`: a private CA and the certificates signed by it that TLS between machines
//! needs: one for the server (the learner or `dvnav serve`) with the names and addresses its
//! clients dial, and one for clients when the server asks for them (mutual TLS).

use clap::Args;
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `dvnav certs` (its help is on `Command::Certs`).
#[derive(Args, Debug)]
pub struct CertsArgs {
    /// Directory to write the files into (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// A name or IP address clients use to reach the server; repeat for more. Each becomes a
    /// subject alternative name of `server.pem` (an IP address as an IP address SAN).
    #[arg(long = "host", value_name = "NAME", required = true)]
    pub hosts: Vec<String>,
    /// Days the certificates are valid, from now.
    #[arg(long, default_value_t = 825)]
    pub days: u32,
    /// Overwrite files that exist (by default they are left alone and nothing is written).
    #[arg(long)]
    pub force: bool,
}

/// A file `dvnav certs` writes.
#[derive(Debug)]
pub struct CertFile {
    /// File name in the output directory.
    pub name: &'static str,
    /// PEM text.
    pub pem: String,
    /// A private key: written readable by its owner only.
    pub secret: bool,
}

/// The file names, in the order they are written.
pub const FILES: [&str; 6] =
    ["ca.pem", "ca.key", "server.pem", "server.key", "client.pem", "client.key"];

/// A CA, a server certificate for `hosts` and a client certificate, valid for `days`.
pub fn generate(hosts: &[String], days: u32) -> anyhow::Result<Vec<CertFile>> {
    anyhow::ensure!(!hosts.is_empty(), "at least one --host is needed");
    anyhow::ensure!(days > 0, "--days must be at least 1");
    for h in hosts {
        dvnav_tls::check_server_name(h).map_err(|e| anyhow::anyhow!("--host {e}"))?;
    }
    let now = time::OffsetDateTime::now_utc();
    // An hour back, for clocks a little behind this one.
    let (not_before, not_after) =
        (now - time::Duration::hours(1), now + time::Duration::days(days.into()));
    let name = |cn: &str| {
        let mut dn = DistinguishedName::new();
        dn.push(DnType::OrganizationName, "dvnav");
        dn.push(DnType::CommonName, cn);
        dn
    };

    let ca_key = KeyPair::generate()?;
    let mut ca = CertificateParams::default();
    // A name of its own: a client that trusts another `dvnav certs` CA finds no issuer of this
    // name (and says "unknown issuer") instead of checking a signature against the wrong key.
    ca.distinguished_name = name(&format!("dvnav CA {}", fingerprint(ca_key.public_key_raw())));
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    (ca.not_before, ca.not_after) = (not_before, not_after);
    let ca_cert = ca.self_signed(&ca_key)?;
    let ca_key_pem = ca_key.serialize_pem();
    let issuer = Issuer::new(ca, ca_key);

    let leaf = |params: &mut CertificateParams, cn: &str, eku: ExtendedKeyUsagePurpose| {
        params.distinguished_name = name(cn);
        params.is_ca = IsCa::ExplicitNoCa;
        params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        params.extended_key_usages = vec![eku];
        params.use_authority_key_identifier_extension = true;
        (params.not_before, params.not_after) = (not_before, not_after);
        let key = KeyPair::generate()?;
        let cert = params.signed_by(&key, &issuer)?;
        anyhow::Ok((cert.pem(), key.serialize_pem()))
    };
    // `new` makes an IP address an IP address SAN and anything else a DNS name.
    let mut server = CertificateParams::new(hosts.to_vec())
        .map_err(|e| anyhow::anyhow!("--host: cannot put {hosts:?} in a certificate: {e}"))?;
    let (server_pem, server_key) =
        leaf(&mut server, &hosts[0], ExtendedKeyUsagePurpose::ServerAuth)?;
    let mut client = CertificateParams::default();
    let (client_pem, client_key) =
        leaf(&mut client, "dvnav client", ExtendedKeyUsagePurpose::ClientAuth)?;

    let file = |name, pem, secret| CertFile { name, pem, secret };
    Ok(vec![
        file(FILES[0], ca_cert.pem(), false),
        file(FILES[1], ca_key_pem, true),
        file(FILES[2], server_pem, false),
        file(FILES[3], server_key, true),
        file(FILES[4], client_pem, false),
        file(FILES[5], client_key, true),
    ])
}

/// 8 hex digits (FNV-1a) of a public key.
fn fingerprint(key: &[u8]) -> String {
    let h = key.iter().fold(0x811c_9dc5u32, |h, &b| (h ^ b as u32).wrapping_mul(0x0100_0193));
    format!("{h:08x}")
}

/// Writes `files` into `dir`; with files of these names there, nothing unless `force`.
pub fn write(dir: &Path, files: &[CertFile], force: bool) -> anyhow::Result<()> {
    let existing: Vec<&str> =
        files.iter().filter(|f| dir.join(f.name).exists()).map(|f| f.name).collect();
    anyhow::ensure!(
        force || existing.is_empty(),
        "{}: {} already there; nothing written (--force overwrites)",
        dir.display(),
        existing.join(", ")
    );
    std::fs::create_dir_all(dir)
        .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", dir.display()))?;
    for f in files {
        let path = dir.join(f.name);
        write_file(&path, f.pem.as_bytes(), f.secret)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8], secret: bool) -> std::io::Result<()> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
        let mode = if secret { 0o600 } else { 0o644 };
        options.mode(mode);
        let mut file = options.open(path)?;
        // A file that was there (--force) keeps its old mode through `open`.
        file.set_permissions(std::fs::Permissions::from_mode(mode))?;
        file.write_all(bytes)?;
        file.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = secret;
        options.open(path)?.write_all(bytes)
    }
}

pub fn run(args: CertsArgs) -> anyhow::Result<ExitCode> {
    let files = generate(&args.hosts, args.days)?;
    write(&args.out, &files, args.force)?;
    let d = args.out.display();
    let host = &args.hosts[0];
    println!(
        "dvnav certs: wrote {d}/: ca.pem, ca.key (the CA; keep ca.key private), server.pem, \
         server.key (for {}), client.pem, client.key; valid {} days",
        args.hosts.join(", "),
        args.days
    );
    println!("  server:  dvnav learner --tls-cert {d}/server.pem --tls-key {d}/server.key ...");
    println!("  clients: dvnav actor --learner https://{host}:50051 --tls-ca {d}/ca.pem ...");
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_tls::{ClientTlsFiles, ServerTlsFiles};

    #[test]
    fn writes_a_ca_and_certificates_that_load_with_private_keys() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = vec!["learner.example".to_string(), "10.77.1.1".to_string()];
        write(dir.path(), &generate(&hosts, 30).unwrap(), false).unwrap();
        for name in FILES {
            let text = std::fs::read_to_string(dir.path().join(name)).unwrap();
            let kind = if name.ends_with(".key") { "PRIVATE KEY" } else { "CERTIFICATE" };
            assert!(text.starts_with(&format!("-----BEGIN {kind}-----")), "{name}: {text}");
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                let mode = std::fs::metadata(dir.path().join(name)).unwrap().permissions().mode();
                let want = if name.ends_with(".key") { 0o600 } else { 0o644 };
                assert_eq!(mode & 0o777, want, "{name}");
            }
        }
        let p = |n: &str| dir.path().join(n);
        let server = ServerTlsFiles {
            cert: p("server.pem"),
            key: p("server.key"),
            client_ca: Some(p("ca.pem")),
        };
        server.load().unwrap();
        let client = ClientTlsFiles {
            ca: Some(p("ca.pem")),
            cert: Some(p("client.pem")),
            key: Some(p("client.key")),
            ..Default::default()
        };
        client.load().unwrap().unwrap();
        // Each key is its own certificate's.
        let mixed = ServerTlsFiles { key: p("client.key"), ..server };
        assert!(mixed.load().is_err());
    }

    #[test]
    fn refuses_to_overwrite_unless_forced() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = vec!["localhost".to_string()];
        std::fs::write(dir.path().join("server.key"), "mine").unwrap();
        let e = write(dir.path(), &generate(&hosts, 1).unwrap(), false).unwrap_err();
        assert!(e.to_string().contains("server.key already there; nothing written"), "{e}");
        assert!(!dir.path().join("ca.pem").exists(), "nothing written");
        assert_eq!(std::fs::read_to_string(dir.path().join("server.key")).unwrap(), "mine");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let perms = std::fs::Permissions::from_mode(0o644);
            std::fs::set_permissions(dir.path().join("server.key"), perms).unwrap();
        }
        write(dir.path(), &generate(&hosts, 1).unwrap(), true).unwrap();
        let key = dir.path().join("server.key");
        assert!(std::fs::read_to_string(&key).unwrap().starts_with("-----BEGIN PRIVATE KEY"));
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(std::fs::metadata(&key).unwrap().permissions().mode() & 0o777, 0o600);
        }
    }

    #[test]
    fn refuses_hosts_that_cannot_be_verified() {
        let e = generate(&["no spaces".to_string()], 1).unwrap_err();
        assert!(e.to_string().starts_with("--host \"no spaces\" is not a host name"), "{e}");
        assert!(generate(&[], 1).is_err());
        assert!(generate(&["::1".to_string()], 0).is_err(), "--days 0");
    }
}
