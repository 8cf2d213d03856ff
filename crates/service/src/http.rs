//! The HTTP JSON API: routes, request and response types (the OpenAPI document is generated
//! from them, `GET /openapi.json`), the JSON body reader with its error classes, and the
//! middleware (request id, metrics and logs on every route; concurrency and time limits on the
//! `/v1` routes).

use std::sync::Arc;
use std::time::Instant;

use axum::body::{Body, Bytes};
use axum::extract::{MatchedPath, Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method as HttpMethod, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Json, Router};
use http_body_util::BodyExt;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use tracing::Instrument;
use utoipa::{OpenApi, ToSchema};

use super::AppState;
use super::config::Limits;
use super::errors::{ApiError, ErrorBody, ErrorKind};
use super::http_registry::{self, BearerAuth};
use super::http_retrain;
use super::metrics::{self, FaceTally};
use super::pose::{FaceSpec, estimate_face, for_each_face, run_maybe_blocking};
use super::registry::{Catalog, ModelSet, ServedModel, StoredVersions};
use super::request_json::{read_batch_request, read_pose_request};
use facepose_core::estimate::Intrinsics;
use facepose_core::record::{Landmarks, PoseRecord};

type SharedState = Arc<AppState>;

// ---------------------------------------------------------------------------------------------
// Wire types

/// Pinhole camera intrinsics in pixels (image x right, y down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl From<Camera> for Intrinsics {
    fn from(c: Camera) -> Self {
        Intrinsics {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
        }
    }
}

/// A client's identifier for a face (a string or a number), echoed in its result.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
#[serde(untagged)]
pub enum FaceId {
    Text(String),
    Integer(i64),
    Number(f64),
}

impl<'de> Deserialize<'de> for FaceId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = FaceId;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("id as a string or a number")
            }
            fn visit_str<E>(self, v: &str) -> Result<FaceId, E> {
                Ok(FaceId::Text(v.to_string()))
            }
            fn visit_i64<E>(self, v: i64) -> Result<FaceId, E> {
                Ok(FaceId::Integer(v))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<FaceId, E> {
                Ok(i64::try_from(v).map_or(FaceId::Number(v as f64), FaceId::Integer))
            }
            fn visit_f64<E>(self, v: f64) -> Result<FaceId, E> {
                Ok(FaceId::Number(v))
            }
        }
        d.deserialize_any(V)
    }
}

/// `POST /v1/pose`: one face.
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PoseRequest {
    /// Image pixels (origin top-left, x right, y down), in the scheme's order; `null` for a
    /// point that could not be found.
    #[schema(value_type = Vec<Option<Vec<f64>>>, example = json!([[231.5, 310.0], null]))]
    pub landmarks: Landmarks,
    /// The landmark scheme (`ibug68`, `inner51`, `five`, ...); default: the model's own.
    #[serde(default)]
    pub scheme: Option<String>,
    /// `auto` (default), `fit`, `fit-shape`, `regression` or `geometry`.
    #[serde(default)]
    pub method: Option<String>,
    /// The model by name; default: `default`.
    #[serde(default)]
    pub model: Option<String>,
    /// Camera intrinsics: the fit methods then refine the pose under full perspective.
    #[serde(default)]
    pub camera: Option<Camera>,
    /// How the landmarks were made: `projected` (default: every landmark is its 3D point's
    /// projection, as 3D-style annotations and 3DMM fitters give) or `contour` (2D-style, as
    /// 300-W / dlib: hidden jaw points sit on the visible outline and the fit leaves them out).
    #[serde(default)]
    pub landmark_style: Option<String>,
    /// Echoed in the response.
    #[serde(default)]
    pub id: Option<FaceId>,
}

/// A pose with its scheme and model.
#[derive(Debug, Serialize, ToSchema)]
pub struct PoseResponse {
    #[serde(flatten)]
    pub pose: PoseRecord,
    /// The scheme of the input landmarks.
    pub scheme: String,
    /// The model's name and version.
    pub model: String,
    pub model_version: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<FaceId>,
}

/// One face of a batch; `scheme`, `method` and `camera` default to the batch's.
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BatchFace {
    #[schema(value_type = Vec<Option<Vec<f64>>>)]
    pub landmarks: Landmarks,
    #[serde(default)]
    pub scheme: Option<String>,
    #[serde(default)]
    pub method: Option<String>,
    #[serde(default)]
    pub camera: Option<Camera>,
    #[serde(default)]
    pub landmark_style: Option<String>,
    #[serde(default)]
    pub id: Option<FaceId>,
}

