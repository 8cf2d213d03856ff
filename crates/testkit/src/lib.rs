//! Helpers of the workspace's tests (a dev-dependency only).
//!
//! - [`faces`]: landmarks of the default model's mean shape seen at known poses, the
//!   independent expectation of every service test, and rotation helpers.
//! - [`server`]: a `facepose_service::serve` in the test process, on a loopback port, on a
//!   runtime of its own, with its log lines captured apart from other servers' ([`logs`]).
//! - [`process`]: the real `facepose serve` binary as a child process, for what only a
//!   process shows: signals, exit statuses, kill -9.
//! - [`raw`]: HTTP/1.1 exchanges written by hand (bodies that stop, lie about their length).
//! - [`raw_grpc`]: gRPC calls with message bytes written by hand (malformed, amplifying).
//! - [`registry`]: models folders, shape sets to upload, and the admin calls of retraining.

pub mod faces;
pub mod logs;
pub mod process;
pub mod raw;
pub mod raw_grpc;
pub mod registry;
pub mod server;

use std::net::SocketAddr;

use facepose_service::proto;

/// A running server, in-process or not: where to reach it.
pub trait Endpoint {
    /// `http://addr`.
    fn base(&self) -> &str;

    /// The server's address.
    fn addr(&self) -> SocketAddr;

    /// `base()` followed by `path`.
    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base())
    }

    /// A gRPC channel to the server.
    #[allow(async_fn_in_trait)]
    async fn channel(&self) -> tonic::transport::Channel {
        tonic::transport::Endpoint::from_shared(self.base().to_string())
            .unwrap()
            .connect()
            .await
            .expect("gRPC connect")
    }

    /// A client of the pose service.
    #[allow(async_fn_in_trait)]
    async fn grpc(
        &self,
    ) -> proto::pose_service_client::PoseServiceClient<tonic::transport::Channel> {
        proto::pose_service_client::PoseServiceClient::new(self.channel().await)
    }
}

/// Opens an `EstimateStream` on `c`: the sender of its frames (up to `capacity` waiting) and
/// its results.
pub async fn open_stream(
    c: &mut proto::pose_service_client::PoseServiceClient<tonic::transport::Channel>,
    capacity: usize,
) -> (
    tokio::sync::mpsc::Sender<proto::Frame>,
    tonic::Streaming<proto::FrameResult>,
) {
    let (tx, rx) = tokio::sync::mpsc::channel(capacity);
    let out = c
        .estimate_stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap()
        .into_inner();
    (tx, out)
}
