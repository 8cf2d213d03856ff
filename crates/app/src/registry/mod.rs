//! The models the service answers with: an immutable [`ModelSet`] behind an [`ArcSwap`], and
//! its link to the models folder (`--models DIR`; layout and crash rules in [`versions`]).
//!
//! A request takes a snapshot (`Arc<ModelSet>`) when it starts and finishes on it, so replacing
//! the set (an activation here, or one seen on disk) is atomic and never fails a request in
//! progress; the old set is freed when its last request ends. A new version is loaded (about
//! 70 ms) on the blocking pool before the swap, never on the async reactor.
//!
//! Loading at start: every folder `DIR/<name>` serves its active version (the one `ACTIVE`
//! names, else the legacy `DIR/<name>/model.json`); folders with neither are listed but not
//! served. A legacy bundle serves under its `name` field (as before versions existed); a
//! numbered version must carry its folder's name. Every active bundle is validated at start; a
//! broken one stops the start with an error naming the file and the field (a service that
//! silently serves fewer models than deployed is worse than one that does not start). Without
//! a model named `default`, the embedded default model serves as `default`, as version
//! [`embedded_version`] of the folder `DIR/default`.
//!
//! Afterwards, [`Registry::sync`] (the watcher, every `--registry-poll`, [`watch`]) reads the
//! pointers again and loads any newly active version, so replicas sharing the folder converge.
//! A version that fails to load there is logged and reported ([`Registry::problems`]) and the
//! previous one keeps serving. Changes made through the API are in [`changes`], the listing
//! of versions in [`catalog`].

pub mod catalog;
pub mod changes;
pub mod file_ops;
pub mod pointer;
pub mod versions;
pub mod watch;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use arc_swap::ArcSwap;

use crate::error::ServiceError;
use crate::metrics::{Metrics, ModelInfo};
pub use catalog::{Catalog, StoredVersions, VersionInfo, embedded_version};
pub use changes::version_error;
use facepose_core::model::bundle::{Bundle, BundleError, Provenance};
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::Method;
use facepose_files::store::{StoreError, load_model};
use versions::{StoredModel, VersionError};
pub use watch::SyncProblem;

/// The name of the model used when a request names none.
pub const DEFAULT_MODEL: &str = "default";

/// Where a model was loaded from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModelSource {
    /// The default model compiled into the binary.
    Embedded,
    /// A bundle file.
    File(PathBuf),
}

impl std::fmt::Display for ModelSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ModelSource::Embedded => f.write_str("embedded"),
            ModelSource::File(p) => write!(f, "{}", p.display()),
        }
    }
}

/// A loaded model with the bundle's metadata (the bundle's arrays are not kept).
#[derive(Debug)]
pub struct ServedModel {
    /// The model's name.
    pub name: String,
    /// The model's version.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// The bundle's checksum, `sha256:<hex>`.
    pub checksum: String,
    /// Its provenance: source files, the command that built it, notes.
    pub provenance: Provenance,
    /// Where it was loaded from.
    pub source: ModelSource,
    /// The models folder entry (`DIR/<store>`) it is a version of, if any.
    pub store: Option<String>,
    /// The model.
    pub model: PoseModel,
}

impl ServedModel {
    /// What the metrics show of it.
    pub fn info(&self) -> ModelInfo<'_> {
        ModelInfo {
            name: &self.name,
            version: &self.version,
            checksum: &self.checksum,
        }
    }

    fn new(bundle: Bundle, model: PoseModel, source: ModelSource, store: Option<String>) -> Self {
        ServedModel {
            name: bundle.name,
            version: bundle.version,
            created: bundle.created,
            checksum: bundle.checksum,
            provenance: bundle.provenance,
            source,
            store,
            model,
        }
    }

    /// The model's own scheme (the default scheme of requests).
    pub fn scheme(&self) -> &str {
        &self.model.scheme.name
    }

    /// `(name, points)` of every scheme it serves, its own first.
    pub fn schemes(&self) -> impl Iterator<Item = (&str, usize)> {
        self.model.schemes().map(|s| (s.name.as_str(), s.len()))
    }

    /// The methods it supports (what each needs: `facepose_core::pose::METHODS`).
    pub fn methods(&self) -> Vec<Method> {
        Method::ALL
            .into_iter()
            .filter(|m| m.is_supported_by(&self.model))
            .collect()
    }
}

