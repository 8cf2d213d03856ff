//! The model routes: the served models, a model folder's versions, activation (and rollback)
//! and deletion. Admin routes check the bearer token first ([`authorize`]).

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use facepose_app::App;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};

use super::error::{ErrorBody, HttpError};
use super::path::Segments;
use super::wire::{
    ActivateResponse, ModelSummary, ModelsResponse, ProvenanceSummary, SchemeResponse,
    VersionsResponse,
};

/// `GET /v1/models/{name}`: a model with its provenance.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelDetail {
    #[serde(flatten)]
    /// The model.
    pub summary: ModelSummary,
    /// Where the model came from: source files, the command that built it, notes.
    pub provenance: ProvenanceSummary,
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

/// Checks the admin bearer token of a request (401 / 403, see `facepose_app::auth`).
pub fn authorize(app: &App, headers: &HeaderMap) -> Result<(), HttpError> {
    Ok(app.authorize(
        headers
            .get_all(header::AUTHORIZATION)
            .iter()
            .map(HeaderValue::as_bytes),
    )?)
}

/// The loaded models.
#[utoipa::path(get, path = "/v1/models", tag = "models",
    responses((status = 200, description = "The loaded models and the default one", body = ModelsResponse)))]
pub async fn list_models(State(app): State<Arc<App>>) -> Json<ModelsResponse> {
    Json(app.models_view().into())
}

/// One model, with its provenance.
#[utoipa::path(get, path = "/v1/models/{name}", tag = "models",
    params(("name" = String, Path, description = "The model's name")),
    responses((status = 200, description = "The model and its provenance", body = ModelDetail), (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 404, description = "Unknown model", body = ErrorBody),
        (status = 422, description = "A name over 64 characters", body = ErrorBody)))]
pub async fn get_model(
    State(app): State<Arc<App>>,
    Segments(name): Segments<String>,
) -> Result<Json<ModelDetail>, HttpError> {
    let detail = app.model_detail(&name)?;
    Ok(Json(ModelDetail {
        summary: detail.model.into(),
        provenance: detail.provenance.into(),
    }))
}

/// A scheme the model serves: its points' names, the model's mean 3D shape in it (mm, model
/// frame) and its anchors, for clients that draw faces or synthesize test landmarks (the demo
/// page projects it at the pose a user picks).
#[utoipa::path(get, path = "/v1/models/{name}/schemes/{scheme}", tag = "models",
    params(("name" = String, Path, description = "The model's name"),
           ("scheme" = String, Path, description = "A scheme the model serves (`GET /v1/models/{name}` lists them)")),
    responses(
        (status = 200, description = "The scheme, with the model's mean shape in it", body = SchemeResponse),
        (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 404, description = "Unknown model, or a scheme the model does not serve (the message lists the ones it serves)", body = ErrorBody),
        (status = 422, description = "A model or scheme name over 64 characters", body = ErrorBody)))]
pub async fn get_scheme(
    State(app): State<Arc<App>>,
    Segments((name, scheme)): Segments<(String, String)>,
) -> Result<Json<SchemeResponse>, HttpError> {
    Ok(Json(app.scheme_detail(&name, &scheme)?.into()))
}

/// A model's versions in the models folder (also for a model not served yet).
#[utoipa::path(get, path = "/v1/models/{name}/versions", tag = "registry",
    params(("name" = String, Path, description = "The model's folder name")),
    responses((status = 200, description = "The model's versions and the active one", body = VersionsResponse), (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 404, description = "No such model in the models folder", body = ErrorBody)))]
pub async fn list_versions(
    State(app): State<Arc<App>>,
    Segments(name): Segments<String>,
) -> Result<Json<VersionsResponse>, HttpError> {
    Ok(Json(app.versions(&name).await?.into()))
}

/// Activate a version: `POST /v1/models/{name}/versions/{version}:activate` (admin). Rolling
/// back is activating an older version.
#[utoipa::path(post, path = "/v1/models/{name}/versions/{version}", tag = "registry",
    operation_id = "activate_version",
    params(("name" = String, Path, description = "The model's folder name"),
           ("version" = String, Path, description = "The version followed by `:activate`: `3:activate` activates version 3",
            pattern = "^[^:/]+:activate$")),
    security(("admin_token" = [])),
    responses(
        (status = 200, description = "Active and served here; other replicas follow within --registry-poll", body = ActivateResponse),
        (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 401, description = "Missing, malformed or wrong admin token (`unauthenticated`)", body = ErrorBody),
        (status = 403, description = "Admin routes disabled: the server has no admin token (`forbidden`)", body = ErrorBody),
        (status = 404, description = "Unknown model or version", body = ErrorBody),
        (status = 422, description = "Not a model name (1-64 of a-z, 0-9, `_`, `.`, `-`) or not a version id", body = ErrorBody),
        (status = 409, description = "The version does not load, or no models folder", body = ErrorBody)))]
pub async fn version_action(
    State(app): State<Arc<App>>,
    Segments((name, version)): Segments<(String, String)>,
    headers: HeaderMap,
) -> Result<Json<ActivateResponse>, HttpError> {
    authorize(&app, &headers)?;
    let Some(version) = version.strip_suffix(":activate") else {
        return Err(HttpError::NotFound(format!(
            "no action in POST /v1/models/{name}/versions/{version}: to activate it, POST \
             /v1/models/{name}/versions/{version}:activate"
        )));
    };
    let model = app.activate(&name, version).await?;
    Ok(Json(ActivateResponse {
        model: model.into(),
    }))
}

/// Delete an inactive version (admin).
#[utoipa::path(delete, path = "/v1/models/{name}/versions/{version}", tag = "registry",
    params(("name" = String, Path, description = "The model's folder name"),
           ("version" = String, Path, description = "The version")),
    security(("admin_token" = [])),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 401, description = "Missing, malformed or wrong admin token (`unauthenticated`)", body = ErrorBody),
        (status = 403, description = "Admin routes disabled: the server has no admin token (`forbidden`)", body = ErrorBody),
        (status = 404, description = "Unknown model or version", body = ErrorBody),
        (status = 422, description = "Not a model name (1-64 of a-z, 0-9, `_`, `.`, `-`) or not a version id", body = ErrorBody),
        (status = 409, description = "The active version, the folder's own bundle or the built-in model", body = ErrorBody)))]
pub async fn delete_version(
    State(app): State<Arc<App>>,
    Segments((name, version)): Segments<(String, String)>,
    headers: HeaderMap,
) -> Result<StatusCode, HttpError> {
    authorize(&app, &headers)?;
    app.delete_version(&name, &version).await?;
    Ok(StatusCode::NO_CONTENT)
}
