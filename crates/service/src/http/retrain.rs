//! The HTTP routes of retraining: `POST /v1/models` (a shape set; answers at once with the
//! job) and `GET /v1/models/jobs/{id}`. The admin token is checked before the body is read.

use std::sync::Arc;

use axum::Json;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use facepose_app::App;
use facepose_app::error::ServiceError;
use facepose_app::jobs::{Cancel, Job};
use facepose_app::retrain::{RawGrid, RawOptions, RawUpload, SchemeSpec, UploadData};
use facepose_core::model::bundle::sha256_hex;
use facepose_core::shape::MAX_POINTS;
use facepose_core::shape::Scheme;
use serde::Deserialize;
use serde::de::{Error as _, IgnoredAny, SeqAccess, Visitor};
use utoipa::ToSchema;
use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, OneOfBuilder, SchemaType, Type};

use super::body::{discard_body, parse_json, read_body_limited, require_json};
use super::error::{ErrorBody, HttpError};
use super::models::authorize;
use super::path::Segments;

/// A point of exactly `N` coordinates. serde's own `[f64; N]` takes a point with one number too
/// many for a JSON syntax error ("trailing characters", 400) but one with a number too few for
/// a value error (422); here both are value errors, as every other unusable value of an upload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coords<const N: usize>(pub [f64; N]);

impl<'de, const N: usize> Deserialize<'de> for Coords<N> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Points<const N: usize>;
        impl<'de, const N: usize> Visitor<'de> for Points<N> {
            type Value = Coords<N>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "a point of {N} numbers")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Coords<N>, A::Error> {
                let mut c = [0.0; N];
                for (i, x) in c.iter_mut().enumerate() {
                    *x = seq
                        .next_element()?
                        .ok_or_else(|| A::Error::invalid_length(i, &self))?;
                }
                let mut len = N;
                while seq.next_element::<IgnoredAny>()?.is_some() {
                    len += 1;
                }
                if len > N {
                    return Err(A::Error::invalid_length(len, &self));
                }
                Ok(Coords(c))
            }
        }
        d.deserialize_seq(Points::<N>)
    }
}

/// An array of points of `n` numbers (each `null` too if `missing`), per shape or view, and
/// `null` too if `optional`.
fn sets_of_points(n: usize, missing: bool, optional: bool) -> ArrayBuilder {
    let kinds = |null: bool| {
        let mut k = vec![Type::Array];
        if null {
            k.push(Type::Null);
        }
        SchemaType::from_iter(k)
    };
    let point = ArrayBuilder::new()
        .schema_type(kinds(missing))
        .items(ObjectBuilder::new().schema_type(Type::Number))
        .min_items(Some(n))
        .max_items(Some(n));
    let set = ArrayBuilder::new().items(point).max_items(Some(MAX_POINTS));
    ArrayBuilder::new().schema_type(kinds(optional)).items(set)
}

fn shapes_schema() -> ArrayBuilder {
    sets_of_points(3, false, true)
}

fn views_schema() -> ArrayBuilder {
    sets_of_points(2, true, false)
}

/// A built-in scheme's name or a scheme definition.
fn scheme_schema() -> OneOfBuilder {
    OneOfBuilder::new()
        .item(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .max_length(Some(64)),
        )
        .item(ObjectBuilder::new().schema_type(Type::Object))
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(
            "A built-in scheme name (default `ibug68`) or a scheme definition (docs/FORMATS.md).",
        ))
}

/// `"wide"`, `"paper"` or a [`CustomGrid`] object.
fn grid_schema() -> OneOfBuilder {
    OneOfBuilder::new()
        .item(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .enum_values(Some(["wide", "paper"])),
        )
        .item(ObjectBuilder::new().schema_type(Type::Object))
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(
            "`wide` (default: coarse yaw ±90° / pitch ±60° at 6° and five yaw bins at 2°), \
             `paper` (yaw and pitch ±40° at 2°), or a CustomGrid object.",
        ))
}

/// One subject of a multi-view upload: its views, each one `[x, y]` (image pixels) or `null`
/// per point of the scheme.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SubjectUpload {
    /// Any JSON value, echoed nowhere; for the client's bookkeeping.
    #[serde(default)]
    #[schema(value_type = Option<Value>)]
    pub id: Option<serde_json::Value>,
    #[schema(schema_with = views_schema)]
    /// The subject's views: per view, one `[x, y]` (image pixels, y down) or `null` per point.
    pub views: Vec<Vec<Option<Coords<2>>>>,
}