/// An immutable set of models.
#[derive(Debug)]
pub struct ModelSet {
    models: BTreeMap<String, Arc<ServedModel>>,
    default: String,
}

impl ModelSet {
    /// A set from models with distinct names; `default` must be one of them.
    pub fn new(models: Vec<ServedModel>, default: &str) -> Result<Self, RegistryError> {
        let mut map: BTreeMap<String, Arc<ServedModel>> = BTreeMap::new();
        for m in models {
            if let Some(first) = map.get(&m.name) {
                return Err(RegistryError::Duplicate {
                    name: m.name.clone(),
                    first: first.source.to_string(),
                    second: m.source.to_string(),
                });
            }
            map.insert(m.name.clone(), Arc::new(m));
        }
        if !map.contains_key(default) {
            return Err(RegistryError::NoDefault(default.into()));
        }
        Ok(ModelSet {
            models: map,
            default: default.into(),
        })
    }

    /// This set with `model` added, replacing the model of the same name and any other model
    /// served from the same folder entry (a folder serves one model; the default model's
    /// entry is kept so that the set always has it).
    pub fn with_model(&self, model: Arc<ServedModel>) -> ModelSet {
        let mut models = self.models.clone();
        if let Some(store) = model.store.as_deref() {
            models.retain(|name, m| {
                *name == self.default || *name == model.name || m.store.as_deref() != Some(store)
            });
        }
        models.insert(model.name.clone(), model);
        ModelSet {
            models,
            default: self.default.clone(),
        }
    }

    /// The model named `name`, or the default one for `None` or an empty name.
    pub fn get(&self, name: Option<&str>) -> Result<&Arc<ServedModel>, ServiceError> {
        let name = name.filter(|n| !n.is_empty()).unwrap_or(&self.default);
        ServiceError::check_name_length("model", name)?;
        self.models
            .get(name)
            .ok_or_else(|| ServiceError::UnknownModel {
                name: name.to_string(),
                loaded: self.models.keys().cloned().collect(),
            })
    }

    /// Why `name` cannot be served from the folder entry `store`: a model of that name is
    /// already served from another folder.
    pub fn name_conflict(&self, name: &str, store: &str) -> Option<ServiceError> {
        let other = self.models.get(name)?;
        let other_store = other.store.as_deref()?;
        (other_store != store).then(|| {
            ServiceError::Conflict(format!(
                "model {name:?} is already served from the folder {other_store:?} ({}); the \
                 folder {store:?} cannot serve a model of the same name: rename one of them",
                other.source
            ))
        })
    }

    /// The model served from the folder entry `store`.
    pub fn by_store(&self, store: &str) -> Option<&Arc<ServedModel>> {
        self.models
            .values()
            .find(|m| m.store.as_deref() == Some(store))
    }

    /// The default model's name.
    pub fn default_name(&self) -> &str {
        &self.default
    }

    /// Every model, by name.
    pub fn iter(&self) -> impl Iterator<Item = &Arc<ServedModel>> {
        self.models.values()
    }

    /// Number of models served.
    pub fn len(&self) -> usize {
        self.models.len()
    }

    /// Whether no model is served.
    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }
}

/// The current model set, swappable atomically, and its models folder.
#[derive(Debug)]
pub struct Registry {
    current: ArcSwap<ModelSet>,
    dir: Option<PathBuf>,
    /// Serializes changes of the set made by this process (activations, the watcher). An
    /// activation holds it in a task of its own, so a request that goes away never releases
    /// it before the change is done.
    changes: Arc<tokio::sync::Mutex<()>>,
    catalog: ArcSwap<Catalog>,
    /// What the watcher could not serve, by model folder.
    failures: Mutex<BTreeMap<String, watch::Failure>>,
    /// Version metadata by bundle file, with the file's modification time; locked by the
    /// reader of the folder for the whole read, so refreshes read one after the other.
    meta: Arc<Mutex<catalog::MetaCache>>,
    /// Refreshes of the catalog: serialized and coalesced ([`catalog`]).
    refresh: catalog::Refresh,
    metrics: Metrics,
}