/// `POST /v1/pose:batch`: many faces, at most `--max-batch` (1000 by default).
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BatchRequest {
    pub faces: Vec<BatchFace>,
    /// Defaults for every face.
    #[serde(default)]
    pub scheme: Option<String>,
    #[serde(default)]
    pub method: Option<String>,
    #[serde(default)]
    pub camera: Option<Camera>,
    #[serde(default)]
    pub landmark_style: Option<String>,
    /// One model for the whole batch; default: `default`.
    #[serde(default)]
    pub model: Option<String>,
}

/// The result for one face of a batch: its pose, or its error.
#[derive(Debug, Serialize, ToSchema)]
#[serde(untagged)]
pub enum BatchResult {
    Pose(BatchPose),
    Error(BatchError),
}

#[derive(Debug, Serialize, ToSchema)]
pub struct BatchPose {
    #[serde(flatten)]
    pub pose: PoseRecord,
    pub scheme: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<FaceId>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct BatchError {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<FaceId>,
    pub error: ApiError,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct BatchResponse {
    pub model: String,
    pub model_version: String,
    pub succeeded: u64,
    pub failed: u64,
    /// One per face, in order.
    pub results: Vec<BatchResult>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct SchemeSummary {
    pub name: String,
    pub points: usize,
}

/// A loaded model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelSummary {
    pub name: String,
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// The model's own scheme (the default scheme of requests).
    pub scheme: String,
    /// Every scheme it serves, its own first.
    pub schemes: Vec<SchemeSummary>,
    /// The methods it supports.
    pub methods: Vec<String>,
    /// `sha256:<hex>` of the bundle.
    pub checksum: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// Whether requests that name no model use it.
    pub default: bool,
    /// Its versions in the models folder (empty without one): the folder's active one and the
    /// one this replica serves are marked.
    pub versions: Vec<VersionSummary>,
}

/// One version of a model in the models folder.
#[derive(Debug, Serialize, ToSchema)]
pub struct VersionSummary {
    pub version: String,
    /// RFC 3339.
    pub created: String,
    pub checksum: String,
    /// The model's own scheme in that version.
    pub scheme: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// The folder's active version: what every replica serves once it has followed the
    /// folder.
    pub active: bool,
    /// The version this replica serves.
    pub served: bool,
    /// Deployed with the folder (`DIR/<name>/model.json`) or built in: not deletable through
    /// the API.
    pub fixed: bool,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct SourceSummary {
    pub path: String,
    pub sha256: String,
    pub shapes: usize,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ProvenanceSummary {
    pub command: String,
    pub notes: String,
    pub sources: Vec<SourceSummary>,
}

/// `GET /v1/models/{name}`: a model with its provenance.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelDetail {
    #[serde(flatten)]
    pub summary: ModelSummary,
    pub provenance: ProvenanceSummary,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ModelsResponse {
    pub default_model: String,
    pub models: Vec<ModelSummary>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Status {
    /// `alive`, `ready` or `draining`.
    pub status: &'static str,
}

/// The versions of a models folder entry, as the API lists them.
pub fn version_summaries(
    stored: Option<&StoredVersions>,
    served: Option<&ServedModel>,
) -> Vec<VersionSummary> {
    let Some(stored) = stored else {
        return vec![];
    };
    stored
        .versions
        .iter()
        .map(|v| VersionSummary {
            version: v.version.clone(),
            created: v.created.clone(),
            checksum: v.checksum.clone(),
            scheme: v.scheme.clone(),
            source: v.source.clone(),
            active: stored.active.as_deref() == Some(v.version.as_str()),
            served: served.is_some_and(|m| m.version == v.version),
            fixed: v.fixed,
        })
        .collect()
}

/// A served model as the API lists it, with its versions from the catalog.
pub fn model_summary(m: &ServedModel, set: &ModelSet, catalog: &Catalog) -> ModelSummary {
    let stored = m.store.as_ref().and_then(|s| catalog.models.get(s));
    ModelSummary {
        name: m.name.clone(),
        version: m.version.clone(),
        created: m.created.clone(),
        scheme: m.scheme().to_string(),
        schemes: m
            .schemes()
            .map(|(name, points)| SchemeSummary {
                name: name.to_string(),
                points,
            })
            .collect(),
        methods: m.methods().iter().map(|x| x.to_string()).collect(),
        checksum: m.checksum.clone(),
        source: m.source.to_string(),
        default: m.name == set.default_name(),
        versions: version_summaries(stored, Some(m)),
    }
}

// ---------------------------------------------------------------------------------------------
// JSON bodies

/// Bodies up to this size (about six 68-point faces) are parsed and estimated inline; larger
/// batches go to the blocking pool.
const INLINE_BODY: usize = 16 * 1024;

pub(super) fn require_json(headers: &HeaderMap) -> Result<(), ApiError> {
    let Some(ct) = headers.get(header::CONTENT_TYPE) else {
        return Err(ApiError::new(
            ErrorKind::UnsupportedMediaType,
            "missing Content-Type: send the body as JSON with Content-Type: application/json",
        ));
    };
    let ct = ct.to_str().unwrap_or("");
    let mime = ct.split(';').next().unwrap_or("").trim();
    let ends = |suffix: &str| {
        mime.len() >= suffix.len()
            && mime.as_bytes()[mime.len() - suffix.len()..].eq_ignore_ascii_case(suffix.as_bytes())
    };
    let starts = |prefix: &str| {
        mime.as_bytes()
            .get(..prefix.len())
            .is_some_and(|p| p.eq_ignore_ascii_case(prefix.as_bytes()))
    };
    if mime.eq_ignore_ascii_case("application/json") || (starts("application/") && ends("+json")) {
        Ok(())
    } else {
        Err(ApiError::new(
            ErrorKind::UnsupportedMediaType,
            format!("Content-Type {ct:?} is not JSON: send Content-Type: application/json"),
        ))
    }
}

/// How much of an over-limit body is read and thrown away before the 413 goes out. Most
/// clients send the whole body before reading the answer (few use `Expect: 100-continue`); a
/// server that answers and closes early makes them see a reset connection instead of the 413.
const DRAIN_LIMIT: u64 = 4 << 20;
/// How long draining an over-limit body may take before the connection is dropped.
const DRAIN_TIME: std::time::Duration = std::time::Duration::from_secs(2);

/// The body, up to `--max-body` bytes (see [`read_body_limited`]).
async fn read_body(headers: &HeaderMap, body: Body, limit: usize) -> Result<Bytes, ApiError> {
    read_body_limited(headers, body, limit, "--max-body", "split the batch").await
}

/// The body, up to `limit` bytes: 413 above, its message naming `flag` and saying what to do
/// (`hint`); an over-limit body of up to [`DRAIN_LIMIT`] is drained first so the client reads
/// the answer.
pub(super) async fn read_body_limited(
    headers: &HeaderMap,
    body: Body,
    limit: usize,
    flag: &str,
    hint: &str,
) -> Result<Bytes, ApiError> {
    let too_large = |len: Option<u64>| {
        ApiError::new(
            ErrorKind::PayloadTooLarge,
            match len {
                Some(n) => format!(
                    "request body of {n} bytes is over the limit of {limit} bytes ({flag}); {hint}"
                ),
                None => format!("request body is over the limit of {limit} bytes ({flag}); {hint}"),
            },
        )
    };
    let unreadable = |e: axum::Error| {
        ApiError::new(
            ErrorKind::MalformedJson,
            format!("could not read the request body: {e}"),
        )
    };
    let declared = declared_length(headers);
    if let Some(n) = declared.filter(|&n| n > limit as u64) {
        discard_body(headers, body).await;
        return Err(too_large(Some(n)));
    }
    let mut first: Option<Bytes> = None;
    let mut rest: Vec<u8> = Vec::new();
    let mut body = body;
    while let Some(frame) = body.frame().await {
        let Ok(data) = frame.map_err(unreadable)?.into_data() else {
            continue; // trailers
        };
        let seen = first.as_ref().map_or(0, Bytes::len) + rest.len() + data.len();
        if seen > limit {
            drain(body, seen as u64).await;
            return Err(too_large(None));
        }
        match &first {
            None => first = Some(data),
            Some(f) => {
                if rest.is_empty() {
                    rest.reserve(declared.map_or(2 * f.len(), |n| n as usize));
                    rest.extend_from_slice(f);
                }
                rest.extend_from_slice(&data);
            }
        }
    }
    Ok(if rest.is_empty() {
        first.unwrap_or_default()
    } else {
        Bytes::from(rest)
    })
}

/// Throws away the body of a request refused before reading it (an admin route without the
/// token, say), within the same bounds as an over-limit body, so that the client reads the
/// answer rather than a reset connection.
pub(super) async fn discard_body(headers: &HeaderMap, body: Body) {
    // A client waiting for `100 Continue` reads the answer without sending the body.
    let waits = headers
        .get(header::EXPECT)
        .is_some_and(|v| v.as_bytes().eq_ignore_ascii_case(b"100-continue"));
    if !waits && declared_length(headers).is_none_or(|n| n <= DRAIN_LIMIT) {
        drain(body, 0).await;
    }
}

/// The body length the request declares (`Content-Length`), if any.
fn declared_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// Reads and discards the rest of a body, up to [`DRAIN_LIMIT`] bytes in all (counting `seen`)
/// and [`DRAIN_TIME`].
async fn drain(mut body: Body, mut seen: u64) {
    let _ = tokio::time::timeout(DRAIN_TIME, async {
        while seen <= DRAIN_LIMIT {
            match body.frame().await {
                Some(Ok(frame)) => {
                    seen += frame.data_ref().map_or(0, |d| d.len() as u64);
                }
                _ => break,
            }
        }
    })
    .await;
}

/// Parses a `POST /v1/pose` body: in one pass when it has the usual shape
/// ([`read_pose_request`]), else with serde and its precise errors ([`parse_json`]).
pub fn parse_pose_request(bytes: &[u8]) -> Result<PoseRequest, ApiError> {
    read_pose_request(bytes).map_or_else(|| parse_json(bytes), Ok)
}

/// [`parse_pose_request`] for `POST /v1/pose:batch`.
pub fn parse_batch_request(bytes: &[u8]) -> Result<BatchRequest, ApiError> {
    read_batch_request(bytes).map_or_else(|| parse_json(bytes), Ok)
}

/// Parses a JSON body. Syntax errors are 400; well-formed JSON with unusable values (wrong
/// types, unknown or missing fields, NaN or infinite numbers) is 422, with the path to the bad
/// value.
pub fn parse_json<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ApiError> {
    match bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') => {}
        None => return Err(empty_body()),
        // Not an object: say so if it is valid JSON (serde would read an array as a struct).
        Some(_) => {
            if let Err(e) = serde_json::from_slice::<serde::de::IgnoredAny>(bytes) {
                return Err(json_error::<T>(bytes, e));
            }
            return Err(ApiError::invalid(
                "the body must be a JSON object, e.g. {\"landmarks\": [[x, y], ...]}",
            ));
        }
    }
    match serde_json::from_slice::<T>(bytes) {
        Ok(v) => Ok(v),
        Err(e) => Err(json_error::<T>(bytes, e)),
    }
}

fn empty_body() -> ApiError {
    ApiError::new(
        ErrorKind::MalformedJson,
        "empty request body: send a JSON object, e.g. {\"landmarks\": [[x, y], ...]}",
    )
}

fn json_error<T: DeserializeOwned>(bytes: &[u8], e: serde_json::Error) -> ApiError {
    use serde_json::error::Category;
    match e.classify() {
        Category::Data => ApiError::invalid(format!("{}{e}", error_path::<T>(bytes))),
        Category::Syntax | Category::Eof | Category::Io => {
            let msg = e.to_string();
            if bytes.iter().all(u8::is_ascii_whitespace) {
                empty_body()
            } else if msg.starts_with("number out of range") {
                ApiError::invalid(format!("a number is too large for a 64-bit float ({msg})"))
            } else if non_finite_literal_at(bytes, e.line(), e.column()) {
                ApiError::invalid(format!(
                    "{}NaN and Infinity are not JSON numbers ({msg}): coordinates must be finite; \
                     send null for a missing landmark (and leave out a 3D shape with a point you \
                     do not have)",
                    error_path::<T>(bytes)
                ))
            } else {
                ApiError::new(ErrorKind::MalformedJson, format!("malformed JSON: {msg}"))
            }
        }
    }
}

/// `"path.to[3].value: "` where parsing `bytes` as `T` fails (empty at the top level). Parses
/// again, tracking the path, only on this error path.
fn error_path<T: DeserializeOwned>(bytes: &[u8]) -> String {
    let de = &mut serde_json::Deserializer::from_slice(bytes);
    match serde_path_to_error::deserialize::<_, T>(de) {
        Err(pe) if pe.path().to_string() != "." => format!("{}: ", pe.path()),
        _ => String::new(),
    }
}

/// Whether the text at a 1-based (line, column) error position is a NaN or Infinity literal
/// (as Python's `json.dumps` writes them).
fn non_finite_literal_at(bytes: &[u8], line: usize, column: usize) -> bool {
    let Some(start) = bytes
        .split(|&b| b == b'\n')
        .take(line.saturating_sub(1))
        .map(|l| l.len() + 1)
        .sum::<usize>()
        .checked_add(column.saturating_sub(1))
    else {
        return false;
    };
    let from = start.saturating_sub(1).min(bytes.len());
    let to = (start + 10).min(bytes.len());
    let window = String::from_utf8_lossy(&bytes[from..to]).to_ascii_lowercase();
    window.contains("nan") || window.contains("inf")
}

/// A JSON response (200) from bytes serialized elsewhere.
fn json_bytes(body: Vec<u8>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

fn to_json<T: Serialize>(v: &T) -> Result<Vec<u8>, ApiError> {
    // A pose with 68 points is about 800 bytes: one allocation rather than a few regrowths.
    let mut out = Vec::with_capacity(1024);
    serde_json::to_writer(&mut out, v)
        .map_err(|e| ApiError::internal(format!("response serialization: {e}")))?;
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Handlers

/// The deadline of a `/v1` request, set by the limits middleware.
#[derive(Debug, Clone, Copy)]
pub struct Deadline(pub Instant);

/// Estimate the head pose of one face.
#[utoipa::path(
    post, path = "/v1/pose", tag = "pose",
    request_body = PoseRequest,
    responses(
        (status = 200, description = "The pose", body = PoseResponse),
        (status = 400, description = "Malformed JSON", body = ErrorBody),
        (status = 404, description = "Unknown model", body = ErrorBody),
        (status = 413, description = "Body over --max-body", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Unusable values: landmark count, NaN/inf, too few or degenerate points, unknown scheme or method, bad camera", body = ErrorBody),
        (status = 429, description = "Overloaded: retry with backoff", body = ErrorBody),
        (status = 503, description = "Timed out", body = ErrorBody),
    )
)]
pub async fn pose(State(st): State<SharedState>, req: Request) -> Result<Response, ApiError> {
    // The request whole rather than a `HeaderMap` extractor, which would copy the headers.
    let (parts, body) = req.into_parts();
    require_json(&parts.headers)?;
    let bytes = read_body(&parts.headers, body, st.limits.max_body).await?;
    let req = parse_pose_request(&bytes)?;
    let models = st.registry.snapshot();
    let model = models.get(req.model.as_deref())?;
    let result = estimate_face(
        model,
        &FaceSpec {
            landmarks: &req.landmarks.0,
            scheme: req.scheme.as_deref(),
            method: req.method.as_deref(),
            camera: req.camera.map(Into::into),
            style: req.landmark_style.as_deref(),
        },
    );
    let mut tally = FaceTally::default();
    match &result {
        Ok(p) => tally.ok(p.record.method),
        Err(e) => tally.err(e.kind),
    }
    tally.record("http");
    let p = result?;
    Ok(json_bytes(to_json(&PoseResponse {
        pose: p.record,
        scheme: p.scheme,
        model: model.name.clone(),
        model_version: model.version.clone(),
        id: req.id,
    })?))
}

/// Estimate many faces; each gets its pose or its own error.
#[utoipa::path(
    post, path = "/v1/pose:batch", tag = "pose",
    request_body = BatchRequest,
    responses(
        (status = 200, description = "One result per face, in order", body = BatchResponse),
        (status = 400, description = "Malformed JSON", body = ErrorBody),
        (status = 404, description = "Unknown model", body = ErrorBody),
        (status = 413, description = "Body over --max-body or more faces than --max-batch", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Unusable request structure", body = ErrorBody),
        (status = 429, description = "Overloaded: retry with backoff", body = ErrorBody),
        (status = 503, description = "Timed out", body = ErrorBody),
    )
)]
pub async fn pose_batch(
    State(st): State<SharedState>,
    Extension(deadline): Extension<Deadline>,
    req: Request,
) -> Result<Response, ApiError> {
    let (parts, body) = req.into_parts();
    require_json(&parts.headers)?;
    let bytes = read_body(&parts.headers, body, st.limits.max_body).await?;
    let models = st.registry.snapshot();
    let limits = st.limits;
    let inline = bytes.len() <= INLINE_BODY;
    let body = run_maybe_blocking(inline, move || {
        answer_batch(bytes, &models, limits, Some(deadline.0))
    })
    .await??;
    Ok(json_bytes(body))
}

/// The answer to a `POST /v1/pose:batch` body: parse, estimate each face against `models`
/// (stopping at `deadline`), serialize. Pure but for the metrics; the handler runs it off the
/// async workers, and `examples/loadgen.rs ceiling` runs it with no network.
pub fn answer_batch(
    bytes: Bytes,
    models: &ModelSet,
    limits: Limits,
    deadline: Option<Instant>,
) -> Result<Vec<u8>, ApiError> {
    let req = parse_batch_request(&bytes)?;
    drop(bytes);
    if req.faces.len() > limits.max_batch {
        return Err(ApiError::batch_too_large(req.faces.len(), limits.max_batch));
    }
    let model = models.get(req.model.as_deref())?;
    let mut tally = FaceTally::default();
    let results = for_each_face(req.faces, deadline, |face| {
        let spec = FaceSpec {
            landmarks: &face.landmarks.0,
            scheme: face.scheme.as_deref().or(req.scheme.as_deref()),
            method: face.method.as_deref().or(req.method.as_deref()),
            camera: face.camera.or(req.camera).map(Into::into),
            style: face
                .landmark_style
                .as_deref()
                .or(req.landmark_style.as_deref()),
        };
        match estimate_face(model, &spec) {
            Ok(p) => {
                tally.ok(p.record.method);
                BatchResult::Pose(BatchPose {
                    pose: p.record,
                    scheme: p.scheme,
                    id: face.id,
                })
            }
            Err(error) => {
                tally.err(error.kind);
                BatchResult::Error(BatchError { id: face.id, error })
            }
        }
    })
    .map_err(|_| ApiError::timeout(limits.request_timeout))?;
    tally.record("http");
    to_json(&BatchResponse {
        model: model.name.clone(),
        model_version: model.version.clone(),
        succeeded: tally.succeeded(),
        failed: tally.failed(),
        results,
    })
}

/// The loaded models.
#[utoipa::path(get, path = "/v1/models", tag = "models",
    responses((status = 200, body = ModelsResponse)))]
pub async fn list_models(State(st): State<SharedState>) -> Json<ModelsResponse> {
    let set = st.registry.snapshot();
    let catalog = st.registry.catalog();
    Json(ModelsResponse {
        default_model: set.default_name().to_string(),
        models: set
            .iter()
            .map(|m| model_summary(m, &set, &catalog))
            .collect(),
    })
}

/// One model, with its provenance.
#[utoipa::path(get, path = "/v1/models/{name}", tag = "models",
    params(("name" = String, Path, description = "The model's name")),
    responses((status = 200, body = ModelDetail), (status = 404, body = ErrorBody)))]
