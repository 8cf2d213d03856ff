//! `facepose serve`: the long-running service (HTTP JSON and gRPC on one port). Everything is in
//! `facepose_service`; this only hands the flags over.

use facepose_service::config::ServeArgs;

use super::CliError;

pub fn run(a: ServeArgs) -> Result<(), CliError> {
    facepose_service::run(a)?;
    Ok(())
}
