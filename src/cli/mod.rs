//! Subcommands of the `facepose` binary: argument parsing, files and printing around the library.

pub mod estimate;
pub mod eval;
pub mod eval_sfm;
pub mod hpr;
pub mod reconstruct;
pub mod serve;
pub mod train;

/// An error of a subcommand, printed with its context chain.
pub type CliError = Box<dyn std::error::Error + Send + Sync>;

/// The model of `--model DIR`, or the embedded default model.
pub fn load_model(
    dir: Option<&std::path::Path>,
) -> Result<
    (
        facepose_core::model::bundle::Bundle,
        facepose_core::model::PoseModel,
    ),
    CliError,
> {
    match dir {
        Some(d) => Ok(facepose_files::store::load_model(d)?),
        None => Ok(facepose_core::model::default_model()?),
    }
}
