//! Work that must not run on the async workers: file I/O of the models folder, training, the
//! check of an upload, big batches. On the blocking pool, a panic is an internal error naming
//! the work, not a crash.

use crate::error::ServiceError;

/// [`tokio::task::spawn_blocking`] in the caller's span: what the work logs is the request's
/// or the server's, as if it ran where it was called.
pub fn spawn_blocking<T, F>(f: F) -> tokio::task::JoinHandle<T>
where
    F: FnOnce() -> T + Send + 'static,
    T: Send + 'static,
{
    let span = tracing::Span::current();
    tokio::task::spawn_blocking(move || span.in_scope(f))
}

/// Runs fallible blocking work (file I/O, training, validation of an upload) on the blocking
/// pool.
pub async fn on_blocking_pool<T, F>(what: &str, f: F) -> Result<T, ServiceError>
where
    F: FnOnce() -> Result<T, ServiceError> + Send + 'static,
    T: Send + 'static,
{
    spawn_blocking(f)
        .await
        .map_err(|e| ServiceError::internal(format!("{what} failed: {e}")))?
}

/// Runs `f` inline when `inline`, else on the blocking pool. Estimation is microseconds per
/// face: a thread hop only pays off for batches.
pub async fn run_maybe_blocking<T, F>(inline: bool, f: F) -> Result<T, ServiceError>
where
    F: FnOnce() -> T + Send + 'static,
    T: Send + 'static,
{
    if inline {
        Ok(f())
    } else {
        spawn_blocking(f)
            .await
            .map_err(|e| ServiceError::internal(format!("estimation task failed: {e}")))
    }
}

/// Runs `f`, which touches the models folder, without holding up the async tasks of the worker
/// it is called on (`block_in_place` on a multi-threaded runtime). The work stays synchronous,
/// so that (for example) a job's record is written before the job is said to have ended.
pub fn off_the_workers<T>(f: impl FnOnce() -> T) -> T {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        _ => f(),
    }
}
