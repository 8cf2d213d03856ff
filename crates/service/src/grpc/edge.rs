//! What wraps every `facepose.v1.PoseService` call before tonic sees it: the pose calls'
//! messages checked against their limits and built as they arrive ([`super::frame_guard`]),
//! for the codec's decoder of the same call ([`Prebuilt`]), and the failures that happen before
//! a handler runs (a message over `--max-body`, a message that does not decode or is over its
//! limits) mapped like the rest and counted in `facepose_grpc_requests_total`, which the
//! handlers count otherwise.

use std::sync::Arc;

use axum::extract::{Request, State};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use facepose_app::App;
use tonic::Status;

use super::codec::{Prebuilt, REFUSED_BEFORE_DECODING};
use super::error::{code_name, is_too_large, too_large_message};
use super::frame_guard::{FrameGuard, GuardedBody, Rpc};
use axum::body::Body;

/// The RPCs of `facepose.v1.PoseService`, by the last segment of their path.
pub const RPCS: [&str; 12] = [
    "Estimate",
    "EstimateBatch",
    "EstimateStream",
    "ListModels",
    "GetModel",
    "Retrain",
    "GetJob",
    "CancelJob",
    "ListVersions",
    "ActivateVersion",
    "DeleteVersion",
    "Unknown",
];

/// The metrics label of the RPC at `path` (`Unknown` for a method the service does not have).
pub fn rpc_label(path: &str) -> &'static str {
    let method = path.rsplit('/').next().unwrap_or_default();
    RPCS.iter()
        .find(|r| **r == method)
        .copied()
        .unwrap_or("Unknown")
}

/// The middleware: see the module doc.
pub async fn edge(State(app): State<Arc<App>>, req: Request, next: Next) -> Response {
    let rpc = rpc_label(req.uri().path());
    // The pose calls' messages are checked as they arrive, before tonic holds them whole, and
    // built on the way for the call's decoder.
    let mut resp = match Rpc::of(req.uri().path()) {
        Some(call) => {
            let prebuilt = Prebuilt::default();
            let guard = FrameGuard::new(call, app.limits.max_batch).building_into(prebuilt.clone());
            let req = req.map(|body| Body::new(GuardedBody::new(body, guard)));
            prebuilt.scope(next.run(req)).await
        }
        None => next.run(req).await,
    };
    // A status in the headers is a call that failed without a body: tonic's own checks and
    // the codec's come this way, before any handler.
    let Some(status) = Status::from_header_map(resp.headers()) else {
        return resp;
    };
    let before_handler = if is_too_large(&status) {
        let mapped =
            Status::resource_exhausted(too_large_message(app.limits.max_body, status.message()));
        let headers = resp.headers_mut();
        headers.remove("grpc-status");
        headers.remove("grpc-message");
        let _ = mapped.add_header(headers);
        Some(mapped.code())
    } else if resp.headers_mut().remove(REFUSED_BEFORE_DECODING).is_some() {
        Some(status.code())
    } else {
        None
    };
    if let Some(code) = before_handler {
        app.metrics.grpc_request(rpc, code_name(code), None);
        tracing::debug!(
            rpc,
            code = code_name(code),
            message = status.message(),
            "gRPC call refused before its handler"
        );
    }
    resp.into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_the_rpcs_of_the_service() {
        assert_eq!(
            rpc_label("/facepose.v1.PoseService/EstimateBatch"),
            "EstimateBatch"
        );
        assert_eq!(rpc_label("/facepose.v1.PoseService/Estimate"), "Estimate");
        assert_eq!(rpc_label("/facepose.v1.PoseService/Nope"), "Unknown");
        assert_eq!(rpc_label(""), "Unknown");
    }
}