pub async fn get_model(
    State(st): State<SharedState>,
    Path(name): Path<String>,
) -> Result<Json<ModelDetail>, ApiError> {
    let set = st.registry.snapshot();
    let m = set.get(Some(&name))?;
    Ok(Json(ModelDetail {
        summary: model_summary(m, &set, &st.registry.catalog()),
        provenance: ProvenanceSummary {
            command: m.provenance.command.clone(),
            notes: m.provenance.notes.clone(),
            sources: m
                .provenance
                .sources
                .iter()
                .map(|s| SourceSummary {
                    path: s.path.clone(),
                    sha256: s.sha256.clone(),
                    shapes: s.shapes,
                })
                .collect(),
        },
    }))
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "operations",
    responses((status = 200, body = Status)))]
pub async fn healthz() -> Response {
    json_bytes(br#"{"status":"alive"}"#.to_vec())
}

/// Readiness: models loaded and not draining (503 while shutting down). While an active
/// version of the models folder fails to load here, the answer is still 200 (the previous
/// version serves) and lists the problem under `problems`.
#[utoipa::path(get, path = "/readyz", tag = "operations",
    responses((status = 200, body = Status), (status = 503, body = Status)))]
pub async fn readyz(State(st): State<SharedState>) -> Response {
    if st.lifecycle.is_ready() {
        let problems = st.registry.problems();
        if problems.is_empty() {
            return json_bytes(br#"{"status":"ready"}"#.to_vec());
        }
        let problems: Vec<_> = problems
            .iter()
            .map(|p| serde_json::json!({"model": p.model, "version": p.version, "message": p.message}))
            .collect();
        Json(serde_json::json!({"status": "ready", "problems": problems})).into_response()
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Status { status: "draining" }),
        )
            .into_response()
    }
}

