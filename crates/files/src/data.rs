//! Reading the data files the project develops and tests with (`../shared/data/`) into the
//! core's types (`facepose_core::data`); errors name the file.

use std::path::{Path, PathBuf};

use facepose_core::data as formats;
pub use facepose_core::data::{
    AflwFace, CanonicalMesh, MorphableModel, MultiViewSet, Population, SubjectViews,
};

/// A data file that could not be read or parsed.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Parse { path: PathBuf, reason: String },
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

/// Where the shared data lives: `$FACEPOSE_DATA`, else `../shared/data` next to the workspace.
pub fn data_dir() -> PathBuf {
    match std::env::var_os("FACEPOSE_DATA") {
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
