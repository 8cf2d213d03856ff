//! The pose routes: `POST /v1/pose` (one face) and `POST /v1/pose:batch` (many, each with its
//! own outcome). The body is checked and read in one pass as it arrives when it has the usual
//! shape ([`super::pose_body`]), else by serde with its precise errors.

use std::sync::Arc;

use axum::Extension;
use axum::body::Bytes;
use axum::extract::{Request, State};
use axum::response::Response;
use facepose_app::App;
use facepose_app::error::ServiceError;
use facepose_app::estimate::{BatchRun, BatchSize, FaceInput, FaceScratch, INLINE_BYTES};
use facepose_app::metrics::Transport;
use facepose_app::pose::FaceSpec;
use facepose_core::estimate::Intrinsics;
use facepose_core::pose::{LandmarkStyle, Method};
use facepose_core::shape::pixels::check_coordinates;

use super::body::{
    ONE_ERROR_JSON, ONE_POSE_JSON, json_bytes, parse_json, read_pose_body, require_json,
    to_json_sized,
};
use super::conventions::{Conventions, Orientation};
use super::error::{ErrorBody, HttpError};
use super::middleware::Deadline;
use super::pose_body::{BodyKind, PoseBody, count_batch_faces};
use super::wire::{
    BatchError, BatchFace, BatchPose, BatchRequest, BatchResponse, BatchResult, Camera,
    PoseRequest, PoseResponse, image_size,
};

impl FaceInput for PoseRequest {
    fn spec<'a>(&'a self, _: &'a mut FaceScratch) -> Result<FaceSpec<'a>, ServiceError> {
        Ok(FaceSpec {
            landmarks: &self.landmarks.0,
            scheme: self.scheme.as_deref(),
            method: self.method.as_deref(),
            camera: self.camera.map(Into::into),
            style: self.landmark_style.as_deref(),
            image_size: image_size(self.image_size),
            conventions: self.conventions.as_ref().map_or(&[], |c| &c.0[..]),
            orientation: self.camera_orientation.map(|o| o.0),
        })
    }
}

/// What a batch's faces take from the batch when they do not say.
pub(super) struct BatchDefaults {
    scheme: Option<String>,
    method: Option<String>,
    camera: Option<Camera>,
    landmark_style: Option<String>,
    image_size: Option<[f64; 2]>,
    conventions: Option<Conventions>,
    camera_orientation: Option<Orientation>,
}

impl BatchDefaults {
    /// No defaults: every face says for itself.
    pub(super) const NONE: BatchDefaults = BatchDefaults {
        scheme: None,
        method: None,
        camera: None,
        landmark_style: None,
        image_size: None,
        conventions: None,
        camera_orientation: None,
    };
}

/// A face of a batch with the batch's defaults.
struct BatchItem<'r> {
    face: BatchFace,
    defaults: &'r BatchDefaults,
}

impl FaceInput for BatchItem<'_> {
    fn spec<'a>(&'a self, _: &'a mut FaceScratch) -> Result<FaceSpec<'a>, ServiceError> {
        Ok(batch_face_spec(&self.face, self.defaults))
    }
}

/// A batch face as the estimator takes it, what it does not say taken from `d` (the batch's
/// defaults, or [`BatchDefaults::NONE`] for a face on its own, as the WebSocket stream's).
pub(super) fn batch_face_spec<'a>(f: &'a BatchFace, d: &'a BatchDefaults) -> FaceSpec<'a> {
    FaceSpec {
        landmarks: &f.landmarks.0,
        scheme: f.scheme.as_deref().or(d.scheme.as_deref()),
        method: f.method.as_deref().or(d.method.as_deref()),
        camera: f.camera.or(d.camera).map(Into::into),
        style: f.landmark_style.as_deref().or(d.landmark_style.as_deref()),
        image_size: image_size(f.image_size.or(d.image_size)),
        conventions: f
            .conventions
            .as_ref()
            .or(d.conventions.as_ref())
            .map_or(&[], |c| &c.0[..]),
        orientation: f.camera_orientation.or(d.camera_orientation).map(|o| o.0),
    }
}

