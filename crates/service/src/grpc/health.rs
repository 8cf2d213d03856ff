//! The standard gRPC health service (`grpc.health.v1.Health`), answering from the lifecycle:
//! SERVING until the drain starts, NOT_SERVING after, for the overall server (`""`) and for
//! `facepose.v1.PoseService`; NOT_FOUND for any other name.
//!
//! Our own rather than tonic-health's reporter because `Watch` streams must end when the server
//! drains (they send NOT_SERVING, then end with UNAVAILABLE): an endless watch would hold the
//! graceful shutdown until the drain cap.

use std::pin::Pin;
use std::sync::Arc;

use futures_util::{Stream, StreamExt};
use tonic::{Request, Response, Status};
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_server::Health;
use tonic_health::pb::{HealthCheckRequest, HealthCheckResponse};

use facepose_app::App;
use facepose_app::error::ServiceError;

use crate::proto::pose_service_server::PoseServiceServer;

/// The gRPC name of the pose service.
pub const POSE_SERVICE: &str =
    <PoseServiceServer<super::PoseApi> as tonic::server::NamedService>::NAME;

/// The health service.
#[derive(Debug, Clone)]
pub struct HealthApi {
    app: Arc<App>,
}

impl HealthApi {
    /// The health service of `app`.
    pub fn new(app: Arc<App>) -> Self {
        HealthApi { app }
    }

    fn status(&self, service: &str) -> Result<ServingStatus, Status> {
        if !(service.is_empty() || service == POSE_SERVICE) {
            return Err(Status::not_found(format!(
                "unknown service {service:?}; known: \"\" (the server), {POSE_SERVICE}"
            )));
        }
        Ok(if self.app.lifecycle.is_ready() {
            ServingStatus::Serving
        } else {
            ServingStatus::NotServing
        })
    }
}

fn response(s: ServingStatus) -> HealthCheckResponse {
    HealthCheckResponse { status: s as i32 }
}

type WatchStream = Pin<Box<dyn Stream<Item = Result<HealthCheckResponse, Status>> + Send>>;

#[tonic::async_trait]
impl Health for HealthApi {
    async fn check(
        &self,
        request: Request<HealthCheckRequest>,
    ) -> Result<Response<HealthCheckResponse>, Status> {
        let s = self.status(&request.into_inner().service)?;
        Ok(Response::new(response(s)))
    }

    type WatchStream = WatchStream;

    async fn watch(
        &self,
        request: Request<HealthCheckRequest>,
    ) -> Result<Response<WatchStream>, Status> {
        let first = self.status(&request.into_inner().service)?;
        let drained = self.app.lifecycle.drained();
        // SERVING now (if so), NOT_SERVING when the drain starts, then the end.
        let out = futures_util::stream::unfold(
            (Some(first), Some(Box::pin(drained))),
            |(first, drained)| async move {
                match (first, drained) {
                    (Some(ServingStatus::Serving), d) => {
                        Some((Ok(response(ServingStatus::Serving)), (None, d)))
                    }
                    (_, Some(d)) => {
                        d.await;
                        Some((Ok(response(ServingStatus::NotServing)), (None, None)))
                    }
                    (_, None) => None,
                }
            },
        )
        .chain(futures_util::stream::once(async {
            Err(super::error::status(&ServiceError::ShuttingDown))
        }));
        Ok(Response::new(Box::pin(out)))
    }
}
