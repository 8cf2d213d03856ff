//! The service's tests, in-process: each test starts `facepose_service::serve` on loopback
//! ports (`facepose_testkit::server`) and calls it as a client would, over HTTP and gRPC. The
//! servers of a test process run side by side, each with its own metrics and its own log
//! lines. What only a process shows (signals, exit statuses, kill -9) is in the root package's
//! tests (tests/integration/service_process.rs).

mod conventions;
mod demo;
mod grpc;
mod grpc_conventions;
mod http;
mod lifecycle;
mod registry;
mod websocket;
