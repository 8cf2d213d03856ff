//! The models the service answers with: an immutable [`ModelSet`] behind an [`ArcSwap`].
//!
//! A request takes a snapshot (`Arc<ModelSet>`) when it starts and finishes on it, so replacing
//! the set ([`Registry::replace`]: a later retraining or rollback) is atomic and never fails a
//! request in progress; the old set is freed when its last request ends.
//!
//! Loading (`--models DIR`): every subfolder holding a `model.json` is a model named by the
//! bundle's `name` field (folders starting with `.` are skipped: they are atomic writes in
//! progress). Every bundle is validated at start; a broken one stops the start with an error
//! naming the file and the field (a service that silently serves fewer models than deployed is
//! worse than one that does not start). Without a model named `default`, the embedded default
//! model serves as `default`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arc_swap::ArcSwap;

use super::errors::{ApiError, ErrorKind};
use crate::estimate::Method;
use crate::model::bundle::{Bundle, BundleError, Provenance};
use crate::model::store::{MODEL_FILE, StoreError, load_model};
use crate::model::{PoseModel, default_model};

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
    pub name: String,
    pub version: String,
    /// RFC 3339.
    pub created: String,
    pub checksum: String,
    pub provenance: Provenance,
    pub source: ModelSource,
    pub model: PoseModel,
}

impl ServedModel {
    fn new(bundle: Bundle, model: PoseModel, source: ModelSource) -> Self {
        ServedModel {
            name: bundle.name,
            version: bundle.version,
            created: bundle.created,
            checksum: bundle.checksum,
            provenance: bundle.provenance,
            source,
            model,
        }
    }

    /// The model's own scheme (the default scheme of requests).
    pub fn scheme(&self) -> &str {
        &self.model.scheme.name
    }

    /// `(name, points)` of every scheme it serves, its own first.
    pub fn schemes(&self) -> impl Iterator<Item = (&str, usize)> {
        self.model
            .subsets
            .iter()
            .map(|s| (s.scheme.name.as_str(), s.scheme.len()))
    }

    /// The methods it supports (`fit-shape` needs a shape basis).
    pub fn methods(&self) -> Vec<Method> {
        [
            Method::Auto,
            Method::Fit,
            Method::FitShape,
            Method::Regression,
            Method::Geometry,
        ]
        .into_iter()
        .filter(|m| *m != Method::FitShape || self.model.morph.is_some())
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

    /// The model named `name`, or the default one for `None` or an empty name.
    pub fn get(&self, name: Option<&str>) -> Result<&Arc<ServedModel>, ApiError> {
        let name = name.filter(|n| !n.is_empty()).unwrap_or(&self.default);
        self.models.get(name).ok_or_else(|| {
            ApiError::new(
                ErrorKind::NotFound,
                format!(
                    "unknown model {name:?}; loaded models: {}",
                    self.models.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            )
        })
    }

    /// The default model's name.
    pub fn default_name(&self) -> &str {
        &self.default
    }

    /// Every model, by name.
    pub fn iter(&self) -> impl Iterator<Item = &Arc<ServedModel>> {
        self.models.values()
    }

    pub fn len(&self) -> usize {
        self.models.len()
    }

    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }
}

/// The current model set, swappable atomically.
#[derive(Debug)]
pub struct Registry {
    current: ArcSwap<ModelSet>,
}

impl Registry {
    pub fn new(set: ModelSet) -> Self {
        Registry {
            current: ArcSwap::from_pointee(set),
        }
    }

    /// The current set; a request keeps it until it ends.
    pub fn snapshot(&self) -> Arc<ModelSet> {
        self.current.load_full()
    }

    /// Replaces the set atomically and returns the previous one. Requests in progress finish on
    /// the set they started with.
    pub fn replace(&self, set: ModelSet) -> Arc<ModelSet> {
        self.current.swap(Arc::new(set))
    }
}

/// Why the models could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum RegistryError {
    #[error("models folder {}: {source}", path.display())]
    Dir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("model bundle {0}")]
    Bundle(#[from] StoreError),
    #[error("embedded default model: {0}")]
    Embedded(#[from] BundleError),
    #[error("two models are named {name:?}: {first} and {second}; names must be unique")]
    Duplicate {
        name: String,
        first: String,
        second: String,
    },
    #[error("no model named {0:?}")]
    NoDefault(String),
}

/// Loads every model of `dir` (see the module docs) in parallel, plus the embedded default
/// model if `dir` has no `default`. `dir = None`: the embedded default model only.
pub fn load_models(dir: Option<&Path>) -> Result<ModelSet, RegistryError> {
    let files = match dir {
        Some(d) => bundle_files(d)?,
        None => vec![],
    };
    let loaded: Vec<Result<ServedModel, RegistryError>> = std::thread::scope(|s| {
        let handles: Vec<_> = files
            .iter()
            .map(|f| {
                s.spawn(move || {
                    let (bundle, model) = load_model(f)?;
                    Ok(ServedModel::new(
                        bundle,
                        model,
                        ModelSource::File(f.clone()),
                    ))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or_else(|_| {
                    Err(RegistryError::NoDefault(
                        "(a loader thread panicked)".into(),
                    ))
                })
            })
            .collect()
    });
    let mut models = loaded.into_iter().collect::<Result<Vec<_>, _>>()?;
    if !models.iter().any(|m| m.name == DEFAULT_MODEL) {
        let (bundle, model) = default_model()?;
        let mut m = ServedModel::new(bundle, model, ModelSource::Embedded);
        m.name = DEFAULT_MODEL.into();
        models.push(m);
    }
    ModelSet::new(models, DEFAULT_MODEL)
}

/// `dir/*/model.json`, sorted, skipping hidden folders.
fn bundle_files(dir: &Path) -> Result<Vec<PathBuf>, RegistryError> {
    let io = |source| RegistryError::Dir {
        path: dir.into(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let path = entry.path();
        let hidden = entry.file_name().to_string_lossy().starts_with('.');
        let file = path.join(MODEL_FILE);
        if !hidden && path.is_dir() && file.is_file() {
            files.push(file);
        }
    }
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_default_serves_without_a_folder() {
        let set = load_models(None).unwrap();
        assert_eq!(set.len(), 1);
        let m = set.get(None).unwrap();
        assert_eq!(m.name, "default");
        assert_eq!(m.source, ModelSource::Embedded);
        assert_eq!(
            m.schemes().collect::<Vec<_>>(),
            [("ibug68", 68), ("inner51", 51), ("five", 5)]
        );
        assert!(set.get(Some("")).is_ok());
        let err = set.get(Some("nope")).unwrap_err();
        assert_eq!(err.kind, ErrorKind::NotFound);
        assert!(err.message.contains("loaded models: default"), "{err}");
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
