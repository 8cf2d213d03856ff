//! What the models folder holds, as the API lists it: every model's versions with their
//! metadata and the active one ([`Catalog`]), re-read after each change made here and after
//! each pass of the watcher. The embedded default model is listed as a version of `default`.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::SystemTime;

use super::versions::{self, VersionError};
use super::{DEFAULT_MODEL, ModelSource, Registry, lock};

/// One version as listed by the API.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VersionInfo {
    /// The version's id.
    pub version: String,
    /// When it was created, RFC 3339.
    pub created: String,
    /// The bundle's checksum, `sha256:<hex>`.
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
    /// The model folder's name.
    pub name: String,
    /// The version the folder's pointer names (or its legacy bundle's); `None`: never
    /// activated.
    pub active: Option<String>,
    /// Its versions on disk.
    pub versions: Vec<VersionInfo>,
}

/// The models folder as last read (by the watcher or after a change made here).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Catalog {
    /// Each model folder's versions, by name.
    pub models: BTreeMap<String, StoredVersions>,
}

/// Version metadata by bundle file, with the file's modification time, and how many reads
/// of the folder began.
#[derive(Debug, Default)]
pub(super) struct MetaCache {
    generation: u64,
    files: HashMap<PathBuf, (Option<SystemTime>, VersionInfo)>,
}

/// The state of the catalog's refreshes. A refresh reads the folder with the metadata cache
/// locked (so reads are serialized and the cache is never lost), and its result is stored only
/// if no read that began later has been stored already. Requests that arrive while a refresh
/// is in progress wait for the next one and share it: a read route never queues one read per
/// request on the blocking pool.
#[derive(Debug, Default)]
pub(super) struct Refresh {
    /// One refresh at a time (from async code).
    running: tokio::sync::Mutex<()>,
    /// Tickets of refresh requests, in order.
    requested: AtomicU64,
    /// The last ticket covered by a completed refresh (issued before that refresh began).
    covered: AtomicU64,
    /// The generation of the catalog stored.
    stored: Mutex<u64>,
}

impl Registry {
    /// Re-reads the folder's versions into the catalog. Returns once a read that began after
    /// this call has been stored (or has failed).
    pub async fn refresh_catalog(&self) {
        let Some(dir) = self.dir.clone() else {
            return;
        };
        let r = &self.refresh;
        let ticket = r.requested.fetch_add(1, Ordering::SeqCst) + 1;
        let _running = r.running.lock().await;
        if r.covered.load(Ordering::SeqCst) >= ticket {
            return;
        }
        let covers = r.requested.load(Ordering::SeqCst);
        let meta = self.meta.clone();
        let read = crate::blocking::spawn_blocking(move || {
            let mut meta = lock(&meta);
            meta.generation += 1;
            let generation = meta.generation;
            (generation, read_catalog(&dir, &mut meta.files))
        })
        .await;
        let (generation, catalog) = match read {
            Ok(x) => x,
            Err(e) => {
                tracing::error!(error = %e, "reading the models folder panicked");
                return;
            }
        };
        r.covered.fetch_max(covers, Ordering::SeqCst);
        match catalog {
            Ok(c) => {
                self.store_catalog(generation, c);
            }
            Err(e) => tracing::warn!(error = %e, "cannot read the models folder"),
        }
    }

    /// Stores the catalog read by read `generation`, unless a later read is stored already.
    fn store_catalog(&self, generation: u64, catalog: Catalog) -> bool {
        let mut stored = lock(&self.refresh.stored);
        if generation <= *stored {
            return false;
        }
        *stored = generation;
        self.catalog.store(Arc::new(catalog));
        true
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
        let h = head(facepose_core::model::DEFAULT_BUNDLE).unwrap_or_default();
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

#[cfg(test)]
mod tests {
    use super::super::testing::{add, temp_root};
    use super::super::{load_models, versions};
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
    async fn concurrent_refreshes_keep_the_cache_and_the_newest_catalog() {
        let root = temp_root("refresh");
        for _ in 0..3 {
            add(&root, "m");
        }
        versions::activate(&root, "m", "2", false).unwrap();
        let reg = Arc::new(Registry::with_dir(
            load_models(Some(&root)).unwrap(),
            Some(root.clone()),
        ));
        let hs: Vec<_> = (0..16)
            .map(|_| {
                let reg = reg.clone();
                tokio::spawn(async move { reg.refresh_catalog().await })
            })
            .collect();
        for h in hs {
            h.await.unwrap();
        }
        // Every version's metadata is cached: no refresh took the cache from another.
        assert_eq!(lock(&reg.meta).files.len(), 3);
        let generation = lock(&reg.meta).generation;
        assert!(generation <= 16, "{generation}");
        let c = reg.catalog();
        assert_eq!(c.models["m"].active.as_deref(), Some("2"));
        assert_eq!(c.models["m"].versions.len(), 3);
        // A change made after a refresh was requested is seen by it.
        versions::activate(&root, "m", "3", false).unwrap();
        reg.refresh_catalog().await;
        assert_eq!(reg.catalog().models["m"].active.as_deref(), Some("3"));
        // An older read never replaces a newer one.
        let newest = lock(&reg.meta).generation;
        assert!(!reg.store_catalog(newest - 1, Catalog::default()));
        assert!(!reg.store_catalog(newest, Catalog::default()));
        assert_eq!(reg.catalog().models["m"].active.as_deref(), Some("3"));
        assert!(reg.store_catalog(newest + 1, Catalog::default()));
        assert_eq!(*reg.catalog(), Catalog::default());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
