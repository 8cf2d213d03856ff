//! The operational routes: liveness, readiness, metrics and the OpenAPI document. None is
//! under the request limits: a busy server still answers its probes.

use std::sync::Arc;

use axum::extract::State;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use facepose_app::{App, Readiness};
use serde::Serialize;
use utoipa::ToSchema;

use super::body::json_bytes;

/// A health probe's answer: `{"status": ...}`.
#[derive(Debug, Serialize, ToSchema)]
pub struct Status {
    /// `alive`, `ready` or `draining`.
    pub status: &'static str,
}

/// The OpenAPI document as served, rendered once when the router is built.
#[derive(Debug, Clone)]
pub struct OpenApiText(pub Arc<str>);

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "operations",
    responses((status = 200, description = "The process answers: `{\"status\": \"alive\"}`", body = Status)))]
pub async fn healthz() -> Response {
    json_bytes(br#"{"status":"alive"}"#.to_vec())
}

/// Readiness: models loaded and not draining (503 while shutting down). While an active
/// version of the models folder fails to load here, the answer is still 200 (the previous
/// version serves) and lists the problem under `problems`.
#[utoipa::path(get, path = "/readyz", tag = "operations",
    responses(
        (status = 200, description = "Ready: models loaded, not draining; `problems` lists active versions that do not load here (the previous one serves)", body = Status),
        (status = 503, description = "Draining: shutting down, send requests elsewhere", body = Status)))]
pub async fn readyz(State(app): State<Arc<App>>) -> Response {
    match app.readiness() {
        Readiness::Ready { problems } if problems.is_empty() => {
            json_bytes(br#"{"status":"ready"}"#.to_vec())
        }
        Readiness::Ready { problems } => {
            let problems: Vec<_> = problems
                .iter()
                .map(|p| serde_json::json!({"model": p.model, "version": p.version, "message": p.message}))
                .collect();
            Json(serde_json::json!({"status": "ready", "problems": problems})).into_response()
        }
        Readiness::Draining => (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Status { status: "draining" }),
        )
            .into_response(),
    }
}

/// Prometheus metrics (text exposition format).
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, description = "The metrics in the Prometheus text exposition format", content_type = "text/plain; version=0.0.4", body = String)))]
pub async fn metrics_text(State(app): State<Arc<App>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        app.metrics.render(),
    )
        .into_response()
}

/// This document.
#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, description = "This OpenAPI document", content_type = "application/json", body = Object)))]
pub async fn openapi(Extension(doc): Extension<OpenApiText>) -> Response {
    json_bytes(doc.0.as_bytes().to_vec())
}
