//! Lifecycle: serving, then draining after SIGTERM or SIGINT.
//!
//! The drain, in order: `/readyz` answers 503 and the gRPC health service NOT_SERVING (so load
//! balancers stop sending new work), the listener stops accepting, open streams are told to end
//! (UNAVAILABLE, "server shutting down"), in-flight requests finish, new retraining uploads are
//! refused (503 / UNAVAILABLE), and the process exits once every connection is done and every
//! accepted retraining job has ended (status 0), or `--drain-timeout` has passed, whichever
//! comes first: then the connections left are closed, the jobs cut off are logged by id, and
//! the process exits with an error status (`ServeError::DrainCut`).

use std::sync::atomic::{AtomicBool, Ordering};

use tokio::sync::watch;

/// Serving or draining, shared by both transports and the health service.
#[derive(Debug)]
pub struct Lifecycle {
    draining: AtomicBool,
    drain_tx: watch::Sender<bool>,
}

impl Default for Lifecycle {
    fn default() -> Self {
        Lifecycle {
            draining: AtomicBool::new(false),
            drain_tx: watch::Sender::new(false),
        }
    }
}

impl Lifecycle {
    /// Records that the service is serving (the models are loaded by then).
    pub fn serving(&self) {
        super::metrics::ready(true);
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
        super::metrics::ready(false);
        self.drain_tx.send_replace(true);
    }

    /// Resolves once the drain has started (for streams and the drain cap).
    pub fn drained(&self) -> impl Future<Output = ()> + Send + 'static {
        let mut rx = self.drain_tx.subscribe();
        async move {
            let _ = rx.wait_for(|d| *d).await;
        }
    }
}

/// Resolves on SIGTERM or SIGINT (Ctrl-C) with the signal's name.
pub async fn termination_signal() -> &'static str {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match (
            signal(SignalKind::terminate()),
            signal(SignalKind::interrupt()),
        ) {
            (Ok(mut term), Ok(mut int)) => tokio::select! {
                _ = term.recv() => "SIGTERM",
                _ = int.recv() => "SIGINT",
            },
            _ => {
                let _ = tokio::signal::ctrl_c().await;
                "SIGINT"
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
        "SIGINT"
    }
}
