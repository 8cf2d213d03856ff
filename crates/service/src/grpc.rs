//! The gRPC API (`facepose.v1.PoseService`, proto/facepose/v1/pose.proto): the same estimation
//! and the same error messages as the HTTP API, through [`super::pose`] and [`super::errors`].
//!
//! Unary calls share the HTTP API's concurrency limit and time limit (UNAVAILABLE and
//! DEADLINE_EXCEEDED). Streams have their own limit (`--max-streams`), watch the drain signal,
//! and end with UNAVAILABLE when the server shuts down.

use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use futures_util::Stream;
use tokio::sync::OwnedSemaphorePermit;
use tonic::{Request, Response, Status, Streaming};

use super::AppState;
use super::errors::{ApiError, ErrorKind};
use super::http::{VersionSummary, version_summaries};
use super::http_registry::versions_response;
use super::jobs::{Cancel, Job};
use super::metrics::{self, FaceTally};
use super::pose::{
    FacePose, FaceSpec, INLINE_FACES, estimate_face, for_each_face, on_blocking_pool,
};
use super::proto::{self, pose_service_server::PoseService};
use super::registry::{Catalog, ModelSet, ServedModel};
use super::retrain::{self, chunks::ChunkCollector};
use super::stream::Session;
use facepose_core::estimate::Intrinsics;
use facepose_core::model::validate::ValidationReport;

/// The gRPC service.
#[derive(Clone, Debug)]
pub struct PoseApi {
    state: Arc<AppState>,
}

impl PoseApi {
    pub fn new(state: Arc<AppState>) -> Self {
        PoseApi { state }
    }

    fn permit(&self) -> Result<OwnedSemaphorePermit, ApiError> {
        self.state
            .permits
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError::overloaded(self.state.limits.max_concurrency))
    }
}

/// `points` (image pixels, all present) as `Landmark` messages, for Rust clients.
pub fn landmark_messages(points: &[[f64; 2]]) -> Vec<proto::Landmark> {
    points
        .iter()
        .map(|p| proto::Landmark {
            x: p[0],
            y: p[1],
            missing: false,
        })
        .collect()
}

/// A face's landmarks (`landmarks` or packed `xy` with `missing`) as optional points, into
/// `out` (reused between faces); INVALID_ARGUMENT when the two forms are mixed or `xy` and
/// `missing` do not fit together.
pub fn landmarks_into(face: &proto::Face, out: &mut Vec<Option<[f64; 2]>>) -> Result<(), ApiError> {
    out.clear();
    if face.xy.is_empty() {
        if !face.missing.is_empty() {
            return Err(ApiError::invalid(
                "Face.missing goes with Face.xy; with Face.landmarks, set Landmark.missing",
            ));
        }
        out.extend(
            face.landmarks
                .iter()
                .map(|l| (!l.missing).then_some([l.x, l.y])),
        );
        return Ok(());
    }
    if !face.landmarks.is_empty() {
        return Err(ApiError::invalid(format!(
            "the face has both Face.landmarks ({}) and Face.xy ({} numbers): set one of them",
            face.landmarks.len(),
            face.xy.len()
        )));
    }
    if !face.xy.len().is_multiple_of(2) {
        return Err(ApiError::invalid(format!(
            "Face.xy has {} numbers: it needs an x and a y per landmark (x0, y0, x1, y1, ...)",
            face.xy.len()
        )));
    }
    let n = face.xy.len() / 2;
    out.extend(face.xy.chunks_exact(2).map(|p| Some([p[0], p[1]])));
    for &i in &face.missing {
        let slot = out.get_mut(i as usize).ok_or_else(|| {
            ApiError::invalid(format!(
                "Face.missing has index {i}, but Face.xy has {n} landmarks (indices 0 to {})",
                n - 1
            ))
        })?;
        *slot = None;
    }
    Ok(())
}

/// The transport-neutral face of a proto face whose landmarks are `points`.
pub fn face_spec<'a>(face: &'a proto::Face, points: &'a [Option<[f64; 2]>]) -> FaceSpec<'a> {
    FaceSpec {
        landmarks: points,
        scheme: Some(face.scheme.as_str()),
        method: Some(face.method.as_str()),
        camera: face.camera.map(|c| Intrinsics {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
        }),
        style: Some(face.landmark_style.as_str()),
    }
}

