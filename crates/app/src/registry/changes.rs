//! Changes of the models folder made through the API: write a new version, activate one
//! (rollback is activating an older one), delete an inactive one. Each runs its file work on
//! the blocking pool and leaves the folder valid if the process dies at any point
//! ([`super::versions`]).

use std::path::PathBuf;
use std::sync::Arc;

use tracing::Instrument;

use super::versions::{self, VersionError};
use super::{
    DEFAULT_MODEL, Registry, Resolved, ServedModel, embedded_version, load_resolved, resolve,
};
use crate::blocking::on_blocking_pool;
use crate::error::ServiceError;
use facepose_core::model::bundle::Bundle;
use facepose_files::store::StoreError;

impl Registry {
    /// Loads version `version` of model `name`, makes it the folder's active version and
    /// serves it. The version is loaded before the pointer is written: the pointer never names
    /// a version that does not load.
    ///
    /// The whole change (load, pointer, install into the served set) runs in a task of its own
    /// that holds the change lock: if the caller goes away (timeout, client gone), the
    /// activation still ends as a whole before another one starts, so an abandoned activation
    /// never overwrites a later one.
    pub async fn activate(
        self: &Arc<Self>,
        name: &str,
        version: &str,
    ) -> Result<Arc<ServedModel>, ServiceError> {
        let dir = self.require_dir()?.to_path_buf();
        versions::check_name(name).map_err(version_error)?;
        let me = self.clone();
        let (n, v) = (name.to_string(), version.to_string());
        tokio::spawn(
            async move {
                let changes = me.changes.clone().lock_owned().await;
                let served = me.activate_locked(dir, n, v).await;
                drop(changes);
                me.refresh_catalog().await;
                served
            }
            .instrument(tracing::Span::current()),
        )
        .await
        .map_err(|e| ServiceError::internal(format!("activating a version failed: {e}")))?
    }

    /// The activation under the change lock.
    async fn activate_locked(
        &self,
        dir: PathBuf,
        n: String,
        v: String,
    ) -> Result<Arc<ServedModel>, ServiceError> {
        let set = self.snapshot();
        let served = on_blocking_pool(
            "activating a version",
            move || -> Result<ServedModel, ServiceError> {
                let stored = versions::scan_model(&dir, &n).map_err(version_error)?;
                let source = resolve(stored.as_ref(), &n, &v).ok_or_else(|| {
                    version_error(with_embedded(VersionError::NotFound {
                        name: n.clone(),
                        version: v.clone(),
                        existing: stored.as_ref().map(|m| m.ids()).unwrap_or_default(),
                    }))
                })?;
                let embedded = matches!(source, Resolved::Embedded);
                let served = load_resolved(&n, &source).map_err(|e| {
                    ServiceError::Conflict(format!(
                        "version {v} of model {n:?} does not load, so it is not activated: {e}"
                    ))
                })?;
                if let Some(e) = set.name_conflict(&served.name, &n) {
                    return Err(e);
                }
                versions::activate(&dir, &n, &v, embedded).map_err(version_error)?;
                Ok(served)
            },
        )
        .await?;
        let served = self.install(served);
        tracing::info!(model = %served.name, version = %served.version, source = %served.source, "version activated");
        Ok(served)
    }

    /// Writes a new version of `name` (see [`versions::write_version`]); `make` builds the
    /// bundle for the id chosen. Returns the id and the bundle file.
    pub async fn write_version(
        &self,
        name: &str,
        make: impl FnOnce(&str) -> Result<Bundle, ServiceError> + Send + 'static,
    ) -> Result<(String, PathBuf), ServiceError> {
        let dir = self.require_dir()?.to_path_buf();
        let n = name.to_string();
        let reserved = if name == DEFAULT_MODEL {
            vec![embedded_version().to_string()]
        } else {
            vec![]
        };
        let mut failure = None;
        let written = on_blocking_pool("writing a version", move || {
            let reserved: Vec<&str> = reserved.iter().map(String::as_str).collect();
            versions::write_version(&dir, &n, &reserved, |v| {
                make(v).map_err(|e| {
                    let m = e.to_string();
                    failure = Some(e);
                    VersionError::Invalid(m)
                })
            })
            .map_err(|e| failure.take().unwrap_or_else(|| version_error(e)))
        })
        .await;
        self.refresh_catalog().await;
        written
    }

    /// Deletes the inactive versions of `name` beyond the `keep` newest
    /// ([`versions::prune`]); logs and returns the ids deleted.
    pub async fn prune(&self, name: &str, keep: usize) -> Result<Vec<String>, ServiceError> {
        let dir = self.require_dir()?.to_path_buf();
        let n = name.to_string();
        let deleted = on_blocking_pool("pruning versions", move || {
            versions::prune(&dir, &n, keep).map_err(version_error)
        })
        .await?;
        if !deleted.is_empty() {
            tracing::info!(model = %name, versions = ?deleted, keep, "inactive versions pruned (--keep-inactive-versions)");
            self.refresh_catalog().await;
        }
        Ok(deleted)
    }

    /// Deletes an inactive version of `name`.
    pub async fn delete(&self, name: &str, version: &str) -> Result<(), ServiceError> {
        let dir = self.require_dir()?.to_path_buf();
        versions::check_name(name).map_err(version_error)?;
        let (n, v) = (name.to_string(), version.to_string());
        on_blocking_pool("deleting a version", move || {
            let stored = versions::scan_model(&dir, &n).map_err(version_error)?;
            let on_disk = stored.as_ref().is_some_and(|m| m.get(&v).is_some());
            if !on_disk && n == DEFAULT_MODEL && v == embedded_version() {
                return Err(ServiceError::Conflict(format!(
                    "version {v} of model {n:?} is the default model built into the binary; it \
                     cannot be deleted"
                )));
            }
            versions::delete_version(&dir, &n, &v).map_err(|e| version_error(with_embedded(e)))
        })
        .await?;
        tracing::info!(model = %name, version = %version, "version deleted");
        self.refresh_catalog().await;
        Ok(())
    }
}