/// A `POST /v1/pose` body that `reader` has read whole: the request it built when the body has
/// the usual shape, else serde's reading of `bytes` with its precise errors ([`parse_json`]).
pub fn pose_request(reader: PoseBody, bytes: &[u8]) -> Result<PoseRequest, HttpError> {
    reader.read_pose().map_or_else(|| parse_json(bytes), Ok)
}

/// [`pose_request`] for `POST /v1/pose:batch`, with at most the reader's `max_faces`: the limit
/// is checked before the faces are built (an empty face is 17 bytes of JSON and about 150 in
/// memory), by the reader as it goes or by counting them in place before serde.
pub fn batch_request(reader: PoseBody, bytes: &[u8]) -> Result<BatchRequest, HttpError> {
    let max_batch = reader.max_faces().unwrap_or(usize::MAX);
    if let Some(req) = reader.read_batch() {
        return Ok(req);
    }
    if bytes.len() >= INLINE_BYTES {
        let faces = count_batch_faces(bytes);
        if faces > max_batch {
            return Err(ServiceError::BatchTooLarge {
                faces,
                limit: max_batch,
            }
            .into());
        }
    }
    parse_json(bytes)
}

/// Parses a whole `POST /v1/pose` body ([`pose_request`] after reading it in one chunk).
pub fn parse_pose_request(bytes: &[u8]) -> Result<PoseRequest, HttpError> {
    let mut reader = PoseBody::new(BodyKind::Pose);
    let _ = reader.feed(bytes);
    pose_request(reader, bytes)
}

/// Parses a whole `POST /v1/pose:batch` body of at most `max_batch` faces ([`batch_request`]).
pub fn parse_batch_request(bytes: &[u8], max_batch: usize) -> Result<BatchRequest, HttpError> {
    let mut reader = PoseBody::new(BodyKind::Batch {
        max_faces: max_batch,
    });
    let _ = reader.feed(bytes);
    batch_request(reader, bytes)
}

/// Refuses (422) a batch with a value its schema rules out, at the batch's level or a face's:
/// a name over 64 characters, a method or landmark style that is not one, a camera without
/// positive focal lengths, a coordinate beyond ±1e9. Such a batch is malformed, not a batch
/// with an unusable face; what the document cannot state (a landmark count that must match
/// the scheme, an unknown scheme, degenerate points) stays each face's own error.
fn check_conformance(req: &BatchRequest) -> Result<(), HttpError> {
    let at = |i: Option<usize>, e: &dyn std::fmt::Display| {
        HttpError::invalid(match i {
            Some(i) => format!("faces[{i}]: {e}"),
            None => e.to_string(),
        })
    };
    let fields = |i,
                  scheme: &Option<String>,
                  method: &Option<String>,
                  style: &Option<String>,
                  camera: &Option<super::wire::Camera>,
                  size: Option<[f64; 2]>| {
        for (what, name) in [
            ("scheme", scheme),
            ("method", method),
            ("landmark style", style),
        ] {
            ServiceError::check_name_length(what, name.as_deref().unwrap_or_default())
                .map_err(|e| at(i, &e))?;
        }
        if let Some(m) = method.as_deref().filter(|m| !m.is_empty()) {
            m.parse::<Method>().map_err(|e| at(i, &e))?;
        }
        if let Some(st) = style.as_deref().filter(|st| !st.is_empty()) {
            st.parse::<LandmarkStyle>().map_err(|e| at(i, &e))?;
        }
        if let Some(c) = camera {
            Intrinsics::from(*c).validate().map_err(|e| at(i, &e))?;
        }
        if let Some(size) = image_size(size) {
            size.validate().map_err(|e| at(i, &e))?;
        }
        Ok::<(), HttpError>(())
    };
    ServiceError::check_name_length("model", req.model.as_deref().unwrap_or_default())?;
    fields(
        None,
        &req.scheme,
        &req.method,
        &req.landmark_style,
        &req.camera,
        req.image_size,
    )?;
    for (i, f) in req.faces.iter().enumerate() {
        fields(
            Some(i),
            &f.scheme,
            &f.method,
            &f.landmark_style,
            &f.camera,
            f.image_size,
        )?;
        check_coordinates(&f.landmarks.0).map_err(|e| at(Some(i), &e))?;
    }
    Ok(())
}

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
pub async fn pose(State(app): State<Arc<App>>, req: Request) -> Result<Response, HttpError> {
    // The request whole rather than a `HeaderMap` extractor, which would copy the headers.
    let (parts, body) = req.into_parts();
    require_json(&parts.headers)?;
    let mut reader = PoseBody::new(BodyKind::Pose);
    let bytes = read_pose_body(&parts.headers, body, app.limits.max_body, &mut reader).await?;
    let req = pose_request(reader, &bytes)?;
    drop(bytes);
    let answer = app.estimate(Transport::Http, req.model.as_deref(), &req)?;
    Ok(json_bytes(
        PoseResponse {
            pose: answer.pose.record,
            scheme: answer.pose.scheme,
            model: answer.model.name.clone(),
            model_version: answer.model.version.clone(),
            id: req.id,
        }
        .to_json(),
    ))
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
    State(app): State<Arc<App>>,
    Extension(deadline): Extension<Deadline>,
    req: Request,
) -> Result<Response, HttpError> {
    let (parts, body) = req.into_parts();
    require_json(&parts.headers)?;
    let mut reader = PoseBody::new(BodyKind::Batch {
        max_faces: app.limits.max_batch,
    });
    let bytes = read_pose_body(&parts.headers, body, app.limits.max_body, &mut reader).await?;
    let size = BatchSize::Bytes(bytes.len());
    // Read as it arrived, or (a surprise) parsed by serde inside the use case, off the async
    // workers when it is long.
    let body = app
        .estimate_batch(Transport::Http, size, deadline.0, move |run| {
            let req = batch_request(reader, &bytes)?;
            drop(bytes);
            answer_batch_request(req, run)
        })
        .await?;
    Ok(json_bytes(body))
}

