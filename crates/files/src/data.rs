//! Reading the data files the project develops and tests with (`../shared/data/`) into the
//! core's types (`facepose_core::data`); errors name the file.

use std::path::{Path, PathBuf};

use facepose_core::data as formats;
pub use facepose_core::data::{
    AflwFace, CanonicalMesh, MorphableModel, MultiViewSet, Population, SubjectViews,
};

/// A data file that could not be read or parsed, or a data folder that was not found.
/// `Debug` prints the message too, so a test's `unwrap` says which file it wanted.
#[derive(thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}{}", hint(source))]
    /// The file could not be read.
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    /// The file's content is not what was expected.
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    #[error(
        "no shared data folder: looked at {}; give it with --data DIR or FACEPOSE_DATA=DIR \
         (the folder with bfm68/, aflw2000/, mediapipe/)",
        looked.join(", then ")
    )]
    /// No shared data folder was found.
    NoFolder {
        /// The places looked at, in order.
        looked: Vec<String>,
    },
}

impl std::fmt::Debug for DataError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(self, f)
    }
}

fn hint(e: &std::io::Error) -> &'static str {
    if e.kind() == std::io::ErrorKind::NotFound {
        " (a file of the shared data? point FACEPOSE_DATA, or --data, at the folder that holds \
         bfm68/, aflw2000/ and mediapipe/)"
    } else {
        ""
    }
}

fn read<T>(path: &Path, parse: impl FnOnce(&str) -> Result<T, String>) -> Result<T, DataError> {
    let text = std::fs::read_to_string(path).map_err(|source| DataError::Io {
        path: path.into(),
        source,
    })?;
    parse_as(path, &text, parse)
}

fn parse_as<T>(
    path: &Path,
    text: &str,
    parse: impl FnOnce(&str) -> Result<T, String>,
) -> Result<T, DataError> {
    parse(text).map_err(|reason| DataError::Parse {
        path: path.into(),
        reason,
    })
}

/// The environment variable that names the shared data folder.
pub const DATA_ENV: &str = "FACEPOSE_DATA";

/// Where the commands look for the shared data, in order (what their `--help` says).
pub const DATA_LOOKUP_HELP: &str = "--data DIR, else $FACEPOSE_DATA, else ../shared/data \
from the working directory";

/// The shared data folder at run time: `explicit` (a `--data` flag) if given, else
/// `$FACEPOSE_DATA`, else `../shared/data` from the working directory (a checkout beside the
/// shared folder). A folder named by the flag or the variable must exist; the error lists every
/// place looked at.
pub fn locate_data_dir(explicit: Option<&Path>) -> Result<PathBuf, DataError> {
    let from_env = std::env::var_os(DATA_ENV).map(PathBuf::from);
    locate_in(explicit, from_env.as_deref(), Path::new("../shared/data"))
}

fn locate_in(
    explicit: Option<&Path>,
    from_env: Option<&Path>,
    beside: &Path,
) -> Result<PathBuf, DataError> {
    let absolute = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let (named, what) = match (explicit, from_env) {
        (Some(p), _) => (Some(p), "--data"),
        (None, Some(p)) => (Some(p), DATA_ENV),
        (None, None) => (None, ""),
    };
    if let Some(p) = named {
        return if p.is_dir() {
            Ok(p.to_path_buf())
        } else {
            Err(DataError::NoFolder {
                looked: vec![format!(
                    "{} (from {what}: no such folder)",
                    absolute(p).display()
                )],
            })
        };
    }
    if beside.is_dir() {
        return Ok(beside.to_path_buf());
    }
    Err(DataError::NoFolder {
        looked: vec![
            "--data (not given)".into(),
            format!("{DATA_ENV} (not set)"),
            format!("{} (no such folder)", absolute(beside).display()),
        ],
    })
}

/// The shared data folder of this workspace's own tests and benches: `$FACEPOSE_DATA`, else
/// `../shared/data` beside the checkout they were built in. (The `facepose` binary looks it up
/// at run time with [`locate_data_dir`].)
pub fn data_dir() -> PathBuf {
    match std::env::var_os(DATA_ENV) {
        Some(p) => PathBuf::from(p),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    }
}

/// Reads a population file (`bfm68/population_*.json`).
pub fn load_population(path: &Path) -> Result<Population, DataError> {
    read(path, formats::parse_population)
}

/// Reads the morphable model file.
pub fn load_morphable_model(path: &Path) -> Result<MorphableModel, DataError> {
    read(path, formats::parse_morphable_model)
}

/// Reads `canonical_face_468.json`.
pub fn load_canonical_mesh(path: &Path) -> Result<CanonicalMesh, DataError> {
    read(path, formats::parse_canonical_mesh)
}

/// Reads a JSON Lines file of faces; errors name the line.
pub fn load_aflw(path: &Path) -> Result<Vec<AflwFace>, DataError> {
    read(path, formats::parse_aflw)
}

/// Parses a multi-view file's text (`path` is only used in messages).
pub fn parse_multi_view(path: &Path, text: &str) -> Result<MultiViewSet, DataError> {
    parse_as(path, text, formats::parse_multi_view)
}

/// Reads a multi-view file.
pub fn load_multi_view(path: &Path) -> Result<MultiViewSet, DataError> {
    read(path, formats::parse_multi_view)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_data_folder_is_looked_up_in_order_and_the_error_says_where() {
        let here = Path::new(env!("CARGO_MANIFEST_DIR"));
        let missing = Path::new("/nonexistent/facepose-data");
        // The flag wins over the variable, the variable over the folder beside.
        assert_eq!(locate_in(Some(here), Some(missing), missing).unwrap(), here);
        assert_eq!(locate_in(None, Some(here), missing).unwrap(), here);
        assert_eq!(locate_in(None, None, here).unwrap(), here);
        // A folder named by the flag or the variable must exist: no silent fallback.
        let e = locate_in(Some(missing), None, here)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/nonexistent/facepose-data (from --data: no such folder)"),
            "{e}"
        );
        let e = locate_in(None, Some(missing), here)
            .unwrap_err()
            .to_string();
        assert!(e.contains("(from FACEPOSE_DATA: no such folder)"), "{e}");
        let e = locate_in(None, None, missing).unwrap_err().to_string();
        assert!(
            e.contains("--data (not given), then FACEPOSE_DATA (not set), then /nonexistent"),
            "{e}"
        );
        assert!(
            e.contains("give it with --data DIR or FACEPOSE_DATA=DIR"),
            "{e}"
        );
    }

    #[test]
    fn a_missing_data_file_says_which_and_how_to_point_at_the_folder() {
        let e = load_population(Path::new("/nonexistent/bfm68/population_249.json")).unwrap_err();
        // Debug (what `unwrap` prints) is the message, not the raw io::Error.
        let shown = format!("{e:?}");
        assert!(
            shown.starts_with("cannot read /nonexistent/bfm68/population_249.json"),
            "{shown}"
        );
        assert!(shown.contains("point FACEPOSE_DATA, or --data"), "{shown}");
    }
}
