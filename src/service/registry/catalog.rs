//! What the models folder holds, as the API lists it: every model's versions with their
//! metadata and the active one ([`Catalog`]), re-read after each change made here and after
//! each pass of the watcher. The embedded default model is listed as a version of `default`.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::SystemTime;

use super::versions::{self, VersionError};
use super::{DEFAULT_MODEL, ModelSource, Registry, lock};

/// One version as listed by the API.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VersionInfo {
    pub version: String,
    pub created: String,
    pub checksum: String,
    /// The model's own scheme in that version.
    pub scheme: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// The bundle deployed with the folder (`DIR/<name>/model.json`) or the embedded model:
    /// not deletable through the API.
    pub fixed: bool,
}

/// One model's versions on disk and which is active there.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredVersions {
    pub name: String,
    /// The version the folder's pointer names (or its legacy bundle's); `None`: never
    /// activated.
    pub active: Option<String>,
    pub versions: Vec<VersionInfo>,
}

/// The models folder as last read (by the watcher or after a change made here).
#[derive(Debug, Clone, Default)]
pub struct Catalog {
    pub models: BTreeMap<String, StoredVersions>,
}

impl Registry {
    /// Re-reads the folder's versions into the catalog.
    pub async fn refresh_catalog(&self) {
        let Some(dir) = self.dir.clone() else {
            return;
        };
        let meta = std::mem::take(&mut *lock(&self.meta));
        let (catalog, meta) = match tokio::task::spawn_blocking(move || {
            let mut meta = meta;
            let c = read_catalog(&dir, &mut meta);
            (c, meta)
        })
        .await
        {
            Ok(x) => x,
            Err(e) => {
                tracing::error!(error = %e, "reading the models folder panicked");
                return;
            }
        };
        *lock(&self.meta) = meta;
        match catalog {
            Ok(c) => self.catalog.store(Arc::new(c)),
            Err(e) => tracing::warn!(error = %e, "cannot read the models folder"),
        }
    }
}

/// Reads the folder's versions with their metadata (`meta` caches it by file and time).
fn read_catalog(
    dir: &Path,
    meta: &mut HashMap<PathBuf, (Option<SystemTime>, VersionInfo)>,
) -> Result<Catalog, VersionError> {
    let mut models = BTreeMap::new();
    let mut seen = Vec::new();
    for m in versions::scan(dir, false)? {
        let mut list = Vec::new();
        for v in &m.versions {
            let mtime = std::fs::metadata(&v.file).and_then(|x| x.modified()).ok();
            seen.push(v.file.clone());
            let info = match meta.get(&v.file) {
                Some((t, info)) if *t == mtime && mtime.is_some() => info.clone(),
                _ => match read_info(&v.file, v.legacy) {
                    Ok(info) => {
                        meta.insert(v.file.clone(), (mtime, info.clone()));
                        info
                    }
                    Err(e) => VersionInfo {
                        version: v.version.clone(),
                        created: String::new(),
                        checksum: String::new(),
                        scheme: String::new(),
                        source: format!("{} (unreadable: {e})", v.file.display()),
                        fixed: v.legacy,
                    },
                },
            };
            list.push(VersionInfo {
                version: v.version.clone(),
                ..info
            });
        }
        let mut active = m.active().map(str::to_string);
        if m.name == DEFAULT_MODEL && !list.iter().any(|v| v.version == embedded_version()) {
            list.insert(0, embedded_info().clone());
            // Never activated: the embedded model is what the folder serves.
            active.get_or_insert_with(|| embedded_version().to_string());
        }
        models.insert(
            m.name.clone(),
            StoredVersions {
                name: m.name.clone(),
                active,
                versions: list,
            },
        );
    }
    models
        .entry(DEFAULT_MODEL.to_string())
        .or_insert_with(|| StoredVersions {
            name: DEFAULT_MODEL.into(),
            active: Some(embedded_version().to_string()),
            versions: vec![embedded_info().clone()],
        });
    meta.retain(|k, _| seen.contains(k));
    Ok(Catalog { models })
}

/// The embedded default model as a version of `DIR/default`.
pub fn embedded_info() -> &'static VersionInfo {
    static I: OnceLock<VersionInfo> = OnceLock::new();
    I.get_or_init(|| {
        // The embedded bundle parses (a unit test of `model` checks it).
        let h = head(crate::model::DEFAULT_BUNDLE).unwrap_or_default();
        VersionInfo {
            version: h.version,
            created: h.created,
            checksum: h.checksum,
            scheme: h.scheme.name,
            source: ModelSource::Embedded.to_string(),
            fixed: true,
        }
    })
}

/// The embedded default model's version.
pub fn embedded_version() -> &'static str {
    &embedded_info().version
}

/// The fields of a bundle the listing shows, read without validating the rest.
#[derive(Default, serde::Deserialize)]
struct Head {
    version: String,
    created: String,
    checksum: String,
    scheme: SchemeHead,
}

#[derive(Default, serde::Deserialize)]
struct SchemeHead {
    name: String,
}

fn head(text: &str) -> Result<Head, serde_json::Error> {
    serde_json::from_str(text)
}

fn read_info(file: &Path, legacy: bool) -> Result<VersionInfo, String> {
    let text = std::fs::read_to_string(file).map_err(|e| e.to_string())?;
    let h = head(&text).map_err(|e| e.to_string())?;
    Ok(VersionInfo {
        version: h.version,
        created: h.created,
        checksum: h.checksum,
        scheme: h.scheme.name,
        source: file.display().to_string(),
        fixed: legacy,
    })
}