/// A pose grid: `[min, max, step]` in degrees per angle; no `roll`: 0 only.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GridUpload {
    #[schema(value_type = Vec<f64>, min_items = 3, max_items = 3)]
    /// Yaw `[min, max, step]`, degrees.
    pub yaw: [f64; 3],
    #[schema(value_type = Vec<f64>, min_items = 3, max_items = 3)]
    /// Pitch `[min, max, step]`, degrees.
    pub pitch: [f64; 3],
    #[serde(default)]
    #[schema(value_type = Option<Vec<f64>>, min_items = 3, max_items = 3)]
    /// Roll `[min, max, step]`, degrees; absent: 0 only.
    pub roll: Option<[f64; 3]>,
}

impl From<&GridUpload> for RawGrid {
    fn from(g: &GridUpload) -> Self {
        RawGrid {
            yaw: g.yaw,
            pitch: g.pitch,
            roll: g.roll,
        }
    }
}

/// A custom grid: the coarse model's grid and the fine bins.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CustomGrid {
    /// The coarse model's grid.
    pub coarse: GridUpload,
    #[serde(default)]
    /// The fine bins' grids.
    pub bins: Vec<GridUpload>,
}

/// Training options; every field is optional.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TrainingOptions {
    /// `"wide"` (default: coarse yaw ±90° / pitch ±60° at 6° and five yaw bins at 2°),
    /// `"paper"` (yaw and pitch ±40° at 2°), or a [`CustomGrid`] object.
    #[serde(default)]
    #[schema(schema_with = grid_schema)]
    pub grid: Option<serde_json::Value>,
    /// Candidate ridge parameters; default 1e-7 ... 1e-3.
    #[serde(default)]
    pub epsilons: Option<Vec<f64>>,
    /// Sub-schemes to serve besides the model's own; default `inner51`, `five` for ibug68,
    /// `five` for other schemes.
    #[serde(default)]
    pub subsets: Option<Vec<String>>,
    /// Principal components of the shape basis for `fit-shape` (0: none); default 40.
    #[serde(default)]
    pub components: Option<usize>,
    /// Seed of the validation views; default 2011.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Fewest shapes (subjects) that must remain after validation; default 10.
    #[serde(default)]
    pub min_shapes: Option<usize>,
    /// `k` of the outlier threshold `median + k · 1.4826 · MAD`; default 6.
    #[serde(default)]
    pub outlier_k: Option<f64>,
}

/// `POST /v1/models`: a shape set to retrain a model from.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RetrainRequest {
    /// The model to retrain (or create); default `default`.
    #[serde(default)]
    pub model: Option<String>,
    /// A built-in scheme name (default `ibug68`) or a scheme definition (docs/FORMATS.md).
    #[serde(default)]
    #[schema(schema_with = scheme_schema)]
    pub scheme: Option<serde_json::Value>,
    /// 3D shapes: one `[x, y, z]` per point of the scheme (model frame, mm).
    #[serde(default)]
    #[schema(schema_with = shapes_schema)]
    pub shapes: Option<Vec<Vec<Coords<3>>>>,
    /// Or several 2D views per subject, rebuilt by structure from motion.
    #[serde(default)]
    pub subjects: Option<Vec<SubjectUpload>>,
    #[serde(default)]
    /// Training options; absent: every default.
    pub options: Option<TrainingOptions>,
    /// Activate the new version once written; default true.
    #[serde(default)]
    pub activate: Option<bool>,
    /// Free text recorded in the version's provenance.
    #[serde(default)]
    pub notes: Option<String>,
}

