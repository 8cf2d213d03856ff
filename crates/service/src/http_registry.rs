//! The HTTP routes of the model registry: the versions of a model, activation (and rollback)
//! and deletion. Admin routes check the bearer token first ([`authorize`]).

use std::sync::Arc;

use axum::Json;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use serde::Serialize;
use utoipa::ToSchema;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};

use super::AppState;
use super::errors::{ApiError, ErrorBody, ErrorKind};
use super::http::{ModelSummary, VersionSummary};

type SharedState = Arc<AppState>;

/// `GET /v1/models/{name}/versions`.
#[derive(Debug, Serialize, ToSchema)]
pub struct VersionsResponse {
    pub name: String,
    /// The folder's active version; `null` if none was ever activated.
    pub active: Option<String>,
    pub versions: Vec<VersionSummary>,
}

/// The answer of an activation: the model now served.
#[derive(Debug, Serialize, ToSchema)]
pub struct ActivateResponse {
    #[serde(flatten)]
    pub model: ModelSummary,
}

/// The OpenAPI security scheme of the admin routes.
pub struct BearerAuth;

impl utoipa::Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "admin_token",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// Checks the admin bearer token of a request (401 / 403, see [`super::auth`]).
pub fn authorize(st: &AppState, headers: &HeaderMap) -> Result<(), ApiError> {
    st.admin.check(
        headers
            .get(header::AUTHORIZATION)
            .map(HeaderValue::as_bytes),
    )
}

/// A model's versions in the models folder (also for a model not served yet).
#[utoipa::path(get, path = "/v1/models/{name}/versions", tag = "registry",
    params(("name" = String, Path, description = "The model's folder name")),
    responses((status = 200, body = VersionsResponse), (status = 404, body = ErrorBody)))]
pub async fn list_versions(
    State(st): State<SharedState>,
    Path(name): Path<String>,
) -> Result<Json<VersionsResponse>, ApiError> {
    st.registry.refresh_catalog().await;
    versions_response(&st, &name).map(Json)
}

/// The versions of `name` from the catalog (shared with gRPC).
pub fn versions_response(st: &AppState, name: &str) -> Result<VersionsResponse, ApiError> {
    let catalog = st.registry.catalog();
    let set = st.registry.snapshot();
    let Some(stored) = catalog.models.get(name) else {
        return Err(ApiError::new(
            ErrorKind::NotFound,
            format!(
                "no model {name:?} in the models folder{}",
                if st.registry.dir().is_none() {
                    " (the server has no models folder)"
                } else {
                    ""
                }
            ),
        ));
    };
    let served = set.by_store(name).map(|m| &**m);
    Ok(VersionsResponse {
        name: name.into(),
        active: stored.active.clone(),
        versions: super::http::version_summaries(Some(stored), served),
    })
}

/// Activate a version: `POST /v1/models/{name}/versions/{version}:activate` (admin). Rolling
/// back is activating an older version.
#[utoipa::path(post, path = "/v1/models/{name}/versions/{version}", tag = "registry",
    params(("name" = String, Path, description = "The model's folder name"),
           ("version" = String, Path, description = "`<version>:activate`, e.g. `3:activate`")),
    security(("admin_token" = [])),
    responses(
        (status = 200, description = "Active and served here; other replicas follow within --registry-poll", body = ActivateResponse),
        (status = 401, body = ErrorBody), (status = 403, body = ErrorBody),
        (status = 404, description = "Unknown model or version", body = ErrorBody),
        (status = 409, description = "The version does not load, or no models folder", body = ErrorBody)))]
pub async fn version_action(
    State(st): State<SharedState>,
    Path((name, version)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Json<ActivateResponse>, ApiError> {
    authorize(&st, &headers)?;
    let Some(version) = version.strip_suffix(":activate") else {
        return Err(ApiError::new(
            ErrorKind::NotFound,
            format!(
                "no action in POST /v1/models/{name}/versions/{version}: to activate it, POST \
                 /v1/models/{name}/versions/{version}:activate"
            ),
        ));
    };
    let served = st.registry.activate(&name, version).await?;
    let set = st.registry.snapshot();
    Ok(Json(ActivateResponse {
        model: super::http::model_summary(&served, &set, &st.registry.catalog()),
    }))
}

/// Delete an inactive version (admin).
#[utoipa::path(delete, path = "/v1/models/{name}/versions/{version}", tag = "registry",
    params(("name" = String, Path, description = "The model's folder name"),
           ("version" = String, Path, description = "The version")),
    security(("admin_token" = [])),
    responses(
        (status = 204, description = "Deleted"),
        (status = 401, body = ErrorBody), (status = 403, body = ErrorBody),
        (status = 404, description = "Unknown model or version", body = ErrorBody),
        (status = 409, description = "The active version, the folder's own bundle or the built-in model", body = ErrorBody)))]
pub async fn delete_version(
    State(st): State<SharedState>,
    Path((name, version)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<StatusCode, ApiError> {
    authorize(&st, &headers)?;
    st.registry.delete(&name, &version).await?;
    Ok(StatusCode::NO_CONTENT)
}
