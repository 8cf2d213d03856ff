//! `facepose serve`: the long-running service (HTTP JSON and gRPC on one port). Everything is in
//! `facepose::service`; this only hands the flags over.

use facepose::service::config::ServeArgs;

use super::CliError;

pub fn run(a: ServeArgs) -> Result<(), CliError> {
    facepose::service::run(a)?;
    Ok(())
}
