//! The watcher: every `--registry-poll`, read each model's active pointer and serve the version
//! it names when that is not the version served here, so that replicas sharing the models folder
//! converge on an activation made through any of them.
//!
//! A version that fails to load (or a model folder that cannot be read) never takes the server
//! down: the previous version keeps serving, the problem is logged once, listed by `/readyz`
//! ([`Registry::problems`]) and counted in the metrics, and the load is tried again after
//! [`RETRY_FAILED`] (at once if the pointer moves to another version).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::versions::{self, StoredModel, VersionError};
use super::{ModelSet, Registry, ServedModel, load_resolved, lock, resolve};

/// How long a version that failed to load is left alone before the watcher tries it again.
pub const RETRY_FAILED: Duration = Duration::from_secs(30);

/// How often stale temporaries are looked for.
const CLEAN_EVERY: Duration = Duration::from_secs(60);

/// Why the watcher could not follow a model's pointer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyncProblem {
    /// The model folder.
    pub model: String,
    /// The version the pointer names (empty when the folder itself could not be read).
    pub version: String,
    /// What went wrong.
    pub message: String,
}

/// A problem and when to try again.
#[derive(Debug)]
pub(super) struct Failure {
    problem: SyncProblem,
    retry_at: Instant,
}

/// What one pass found for one model folder.
enum Outcome {
    /// The served version is the active one.
    Current(String),
    /// The newly active version, loaded.
    Loaded(Box<ServedModel>),
    Failed(SyncProblem),
    /// A folder whose problem is left alone until its retry time: the problem stands.
    Waiting(String),
}

impl Registry {
    /// Versions the watcher could not serve (the previous version keeps serving).
    pub fn problems(&self) -> Vec<SyncProblem> {
        lock(&self.failures)
            .values()
            .map(|f| f.problem.clone())
            .collect()
    }

    /// One pass of the watcher: reads every pointer and serves each newly active version
    /// (loaded off the reactor). Also removes stale temporaries when `clean` is set.
    pub async fn sync(&self, clean: bool) {
        let Some(dir) = self.dir.clone() else {
            return;
        };
        let changes = self.changes.lock().await;
        let snapshot = self.snapshot();
        let skip: Vec<(String, String)> = {
            let now = Instant::now();
            lock(&self.failures)
                .values()
                .filter(|f| f.retry_at > now)
                .map(|f| (f.problem.model.clone(), f.problem.version.clone()))
                .collect()
        };
        let outcomes =
            crate::blocking::spawn_blocking(move || sync_pass(&dir, &snapshot, &skip, clean)).await;
        let outcomes = match outcomes {
            Ok(o) => o,
            Err(e) => {
                tracing::error!(error = %e, "the models folder watcher panicked");
                return;
            }
        };
        // Problems not reported again in this pass are gone (the folder was fixed or
        // removed, the folder list can be read again).
        let mut reported: Vec<String> = Vec::new();
        for outcome in outcomes {
            match outcome {
                Outcome::Waiting(store) => reported.push(store),
                Outcome::Current(store) => {
                    let mut failures = lock(&self.failures);
                    if failures.remove(&store).is_some() {
                        self.metrics.sync_problems(failures.len());
                    }
                }
                Outcome::Loaded(m) => {
                    let m = self.install(*m);
                    tracing::info!(model = %m.name, version = %m.version, source = %m.source,
                        "serving the version now active in the models folder");
                }
                Outcome::Failed(problem) => {
                    reported.push(problem.model.clone());
                    self.record_failure(problem);
                }
            }
        }
        // When the folder list could not be read, nothing is known of the others.
        if !reported.iter().any(|m| m == "*") {
            let mut failures = lock(&self.failures);
            let before = failures.len();
            failures.retain(|model, _| reported.contains(model));
            if failures.len() != before {
                self.metrics.sync_problems(failures.len());
            }
        }
        drop(changes);
        self.refresh_catalog().await;
    }

    fn record_failure(&self, problem: SyncProblem) {
        let mut failures = lock(&self.failures);
        let new = failures
            .get(&problem.model)
            .is_none_or(|f| f.problem != problem);
        if new {
            tracing::error!(model = %problem.model, version = %problem.version,
                error = %problem.message,
                "cannot serve the active version of the models folder; still serving the previous one");
            self.metrics.model_load_failed(&problem.model);
        }
        failures.insert(
            problem.model.clone(),
            Failure {
                problem,
                retry_at: Instant::now() + RETRY_FAILED,
            },
        );
        self.metrics.sync_problems(failures.len());
    }

