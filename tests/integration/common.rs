//! Helpers shared by the integration tests: the shared data folder and seeded synthetic views.
#![allow(dead_code)]

use std::path::PathBuf;

pub use facepose_files::data::data_dir;

/// A file of the shared data, with a clear message when the folder is not beside the repo.
pub fn data_file(rel: &str) -> PathBuf {
    let p = data_dir().join(rel);
    assert!(
        p.exists(),
        "missing {} (set FACEPOSE_DATA or put ../shared/data beside the repo)",
        p.display()
    );
    p
}
