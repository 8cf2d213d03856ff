//! What runs around the handlers: on every request (HTTP and gRPC) the request id, and for
//! HTTP the metrics and a log line ([`observe`]); on the `/v1` routes the concurrency limit and
//! the time limit of the route's class ([`TimeLimit`], set where the route is declared).

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method as HttpMethod, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use facepose_app::App;
use facepose_app::error::ServiceError;
use tracing::Instrument;

use super::error::HttpError;

/// The deadline of a `/v1` request, for the handlers that stop work at it (batches).
#[derive(Debug, Clone, Copy)]
pub struct Deadline(pub Instant);

/// The time limit of a `/v1` route, and what its 503 says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeLimit {
    /// `--request-timeout`.
    Request,
    /// `--upload-timeout`: receiving and checking a retraining upload.
    Upload,
    /// `--request-timeout` for a change of the models folder, which goes on in the background
    /// when the request is cut.
    Change,
}

/// Refuses at once above the concurrency limit (429) and ends the request at its time limit
/// (503). Estimation of a batch also stops at the deadline.
pub async fn limits(
    State((app, limit)): State<(Arc<App>, TimeLimit)>,
    mut req: Request,
    next: Next,
) -> Response {
    let _permit = match app.request_permit() {
        Ok(p) => p,
        Err(e) => return HttpError::from(e).into_response(),
    };
    let timeout = match limit {
        TimeLimit::Upload => app.limits.upload_timeout,
        TimeLimit::Request | TimeLimit::Change => app.limits.request_timeout,
    };
    req.extensions_mut()
        .insert(Deadline(Instant::now() + timeout));
    match tokio::time::timeout(timeout, next.run(req)).await {
        Ok(resp) => resp,
        Err(_) => HttpError::from(match limit {
            TimeLimit::Request => ServiceError::Timeout { limit: timeout },
            TimeLimit::Upload => ServiceError::UploadTimeout { limit: timeout },
            TimeLimit::Change => ServiceError::ChangeTimedOut { limit: timeout },
        })
        .into_response(),
    }
}

fn method_label(m: &HttpMethod) -> &'static str {
    match *m {
        HttpMethod::GET => "GET",
        HttpMethod::POST => "POST",
        HttpMethod::PUT => "PUT",
        HttpMethod::DELETE => "DELETE",
        HttpMethod::HEAD => "HEAD",
        HttpMethod::PATCH => "PATCH",
        HttpMethod::OPTIONS => "OPTIONS",
        _ => "other",
    }
}

/// The request id header, accepted from the client or made here.
pub const REQUEST_ID: &str = "x-request-id";

fn request_id(headers: &HeaderMap) -> HeaderValue {
    headers
        .get(REQUEST_ID)
        .filter(|v| {
            let b = v.as_bytes();
            !b.is_empty() && b.len() <= 128 && b.iter().all(|c| c.is_ascii_graphic())
        })
        .cloned()
        .unwrap_or_else(|| {
            HeaderValue::from_str(&format!("{:016x}", rand::random::<u64>()))
                .unwrap_or_else(|_| HeaderValue::from_static("0"))
        })
}

/// Whether a request is gRPC.
pub fn is_grpc(headers: &HeaderMap) -> bool {
    headers
        .get(axum::http::header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/grpc"))
}

/// On every request (HTTP and gRPC): the request id (echoed, and in the log span, a child of
/// the server's), then for HTTP the metrics (by route template: a bounded set) and a log line
/// (errors at warn/error, the rest at debug).
pub async fn observe(State(app): State<Arc<App>>, mut req: Request, next: Next) -> Response {
    let started = Instant::now();
    let id = request_id(req.headers());
    let grpc = is_grpc(req.headers());
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_string());
    let method = method_label(req.method());
    let span = tracing::info_span!(
        parent: app.span(),
        "request",
        id = id.to_str().unwrap_or(""),
        method,
        path = req.uri().path()
    );
    req.headers_mut().insert(REQUEST_ID, id.clone());
    let mut resp = next.run(req).instrument(span.clone()).await;
    resp.headers_mut().insert(REQUEST_ID, id);
    if !grpc {
        let status = resp.status();
        let elapsed = started.elapsed();
        app.metrics.http_request(
            route.as_deref().unwrap_or("unmatched"),
            method,
            status.as_u16(),
            elapsed,
        );
        let _e = span.enter();
        if status.is_server_error() && status != StatusCode::SERVICE_UNAVAILABLE {
            tracing::error!(status = status.as_u16(), ?elapsed, "request failed");
        } else if status.is_client_error() || status.is_server_error() {
            tracing::debug!(status = status.as_u16(), ?elapsed, "request refused");
        } else {
            tracing::debug!(status = status.as_u16(), ?elapsed, "request");
        }
    }
    resp
}