    /// Runs [`Registry::sync`] every `period`, for ever (stale temporaries are looked for
    /// about once a minute); at once without a models folder.
    pub async fn watch(self: Arc<Self>, period: Duration) {
        if self.dir.is_none() {
            return;
        }
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut cleaned = Instant::now();
        loop {
            tick.tick().await;
            let clean = cleaned.elapsed() >= CLEAN_EVERY;
            if clean {
                cleaned = Instant::now();
            }
            self.sync(clean).await;
        }
    }
}

/// The watcher's work on the blocking pool: what each model folder needs.
fn sync_pass(
    dir: &Path,
    current: &ModelSet,
    skip: &[(String, String)],
    clean: bool,
) -> Vec<Outcome> {
    let folders = match versions::scan_each(dir) {
        Ok(f) => f,
        Err(e) => {
            return vec![Outcome::Failed(SyncProblem {
                model: "*".into(),
                version: String::new(),
                message: format!("cannot list the models folder: {e}"),
            })];
        }
    };
    let mut out = Vec::new();
    for (name, scanned) in folders {
        if clean {
            for p in versions::clean_stale(&dir.join(&name), versions::STALE_AGE) {
                tracing::info!(path = %p.display(), "removed a stale temporary entry");
            }
        }
        match scanned {
            Ok(Some(m)) => out.extend(follow(&m, current, skip)),
            Ok(None) => {}
            Err(_) if skip.iter().any(|(n, v)| *n == name && v.is_empty()) => {
                out.push(Outcome::Waiting(name));
            }
            Err(e) => out.push(Outcome::Failed(SyncProblem {
                model: name,
                version: String::new(),
                message: e.to_string(),
            })),
        }
    }
    out
}

/// What the folder `m` needs: nothing, its active version loaded, or a problem reported.
fn follow(m: &StoredModel, current: &ModelSet, skip: &[(String, String)]) -> Option<Outcome> {
    let active = m.active()?;
    let served = current.by_store(&m.name);
    if served.is_some_and(|s| s.version == active) {
        return Some(Outcome::Current(m.name.clone()));
    }
    if skip.iter().any(|(n, v)| *n == m.name && v == active) {
        return Some(Outcome::Waiting(m.name.clone()));
    }
    let failed = |message: String| {
        Outcome::Failed(SyncProblem {
            model: m.name.clone(),
            version: active.to_string(),
            message,
        })
    };
    let Some(source) = resolve(Some(m), &m.name, active) else {
        let missing = VersionError::NotFound {
            name: m.name.clone(),
            version: active.into(),
            existing: m.ids(),
        };
        return Some(failed(format!(
            "the active pointer names a version that is not there: {missing}"
        )));
    };
    Some(match load_resolved(&m.name, &source) {
        Ok(s)
            if current
                .get(Some(&s.name))
                .is_ok_and(|c| c.store.as_deref() != Some(m.name.as_str())) =>
        {
            failed(format!(
                "its bundle is named {:?}, a model already served from another folder",
                s.name
            ))
        }
        Ok(s) => Outcome::Loaded(Box::new(s)),
        Err(e) => failed(e.to_string()),
    })
}

#[cfg(test)]
mod tests {
    use super::super::load_models;
    use super::super::testing::{add, temp_root};
    use super::*;

    #[tokio::test]
    async fn problems_that_are_not_reported_again_are_cleared() {
        let root = temp_root("problems");
        assert_eq!(add(&root, "m"), "1");
        let reg = Registry::with_dir(load_models(Some(&root)).unwrap(), Some(root.clone()));
        // A problem of the folder list, from an earlier pass.
        reg.record_failure(SyncProblem {
            model: "*".into(),
            version: String::new(),
            message: "cannot list the models folder".into(),
        });
        // A folder whose pointer names a version that is not there.
        let g = root.join("g");
        std::fs::create_dir_all(&g).unwrap();
        std::fs::write(g.join(super::super::pointer::ACTIVE_FILE), "5\n").unwrap();
        reg.sync(false).await;
        let models = |reg: &Registry| {
            reg.problems()
                .into_iter()
                .map(|p| p.model)
                .collect::<Vec<_>>()
        };
        assert_eq!(models(&reg), ["g"]);
        // Still broken, waiting for its retry: the problem stands.
        reg.sync(false).await;
        assert_eq!(models(&reg), ["g"]);
        // The folder disappears: so does its problem.
        std::fs::remove_dir_all(&g).unwrap();
        reg.sync(false).await;
        assert!(reg.problems().is_empty(), "{:?}", reg.problems());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