impl Registry {
    /// A registry without a models folder (the set never changes), with metrics of its own.
    pub fn new(set: ModelSet) -> Self {
        Self::with_dir(set, None)
    }

    /// A registry following the models folder `dir`, with metrics of its own.
    pub fn with_dir(set: ModelSet, dir: Option<PathBuf>) -> Self {
        Self::with_metrics(set, dir, Metrics::new())
    }

    /// A registry following the models folder `dir`, reporting into `metrics`.
    pub fn with_metrics(set: ModelSet, dir: Option<PathBuf>, metrics: Metrics) -> Self {
        metrics.models(set.iter().map(|m| m.info()), set.default_name());
        Registry {
            current: ArcSwap::from_pointee(set),
            dir,
            changes: Arc::new(tokio::sync::Mutex::new(())),
            catalog: ArcSwap::from_pointee(Catalog::default()),
            failures: Mutex::new(BTreeMap::new()),
            meta: Arc::new(Mutex::new(catalog::MetaCache::default())),
            refresh: catalog::Refresh::default(),
            metrics,
        }
    }

    /// The current set; a request keeps it until it ends.
    pub fn snapshot(&self) -> Arc<ModelSet> {
        self.current.load_full()
    }

    /// Replaces the set atomically and returns the previous one. Requests in progress finish on
    /// the set they started with. (The service changes the set one model at a time, through
    /// activations and the watcher.)
    #[cfg(test)]
    pub fn replace(&self, set: ModelSet) -> Arc<ModelSet> {
        self.current.swap(Arc::new(set))
    }

    /// The models folder, if the server has one.
    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// The models folder, or the error every registry change gives without one.
    pub fn require_dir(&self) -> Result<&Path, ServiceError> {
        self.dir.as_deref().ok_or(ServiceError::NoModelsFolder)
    }

    /// The folder's versions as last read.
    pub fn catalog(&self) -> Arc<Catalog> {
        self.catalog.load_full()
    }

    /// Swaps `model` into the set in one atomic step (requests in progress keep the set they
    /// started with), replacing the model of the same name.
    fn install(&self, model: ServedModel) -> Arc<ServedModel> {
        let model = Arc::new(model);
        let old = self
            .current
            .rcu(|set| Arc::new(set.with_model(model.clone())));
        let previous = model
            .store
            .as_deref()
            .and_then(|s| old.by_store(s))
            .or_else(|| old.get(Some(&model.name)).ok())
            .cloned();
        self.metrics.model_swapped(
            previous.as_deref().map(ServedModel::info),
            model.info(),
            old.default_name(),
        );
        let mut failures = lock(&self.failures);
        if failures
            .remove(model.store.as_deref().unwrap_or(&model.name))
            .is_some()
        {
            self.metrics.sync_problems(failures.len());
        }
        drop(failures);
        model
    }
}

/// A std mutex's guard, also after a panic elsewhere (the data stay consistent: every
/// critical section here is a single insert, remove or read).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Where an active version comes from.
#[derive(Debug, Clone)]
enum Resolved {
    File { file: PathBuf, legacy: bool },
    Embedded,
}

/// Version `version` of the folder entry `name`: a numbered version, the legacy bundle, or the
/// embedded default.
fn resolve(stored: Option<&StoredModel>, name: &str, version: &str) -> Option<Resolved> {
    if let Some(v) = stored.and_then(|m| m.get(version)) {
        return Some(Resolved::File {
            file: v.file.clone(),
            legacy: v.legacy,
        });
    }
    (name == DEFAULT_MODEL && version == embedded_version()).then_some(Resolved::Embedded)
}

