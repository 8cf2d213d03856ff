//! `facepose reconstruct`: structure from motion on a multi-view JSON file.

use std::path::PathBuf;

use clap::Args;

use super::CliError;

#[derive(Args)]
pub struct ReconstructArgs {
    /// The multi-view JSON file.
    #[arg(long)]
    views: PathBuf,
}

pub fn run(a: ReconstructArgs) -> Result<(), CliError> {
    Err(format!("reconstruct: {} (not wired yet)", a.views.display()).into())
}
