//! The rendered ground-truth benchmark (`tests/fixtures/rendered/`, issue 37): gzip'd JSON
//! Lines, one render per line, and `identities.json` listing the files. Decompressed and parsed
//! here; the protocol (`facepose_eval::rendered`) takes the records.

use std::io::Read;
use std::path::{Path, PathBuf};

use facepose_core::data::{RenderedRecord, parse_rendered_lines};
use serde::Deserialize;

use crate::data::DataError;

/// Where the fixtures live in the repository, relative to its root.
pub const RENDERED_DIR: &str = "tests/fixtures/rendered";

/// The record files `identities.json` lists, in its order.
pub fn rendered_files(dir: &Path) -> Result<Vec<String>, DataError> {
    #[derive(Deserialize)]
    struct Index {
        files: Vec<Entry>,
    }
    #[derive(Deserialize)]
    struct Entry {
        file: String,
    }
    let path = dir.join("identities.json");
    let text = std::fs::read_to_string(&path).map_err(|source| DataError::Io {
        path: path.clone(),
        source,
    })?;
    let index: Index = serde_json::from_str(&text).map_err(|e| DataError::Parse {
        path,
        reason: e.to_string(),
    })?;
    Ok(index.files.into_iter().map(|e| e.file).collect())
}

/// The records of one `*.jsonl.gz` file.
pub fn load_rendered_file(path: &Path) -> Result<Vec<RenderedRecord>, DataError> {
    let io = |source| DataError::Io {
        path: path.into(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let mut text = String::new();
    flate2::read::GzDecoder::new(std::io::BufReader::new(file))
        .read_to_string(&mut text)
        .map_err(io)?;
    parse_rendered_lines(&text).map_err(|reason| DataError::Parse {
        path: path.into(),
        reason,
    })
}

/// Every record of the files `identities.json` lists (`only`: just the files so named).
pub fn load_rendered(dir: &Path, only: Option<&[&str]>) -> Result<Vec<RenderedRecord>, DataError> {
    let mut out = Vec::new();
    for f in rendered_files(dir)? {
        if only.is_some_and(|o| !o.contains(&f.as_str())) {
            continue;
        }
        let path: PathBuf = dir.join(&f);
        out.extend(load_rendered_file(&path)?);
    }
    Ok(out)
}