/// Prometheus metrics (text exposition format).
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, content_type = "text/plain; version=0.0.4", body = String)))]
pub async fn metrics_text(State(st): State<SharedState>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        st.metrics.render(),
    )
        .into_response()
}

/// This document.
#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, content_type = "application/json", body = Object)))]
pub async fn openapi(State(st): State<SharedState>) -> Response {
    json_bytes(st.openapi.as_bytes().to_vec())
}

/// The OpenAPI document of the HTTP API.
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
    paths(pose, pose_batch, list_models, get_model, http_retrain::retrain, http_retrain::get_job, http_retrain::job_action,
        http_registry::list_versions, http_registry::version_action, http_registry::delete_version,
        healthz, readyz, metrics_text, openapi),
    components(schemas(ErrorBody, ApiError, ErrorKind)),
    modifiers(&BearerAuth),
    tags(
        (name = "pose", description = "Pose estimation"),
        (name = "models", description = "Loaded model bundles"),
        (name = "registry", description = "Retraining, model versions, activation (admin routes need a bearer token)"),
        (name = "operations", description = "Health, readiness, metrics")
    )
)]
pub struct ApiDoc;

/// The OpenAPI document as JSON text.
pub fn openapi_json() -> String {
    ApiDoc::openapi()
        .to_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

// ---------------------------------------------------------------------------------------------
// Router and middleware

/// The HTTP routes: the `/v1` API under the concurrency and time limits, the operational routes
/// without them.
pub fn router(state: SharedState) -> Router {
    Router::new()
        .route("/v1/pose", post(pose))
        .route("/v1/pose:batch", post(pose_batch))
        .route("/v1/models", get(list_models).post(http_retrain::retrain))
        .route("/v1/models/{name}", get(get_model))
        .route(
            "/v1/models/jobs/{id}",
            get(http_retrain::get_job).post(http_retrain::job_action),
        )
        .route(
            "/v1/models/{name}/versions",
            get(http_registry::list_versions),
        )
        .route(
            "/v1/models/{name}/versions/{version}",
            post(http_registry::version_action).delete(http_registry::delete_version),
        )
        .route_layer(middleware::from_fn_with_state(state.clone(), limits))
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics_text))
        .route("/openapi.json", get(openapi))
        .method_not_allowed_fallback(method_not_allowed)
        .with_state(state)
}

