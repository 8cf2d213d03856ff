//! Serving, then draining: the state both transports and the health service read.
//!
//! The drain, in order (the server drives it, `facepose_service::server`): `/readyz` answers
//! 503 and the gRPC health service NOT_SERVING (so load balancers stop sending new work), the
//! listener stops accepting, open streams are told to end (UNAVAILABLE, "server shutting
//! down"), in-flight requests finish, new retraining uploads are refused (503 / UNAVAILABLE),
//! and the server stops once every connection is done and every accepted retraining job has
//! ended, or the drain's cap has passed.

use std::sync::atomic::{AtomicBool, Ordering};

use tokio::sync::watch;
use tokio_util::task::{TaskTracker, task_tracker::TaskTrackerToken};

use crate::metrics::Metrics;

/// Serving or draining.
#[derive(Debug)]
pub struct Lifecycle {
    draining: AtomicBool,
    drain_tx: watch::Sender<bool>,
    metrics: Metrics,
    /// The open streams that outlive their connection's task (WebSocket streams, which run on
    /// their own once upgraded), each holding a token until its closing handshake is over.
    streams: TaskTracker,
}

impl Lifecycle {
    /// A lifecycle that reports readiness into `metrics`.
    pub fn new(metrics: Metrics) -> Self {
        Lifecycle {
            draining: AtomicBool::new(false),
            drain_tx: watch::Sender::new(false),
            metrics,
            streams: TaskTracker::new(),
        }
    }

    /// Records that the service is serving (the models are loaded by then).
    pub fn serving(&self) {
        self.metrics.ready(true);
    }

    /// Whether new work should come here: models loaded (always, once serving) and not draining.
    pub fn is_ready(&self) -> bool {
        !self.draining.load(Ordering::Acquire)
    }

    /// Starts the drain: readiness and gRPC health flip (health watchers get NOT_SERVING),
    /// and open streams are told to end.
    pub fn begin_drain(&self) {
        if self.draining.swap(true, Ordering::AcqRel) {
            return;
        }
        self.metrics.ready(false);
        self.drain_tx.send_replace(true);
    }

    /// A token for a stream that runs apart from its connection's task, held until the stream
    /// is over, closing handshake included: the drain waits for every one
    /// ([`Lifecycle::streams_ended`]), so that a stream told to end is not cut off by the
    /// process's exit before its close reaches the client.
    pub fn stream_token(&self) -> TaskTrackerToken {
        self.streams.token()
    }

    /// Resolves once every stream token has been dropped. For the drain, once no connection
    /// can open a new stream.
    pub fn streams_ended(&self) -> impl Future<Output = ()> + Send + 'static {
        self.streams.close();
        let streams = self.streams.clone();
        async move { streams.wait().await }
    }

    /// Resolves once the drain has started (for streams and the drain cap).
    pub fn drained(&self) -> impl Future<Output = ()> + Send + 'static {
        let mut rx = self.drain_tx.subscribe();
        async move {
            let _ = rx.wait_for(|d| *d).await;
        }
    }
}
