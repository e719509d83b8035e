//! What the process-level tests share: waiting with a deadline, a child process that cannot
//! outlive its test, and one HTTP GET against the learner's metrics and probe port.
// Each test binary compiles this module and uses a part of it.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::ops::{Deref, DerefMut};
use std::process::{Child, ExitStatus};
use std::time::{Duration, Instant};

/// A run of learner and actor processes that only streams transitions: a 600-step budget and
/// no updates, so ingestion never waits for training (the reconnection tests).
pub const INGEST_ONLY_CONFIG: &str = r#"
[run]
steps = 600

[sac]
learning_starts = 1000000

[actor]
envs = 2
batch_transitions = 32

[logging]
every_nth_episode = 0
"#;

/// Polls `f` every 20 ms until it gives a value; fails naming `what` after `limit`.
pub fn wait_for<T>(what: &str, limit: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits up to `limit` for `child` to exit; kills it and fails with `log()` if it does not.
pub fn wait_exit(
    child: &mut Child,
    what: &str,
    limit: Duration,
    log: impl Fn() -> String,
) -> ExitStatus {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} still running after {limit:?}:\n{}", log());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A child process killed when the test ends before it does, so a failing test leaves no
/// process behind.
pub struct KillOnDrop(pub Child);

impl Deref for KillOnDrop {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl DerefMut for KillOnDrop {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// One HTTP/1.1 `GET path` on `addr`: the whole reply, empty when the server is gone or
/// answers nothing within 10 s.
pub fn http_get(addr: &str, path: &str) -> String {
    let get = || -> std::io::Result<String> {
        let mut sock = std::net::TcpStream::connect(addr)?;
        sock.set_read_timeout(Some(Duration::from_secs(10)))?;
        write!(sock, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n")?;
        let mut reply = String::new();
        sock.read_to_string(&mut reply)?;
        Ok(reply)
    };
    get().unwrap_or_default()
}

/// The status line of a `GET path` on `addr`.
pub fn http_status(addr: &str, path: &str) -> String {
    http_get(addr, path).lines().next().unwrap_or("").to_string()
}