/// Refuses at once above the concurrency limit (429) and ends requests at the time limit
/// (503; `--upload-timeout` for retraining uploads). Estimation of a batch also stops at the
/// deadline (see [`for_each_face`]).
async fn limits(State(st): State<SharedState>, mut req: Request, next: Next) -> Response {
    let Ok(_permit) = st.permits.clone().try_acquire_owned() else {
        return ApiError::overloaded(st.limits.max_concurrency).into_response();
    };
    let path = req.uri().path();
    let upload = req.method() == HttpMethod::POST && path == "/v1/models";
    let change = path.starts_with("/v1/models/") && path.contains("/versions/");
    let timeout = if upload {
        st.limits.upload_timeout
    } else {
        st.limits.request_timeout
    };
    req.extensions_mut()
        .insert(Deadline(Instant::now() + timeout));
    match tokio::time::timeout(timeout, next.run(req)).await {
        Ok(resp) => resp,
        Err(_) if upload => ApiError::upload_timeout(timeout).into_response(),
        Err(_) if change => ApiError::change_timeout(timeout).into_response(),
        Err(_) => ApiError::timeout(timeout).into_response(),
    }
}

async fn method_not_allowed(method: HttpMethod, uri: axum::http::Uri) -> ApiError {
    ApiError::new(
        ErrorKind::MethodNotAllowed,
        format!(
            "method {method} is not allowed on {}; see /openapi.json",
            uri.path()
        ),
    )
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
    ApiError::new(
        ErrorKind::NotFound,
        format!(
            "no route {} {}; see /openapi.json",
            req.method(),
            req.uri().path()
        ),
    )
    .into_response()
}

