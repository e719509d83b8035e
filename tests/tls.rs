//! TLS between the learner and its actors, with the certificates `dvnav certs` writes: a real
//! `dvnav learner` process serving over TLS with a token, probed by clients that must be
//! refused (plaintext, another CA, a name not in the certificate, no token) and one that must
//! be admitted; then a `dvnav actor` process with the CA and the token trains to the budget
//! across a learner that is killed and restarted (TLS survives the reconnection). Mutual TLS:
//! only a client presenting a certificate from the CA is admitted.

use dvnav_proto::learner_client::LearnerClient;
use dvnav_proto::{RegisterRequest, StatusRequest};
use dvnav_tls::{ClientTlsFiles, endpoint};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use support::{INGEST_ONLY_CONFIG, KillOnDrop, wait_exit};

mod support;

fn dvnav() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dvnav"));
    c.env_remove("DVNAV_TOKEN").env("RUST_LOG", "info");
    c
}

/// `dvnav certs --out DIR --host …`.
fn certs(dir: &Path, hosts: &[&str]) -> PathBuf {
    let mut c = dvnav();
    c.args(["certs", "--out"]).arg(dir);
    for h in hosts {
        c.args(["--host", h]);
    }
    let out = c.output().unwrap();
    assert!(out.status.success(), "dvnav certs: {}", String::from_utf8_lossy(&out.stderr));
    dir.to_path_buf()
}

/// A child process, killed if the test ends before it does, and its log.
struct Proc {
    child: KillOnDrop,
    log: PathBuf,
}

impl Proc {
    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn wait(&mut self, what: &str, limit: Duration) -> std::process::ExitStatus {
        let log = &self.log;
        wait_exit(&mut self.child, what, limit, || std::fs::read_to_string(log).unwrap_or_default())
    }
}