pub fn pose_message(p: &FacePose) -> proto::Pose {
    let r = &p.record;
    proto::Pose {
        yaw: r.yaw,
        pitch: r.pitch,
        roll: r.roll,
        rotation: r.rotation.iter().flatten().copied().collect(),
        visible: r.visible.clone(),
        residual: r.residual,
        method: r.method.to_string(),
        scheme: p.scheme.clone(),
        translation: r
            .translation
            .map(|[x, y, z]| proto::Translation { x, y, z }),
        smoothed: false,
    }
}

pub fn face_error(e: &ApiError) -> proto::FaceError {
    proto::FaceError {
        code: metrics::grpc_code_label(e.kind.grpc_code()).to_string(),
        message: e.message.clone(),
    }
}

fn model_info(m: &ServedModel, set: &ModelSet, catalog: &Catalog) -> proto::ModelInfo {
    let stored = m.store.as_ref().and_then(|s| catalog.models.get(s));
    proto::ModelInfo {
        versions: version_summaries(stored, Some(m))
            .into_iter()
            .map(version_message)
            .collect(),
        name: m.name.clone(),
        version: m.version.clone(),
        created: m.created.clone(),
        scheme: m.scheme().to_string(),
        schemes: m
            .schemes()
            .map(|(name, points)| proto::SchemeInfo {
                name: name.to_string(),
                points: points as u32,
            })
            .collect(),
        methods: m.methods().iter().map(|x| x.to_string()).collect(),
        checksum: m.checksum.clone(),
        source: m.source.to_string(),
        is_default: m.name == set.default_name(),
    }
}

fn version_message(v: VersionSummary) -> proto::VersionInfo {
    proto::VersionInfo {
        version: v.version,
        created: v.created,
        checksum: v.checksum,
        scheme: v.scheme,
        source: v.source,
        active: v.active,
        served: v.served,
        fixed: v.fixed,
    }
}

fn report_message(r: &ValidationReport) -> proto::ValidationReport {
    proto::ValidationReport {
        total: r.total as u32,
        kept: r.kept as u32,
        dropped: r
            .dropped
            .iter()
            .map(|d| proto::DroppedShape {
                index: d.index as u32,
                reason: d.reason.name().to_string(),
                detail: d.detail.clone(),
            })
            .collect(),
        median_distance: r.median_distance,
        outlier_threshold: r.outlier_threshold,
    }
}

/// A job as its gRPC message.
pub fn job_message(j: &Job) -> proto::Job {
    proto::Job {
        id: j.id.clone(),
        model: j.model.clone(),
        state: j.state.name().to_string(),
        stage: j.stage.map_or("", |s| s.name()).to_string(),
        progress: j.progress,
        kind: j.kind.clone(),
        uploaded: j.uploaded as u32,
        activate: j.activate,
        created: j.created.clone(),
        updated: j.updated.clone(),
        validation: j.validation.as_ref().map(report_message),
        version: j.version.clone().unwrap_or_default(),
        error: j.error.clone().unwrap_or_default(),
        replica: j.replica.clone(),
    }
}

/// Checks the admin token of a call (`authorization: Bearer <token>` metadata).
fn authorize<T>(state: &AppState, request: &Request<T>) -> Result<(), ApiError> {
    state.admin.check(
        request
            .metadata()
            .get("authorization")
            .map(|v| v.as_bytes()),
    )
}

/// One face with its own outcome, as in a batch or a frame.
fn face_result(
    model: &ServedModel,
    face: &proto::Face,
    points: &mut Vec<Option<[f64; 2]>>,
) -> (
    proto::FaceResult,
    Result<facepose_core::pose::Method, ErrorKind>,
) {
    let estimate =
        landmarks_into(face, points).and_then(|()| estimate_face(model, &face_spec(face, points)));
    let (result, outcome) = match estimate {
        Ok(p) => (
            proto::face_result::Result::Pose(pose_message(&p)),
            Ok(p.record.method),
        ),
        Err(e) => (
            proto::face_result::Result::Error(face_error(&e)),
            Err(e.kind),
        ),
    };
    (
        proto::FaceResult {
            id: face.id.clone(),
            result: Some(result),
        },
        outcome,
    )
}

