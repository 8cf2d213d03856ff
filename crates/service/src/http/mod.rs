//! The HTTP JSON API. Its routes and its OpenAPI document come from one list ([`api`]): each
//! handler's `#[utoipa::path]` gives both its route and its part of the document, so the two
//! cannot disagree. The handlers convert between the JSON of [`wire`] and the application
//! (`facepose_app::App`), and [`error`] maps its errors to statuses in HTTP's words.
//!
//! - [`pose`]: `POST /v1/pose`, `POST /v1/pose:batch`.
//! - [`models`]: the served models, their schemes (with the mean shape), versions, activation,
//!   deletion.
//! - [`retrain`]: `POST /v1/models` (an upload becomes a job), the jobs.
//! - [`ops`]: `/healthz`, `/readyz`, `/metrics`, `/openapi.json`.
//! - [`demo`]: the demo page at `/demo` (`--demo`), outside the document: a page, not an
//!   operation.
//! - [`body`], [`pose_body`]: reading request bodies (a pose body checked and parsed in one
//!   pass as it arrives); [`middleware`]: limits, request ids,
//!   metrics and logs; [`cors`]: the answers to browsers of other origins (`--cors-origins`).

pub mod body;
pub mod conventions;
pub mod cors;
pub mod demo;
pub mod error;
pub mod middleware;
pub mod models;
pub mod ops;
pub mod path;
pub mod pose;
pub mod pose_body;
pub mod retrain;
pub mod stream;
pub mod wire;

use std::sync::Arc;

use axum::Router;
use axum::body::Body;
use axum::extract::Request;
use axum::http::{Method as HttpMethod, Uri};
use axum::response::{IntoResponse, Response};
use facepose_app::App;
use utoipa::OpenApi;
use utoipa_axum::router::{OpenApiRouter, UtoipaMethodRouter, UtoipaMethodRouterExt};
use utoipa_axum::routes;

use error::{ErrorBody, ErrorCode, ErrorObject, HttpError};
use middleware::{TimeLimit, is_grpc};
use models::BearerAuth;

/// The document's parts that no route gives: its description, the error schemas, the admin
/// token's security scheme and the tags.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "facepose",
        description = "Head pose (yaw, pitch, roll in degrees, and the rotation matrix) from 2D \
            facial landmarks. Landmarks are image pixels (x right, y down). Angles follow the \
            300W-LP / AFLW2000-3D Pose_Para convention: pitch > 0 chin up, yaw > 0 the nose \
            turns towards image-left, roll > 0 clockwise on screen, R = Rx(pitch) Ry(yaw) \
            Rz(roll), given row-major. The same service answers gRPC (facepose.v1.PoseService) \
            on the same port."
    ),
    components(schemas(ErrorBody, ErrorObject, ErrorCode)),
    modifiers(&BearerAuth),
    tags(
        (name = "pose", description = "Pose estimation"),
        (name = "models", description = "Loaded model bundles"),
        (name = "registry", description = "Retraining, model versions, activation (admin routes need a bearer token)"),
        (name = "operations", description = "Health, readiness, metrics")
    )
)]
struct ApiDoc;

/// Every route with its part of the OpenAPI document: the `/v1` API under the concurrency
/// limit and its time limit class, the operational routes without limits.
pub fn api(app: &Arc<App>) -> OpenApiRouter<Arc<App>> {
    let v1 = |limit: TimeLimit, r: UtoipaMethodRouter<Arc<App>>| {
        r.layer(axum::middleware::from_fn_with_state(
            (app.clone(), limit),
            middleware::limits,
        ))
    };
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(v1(TimeLimit::Request, routes!(pose::pose)))
        .routes(v1(TimeLimit::Request, routes!(pose::pose_batch)))
        .routes(v1(TimeLimit::Request, routes!(models::list_models)))
        .routes(v1(TimeLimit::Upload, routes!(retrain::retrain)))
        .routes(v1(TimeLimit::Request, routes!(models::get_model)))
        .routes(v1(TimeLimit::Request, routes!(models::get_scheme)))
        .routes(v1(
            TimeLimit::Request,
            routes!(retrain::get_job, retrain::job_action),
        ))
        .routes(v1(TimeLimit::Request, routes!(models::list_versions)))
        .routes(v1(
            TimeLimit::Change,
            routes!(models::version_action, models::delete_version),
        ))
        .routes(routes!(ops::healthz))
        .routes(routes!(ops::readyz))
        .routes(routes!(ops::metrics_text))
        .routes(routes!(ops::openapi))
}

