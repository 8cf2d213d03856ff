//! Subcommands of the `facepose` binary: argument parsing, files and printing around the library.

pub mod estimate;
pub mod eval;
pub mod eval_sfm;
pub mod healthcheck;
pub mod hpr;
pub mod names;
pub mod progress;
pub mod reconstruct;
pub mod serve;
pub mod train;

/// An error of a subcommand, printed with its context chain.
pub type CliError = Box<dyn std::error::Error + Send + Sync>;

/// A subcommand that ran to its end with an outcome its exit status reports (`estimate`: some
/// or no faces estimated): the message goes to standard error, `status` is the exit status.
#[derive(Debug)]
pub struct Finished {
    /// The process's exit status.
    pub status: u8,
    /// What standard error says about the outcome.
    pub message: String,
}

impl Finished {
    pub fn new(status: u8, message: impl Into<String>) -> Self {
        Finished {
            status,
            message: message.into(),
        }
    }
}

impl std::fmt::Display for Finished {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Finished {}

/// `--data DIR`: the shared data folder, for the commands whose default inputs come from it.
#[derive(clap::Args)]
pub struct DataArg {
    /// The shared data folder (with bfm68/, aflw2000/, mediapipe/), for the default input
    /// files. Looked up at run time: --data DIR, else $FACEPOSE_DATA, else ../shared/data from
    /// the working directory; the error lists where it looked.
    #[arg(long, value_name = "DIR")]
    pub data: Option<std::path::PathBuf>,
}

impl DataArg {
    /// `explicit` if given, else the shared data folder's file `rel`.
    pub fn or_file(
        &self,
        explicit: Option<&std::path::Path>,
        rel: &str,
    ) -> Result<std::path::PathBuf, CliError> {
        match explicit {
            Some(p) => Ok(p.to_path_buf()),
            None => Ok(facepose_files::data::locate_data_dir(self.data.as_deref())?.join(rel)),
        }
    }
}

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