/// Runs a unary call under the concurrency and time limits and records its metrics.
async fn unary<T, F>(api: &PoseApi, rpc: &'static str, f: F) -> Result<Response<T>, Status>
where
    F: Future<Output = Result<T, ApiError>>,
{
    let started = Instant::now();
    let result = match api.permit() {
        Err(e) => Err(e),
        Ok(_permit) => match tokio::time::timeout(api.state.limits.request_timeout, f).await {
            Ok(r) => r,
            Err(_) => Err(ApiError::timeout(api.state.limits.request_timeout)),
        },
    };
    let code = match &result {
        Ok(_) => tonic::Code::Ok,
        Err(e) => e.kind.grpc_code(),
    };
    metrics::grpc_request(rpc, code, Some(started.elapsed()));
    if let Err(e) = &result {
        tracing::debug!(rpc, error = %e, "gRPC call failed");
    }
    result.map(Response::new).map_err(Status::from)
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<proto::FrameResult, Status>> + Send>>;

#[tonic::async_trait]
impl PoseService for PoseApi {
    async fn estimate(
        &self,
        request: Request<proto::EstimateRequest>,
    ) -> Result<Response<proto::EstimateResponse>, Status> {
        let state = self.state.clone();
        unary(self, "Estimate", async move {
            let req = request.into_inner();
            let face = req
                .face
                .ok_or_else(|| ApiError::invalid("missing face: set EstimateRequest.face"))?;
            let models = state.registry.snapshot();
            let model = models.get(Some(&req.model))?;
            let mut points = Vec::with_capacity(face.landmarks.len().max(face.xy.len() / 2));
            let mut tally = FaceTally::default();
            let result = landmarks_into(&face, &mut points)
                .and_then(|()| estimate_face(model, &face_spec(&face, &points)));
            match &result {
                Ok(p) => tally.ok(p.record.method),
                Err(e) => tally.err(e.kind),
            }
            tally.record("grpc");
            let p = result?;
            Ok(proto::EstimateResponse {
                pose: Some(pose_message(&p)),
                id: face.id,
                model: model.name.clone(),
                model_version: model.version.clone(),
            })
        })
        .await
    }

    async fn estimate_batch(
        &self,
        request: Request<proto::EstimateBatchRequest>,
    ) -> Result<Response<proto::EstimateBatchResponse>, Status> {
        let state = self.state.clone();
        unary(self, "EstimateBatch", async move {
            let req = request.into_inner();
            let limits = state.limits;
            if req.faces.len() > limits.max_batch {
                return Err(ApiError::batch_too_large(req.faces.len(), limits.max_batch));
            }
            let models = state.registry.snapshot();
            let model = models.get(Some(&req.model))?.clone();
            let deadline = Instant::now() + limits.request_timeout;
            let inline = req.faces.len() <= INLINE_FACES;
            super::pose::run_maybe_blocking(inline, move || {
                let mut points = Vec::new();
                let mut tally = FaceTally::default();
                let results = for_each_face(&req.faces, Some(deadline), |face| {
                    let (r, outcome) = face_result(&model, face, &mut points);
                    match outcome {
                        Ok(m) => tally.ok(m),
                        Err(k) => tally.err(k),
                    }
                    r
                })
                .map_err(|_| ApiError::timeout(limits.request_timeout))?;
                tally.record("grpc");
                Ok(proto::EstimateBatchResponse {
                    results,
                    model: model.name.clone(),
                    model_version: model.version.clone(),
                    succeeded: tally.succeeded() as u32,
                    failed: tally.failed() as u32,
                })
            })
            .await?
        })
        .await
    }

    type EstimateStreamStream = FrameStream;

    async fn estimate_stream(
        &self,
        request: Request<Streaming<proto::Frame>>,
    ) -> Result<Response<FrameStream>, Status> {
        let Ok(permit) = self.state.streams.clone().try_acquire_owned() else {
            metrics::grpc_request("EstimateStream", tonic::Code::Unavailable, None);
            return Err(Status::unavailable(format!(
                "server busy: {} streams already open (--max-streams); retry with backoff",
                self.state.limits.max_streams
            )));
        };
        if !self.state.lifecycle.is_ready() {
            return Err(ApiError::shutting_down().into());
        }
        metrics::stream_opened();
        let guard = StreamGuard {
            _permit: permit,
            code: tonic::Code::Ok,
        };
        let st = StreamState {
            state: self.state.clone(),
            inbound: request.into_inner(),
            session: Session::default(),
            drained: Box::pin(self.state.lifecycle.drained()),
            guard,
            done: false,
        };
        let out = futures_util::stream::unfold(st, |mut st| async move {
            if st.done {
                return None;
            }
            let item = tokio::select! {
                biased;
                _ = &mut st.drained => Err(ApiError::shutting_down().into()),
                msg = st.inbound.message() => match msg {
                    Ok(Some(frame)) => {
                        let models = st.state.registry.snapshot();
                        st.session
                            .frame(&models, frame, st.state.limits.max_batch)
                            .map_err(Status::from)
                    }
                    Ok(None) => return None,
                    Err(status) => Err(inbound_error(status, st.state.limits.max_body)),
                },
            };
            if let Err(s) = &item {
                st.done = true;
                st.guard.code = s.code();
                tracing::debug!(code = ?s.code(), message = s.message(), "stream ended by the server");
            }
            Some((item, st))
        });
        Ok(Response::new(Box::pin(out)))
    }

    async fn list_models(
        &self,
        _request: Request<proto::ListModelsRequest>,
    ) -> Result<Response<proto::ListModelsResponse>, Status> {
        let state = self.state.clone();
        unary(self, "ListModels", async move {
            let set = state.registry.snapshot();
            let catalog = state.registry.catalog();
            Ok(proto::ListModelsResponse {
                models: set.iter().map(|m| model_info(m, &set, &catalog)).collect(),
                default_model: set.default_name().to_string(),
            })
        })
        .await
    }

    async fn get_model(
        &self,
        request: Request<proto::GetModelRequest>,
    ) -> Result<Response<proto::ModelInfo>, Status> {
        let state = self.state.clone();
        unary(self, "GetModel", async move {
            let name = request.into_inner().name;
            if name.is_empty() {
                return Err(ApiError::invalid("missing name: set GetModelRequest.name"));
            }
            let set = state.registry.snapshot();
            let m = set.get(Some(&name))?;
            Ok(model_info(m, &set, &state.registry.catalog()))
        })
        .await
    }

    async fn retrain(
        &self,
        request: Request<Streaming<proto::RetrainChunk>>,
    ) -> Result<Response<proto::Job>, Status> {
        let started = Instant::now();
        let state = self.state.clone();
        let result: Result<proto::Job, Status> = async {
            authorize(&state, &request)?;
            state.registry.require_dir()?;
            let _permit = self.permit()?;
            // A queue slot before the upload is read: queued uploads bound the memory.
            let slot = state.reserve_job()?;
            let limits = state.limits;
            let mut inbound = request.into_inner();
            let mut chunks = ChunkCollector::new(limits.max_upload);
            let receive = async {
                while let Some(chunk) = inbound
                    .message()
                    .await
                    .map_err(|s| inbound_error(s, limits.max_body))?
                {
                    chunks.push(chunk)?;
                }
                Ok::<_, Status>(())
            };
            tokio::time::timeout(limits.upload_timeout, receive)
                .await
                .map_err(|_| {
                    Status::deadline_exceeded(format!(
                        "the upload took longer than {:?} (--upload-timeout)",
                        limits.upload_timeout
                    ))
                })??;
            let raw = chunks.finish()?;
            let prepared =
                on_blocking_pool("checking the upload", move || retrain::prepare(raw)).await?;
            let job = retrain::job::submit_reserved(&state, prepared, slot)?;
            Ok(job_message(&job))
        }
        .await;
        let code = result
            .as_ref()
            .map_or_else(|s| s.code(), |_| tonic::Code::Ok);
        metrics::grpc_request("Retrain", code, Some(started.elapsed()));
        result.map(Response::new)
    }

    async fn get_job(
        &self,
        request: Request<proto::GetJobRequest>,
    ) -> Result<Response<proto::Job>, Status> {
        let state = self.state.clone();
        unary(self, "GetJob", async move {
            let id = request.into_inner().id;
            let jobs = state.clone();
            Ok(job_message(
                &on_blocking_pool("job look-up", move || jobs.jobs.get(&id)).await?,
            ))
        })
        .await
    }

    async fn cancel_job(
        &self,
        request: Request<proto::CancelJobRequest>,
    ) -> Result<Response<proto::Job>, Status> {
        let state = self.state.clone();
        unary(self, "CancelJob", async move {
            authorize(&state, &request)?;
            let id = request.into_inner().id;
            if id.is_empty() {
                return Err(ApiError::invalid("missing id: set CancelJobRequest.id"));
            }
            let jobs = state.clone();
            match on_blocking_pool("job cancel", move || jobs.jobs.cancel(&id)).await? {
                Cancel::Done(job) | Cancel::Requested(job) => Ok(job_message(&job)),
            }
        })
        .await
    }

    async fn list_versions(
        &self,
        request: Request<proto::ListVersionsRequest>,
    ) -> Result<Response<proto::ListVersionsResponse>, Status> {
        let state = self.state.clone();
        unary(self, "ListVersions", async move {
            let name = request.into_inner().name;
            if name.is_empty() {
                return Err(ApiError::invalid(
                    "missing name: set ListVersionsRequest.name",
                ));
            }
            state.registry.refresh_catalog().await;
            let v = versions_response(&state, &name)?;
            Ok(proto::ListVersionsResponse {
                name: v.name,
                active: v.active.unwrap_or_default(),
                versions: v.versions.into_iter().map(version_message).collect(),
            })
        })
        .await
    }

    async fn activate_version(
        &self,
        request: Request<proto::ActivateVersionRequest>,
    ) -> Result<Response<proto::ModelInfo>, Status> {
        let state = self.state.clone();
        unary(self, "ActivateVersion", async move {
            authorize(&state, &request)?;
            let req = request.into_inner();
            let served = state.registry.activate(&req.name, &req.version).await?;
            let set = state.registry.snapshot();
            Ok(model_info(&served, &set, &state.registry.catalog()))
        })
        .await
    }

    async fn delete_version(
        &self,
        request: Request<proto::DeleteVersionRequest>,
    ) -> Result<Response<proto::DeleteVersionResponse>, Status> {
        let state = self.state.clone();
        unary(self, "DeleteVersion", async move {
            authorize(&state, &request)?;
            let req = request.into_inner();
            state.registry.delete(&req.name, &req.version).await?;
            Ok(proto::DeleteVersionResponse {})
        })
        .await
    }
}

/// What a stream carries between frames.
struct StreamState {
    state: Arc<AppState>,
    inbound: Streaming<proto::Frame>,
    session: Session,
    drained: Pin<Box<dyn Future<Output = ()> + Send>>,
    guard: StreamGuard,
    done: bool,
}

/// Releases the stream's slot and records it when the stream ends, however it ends.
struct StreamGuard {
    _permit: OwnedSemaphorePermit,
    code: tonic::Code,
}

impl Drop for StreamGuard {
    fn drop(&mut self) {
        metrics::stream_closed();
        metrics::grpc_request("EstimateStream", self.code, None);
    }
}

/// A client-side stream error as the status to end the stream with: tonic's "message too
/// large" (OUT_OF_RANGE) is RESOURCE_EXHAUSTED with the limit, like every other size limit.
fn inbound_error(status: Status, max_body: usize) -> Status {
    if is_too_large(&status) {
        Status::resource_exhausted(too_large_message(max_body, status.message()))
    } else {
        status
    }
}

/// Whether `status` is tonic's decode-size error.
pub fn is_too_large(status: &Status) -> bool {
    status.code() == tonic::Code::OutOfRange && status.message().contains("too large")
}

pub fn too_large_message(max_body: usize, detail: &str) -> String {
    format!("message over the limit of {max_body} bytes (--max-body); split it: {detail}")
}

/// The response of a unary call that failed before the handler (tonic's own checks), with an
/// oversize message remapped like [`inbound_error`].
pub fn remap_trailers_only(
    mut resp: axum::http::Response<tonic::body::Body>,
    max_body: usize,
) -> axum::http::Response<tonic::body::Body> {
    if let Some(status) = Status::from_header_map(resp.headers())
        && is_too_large(&status)
    {
        let new = Status::resource_exhausted(too_large_message(max_body, status.message()));
        let headers = resp.headers_mut();
        headers.remove("grpc-status");
        headers.remove("grpc-message");
        let _ = new.add_header(headers);
    }
    resp
}
