//! Bundles on disk: `DIR/model.json`. Writing is atomic: the bundle goes to a temporary sibling
//! directory, is fsynced, and is renamed into place, so a crash never leaves a half-written
//! model at `DIR`. With `data.rs`'s readers, the only file-system code of the library.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use facepose_core::model::PoseModel;
use facepose_core::model::bundle::{Bundle, BundleError};

/// The file name of a bundle inside its directory.
pub const MODEL_FILE: &str = "model.json";

/// A bundle that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{path}: {source}")]
    /// The file could not be read or written.
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    /// The file is not a valid bundle.
    Bundle {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: BundleError,
    },
    #[error("{path} already exists; choose another --out or remove it")]
    /// The target exists already.
    Exists {
        /// The existing path.
        path: PathBuf,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.into(),
        source,
    }
}

/// The bundle file of `path`: `path/model.json` for a directory, else `path` itself.
pub fn bundle_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join(MODEL_FILE)
    } else {
        path.into()
    }
}

/// Reads and parses a bundle (not yet validated).
pub fn read_bundle(path: &Path) -> Result<Bundle, StoreError> {
    let file = bundle_file(path);
    let text = fs::read_to_string(&file).map_err(io(&file))?;
    Bundle::parse(&text).map_err(|source| StoreError::Bundle { path: file, source })
}

/// Reads, validates and builds the model of a bundle.
pub fn load_model(path: &Path) -> Result<(Bundle, PoseModel), StoreError> {
    let bundle = read_bundle(path)?;
    let model = bundle.load().map_err(|source| StoreError::Bundle {
        path: bundle_file(path),
        source,
    })?;
    Ok((bundle, model))
}

/// A suffix for temporary names no other writer uses: the process id and the time in ns.
pub fn unique_suffix() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("{}-{nanos}", std::process::id())
}

/// Makes the entries of the folder `dir` durable (fsync of the folder).
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir).and_then(|d| d.sync_all())
}

/// Writes `bundle` as the new directory `dir` atomically. Fails if `dir` exists.
pub fn write_bundle_dir(dir: &Path, bundle: &Bundle) -> Result<(), StoreError> {
    if dir.exists() {
        return Err(StoreError::Exists { path: dir.into() });
    }
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    fs::create_dir_all(&parent).map_err(io(&parent))?;
    let base = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into());
    let tmp = parent.join(format!(".{base}.tmp-{}", unique_suffix()));
    let result = (|| {
        fs::create_dir(&tmp).map_err(io(&tmp))?;
        let file = tmp.join(MODEL_FILE);
        let mut f = File::create(&file).map_err(io(&file))?;
        f.write_all(bundle.to_json().as_bytes())
            .map_err(io(&file))?;
        f.sync_all().map_err(io(&file))?;
        sync_dir(&tmp).map_err(io(&tmp))?;
        fs::rename(&tmp, dir).map_err(io(dir))?;
        sync_dir(&parent).map_err(io(&parent))
    })();
    if result.is_err() {
        let _ = fs::remove_dir_all(&tmp);
    }
    result
}