impl RetrainRequest {
    fn into_raw(self, sha256: String) -> Result<RawUpload, ServiceError> {
        let scheme = match self.scheme {
            None => None,
            Some(serde_json::Value::String(s)) => Some(SchemeSpec::Name(s)),
            Some(v @ serde_json::Value::Object(_)) => Some(SchemeSpec::Definition(Box::new(
                serde_json::from_value::<Scheme>(v)
                    .map_err(|e| ServiceError::invalid(format!("scheme: {e}")))?,
            ))),
            Some(_) => {
                return Err(ServiceError::invalid(
                    "scheme: give a built-in scheme name or a scheme definition object",
                ));
            }
        };
        let o = self.options.unwrap_or_default();
        let (grid, custom_grid) = match o.grid {
            None => (None, None),
            Some(serde_json::Value::String(s)) => (Some(s), None),
            Some(v @ serde_json::Value::Object(_)) => {
                let g: CustomGrid = serde_json::from_value(v)
                    .map_err(|e| ServiceError::invalid(format!("options.grid: {e}")))?;
                (
                    None,
                    Some(((&g.coarse).into(), g.bins.iter().map(Into::into).collect())),
                )
            }
            Some(_) => {
                return Err(ServiceError::invalid(
                    "options.grid: give \"wide\", \"paper\" or a grid object",
                ));
            }
        };
        let both = self.shapes.is_some() && self.subjects.is_some();
        let data = match (self.shapes, self.subjects) {
            // Each shape's arrays are freed as it is converted (uploads run to 64 MiB).
            (Some(s), _) => Some(UploadData::Shapes(
                s.into_iter()
                    .map(|shape| {
                        shape
                            .into_iter()
                            .map(|c| facepose_core::shape::Point3::from(c.0))
                            .collect()
                    })
                    .collect(),
            )),
            (None, Some(s)) => Some(UploadData::Subjects(
                s.into_iter()
                    .map(|s| {
                        s.views
                            .into_iter()
                            .map(|view| view.into_iter().map(|p| p.map(|c| c.0)).collect())
                            .collect()
                    })
                    .collect(),
            )),
            (None, None) => None,
        };
        Ok(RawUpload {
            model: self.model,
            scheme,
            data,
            both,
            options: RawOptions {
                grid,
                custom_grid,
                epsilons: o.epsilons,
                subsets: o.subsets,
                components: o.components,
                seed: o.seed,
                min_shapes: o.min_shapes,
                outlier_k: o.outlier_k,
            },
            activate: self.activate,
            notes: self.notes,
            sha256,
            origin: "POST /v1/models",
        })
    }
}

/// A `POST /v1/models` body as the application's upload (not yet validated: see
/// `facepose_app::retrain::prepare`).
pub fn parse_upload(bytes: &[u8]) -> Result<RawUpload, HttpError> {
    let req: RetrainRequest = parse_json(bytes)?;
    Ok(req.into_raw(sha256_hex(bytes))?)
}

/// Upload a shape set and retrain a model in the background (admin).
#[utoipa::path(
    post, path = "/v1/models", tag = "registry",
    request_body = RetrainRequest,
    security(("admin_token" = [])),
    responses(
        (status = 202, description = "Accepted: the job (Location: /v1/models/jobs/{id}); its validation report for 3D shapes", body = Job),
        (status = 400, description = "Malformed JSON", body = ErrorBody),
        (status = 401, description = "Missing or wrong admin token", body = ErrorBody),
        (status = 403, description = "Admin routes disabled (no token configured)", body = ErrorBody),
        (status = 409, description = "The server has no models folder", body = ErrorBody),
        (status = 413, description = "Body over --max-upload", body = ErrorBody),
        (status = 415, description = "Not JSON", body = ErrorBody),
        (status = 422, description = "Unusable upload: scheme, options, counts, or too few valid shapes (details.validation lists every dropped shape)", body = ErrorBody),
        (status = 429, description = "Too many jobs queued", body = ErrorBody),
    )
)]
pub async fn retrain(
    State(app): State<Arc<App>>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, HttpError> {
    let refused = authorize(&app, &headers)
        .and_then(|()| Ok(app.registry.require_dir().map(drop)?))
        .and_then(|()| require_json(&headers));
    // A place in the queue before the body is read: uploads in memory are bounded too.
    let slot = match refused.and_then(|()| Ok(app.reserve_job()?)) {
        Ok(slot) => slot,
        Err(e) => {
            discard_body(&headers, body).await;
            return Err(e);
        }
    };
    let bytes = read_body_limited(
        &headers,
        body,
        app.limits.max_upload,
        "--max-upload",
        "send fewer shapes",
    )
    .await?;
    let job = app
        .retrain(
            move || {
                let raw = parse_upload(&bytes)?;
                drop(bytes);
                Ok::<_, HttpError>(raw)
            },
            slot,
        )
        .await?;
    let location = HeaderValue::from_str(&format!("/v1/models/jobs/{}", job.id))
        .map_err(|e| ServiceError::internal(e.to_string()))?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(job),
    )
        .into_response())
}

/// A retraining job, from any replica sharing the models folder.
#[utoipa::path(get, path = "/v1/models/jobs/{id}", tag = "registry",
    params(("id" = String, Path, description = "The job id from POST /v1/models")),
    responses(
        (status = 200, description = "The job", body = Job),
        (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 404, description = "Unknown job, or ended more than an hour ago", body = ErrorBody)))]