/// A `dvnav learner` on `listen` with `extra` flags; returns once it listens.
fn learner(out: &Path, listen: &str, extra: &[&str]) -> Proc {
    let config = out.with_extension("toml");
    std::fs::write(&config, INGEST_ONLY_CONFIG).unwrap();
    let addr_file = out.with_extension("addr");
    let _ = std::fs::remove_file(&addr_file);
    let log = out.with_extension("log");
    let child = dvnav()
        .args(["learner", "--listen", listen, "--config"])
        .arg(&config)
        .arg("--out")
        .arg(out)
        .arg("--addr-file")
        .arg(&addr_file)
        .args(extra)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let mut p = Proc { child: KillOnDrop(child), log };
    let deadline = Instant::now() + Duration::from_secs(60);
    while !addr_file.exists() {
        if let Some(st) = p.child.try_wait().unwrap() {
            panic!("the learner exited with {st}:\n{}", p.log());
        }
        assert!(Instant::now() < deadline, "the learner never listened:\n{}", p.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    p
}

fn client_tls(
    ca: Option<&Path>,
    domain: Option<&str>,
    identity: Option<(&Path, &Path)>,
) -> ClientTlsFiles {
    ClientTlsFiles {
        ca: ca.map(Path::to_path_buf),
        domain: domain.map(str::to_string),
        cert: identity.map(|(c, _)| c.to_path_buf()),
        key: identity.map(|(_, k)| k.to_path_buf()),
    }
}

/// Connects to `url` with `tls` and registers; the actor id, or what went wrong.
async fn register(url: &str, tls: &ClientTlsFiles, token: Option<&str>) -> Result<u32, String> {
    tokio::time::timeout(Duration::from_secs(10), try_register(url, tls, token))
        .await
        .unwrap_or_else(|_| panic!("neither admitted nor refused within 10 s: {url} {tls:?}"))
}

async fn try_register(url: &str, tls: &ClientTlsFiles, token: Option<&str>) -> Result<u32, String> {
    let ep = endpoint(url, tls.load().unwrap().as_ref()).unwrap();
    let channel =
        ep.connect().await.map_err(|e| format!("connect: {}", dvnav_tls::error_chain(&e)))?;
    let mut client = LearnerClient::new(channel);
    let mut req = tonic::Request::new(RegisterRequest {
        actor_name: "probe".into(),
        protocol_version: dvnav_proto::PROTOCOL_VERSION,
        num_envs: 0,
    });
    if let Some(t) = token {
        req.metadata_mut().insert("authorization", format!("Bearer {t}").parse().unwrap());
    }
    match client.register(req).await {
        Ok(r) => Ok(r.into_inner().actor_id),
        Err(s) => Err(format!("{:?}: {}", s.code(), dvnav_tls::error_chain(&s))),
    }
}

fn summary(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn n(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn actors_with_the_ca_and_token_train_over_tls_and_others_are_refused() {
    let started = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The certificate names only `localhost`: dialling 127.0.0.1 needs --tls-domain.
    let good = certs(&d.join("certs"), &["localhost"]);
    let other = certs(&d.join("other"), &["localhost"]);
    let (ca, other_ca) = (good.join("ca.pem"), other.join("ca.pem"));
    let token_file = d.join("token");
    std::fs::write(&token_file, "tls-test-token\n").unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let tls_flags = [
        "--tls-cert",
        good.join("server.pem").to_str().unwrap(),
        "--tls-key",
        good.join("server.key").to_str().unwrap(),
        "--token-file",
        token_file.to_str().unwrap(),
    ]
    .map(str::to_string);
    let tls_flags: Vec<&str> = tls_flags.iter().map(String::as_str).collect();
    // The first learner's budget is out of reach: were it to say stop before it is killed, the
    // actor would rightly finish and leave the second learner waiting (as tests/reconnect.rs).
    let first_flags: Vec<&str> = tls_flags.iter().copied().chain(["--steps", "1000000"]).collect();
    let mut first = learner(&d.join("first"), &addr, &first_flags);
    assert!(first.log().contains("tls=true"), "{}", first.log());

    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let https = format!("https://{addr}");
    let right = client_tls(Some(&ca), Some("localhost"), None);
    rt.block_on(async {
        let token = Some("tls-test-token");
        // Plaintext: no TLS handshake, no service.
        let e = register(&format!("http://{addr}"), &ClientTlsFiles::default(), token).await;
        let e = e.expect_err("a plaintext client is refused");
        assert!(!e.contains("Unauthenticated"), "refused before the token is looked at: {e}");
        // A CA that did not sign the learner's certificate.
        let wrong = client_tls(Some(&other_ca), Some("localhost"), None);
        let e = register(&https, &wrong, token).await.expect_err("another CA is refused");
        assert!(e.contains("UnknownIssuer"), "{e}");
        // The right CA, but the address dialled is not in the certificate.
        let by_ip = client_tls(Some(&ca), None, None);
        let e = register(&https, &by_ip, token).await.expect_err("127.0.0.1 is not in it");
        assert!(e.contains("certificate not valid for name \"127.0.0.1\""), "{e}");
        // TLS without the token: the service answers, and refuses.
        let e = register(&https, &right, None).await.expect_err("no token");
        assert!(e.starts_with("Unauthenticated"), "{e}");
        let e = register(&https, &right, Some("wrong")).await.expect_err("wrong token");
        assert!(e.starts_with("Unauthenticated"), "{e}");
        // TLS and the token.
        register(&https, &right, token).await.expect("the CA, the name and the token");
    });

    // Command-line clients that cannot get in fail at start-up, saying why.
    for (flags, why) in [
        (
            vec!["--tls-ca", other_ca.to_str().unwrap(), "--tls-domain", "localhost"],
            "UnknownIssuer",
        ),
        (vec![], "a learner that serves TLS drops plaintext connections"),
    ] {
        let out = dvnav()
            .args(["actor", "--name", "outsider", "--connect-timeout-s", "1"])
            .args(["--learner", &format!("http://{addr}"), "--out"])
            .arg(d.join("outsider"))
            .args(["--token-file", token_file.to_str().unwrap()])
            .args(&flags)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{flags:?} got in: {stderr}");
        assert!(stderr.contains(why), "{flags:?}: no `{why}` in:\n{stderr}");
    }

    // An actor with the CA and the token; `http://` with --tls-ca is dialled as https://.
    let actor_out = d.join("actor");
    let actor_log = d.join("actor.log");
    let mut actor = Proc {
        child: KillOnDrop(
            dvnav()
                .args(["actor", "--name", "trusted", "--learner", &format!("http://{addr}")])
                .args(["--tls-ca", ca.to_str().unwrap(), "--tls-domain", "localhost"])
                .args(["--token-file", token_file.to_str().unwrap(), "--out"])
                .arg(&actor_out)
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(&actor_log).unwrap())
                .spawn()
                .unwrap(),
        ),
        log: actor_log,
    };
    // Transitions arrive over TLS; then the learner dies and another takes its place.
    let received = rt.block_on(async {
        let tls = right.load().unwrap();
        let channel = endpoint(&https, tls.as_ref()).unwrap().connect().await.unwrap();
        let mut c = LearnerClient::new(channel);
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let mut req = tonic::Request::new(StatusRequest {});
            req.metadata_mut().insert("authorization", "Bearer tls-test-token".parse().unwrap());
            let s = c.status(req).await.unwrap().into_inner();
            if s.transitions_received >= 200 {
                return s.transitions_received;
            }
            assert!(Instant::now() < deadline, "the learner got only {s:?}\n{}", actor.log());
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    assert!(received >= 200);
    first.child.kill().unwrap();
    first.child.wait().unwrap();
    let mut second = learner(&d.join("second"), &addr, &tls_flags);
    let st = actor.wait("the actor", Duration::from_secs(60));
    assert!(st.success(), "the actor failed:\n{}", actor.log());
    assert!(second.wait("the second learner", Duration::from_secs(60)).success());

    let s = summary(&actor_out.join("actors/trusted/summary.json"));
    assert!(n(&s["link"]["reconnects"]) >= 1, "{s}");
    assert_eq!(n(&s["link"]["transitions_undelivered"]), 0, "{s}");
    assert_eq!(n(&s["transitions_acked"]), n(&s["transitions_sent"]), "{s}");
    assert_eq!(s["stop_reason"], "learner said stop", "{s}");
    let l = summary(&d.join("second/learner_summary.json"));
    assert!(n(&l["transitions_received"]) >= 600, "{l}");
    assert_eq!(n(&l["transitions_rejected"]), 0, "{l}");
    assert!(actor.log().contains("reconnected to the learner"), "{}", actor.log());
    let log = format!("{}{}", second.log(), actor.log());
    assert!(!log.contains("tls-test-token"), "the token is never logged:\n{log}");
    eprintln!("took {:?}", started.elapsed());
}

#[test]
fn with_mutual_tls_only_clients_with_a_certificate_from_the_ca_get_in() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = certs(&d.join("certs"), &["127.0.0.1"]);
    let other = certs(&d.join("other"), &["127.0.0.1"]);
    let p = |dir: &Path, f: &str| dir.join(f).to_str().unwrap().to_string();
    let flags = [
        "--tls-cert".to_string(),
        p(&good, "server.pem"),
        "--tls-key".into(),
        p(&good, "server.key"),
        "--tls-client-ca".into(),
        p(&good, "ca.pem"),
    ];
    let flags: Vec<&str> = flags.iter().map(String::as_str).collect();
    let learner = learner(&d.join("run"), "127.0.0.1:0", &flags);
    let url = format!("https://{}", std::fs::read_to_string(d.join("run.addr")).unwrap().trim());
    let ca = good.join("ca.pem");
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        // The certificate's IP address SAN is verified without --tls-domain.
        let e = register(&url, &client_tls(Some(&ca), None, None), None).await;
        assert!(e.is_err(), "no client certificate: {e:?}");
        let stranger = (other.join("client.pem"), other.join("client.key"));
        let with = client_tls(Some(&ca), None, Some((&stranger.0, &stranger.1)));
        let e = register(&url, &with, None).await;
        assert!(e.is_err(), "a client certificate from another CA: {e:?}");
        let member = (good.join("client.pem"), good.join("client.key"));
        let with = client_tls(Some(&ca), None, Some((&member.0, &member.1)));
        register(&url, &with, None).await.expect("a client certificate from the CA");
    });
    drop(learner);
}

#[test]
fn bad_tls_flags_fail_at_start_naming_the_flag_or_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = certs(&d.join("certs"), &["localhost"]);
    let cert = good.join("server.pem");
    let key = good.join("server.key");
    let run = |args: &[&str]| {
        let out = dvnav()
            .args(["learner", "--listen", "127.0.0.1:0", "--out"])
            .arg(d.join("run"))
            .args(args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?} started");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = run(&["--tls-cert", cert.to_str().unwrap()]);
    assert!(e.contains("--tls-cert needs --tls-key"), "{e}");
    let missing = d.join("missing.key");
    let e = run(&["--tls-cert", cert.to_str().unwrap(), "--tls-key", missing.to_str().unwrap()]);
    assert!(e.contains(&format!("TLS private key {}: cannot read it", missing.display())), "{e}");
    let e = run(&["--tls-cert", key.to_str().unwrap(), "--tls-key", key.to_str().unwrap()]);
    assert!(e.contains("server.key: no certificate in it"), "{e}");
    let e = run(&[
        "--tls-cert",
        cert.to_str().unwrap(),
        "--tls-key",
        good.join("client.key").to_str().unwrap(),
    ]);
    assert!(e.contains("client.key cannot serve the certificate"), "{e}");
    assert!(!d.join("run").exists(), "nothing started");
}