/// Loads a resolved version as a served model of the folder entry `store`.
fn load_resolved(store: &str, source: &Resolved) -> Result<ServedModel, RegistryError> {
    match source {
        Resolved::Embedded => {
            let (bundle, model) = default_model()?;
            let mut m = ServedModel::new(
                bundle,
                model,
                ModelSource::Embedded,
                Some(store.to_string()),
            );
            m.name = DEFAULT_MODEL.into();
            Ok(m)
        }
        Resolved::File { file, legacy } => {
            let (bundle, model) = load_model(file)?;
            if !legacy {
                let id = file
                    .parent()
                    .and_then(|p| p.file_name())
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                if bundle.name != store || bundle.version != id {
                    return Err(RegistryError::Mismatch {
                        file: file.clone(),
                        found: format!("{:?} version {:?}", bundle.name, bundle.version),
                        expected: format!("{store:?} version {id:?}"),
                    });
                }
            }
            Ok(ServedModel::new(
                bundle,
                model,
                ModelSource::File(file.clone()),
                Some(store.to_string()),
            ))
        }
    }
}

/// Why the models could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum RegistryError {
    #[error("models folder {}: {source}", path.display())]
    /// The models folder could not be read.
    Dir {
        /// The folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    #[error("model bundle {0}")]
    /// A bundle could not be read.
    Bundle(#[from] StoreError),
    #[error("embedded default model: {0}")]
    /// The embedded default model is invalid.
    Embedded(#[from] BundleError),
    #[error("two models are named {name:?}: {first} and {second}; names must be unique")]
    /// Two bundles name the same model.
    Duplicate {
        /// The model's name.
        name: String,
        /// The first bundle.
        first: String,
        /// The second bundle.
        second: String,
    },
    #[error("no model named {0:?}")]
    /// The default model (named) is not among the loaded ones.
    NoDefault(String),
    #[error("loading the models failed: {0}")]
    /// Loading the models panicked (the message).
    Panicked(String),
    #[error("models folder: {0}")]
    /// The models folder's versions are inconsistent.
    Versions(#[from] VersionError),
    #[error("{}: holds model {found}, its place in the folder says {expected}", file.display())]
    /// A bundle's model name differs from its place in the folder.
    Mismatch {
        /// The bundle file.
        file: PathBuf,
        /// The model name it holds.
        found: String,
        /// The name its place says.
        expected: String,
    },
    #[error("{}: names version {version}, which is not in the folder (it has {})", pointer.display(), existing.join(", "))]
    /// A pointer names a version that is not in the folder.
    Pointer {
        /// The pointer file.
        pointer: PathBuf,
        /// The version it names.
        version: String,
        /// The versions in the folder.
        existing: Vec<String>,
    },
}

/// Loads the active version of every model of `dir` (see the module docs) in parallel, plus
/// the embedded default model if `dir` serves no `default`, and removes stale temporaries.
/// `dir = None`: the embedded default model only.
pub fn load_models(dir: Option<&Path>) -> Result<ModelSet, RegistryError> {
    let stored = match dir {
        Some(d) => {
            if !d.is_dir() {
                return Err(RegistryError::Dir {
                    path: d.into(),
                    source: std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        "not a folder (or does not exist)",
                    ),
                });
            }
            versions::scan(d, true)?
        }
        None => vec![],
    };
    let mut sources = Vec::new();
    for m in &stored {
        for p in versions::clean_stale(&m.dir, versions::STALE_AGE) {
            tracing::info!(path = %p.display(), "removed a stale temporary entry");
        }
        let Some(active) = m.active() else { continue };
        match resolve(Some(m), &m.name, active) {
            Some(source) => sources.push((m.name.clone(), source)),
            None => {
                return Err(RegistryError::Pointer {
                    pointer: m.dir.join(pointer::ACTIVE_FILE),
                    version: active.into(),
                    existing: m.ids(),
                });
            }
        }
    }
    let loaded: Vec<Result<ServedModel, RegistryError>> = std::thread::scope(|s| {
        let handles: Vec<_> = sources
            .iter()
            .map(|(name, source)| s.spawn(move || load_resolved(name, source)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or_else(|_| {
                    Err(RegistryError::Panicked("a loader thread panicked".into()))
                })
            })
            .collect()
    });
    let mut models = loaded.into_iter().collect::<Result<Vec<_>, _>>()?;
    if !models.iter().any(|m| m.name == DEFAULT_MODEL) {
        let store = dir.map(|_| DEFAULT_MODEL);
        let mut m = load_resolved(DEFAULT_MODEL, &Resolved::Embedded)?;
        m.store = store.map(str::to_string);
        models.push(m);
    }
    ModelSet::new(models, DEFAULT_MODEL)
}

/// Models folders for the unit tests of the registry.
#[cfg(test)]
pub(crate) mod testing {
    use std::fs;
    use std::path::{Path, PathBuf};

    use facepose_core::model::bundle::Bundle;

    /// A fresh empty folder under the temporary directory.
    pub fn temp_root(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!(
            "facepose-registry-{tag}-{}",
            super::file_ops::unique_suffix()
        ));
        fs::create_dir_all(&d).unwrap();
        d
    }

    /// The default bundle renamed.
    pub fn bundle(name: &str, version: &str) -> Bundle {
        let mut b = Bundle::parse(facepose_core::model::DEFAULT_BUNDLE).unwrap();
        b.name = name.into();
        b.version = version.into();
        b.checksum = b.compute_checksum().unwrap();
        b
    }

    /// Writes a new version of `name`; its id.
    pub fn add(root: &Path, name: &str) -> String {
        super::versions::write_version(root, name, &[], |v| Ok(bundle(name, v)))
            .unwrap()
            .0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::ErrorKind;

    #[test]
    fn the_embedded_default_serves_without_a_folder() {
        let set = load_models(None).unwrap();
        assert_eq!(set.len(), 1);
        let m = set.get(None).unwrap();
        assert_eq!(m.name, "default");
        assert_eq!(m.source, ModelSource::Embedded);
        assert_eq!(m.store, None);
        assert_eq!(
            m.schemes().collect::<Vec<_>>(),
            [
                ("ibug68", 68),
                ("inner51", 51),
                ("five", 5),
                ("dlib5", 5),
                ("mediapipe468", 468),
                ("mediapipe478", 478)
            ]
        );
        assert!(set.get(Some("")).is_ok());
        let err = set.get(Some("nope")).unwrap_err();
        assert_eq!(err.kind(), ErrorKind::NotFound);
        assert!(err.to_string().contains("loaded models: default"), "{err}");
        assert_eq!(embedded_version(), m.version);
    }

    fn embedded_as(name: &str, store: &str) -> ServedModel {
        let mut m = load_resolved(store, &Resolved::Embedded).unwrap();
        m.name = name.into();
        m
    }

    #[test]
    fn a_folder_serves_one_model_and_names_do_not_clash() {
        let set = ModelSet::new(
            vec![
                embedded_as("default", "default"),
                embedded_as("legacy-name", "x"),
            ],
            "default",
        )
        .unwrap();
        // The folder x now serves a version named after it: the old name goes.
        let set = set.with_model(Arc::new(embedded_as("x", "x")));
        assert_eq!(
            set.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(),
            ["default", "x"]
        );
        assert_eq!(set.by_store("x").unwrap().name, "x");
        // The default model's entry stays even if its folder serves another name.
        let set = set.with_model(Arc::new(embedded_as("other", "default")));
        assert!(set.get(None).is_ok());
        let e = set.name_conflict("x", "y").unwrap();
        assert_eq!(e.kind(), ErrorKind::Conflict);
        assert!(
            e.to_string()
                .contains("already served from the folder \"x\""),
            "{e}"
        );
        assert!(set.name_conflict("x", "x").is_none());
        assert!(set.name_conflict("new", "y").is_none());
    }

    #[test]
    fn a_snapshot_outlives_a_replace() {
        let reg = Registry::new(load_models(None).unwrap());
        let before = reg.snapshot();
        let old = reg.replace(load_models(None).unwrap());
        assert!(Arc::ptr_eq(&before, &old));
        assert!(!Arc::ptr_eq(&before, &reg.snapshot()));
        assert_eq!(before.get(None).unwrap().name, "default");
    }
}