pub async fn get_job(
    State(app): State<Arc<App>>,
    Segments(id): Segments<String>,
) -> Result<Json<Job>, HttpError> {
    Ok(Json(app.job(&id).await?))
}

/// Cancel a retraining job: `POST /v1/models/jobs/{id}:cancel` (admin). A queued job never
/// trains; a running one stops at its next stage, before its version is written.
#[utoipa::path(post, path = "/v1/models/jobs/{id}", tag = "registry",
    operation_id = "cancel_job",
    params(("id" = String, Path, description = "The job id followed by `:cancel`", pattern = "^[0-9a-f]{32}:cancel$")),
    security(("admin_token" = [])),
    responses(
        (status = 200, description = "Cancelled (state `cancelled`)", body = Job),
        (status = 202, description = "The job runs on another replica, asked to cancel it at its next stage; the job as last recorded", body = Job),
        (status = 400, description = "A path segment that is not UTF-8 once decoded (`malformed_path`)", body = ErrorBody),
        (status = 401, description = "Missing, malformed or wrong admin token (`unauthenticated`)", body = ErrorBody),
        (status = 403, description = "Admin routes disabled: the server has no admin token (`forbidden`)", body = ErrorBody),
        (status = 404, description = "Unknown job, or no action", body = ErrorBody),
        (status = 409, description = "The job has ended, or is writing or activating its version", body = ErrorBody)))]
pub async fn job_action(
    State(app): State<Arc<App>>,
    Segments(id): Segments<String>,
    headers: HeaderMap,
) -> Result<(StatusCode, Json<Job>), HttpError> {
    authorize(&app, &headers)?;
    let Some(job) = id.strip_suffix(":cancel") else {
        return Err(HttpError::NotFound(format!(
            "no action in POST /v1/models/jobs/{id}: to cancel the job, POST \
             /v1/models/jobs/{id}:cancel"
        )));
    };
    Ok(match app.cancel_job(job).await? {
        Cancel::Done(job) => (StatusCode::OK, Json(job)),
        Cancel::Requested(job) => (StatusCode::ACCEPTED, Json(job)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::http::error::ErrorCode;
    use facepose_app::auth::AdminToken;
    use facepose_app::registry::load_models;
    use facepose_app::{Limits, Settings};
    use std::time::Duration;

    #[tokio::test]
    async fn a_full_queue_refuses_an_upload_before_reading_it() {
        let root = std::env::temp_dir().join(format!("facepose-queue-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        let limits = Limits {
            max_batch: 10,
            max_body: 1 << 20,
            request_timeout: Duration::from_secs(5),
            max_concurrency: 4,
            max_streams: 4,
            max_upload: 16,
            upload_timeout: Duration::from_secs(5),
        };
        let settings = Settings {
            models: Some(root.clone()),
            limits,
            admin_token: AdminToken::new("secret-token-for-tests"),
            max_queued_jobs: 0,
            registry_poll: Duration::from_secs(60),
            replica: "test".into(),
            keep_inactive_versions: None,
        };
        let st = App::with_models(
            settings,
            load_models(Some(&root)).unwrap(),
            tracing::Span::none(),
        );
        let mut headers = HeaderMap::new();
        headers.insert(
            header::AUTHORIZATION,
            HeaderValue::from_static("Bearer secret-token-for-tests"),
        );
        headers.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        );
        let body = || Body::from(vec![b' '; 100]);
        // With a free slot, the body is read (and is over --max-upload here).
        let e = retrain(State(st.clone()), headers.clone(), body())
            .await
            .unwrap_err();
        assert_eq!(e.code(), ErrorCode::PayloadTooLarge, "{e}");
        // The only slot is taken (a job in progress): refused before the body is read.
        let held = st.jobs.reserve().unwrap();
        let e = retrain(State(st.clone()), headers.clone(), body())
            .await
            .unwrap_err();
        assert_eq!(e.code(), ErrorCode::Overloaded, "{e}");
        assert!(e.message().contains("retry later"), "{e}");
        drop(held);
        let e = retrain(State(st.clone()), headers, body())
            .await
            .unwrap_err();
        assert_eq!(e.code(), ErrorCode::PayloadTooLarge, "{e}");
        st.stop().await;
        std::fs::remove_dir_all(&root).unwrap();
    }
}