/// The HTTP router, with its state, and the OpenAPI document it serves.
pub fn router(app: &Arc<App>) -> (Router, utoipa::openapi::OpenApi) {
    let (router, doc) = api(app).split_for_parts();
    let text: Arc<str> = doc
        .to_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
        .into();
    let router = router
        .method_not_allowed_fallback(method_not_allowed)
        .layer(axum::Extension(ops::OpenApiText(text)))
        .with_state(app.clone());
    (router, doc)
}

async fn method_not_allowed(method: HttpMethod, uri: Uri) -> HttpError {
    HttpError::MethodNotAllowed(format!(
        "method {method} is not allowed on {}; see /openapi.json",
        uri.path()
    ))
}

/// The fallback of the whole router: gRPC UNIMPLEMENTED for gRPC requests, 404 otherwise.
pub async fn fallback(req: Request) -> Response {
    if is_grpc(req.headers()) {
        let status = tonic::Status::unimplemented(format!(
            "unknown gRPC method {}; see server reflection",
            req.uri().path()
        ));
        return status.into_http::<Body>().into_response();
    }
    HttpError::NotFound(format!(
        "no route {} {}; see /openapi.json",
        req.method(),
        req.uri().path()
    ))
    .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    /// The OpenAPI document as the server serves it.
    pub(super) fn document_of() -> utoipa::openapi::OpenApi {
        let settings = facepose_app::Settings {
            models: None,
            limits: facepose_app::Limits {
                max_batch: 10,
                max_body: 1 << 20,
                request_timeout: std::time::Duration::from_secs(5),
                max_concurrency: 4,
                max_streams: 4,
                max_upload: 1 << 20,
                upload_timeout: std::time::Duration::from_secs(5),
            },
            admin_token: facepose_app::auth::AdminToken::disabled(),
            max_queued_jobs: 1,
            registry_poll: std::time::Duration::from_secs(60),
            replica: "test".into(),
            keep_inactive_versions: None,
        };
        let runtime = tokio::runtime::Runtime::new().unwrap();
        let _enter = runtime.enter();
        let app = App::with_models(
            settings,
            facepose_app::registry::load_models(None).unwrap(),
            tracing::Span::none(),
        );
        router(&app).1
    }

    /// The OpenAPI document as the server serves it, as JSON.
    fn document() -> Value {
        serde_json::from_str(&document_of().to_json().unwrap()).unwrap()
    }

    const METHODS: [&str; 8] = [
        "get", "put", "post", "delete", "options", "head", "patch", "trace",
    ];

    /// Every operation of the document: (method, path template, operation).
    fn operations(doc: &Value) -> Vec<(&str, &str, &Value)> {
        let mut ops = Vec::new();
        for (path, item) in doc["paths"].as_object().unwrap() {
            for (method, op) in item.as_object().unwrap() {
                if METHODS.contains(&method.as_str()) {
                    ops.push((method.as_str(), path.as_str(), op));
                }
            }
        }
        ops
    }

    /// Every `$ref` under `v`, with where it stands.
    fn refs<'a>(v: &'a Value, at: String, out: &mut Vec<(String, &'a str)>) {
        match v {
            Value::Object(map) => {
                for (k, x) in map {
                    match (k.as_str(), x) {
                        ("$ref", Value::String(r)) => out.push((at.clone(), r)),
                        _ => refs(x, format!("{at}/{k}"), out),
                    }
                }
            }
            Value::Array(items) => {
                for (i, x) in items.iter().enumerate() {
                    refs(x, format!("{at}/{i}"), out);
                }
            }
            _ => {}
        }
    }

    #[test]
    fn the_openapi_document_lists_every_route() {
        let doc = document();
        let paths = doc["paths"].as_object().unwrap();
        let mut listed: Vec<&str> = paths.keys().map(String::as_str).collect();
        listed.sort();
        assert_eq!(
            listed,
            [
                "/healthz",
                "/metrics",
                "/openapi.json",
                "/readyz",
                "/v1/models",
                "/v1/models/jobs/{id}",
                "/v1/models/{name}",
                "/v1/models/{name}/schemes/{scheme}",
                "/v1/models/{name}/versions",
                "/v1/models/{name}/versions/{version}",
                "/v1/pose",
                "/v1/pose:batch",
            ]
        );
        assert_eq!(paths["/v1/models"].as_object().unwrap().len(), 2);
        assert!(doc["components"]["schemas"]["PoseRequest"].is_object());
        assert!(doc["components"]["schemas"]["ErrorBody"].is_object());
        assert!(doc["components"]["securitySchemes"]["admin_token"].is_object());
    }

    /// What OpenAPI 3.1 requires of every operation and what client generators rely on
    /// (openapi-spec-validator and openapi-python-client refused the document without the
    /// responses' descriptions; scripts/openapi-client.sh runs both on the served document).
    #[test]
    fn every_operation_is_complete() {
        let doc = document();
        assert!(doc["openapi"].as_str().unwrap().starts_with("3.1."));
        for field in ["title", "version"] {
            assert!(
                doc["info"][field].as_str().is_some_and(|s| !s.is_empty()),
                "info.{field}"
            );
        }
        let ops = operations(&doc);
        assert!(ops.len() >= doc["paths"].as_object().unwrap().len());
        let mut ids = std::collections::BTreeSet::new();
        for &(method, path, op) in &ops {
            let at = format!("{} {path}", method.to_uppercase());
            let id = op["operationId"].as_str().unwrap_or_default();
            assert!(!id.is_empty(), "{at}: no operationId");
            assert!(ids.insert(id), "{at}: operationId {id} given twice");
            let responses = op["responses"].as_object().unwrap();
            assert!(
                responses.keys().any(|s| s.starts_with('2')),
                "{at}: no 2xx response"
            );
            for (status, r) in responses {
                assert!(
                    status.len() == 3 && status.bytes().all(|b| b.is_ascii_digit()),
                    "{at}: status {status}"
                );
                assert!(
                    r["description"]
                        .as_str()
                        .is_some_and(|d| !d.trim().is_empty()),
                    "{at}: the {status} response has no description: {r}"
                );
            }
            // The path's template parameters and the declared path parameters are the same set.
            let template: std::collections::BTreeSet<&str> = path
                .split('{')
                .skip(1)
                .map(|s| s.split_once('}').unwrap().0)
                .collect();
            let params = op["parameters"]
                .as_array()
                .map(Vec::as_slice)
                .unwrap_or(&[]);
            let declared: std::collections::BTreeSet<&str> = params
                .iter()
                .filter(|p| p["in"] == "path")
                .map(|p| {
                    assert_eq!(p["required"], true, "{at}: path parameter {p} not required");
                    assert!(p["schema"].is_object(), "{at}: {p} without a schema");
                    p["name"].as_str().unwrap()
                })
                .collect();
            assert_eq!(template, declared, "{at}: template vs declared parameters");
            for s in op["security"].as_array().into_iter().flatten() {
                for scheme in s.as_object().unwrap().keys() {
                    assert!(
                        doc["components"]["securitySchemes"][scheme].is_object(),
                        "{at}: unknown security scheme {scheme}"
                    );
                }
            }
        }
    }

    /// The `$ref`s of `doc` that name nothing in it, with where they stand.
    fn dangling(doc: &Value) -> Vec<(String, &str)> {
        let mut found = Vec::new();
        refs(doc, String::new(), &mut found);
        found.retain(|(_, r)| {
            r.strip_prefix('#')
                .and_then(|pointer| doc.pointer(pointer))
                .is_none_or(Value::is_null)
        });
        found
    }

    #[test]
    fn every_reference_resolves() {
        let doc = document();
        let mut all = Vec::new();
        refs(&doc, String::new(), &mut all);
        assert!(all.len() > 20, "{} references", all.len());
        assert_eq!(dangling(&doc), [], "references that name nothing");
        // The check itself: a reference to a schema that is not there, or outside the document.
        let mut broken = doc.clone();
        broken["components"]["schemas"]
            .as_object_mut()
            .unwrap()
            .remove("ErrorBody");
        assert!(
            dangling(&broken)
                .iter()
                .any(|(_, r)| *r == "#/components/schemas/ErrorBody")
        );
        broken["components"]["schemas"]["X"] = serde_json::json!({"$ref": "other.json#/X"});
        assert!(dangling(&broken).iter().any(|(_, r)| *r == "other.json#/X"));
    }
}
