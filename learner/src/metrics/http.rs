//! The learner's HTTP endpoints: an axum [`router`] with `GET /metrics` (the latest rendered
//! sample), the health probes `GET /healthz` (200 while the process serves; 503 once the
//! trainer or the rate limiter has been stalled for `learner.liveness_stall_s`) and
//! `GET /readyz` (200 while the learner takes actors, 503 while starting and once the run is
//! finished; [`LearnerState::readiness`]), and [`serve`], which runs it on hyper's HTTP/1.1
//! connection until its shutdown is cancelled.
//!
//! hyper directly rather than `axum::serve`, for the connection settings that one does not
//! expose: one request per connection (`Connection: close`), a request head of at most
//! [`MAX_REQUEST_BYTES`] (431 beyond), a client that sends no complete head within
//! [`REQUEST_TIMEOUT`] is dropped, and header names in title case.

use crate::state::{LearnerState, Readiness};
use axum::Router;
use axum::extract::State;
use axum::http::StatusCode;
use axum::http::header::CONTENT_TYPE;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::task::JoinSet;
use tokio_util::sync::CancellationToken;

/// Paths the HTTP server answers (Kubernetes probes point at the last two;
/// `make check-deploy` checks the manifests against this list).
pub const HTTP_PATHS: [&str; 4] = ["/", "/metrics", "/healthz", "/readyz"];
/// Largest HTTP request head accepted (bytes; hyper's smallest read buffer).
pub const MAX_REQUEST_BYTES: usize = 8 * 1024;
/// A client that sends no complete request head within this time is dropped.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// Content type of the Prometheus text exposition format.
const PROMETHEUS: &str = "text/plain; version=0.0.4; charset=utf-8";
/// Content type of the probes' and the index's text.
const TEXT: &str = "text/plain; charset=utf-8";

/// The routes of [`HTTP_PATHS`] on `state`. `HEAD` is answered like `GET` without the body;
/// another method on a route is 405, another path 404.
pub fn router(state: Arc<LearnerState>) -> Router {
    Router::new()
        .route("/", get(index).fallback(not_found))
        .route("/metrics", get(metrics))
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .fallback(not_found)
        .with_state(state)
}

async fn index() -> Response {
    let body = "dvnav learner: Prometheus metrics at /metrics; probes at /healthz and /readyz\n";
    ([(CONTENT_TYPE, TEXT)], body).into_response()
}

async fn metrics(State(state): State<Arc<LearnerState>>) -> Response {
    ([(CONTENT_TYPE, PROMETHEUS)], state.live().text().to_string()).into_response()
}

/// Liveness: this answer comes from the learner's runtime, so a process that answers is alive
/// and not wedged in its I/O; a trainer stalled past `learner.liveness_stall_s` makes it 503 so
/// a supervisor restarts (and resumes) it.
async fn healthz(State(state): State<Arc<LearnerState>>) -> Response {
    match state.liveness() {
        Ok(()) => text(StatusCode::OK, "ok\n".into()),
        Err(why) => text(StatusCode::SERVICE_UNAVAILABLE, format!("wedged: {why}\n")),
    }
}

/// Readiness: whether it takes actors. A stall does not make it unready (actors could not
/// reconnect, which would not help), but the body names what is stalled.
async fn readyz(State(state): State<Arc<LearnerState>>) -> Response {
    let (status, mut body) = match state.readiness() {
        Readiness::Ready => (StatusCode::OK, "ready\n".to_string()),
        Readiness::Starting => (StatusCode::SERVICE_UNAVAILABLE, "starting\n".to_string()),
        Readiness::Finished => (
            StatusCode::SERVICE_UNAVAILABLE,
            "finished: the run takes no more actors\n".to_string(),
        ),
    };
    for s in state.stalled() {
        body += &format!(
            "stalled: {} for {:.1} s: {}; last error: {}\n",
            s.component,
            s.for_s,
            s.what,
            s.last_error.as_deref().unwrap_or("none")
        );
    }
    text(status, body)
}

async fn not_found() -> Response {
    (StatusCode::NOT_FOUND, [(CONTENT_TYPE, "text/plain")], "not found\n").into_response()
}

fn text(status: StatusCode, body: String) -> Response {
    (status, [(CONTENT_TYPE, TEXT)], body).into_response()
}

/// Serves [`router`] on `listener` until `shutdown` is cancelled, then stops accepting, lets
/// the requests in flight finish and returns.
pub async fn serve(
    listener: TcpListener,
    shutdown: CancellationToken,
    state: Arc<LearnerState>,
) -> std::io::Result<()> {
    let app = router(state);
    let mut http = hyper::server::conn::http1::Builder::new();
    http.keep_alive(false)
        .title_case_headers(true)
        .max_buf_size(MAX_REQUEST_BYTES)
        .timer(TokioTimer::new())
        .header_read_timeout(REQUEST_TIMEOUT);
    let mut connections = JoinSet::new();
    loop {
        tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((sock, _)) => {
                    let conn = http
                        .serve_connection(TokioIo::new(sock), TowerToHyperService::new(app.clone()));
                    let stop = shutdown.clone();
                    connections.spawn(async move {
                        tokio::pin!(conn);
                        let mut stopping = false;
                        let served = loop {
                            tokio::select! {
                                served = conn.as_mut() => break served,
                                () = stop.cancelled(), if !stopping => {
                                    stopping = true;
                                    conn.as_mut().graceful_shutdown();
                                }
                            }
                        };
                        if let Err(e) = served {
                            tracing::debug!(error = %e, "metrics request failed");
                        }
                    });
                }
                Err(e) => {
                    tracing::warn!(error = %e, "metrics listener: accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
            // Finished connections, reaped as they end.
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
            () = shutdown.cancelled() => break,
        }
    }
    drop(listener);
    // Each ends within its request timeout.
    while connections.join_next().await.is_some() {}
    Ok(())
}
