//! The accept loop: HTTP/1 and HTTP/2 (gRPC) connections on one listener, with the bounds a
//! server facing anyone needs, which `axum::serve` does not set.
//!
//! - **A cap on open connections** (`--max-connections`, by default the open-file limit less a
//!   reserve for the models folder and the jobs): past it a connection is answered at once with
//!   a 503 and closed, rather than left to exhaust the process's file descriptors (which made
//!   every accept, and the models folder's poll, fail with "Too many open files").
//! - **A header-read timeout** (`--header-timeout`): an HTTP/1 client has that long to send a
//!   request's headers, counted from the connection's start or the end of the previous request
//!   (hyper's timer, and ours for the first byte of either protocol), so silent connections,
//!   slow-header clients and idle HTTP/1 connections are closed after it.
//! - **An idle timeout** (`--idle-timeout`): an HTTP/2 connection with no request or stream in
//!   progress that long is closed gracefully (GOAWAY).
//! - **An HTTP/1 read buffer of [`HTTP1_BUFFER`]** (headers up to that, 431 past it), so that
//!   a body streaming in holds that much per connection, not hyper's 400 KiB.
//! - **Request headers up to [`MAX_HEADER_LIST`] on HTTP/2**, about what HTTP/1's buffer
//!   allows (with hyper's 16 KiB default, h2 took a 100 KiB header block for abuse, past 4
//!   times the limit, and closed the connection with every other call on it). Past the limit
//!   the request alone is refused (431, its stream reset); h2 still closes the connection
//!   (GOAWAY) for a block past 4 times it or spread over more than 20 CONTINUATION frames.
//! - **Keep-alive pings** (`--keepalive`) on HTTP/2: a peer that does not answer a ping within
//!   the same period is gone, and its connection (and streams) are closed; streams that should
//!   live stay open however quiet they are.
//! - **A maximum connection age** (`--max-connection-age`, off by default; ±10% by the client's
//!   port): an older connection is asked to close (GOAWAY, or after the current HTTP/1
//!   request), and after `--max-connection-age-grace` it is closed under whatever still runs,
//!   so that long-lived gRPC channels spread again over replicas added since.
//!
//! On shutdown the loop stops accepting and asks every connection to finish gracefully (HTTP/1
//! after its current request, HTTP/2 by GOAWAY), then waits for them all, as `axum::serve`'s
//! graceful shutdown did.

use std::pin::pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Semaphore, watch};
use tokio_util::task::TaskTracker;
use tower::ServiceExt;

/// The read buffer of an HTTP/1 connection, at most (hyper's default is about 400 KiB): a
/// request's headers must fit in it. Each connection's buffer grows to it while a body streams
/// in, so 60 connections draining refused 8 MB bodies held 54 MiB at hyper's default.
pub const HTTP1_BUFFER: usize = 64 * 1024;

/// The most bytes of request headers an HTTP/2 request may have (HPACK-decoded).
pub const MAX_HEADER_LIST: u32 = 256 * 1024;

/// The connection bounds of the module doc.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionLimits {
    /// Most open connections (HTTP/1 and HTTP/2); past it a connection is answered 503 and closed.
    pub max_connections: usize,
    /// HTTP/1: the time a client has to send a request's headers.
    pub header_timeout: Duration,
    /// HTTP/2: a connection with no call in progress this long is closed.
    pub idle_timeout: Duration,
    /// HTTP/2: the interval of keep-alive pings.
    pub keepalive: Duration,
    /// Connections older than about this are asked to close (GOAWAY / close after the
    /// request); `None`: never.
    pub max_age: Option<Duration>,
    /// How long an aged connection's calls may go on before it is closed under them.
    pub age_grace: Duration,
}

/// A connection's own maximum age: `age` spread by ±10% with the client's port, so that the
/// connections a load balancer opened together do not all close together.
fn jittered(age: Duration, port: u16) -> Duration {
    age.mul_f64(0.9 + 0.2 * f64::from(port % 101) / 100.0)
}

