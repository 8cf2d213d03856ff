//! What every part of the models folder's file work shares: its error, [`VersionError`], and
//! the small operations that produce it (an I/O error with its path, a folder's fsync, a unique
//! suffix for hidden temporaries). Below both the versions and the pointer, so that neither
//! depends on the other for them.

use std::path::{Path, PathBuf};

use facepose_files::store::{self, StoreError};

pub use facepose_files::store::unique_suffix;

/// A failure of a versions operation.
#[derive(Debug, thiserror::Error)]
pub enum VersionError {
    #[error("{}: {source}", path.display())]
    /// A file or directory could not be read or written.
    Io {
        /// The path.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error(transparent)]
    /// A bundle could not be read or written.
    Store(#[from] StoreError),
    #[error("model {name:?} has no version {version:?}{}", list(existing))]
    /// No such version.
    NotFound {
        /// The model's name.
        name: String,
        /// The version asked for.
        version: String,
        /// The versions there are.
        existing: Vec<String>,
    },
    #[error("version {version} of model {name:?} is active; activate another version first")]
    /// The version is active, so cannot be deleted.
    Active {
        /// The model's name.
        name: String,
        /// The version.
        version: String,
    },
    #[error(
        "version {version} of model {name:?} is the bundle deployed with the folder ({}); it is not deleted through the API",
        path.display()
    )]
    /// The version is the legacy bundle deployed with the folder, not deleted through the API.
    Legacy {
        /// The model's name.
        name: String,
        /// The version.
        version: String,
        /// The legacy bundle file.
        path: PathBuf,
    },
    #[error("{0}")]
    /// The request is invalid (the message says why).
    Invalid(String),
}

fn list(v: &[String]) -> String {
    if v.is_empty() {
        "; it has none".into()
    } else {
        format!("; it has {}", v.join(", "))
    }
}

/// Maps an I/O error on `path` to [`VersionError::Io`].
pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> VersionError + '_ {
    move |source| VersionError::Io {
        path: path.into(),
        source,
    }
}

/// Fsyncs folder `dir`, so that the entries renamed into it last.
pub fn sync_dir(dir: &Path) -> Result<(), VersionError> {
    store::sync_dir(dir).map_err(io(dir))
}
