//! The gRPC API (`facepose.v1.PoseService`, proto/facepose/v1/pose.proto): the same
//! application as the HTTP API (`facepose_app::App`), through the conversions of [`convert`]
//! and the statuses of [`error`].
//!
//! Unary calls share the HTTP API's concurrency limit and time limit (UNAVAILABLE and
//! DEADLINE_EXCEEDED). Streams ([`stream`]) have their own limit (`--max-streams`), watch the
//! drain signal, and end with UNAVAILABLE when the server shuts down. [`health`] is the
//! standard health service, [`retrain`] turns a `Retrain` stream into an upload.

pub mod codec;
pub mod convert;
pub mod edge;
pub mod error;
pub mod frame_guard;
pub mod health;
pub mod retrain;
pub mod stream;

use std::sync::Arc;
use std::time::Instant;

use facepose_app::App;
use facepose_app::error::ServiceError;
use facepose_app::estimate::{BatchSize, check_batch_size};
use facepose_app::jobs::Cancel;
use facepose_app::metrics::Transport;
use facepose_app::tracking::Smoothed;
use tonic::{Request, Response, Status, Streaming};

pub use convert::landmark_messages;
use convert::{face_result, job_message, model_info, pose_message};
use error::{code_name, inbound_error};
use retrain::ChunkCollector;
use stream::FrameStream;

use crate::proto::{self, pose_service_server::PoseService};

/// The gRPC service.
#[derive(Clone, Debug)]
pub struct PoseApi {
    app: Arc<App>,
}

impl PoseApi {
    /// The gRPC service of `app`.
    pub fn new(app: Arc<App>) -> Self {
        PoseApi { app }
    }
}

/// Checks the admin token of a call (`authorization: Bearer <token>` metadata).
fn authorize<T>(app: &App, request: &Request<T>) -> Result<(), ServiceError> {
    app.authorize(
        request
            .metadata()
            .get_all("authorization")
            .iter()
            .map(|v| v.as_bytes()),
    )
}