/// The answer to a connection over the cap, whatever it sent.
fn refusal(max: usize) -> Vec<u8> {
    let body = format!(
        "{{\"error\":{{\"code\":\"unavailable\",\"message\":\"too many open connections \
         ({max}, --max-connections): retry, possibly on another replica\"}}}}"
    );
    format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n\
         retry-after: 1\r\nconnection: close\r\ncontent-length: {}\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

/// What one connection is doing: requests (and response bodies, streams included) in progress,
/// and when the last one ended.
#[derive(Debug, Default)]
struct Activity {
    in_progress: AtomicUsize,
    /// Milliseconds since the connection's start at which it last became idle.
    idle_since_ms: AtomicU64,
}

/// Held while a request's response is being sent.
struct Busy {
    activity: Arc<Activity>,
    start: Instant,
}

impl Busy {
    fn new(activity: Arc<Activity>, start: Instant) -> Busy {
        activity.in_progress.fetch_add(1, Ordering::AcqRel);
        Busy { activity, start }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        let ms = self.start.elapsed().as_millis() as u64;
        self.activity.idle_since_ms.store(ms, Ordering::Release);
        self.activity.in_progress.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A response body that keeps its connection busy until it is sent or dropped.
struct TrackedBody {
    inner: Body,
    _busy: Busy,
}

impl http_body::Body for TrackedBody {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        std::pin::Pin::new(&mut self.inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// Serves `router` on `listener` until `shutdown` resolves, then drains (module doc).
/// Serves `router` on `listener` within `limits` until `shutdown`, then drains; `aged` is
/// called for each connection asked to close for its age.
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ConnectionLimits,
    aged: impl Fn() + Clone + Send + Sync + 'static,
    shutdown: impl Future<Output = ()>,
) {
    let mut builder = auto::Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout)
        .max_buf_size(HTTP1_BUFFER);
    builder
        .http2()
        .timer(TokioTimer::new())
        .keep_alive_interval(limits.keepalive)
        .keep_alive_timeout(limits.keepalive)
        .max_header_list_size(MAX_HEADER_LIST);
    let builder = Arc::new(builder);
    let permits = Arc::new(Semaphore::new(limits.max_connections));
    let refusing = Arc::new(Semaphore::new(MAX_REFUSING));
    let (stop_tx, stop_rx) = watch::channel(false);
    let connections = TaskTracker::new();
    let mut shutdown = pin!(shutdown);
    let mut last_accept_error: Option<Instant> = None;
    loop {
        let (tcp, peer) = tokio::select! {
            biased;
            _ = &mut shutdown => break,
            accepted = listener.accept() => match accepted {
                Ok(c) => c,
                Err(e) => {
                    // Out of file descriptors, or a connection reset before it was accepted:
                    // say so at most once a second, and give the process a moment.
                    if last_accept_error.is_none_or(|t| t.elapsed() > Duration::from_secs(1)) {
                        tracing::warn!(error = %e, "accept failed");
                        last_accept_error = Some(Instant::now());
                    }
                    if !matches!(
                        e.kind(),
                        std::io::ErrorKind::ConnectionReset | std::io::ErrorKind::ConnectionAborted
                    ) {
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                    continue;
                }
            },
        };
        let _ = tcp.set_nodelay(true);
        let Ok(permit) = permits.clone().try_acquire_owned() else {
            refuse(tcp, limits.max_connections, &refusing);
            continue;
        };
        let (builder, router, stop) = (builder.clone(), router.clone(), stop_rx.clone());
        let age = limits.max_age.map(|age| jittered(age, peer.port()));
        let aged = aged.clone();
        connections.spawn(async move {
            let mut stop = stop;
            if first_byte(&tcp, limits.header_timeout, &mut stop).await {
                let ageing = age.map(|age| Ageing {
                    age,
                    grace: limits.age_grace,
                    aged: &aged,
                });
                serve_connection(&builder, tcp, router, limits.idle_timeout, ageing, stop).await;
            }
            drop(permit);
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    connections.close();
    connections.wait().await;
}

/// Connections over the cap being answered at once, at most: past it they are closed without
/// an answer.
const MAX_REFUSING: usize = 64;

/// How long a refused connection may take to read its answer.
const REFUSAL_TIME: Duration = Duration::from_secs(1);

/// Answers a connection over the cap and closes it. The answer fits a fresh socket's send
/// buffer, so one non-blocking write sends it; what the client sent meanwhile is read and
/// dropped for up to [`REFUSAL_TIME`], since closing a socket with unread bytes resets it and
/// the client would lose the answer.
fn refuse(tcp: TcpStream, max: usize, refusing: &Arc<Semaphore>) {
    tracing::debug!(max, "connection refused: too many open connections");
    let Ok(slot) = refusing.clone().try_acquire_owned() else {
        return;
    };
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut tcp = tcp;
        if tcp.try_write(&refusal(max)).is_err() {
            return;
        }
        let _ = tcp.shutdown().await;
        let mut sink = [0u8; 4096];
        let _ = tokio::time::timeout(REFUSAL_TIME, async {
            while matches!(tcp.read(&mut sink).await, Ok(n) if n > 0) {}
        })
        .await;
        drop(slot);
    });
}

/// Waits for a connection's first byte, for at most `within`: hyper's header timer starts
/// only once a request's bytes come, so a client that sends nothing held its connection until
/// the idle timeout. `false`: close it (silent, gone, or the server stopping).
async fn first_byte(tcp: &TcpStream, within: Duration, stop: &mut watch::Receiver<bool>) -> bool {
    let mut byte = [0u8; 1];
    tokio::select! {
        peeked = tokio::time::timeout(within, tcp.peek(&mut byte)) => {
            matches!(peeked, Ok(Ok(n)) if n > 0)
        }
        _ = stop.changed() => false,
    }
}

/// A connection's maximum age, the grace its calls get once it is reached, and what to call
/// then (a metric).
#[derive(Clone, Copy)]
struct Ageing<'a> {
    age: Duration,
    grace: Duration,
    aged: &'a (dyn Fn() + Send + Sync),
}

async fn serve_connection(
    builder: &auto::Builder<TokioExecutor>,
    tcp: TcpStream,
    router: Router,
    idle_timeout: Duration,
    ageing: Option<Ageing<'_>>,
    mut stop: watch::Receiver<bool>,
) {
    let start = Instant::now();
    let activity = Arc::new(Activity::default());
    let tracked = activity.clone();
    let service = hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
        let busy = Busy::new(tracked.clone(), start);
        let router = router.clone();
        async move {
            let resp = router.oneshot(req.map(Body::new)).await?;
            Ok::<_, std::convert::Infallible>(resp.map(|inner| TrackedBody { inner, _busy: busy }))
        }
    });
    let mut conn = pin!(builder.serve_connection_with_upgrades(TokioIo::new(tcp), service));
    let mut closing = false;
    // Set once the connection is past its age: then it is closed, whatever runs on it.
    let mut cut_at: Option<tokio::time::Instant> = None;
    let period = ageing.map_or(idle_timeout, |a| a.age.min(idle_timeout));
    let mut tick = tokio::time::interval(period.min(Duration::from_secs(1)));
    loop {
        let cut = async {
            match cut_at {
                Some(t) => tokio::time::sleep_until(t).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            result = conn.as_mut() => {
                if let Err(e) = result {
                    tracing::debug!(error = %e, "connection ended with an error");
                }
                return;
            }
            _ = stop.changed(), if !closing => {
                closing = true;
                conn.as_mut().graceful_shutdown();
            }
            _ = cut => {
                tracing::debug!("connection closed: past its maximum age and grace");
                return;
            }
            _ = tick.tick(), if !closing => {
                if let Some(a) = ageing.filter(|a| start.elapsed() >= a.age) {
                    (a.aged)();
                    closing = true;
                    cut_at = Some(tokio::time::Instant::now() + a.grace);
                    conn.as_mut().graceful_shutdown();
                    continue;
                }
                let idle = activity.in_progress.load(Ordering::Acquire) == 0;
                let since = Duration::from_millis(activity.idle_since_ms.load(Ordering::Acquire));
                if idle && start.elapsed().saturating_sub(since) >= idle_timeout {
                    closing = true;
                    conn.as_mut().graceful_shutdown();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connection_ages_spread_by_ten_percent() {
        let age = Duration::from_secs(300);
        let ages: Vec<Duration> = (40000..40101).map(|p| jittered(age, p)).collect();
        assert!(
            ages.iter()
                .all(|a| *a >= age.mul_f64(0.9) && *a <= age.mul_f64(1.1))
        );
        let (lo, hi) = (ages.iter().min().unwrap(), ages.iter().max().unwrap());
        assert!(*hi - *lo >= age.mul_f64(0.19), "{lo:?}..{hi:?}");
    }

    #[test]
    fn the_refusal_is_a_complete_http_answer() {
        let text = String::from_utf8(refusal(10)).unwrap();
        let (head, body) = text.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 503 "));
        let length: usize = head
            .lines()
            .find_map(|l| l.strip_prefix("content-length: "))
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(length, body.len());
        let v: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(v["error"]["code"], "unavailable");
        assert!(
            v["error"]["message"]
                .as_str()
                .unwrap()
                .contains("--max-connections")
        );
    }
}
