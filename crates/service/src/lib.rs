//! `facepose serve`: HTTP JSON (axum) and gRPC (tonic) on one port, over the application layer
//! (`facepose_app`). This crate is the transports and nothing more: [`http`] and [`grpc`]
//! convert between their wire types and the application's, and map its errors to their
//! statuses in their own words; neither imports the other. [`server`] composes them on one
//! listener and drains; [`config`] holds the flags.

pub mod config;
pub mod connections;
pub mod grpc;
pub mod http;
pub mod proto;
pub mod server;

pub use config::{Config, ServeArgs};
pub use server::{ServeError, run, serve};