/// One face with its own outcome, as in a batch.
async fn unary<T, F>(app: &App, rpc: &'static str, f: F) -> Result<Response<T>, Status>
where
    F: Future<Output = Result<T, ServiceError>>,
{
    let started = Instant::now();
    let result = match app.request_permit() {
        Err(e) => Err(e),
        Ok(_permit) => match tokio::time::timeout(app.limits.request_timeout, f).await {
            Ok(r) => r,
            Err(_) => Err(ServiceError::Timeout {
                limit: app.limits.request_timeout,
            }),
        },
    };
    let code = match &result {
        Ok(_) => tonic::Code::Ok,
        Err(e) => error::code(e.kind()),
    };
    app.metrics
        .grpc_request(rpc, code_name(code), Some(started.elapsed()));
    if let Err(e) = &result {
        tracing::debug!(rpc, error = %e, "gRPC call failed");
    }
    result.map(Response::new).map_err(|e| error::status(&e))
}

#[tonic::async_trait]
impl PoseService for PoseApi {
    async fn estimate(
        &self,
        request: Request<proto::EstimateRequest>,
    ) -> Result<Response<proto::EstimateResponse>, Status> {
        let app = self.app.clone();
        unary(&self.app, "Estimate", async move {
            let req = request.into_inner();
            let face = req
                .face
                .ok_or_else(|| ServiceError::invalid("missing face: set EstimateRequest.face"))?;
            let answer = app.estimate(Transport::Grpc, Some(&req.model), &face)?;
            Ok(proto::EstimateResponse {
                pose: Some(pose_message(&answer.pose, Smoothed::default())),
                id: face.id,
                model: answer.model.name.clone(),
                model_version: answer.model.version.clone(),
            })
        })
        .await
    }

    async fn estimate_batch(
        &self,
        request: Request<proto::EstimateBatchRequest>,
    ) -> Result<Response<proto::EstimateBatchResponse>, Status> {
        let app = self.app.clone();
        unary(&self.app, "EstimateBatch", async move {
            let req = request.into_inner();
            check_batch_size(req.faces.len(), app.limits.max_batch)?;
            let deadline = Instant::now() + app.limits.request_timeout;
            let size = BatchSize::Faces(req.faces.len());
            app.estimate_batch(Transport::Grpc, size, deadline, move |run| {
                let model = run.model(Some(&req.model))?;
                let results = run.estimate_each(&model, req.faces, |face, outcome| {
                    face_result(face, outcome, Smoothed::default())
                })?;
                Ok(proto::EstimateBatchResponse {
                    results,
                    model: model.name.clone(),
                    model_version: model.version.clone(),
                    succeeded: run.tally().succeeded() as u32,
                    failed: run.tally().failed() as u32,
                })
            })
            .await
        })
        .await
    }

    type EstimateStreamStream = FrameStream;

    async fn estimate_stream(
        &self,
        request: Request<Streaming<proto::Frame>>,
    ) -> Result<Response<FrameStream>, Status> {
        stream::open(&self.app, request.into_inner()).map(Response::new)
    }

    async fn list_models(
        &self,
        _request: Request<proto::ListModelsRequest>,
    ) -> Result<Response<proto::ListModelsResponse>, Status> {
        let app = self.app.clone();
        unary(&self.app, "ListModels", async move {
            let v = app.models_view();
            Ok(proto::ListModelsResponse {
                models: v.models.into_iter().map(model_info).collect(),
                default_model: v.default_model,
            })
        })
        .await
    }

    async fn get_model(
        &self,
        request: Request<proto::GetModelRequest>,
    ) -> Result<Response<proto::ModelInfo>, Status> {
        let app = self.app.clone();
        unary(&self.app, "GetModel", async move {
            let name = request.into_inner().name;
            if name.is_empty() {
                return Err(ServiceError::invalid(
                    "missing name: set GetModelRequest.name",
                ));
            }
            Ok(model_info(app.model_detail(&name)?.model))
        })
        .await
    }

    async fn retrain(
        &self,
        request: Request<Streaming<proto::RetrainChunk>>,
    ) -> Result<Response<proto::Job>, Status> {
        let started = Instant::now();
        let app = self.app.clone();
        let result: Result<proto::Job, Status> = async {
            let refuse = |e: ServiceError| error::status(&e);
            authorize(&app, &request).map_err(refuse)?;
            app.registry.require_dir().map_err(refuse)?;
            let _permit = app.request_permit().map_err(refuse)?;
            // A queue slot before the upload is read: queued uploads bound the memory.
            let slot = app.reserve_job().map_err(refuse)?;
            let limits = app.limits;
            let mut inbound = request.into_inner();
            let mut chunks = ChunkCollector::new(limits.max_upload);
            let receive = async {
                while let Some(chunk) = inbound
                    .message()
                    .await
                    .map_err(|s| inbound_error(s, limits.max_body))?
                {
                    chunks.push(chunk).map_err(refuse)?;
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
            let job = app
                .retrain(move || chunks.finish(), slot)
                .await
                .map_err(refuse)?;
            Ok(job_message(&job))
        }
        .await;
        let code = result
            .as_ref()
            .map_or_else(|s| s.code(), |_| tonic::Code::Ok);
        self.app
            .metrics
            .grpc_request("Retrain", code_name(code), Some(started.elapsed()));
        result.map(Response::new)
    }

    async fn get_job(
        &self,
        request: Request<proto::GetJobRequest>,
    ) -> Result<Response<proto::Job>, Status> {
        let app = self.app.clone();
        unary(&self.app, "GetJob", async move {
            let id = request.into_inner().id;
            Ok(job_message(&app.job(&id).await?))
        })
        .await
    }

    async fn cancel_job(
        &self,
        request: Request<proto::CancelJobRequest>,
    ) -> Result<Response<proto::Job>, Status> {
        let app = self.app.clone();
        unary(&self.app, "CancelJob", async move {
            authorize(&app, &request)?;
            let id = request.into_inner().id;
            if id.is_empty() {
                return Err(ServiceError::invalid("missing id: set CancelJobRequest.id"));
            }
            match app.cancel_job(&id).await? {
                Cancel::Done(job) | Cancel::Requested(job) => Ok(job_message(&job)),
            }
        })
        .await
    }

    async fn list_versions(
        &self,
        request: Request<proto::ListVersionsRequest>,
    ) -> Result<Response<proto::ListVersionsResponse>, Status> {
        let app = self.app.clone();
        unary(&self.app, "ListVersions", async move {
            let name = request.into_inner().name;
            if name.is_empty() {
                return Err(ServiceError::invalid(
                    "missing name: set ListVersionsRequest.name",
                ));
            }
            let v = app.versions(&name).await?;
            Ok(proto::ListVersionsResponse {
                name: v.name,
                active: v.active.unwrap_or_default(),
                versions: v
                    .versions
                    .into_iter()
                    .map(convert::version_message)
                    .collect(),
            })
        })
        .await
    }

    async fn activate_version(
        &self,
        request: Request<proto::ActivateVersionRequest>,
    ) -> Result<Response<proto::ModelInfo>, Status> {
        let app = self.app.clone();
        unary(&self.app, "ActivateVersion", async move {
            authorize(&app, &request)?;
            let req = request.into_inner();
            Ok(model_info(app.activate(&req.name, &req.version).await?))
        })
        .await
    }

    async fn delete_version(
        &self,
        request: Request<proto::DeleteVersionRequest>,
    ) -> Result<Response<proto::DeleteVersionResponse>, Status> {
        let app = self.app.clone();
        unary(&self.app, "DeleteVersion", async move {
            authorize(&app, &request)?;
            let req = request.into_inner();
            app.delete_version(&req.name, &req.version).await?;
            Ok(proto::DeleteVersionResponse {})
        })
        .await
    }
}