fn is_grpc(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/grpc"))
}

/// The route template as a fixed label (bounded cardinality).
fn route_label(path: Option<&MatchedPath>) -> &'static str {
    match path.map(MatchedPath::as_str) {
        Some("/v1/pose") => "/v1/pose",
        Some("/v1/pose:batch") => "/v1/pose:batch",
        Some("/v1/models") => "/v1/models",
        Some("/v1/models/{name}") => "/v1/models/{name}",
        Some("/v1/models/jobs/{id}") => "/v1/models/jobs/{id}",
        Some("/v1/models/{name}/versions") => "/v1/models/{name}/versions",
        Some("/v1/models/{name}/versions/{version}") => "/v1/models/{name}/versions/{version}",
        Some("/healthz") => "/healthz",
        Some("/readyz") => "/readyz",
        Some("/metrics") => "/metrics",
        Some("/openapi.json") => "/openapi.json",
        _ => "unmatched",
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

/// On every request (HTTP and gRPC): the request id (echoed, and in the log span), then for
/// HTTP the metrics and a log line (errors at warn/error, the rest at debug).
pub async fn observe(mut req: Request, next: Next) -> Response {
    let started = Instant::now();
    let id = request_id(req.headers());
    let grpc = is_grpc(req.headers());
    let route = route_label(req.extensions().get::<MatchedPath>());
    let method = method_label(req.method());
    let span = tracing::info_span!(
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
        metrics::http_request(route, method, status.as_u16(), elapsed);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_content_types_are_recognized() {
        let with = |ct: &str| {
            let mut h = HeaderMap::new();
            h.insert(header::CONTENT_TYPE, HeaderValue::from_str(ct).unwrap());
            require_json(&h).is_ok()
        };
        for ok in [
            "application/json",
            "Application/JSON; charset=utf-8",
            " application/json ;x=y",
            "application/problem+json",
            "APPLICATION/VND.API+JSON",
        ] {
            assert!(with(ok), "{ok}");
        }
        for bad in [
            "text/plain",
            "application/jsonx",
            "+json",
            "application/",
            "json",
            "",
        ] {
            assert!(!with(bad), "{bad}");
        }
        assert!(require_json(&HeaderMap::new()).is_err());
    }

    #[test]
    fn json_errors_are_classified() {
        let cases: [(&[u8], ErrorKind, &str); 9] = [
            (b"", ErrorKind::MalformedJson, "empty request body"),
            (b"  \n", ErrorKind::MalformedJson, "empty request body"),
            (
                b"{\"landmarks\": [",
                ErrorKind::MalformedJson,
                "malformed JSON",
            ),
            (
                b"{\"landmarks\": [[1, NaN]]}",
                ErrorKind::InvalidArgument,
                "NaN and Infinity",
            ),
            (
                b"{\"landmarks\": [[1, -Infinity]]}",
                ErrorKind::InvalidArgument,
                "NaN and Infinity",
            ),
            (
                b"{\"landmarks\": [[1, 1e999]]}",
                ErrorKind::InvalidArgument,
                "out of range",
            ),
            (
                b"{\"landmarks\": 5}",
                ErrorKind::InvalidArgument,
                "landmarks: expected an array",
            ),
            (
                b"{\"landmarks\": [], \"methd\": 1}",
                ErrorKind::InvalidArgument,
                "unknown field `methd`",
            ),
            (
                b"[1, 2]",
                ErrorKind::InvalidArgument,
                "must be a JSON object",
            ),
        ];
        for (body, kind, want) in cases {
            let e = parse_json::<PoseRequest>(body).unwrap_err();
            assert_eq!(e.kind, kind, "{}: {e}", String::from_utf8_lossy(body));
            assert!(
                e.message.contains(want),
                "{}: {e}",
                String::from_utf8_lossy(body)
            );
        }
        let e = parse_json::<BatchRequest>(b"{\"faces\": [{\"landmarks\": [[1, 2], [3, \"x\"]]}]}")
            .unwrap_err();
        assert!(e.message.starts_with("faces[0].landmarks"), "{e}");
        assert!(e.message.contains("landmark 1 y"), "{e}");
    }

    #[test]
    fn the_openapi_document_lists_every_route() {
        let doc: serde_json::Value = serde_json::from_str(&openapi_json()).unwrap();
        let paths = doc["paths"].as_object().unwrap();
        for p in [
            "/v1/pose",
            "/v1/pose:batch",
            "/v1/models",
            "/v1/models/{name}",
            "/v1/models/jobs/{id}",
            "/v1/models/{name}/versions",
            "/v1/models/{name}/versions/{version}",
            "/healthz",
            "/readyz",
            "/metrics",
            "/openapi.json",
        ] {
            assert!(
                paths.contains_key(p),
                "{p} missing from the OpenAPI document"
            );
            assert_ne!(route_label(None), p);
        }
        assert!(doc["components"]["schemas"]["PoseRequest"].is_object());
    }
}