/// The answer to a `POST /v1/pose:batch` body: parse, estimate each face in `run`, serialize.
/// The handler runs it through the batch use case ([`App::estimate_batch`]); `loadgen
/// ceiling` (crates/service/examples) runs it with no network.
pub fn answer_batch(bytes: Bytes, run: &mut BatchRun) -> Result<Vec<u8>, HttpError> {
    let req = parse_batch_request(&bytes, run.max_faces())?;
    drop(bytes);
    answer_batch_request(req, run)
}

/// [`answer_batch`] on a request already read.
fn answer_batch_request(req: BatchRequest, run: &mut BatchRun) -> Result<Vec<u8>, HttpError> {
    run.check_size(req.faces.len())?;
    check_conformance(&req)?;
    let model = run.model(req.model.as_deref())?;
    let BatchRequest {
        faces,
        scheme,
        method,
        camera,
        landmark_style,
        image_size,
        model: _,
        conventions,
        camera_orientation,
    } = req;
    let defaults = BatchDefaults {
        scheme,
        method,
        camera,
        landmark_style,
        image_size,
        conventions,
        camera_orientation,
    };
    let items = faces.into_iter().map(|face| BatchItem {
        face,
        defaults: &defaults,
    });
    let results = run.estimate_each(&model, items, |item, outcome| match outcome {
        Ok(p) => BatchResult::Pose(BatchPose {
            pose: p.record,
            scheme: p.scheme,
            id: item.face.id,
        }),
        Err(error) => BatchResult::Error(BatchError {
            id: item.face.id,
            error: HttpError::from(error).object(),
        }),
    })?;
    let tally = run.tally();
    // Room for what the answer will hold: a pose or a shorter error a face.
    let capacity = ONE_POSE_JSON
        .saturating_mul(tally.succeeded() as usize)
        .saturating_add(ONE_ERROR_JSON.saturating_mul(tally.failed() as usize))
        .max(ONE_ERROR_JSON);
    to_json_sized(
        &BatchResponse {
            model: model.name.clone(),
            model_version: model.version.clone(),
            succeeded: tally.succeeded(),
            failed: tally.failed(),
            results,
        },
        capacity,
    )
}