/// A "no such version" error of `default` that also lists the embedded version (the listing
/// shows it as one).
fn with_embedded(e: VersionError) -> VersionError {
    match e {
        VersionError::NotFound {
            name,
            version,
            mut existing,
        } if name == DEFAULT_MODEL && !existing.iter().any(|v| v == embedded_version()) => {
            existing.insert(0, embedded_version().to_string());
            VersionError::NotFound {
                name,
                version,
                existing,
            }
        }
        e => e,
    }
}

/// A versions error as an API error.
pub fn version_error(e: VersionError) -> ServiceError {
    match e {
        VersionError::NotFound { .. } => ServiceError::UnknownVersion(e.to_string()),
        VersionError::Active { .. } | VersionError::Legacy { .. } => {
            ServiceError::Conflict(e.to_string())
        }
        VersionError::Invalid(m) => ServiceError::invalid(m),
        VersionError::Store(StoreError::Exists { ref path }) => ServiceError::Conflict(format!(
            "{} already exists in the models folder (written outside this service?); the \
                 version was not written: retry, or remove the entry",
            path.display()
        )),
        VersionError::Io { ref source, .. }
        | VersionError::Store(StoreError::Io { ref source, .. })
            if matches!(
                source.kind(),
                std::io::ErrorKind::PermissionDenied | std::io::ErrorKind::ReadOnlyFilesystem
            ) =>
        {
            tracing::error!(error = %e, "models folder not writable");
            ServiceError::Conflict(format!(
                "the models folder is not writable by this server ({e}); an operator must mount \
                 it read-write for the service's user"
            ))
        }
        VersionError::Io { .. } | VersionError::Store(_) => {
            tracing::error!(error = %e, "models folder");
            ServiceError::internal(format!("models folder: {e}"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{add, temp_root};
    use super::super::{load_models, pointer::read_pointer};
    use super::*;
    use crate::error::ErrorKind;
    use std::time::Duration;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn an_abandoned_activation_still_ends_as_a_whole() {
        let root = temp_root("abandoned");
        assert_eq!(add(&root, "m"), "1");
        assert_eq!(add(&root, "m"), "2");
        versions::activate(&root, "m", "1", false).unwrap();
        let reg = Arc::new(Registry::with_dir(
            load_models(Some(&root)).unwrap(),
            Some(root.clone()),
        ));
        assert_eq!(reg.snapshot().get(Some("m")).unwrap().version, "1");
        // The request goes away right after it started the activation.
        let r = tokio::time::timeout(Duration::ZERO, reg.activate("m", "2")).await;
        assert!(r.is_err(), "the activation did not wait for anything");
        // The activation still completes as a whole: pointer written and version served, and
        // it holds the change lock until then.
        let mut served = String::new();
        for _ in 0..1000 {
            tokio::time::sleep(Duration::from_millis(10)).await;
            let _changes = reg.changes.lock().await;
            served = reg.snapshot().get(Some("m")).unwrap().version.clone();
            if served == "2" {
                assert_eq!(read_pointer(&root.join("m")).unwrap().as_deref(), Some("2"));
                break;
            }
        }
        assert_eq!(served, "2");
        // A later activation is not overwritten by the abandoned one.
        reg.activate("m", "1").await.unwrap();
        assert_eq!(read_pointer(&root.join("m")).unwrap().as_deref(), Some("1"));
        assert_eq!(reg.snapshot().get(Some("m")).unwrap().version, "1");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[tokio::test]
    async fn activating_a_name_served_from_another_folder_is_a_conflict() {
        let root = temp_root("clash");
        // The folder "a" serves its legacy bundle, named "shared".
        std::fs::create_dir_all(root.join("a")).unwrap();
        std::fs::write(
            root.join("a").join(facepose_files::store::MODEL_FILE),
            super::super::testing::bundle("shared", "7").to_json(),
        )
        .unwrap();
        assert_eq!(add(&root, "shared"), "1");
        let reg = Arc::new(Registry::with_dir(
            load_models(Some(&root)).unwrap(),
            Some(root.clone()),
        ));
        let e = reg.activate("shared", "1").await.unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Conflict);
        assert!(
            e.to_string()
                .contains("already served from the folder \"a\""),
            "{e}"
        );
        assert_eq!(read_pointer(&root.join("shared")).unwrap(), None);
        assert_eq!(reg.snapshot().by_store("a").unwrap().name, "shared");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn a_folder_the_server_cannot_write_is_a_conflict_that_says_so() {
        for kind in [
            std::io::ErrorKind::PermissionDenied,
            std::io::ErrorKind::ReadOnlyFilesystem,
        ] {
            let e = version_error(VersionError::Io {
                path: "/models/default/versions/2".into(),
                source: kind.into(),
            });
            assert_eq!(e.kind(), ErrorKind::Conflict);
            assert!(e.to_string().contains("not writable"), "{}", e);
        }
        let e = version_error(VersionError::Io {
            path: "/models".into(),
            source: std::io::ErrorKind::StorageFull.into(),
        });
        assert_ne!(e.kind(), ErrorKind::Conflict, "{}", e);
        let e = version_error(VersionError::Store(StoreError::Exists {
            path: "/models/m/versions/2".into(),
        }));
        assert_eq!(e.kind(), ErrorKind::Conflict);
        assert!(e.to_string().contains("versions/2 already exists"), "{}", e);
    }
}
