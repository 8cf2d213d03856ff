//! facepose's application layer: what the service does, whatever the transport. [`App`] holds
//! one server's state (the served models and the models folder, the retraining jobs, limits,
//! lifecycle, metrics) and offers its use cases (estimate, list, activate, retrain, cancel ...)
//! as methods that take and return plain data and a typed [`ServiceError`].
//!
//! This crate knows no HTTP and no gRPC: it has neither among its dependencies. The transports
//! (`facepose-service`) convert their wire types to and from these, and map [`ServiceError`] to
//! their statuses in their own words. It does no linear algebra either: estimation is the
//! core's (`facepose_core::pose`), reached through [`pose::estimate_face`].

pub mod auth;
pub mod blocking;
pub mod error;
pub mod estimate;
pub mod job_state;
pub mod jobs;
pub mod lifecycle;
pub mod metrics;
pub mod pose;
pub mod registry;
pub mod retrain;
pub mod tracking;
pub mod views;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

pub use error::{ErrorKind, ServiceError};

use auth::AdminToken;
use blocking::on_blocking_pool;
use jobs::records::{HEARTBEAT, JobRecords};
use jobs::{Cancel, Job, Jobs, Slot};
use lifecycle::Lifecycle;
use metrics::Metrics;
use registry::{ModelSet, Registry, RegistryError, SyncProblem, load_models};
use retrain::RawUpload;
use retrain::job::Trainer;
use views::{
    ModelDetail, ModelView, ModelsView, SchemeDetail, VersionsView, model_view, scheme_detail,
    versions_of,
};

/// The request limits, shared by both transports.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Most faces in one batch or stream frame.
    pub max_batch: usize,
    /// Largest request body (HTTP) or message (gRPC), bytes.
    pub max_body: usize,
    /// Longest a request may take (`--request-timeout`).
    pub request_timeout: Duration,
    /// Most requests (HTTP API, gRPC unary calls) in progress.
    pub max_concurrency: usize,
    /// Most streams open at once.
    pub max_streams: usize,
    /// Largest retraining upload, bytes.
    pub max_upload: usize,
    /// Longest an upload may take to arrive and be checked (`--upload-timeout`).
    pub upload_timeout: Duration,
}

/// What an [`App`] starts from (the server's configuration, minus what is the transport's).
#[derive(Debug, Clone)]
pub struct Settings {
    /// The models folder; `None`: the embedded default model only.
    pub models: Option<PathBuf>,
    /// The request limits.
    pub limits: Limits,
    /// The admin token, if any (none: admin routes disabled).
    pub admin_token: AdminToken,
    /// Most retraining jobs queued beside the running one (`--max-queued-jobs`).
    pub max_queued_jobs: usize,
    /// How often the models folder's pointers are read.
    pub registry_poll: Duration,
    /// This replica's name in its jobs.
    pub replica: String,
    /// How many inactive versions of a model a retraining job leaves (`None`: all).
    pub keep_inactive_versions: Option<usize>,
}

/// One server's state and its use cases.
#[derive(Debug)]
pub struct App {
    /// The served models.
    pub registry: Arc<Registry>,
    /// The retraining jobs.
    pub jobs: Arc<Jobs>,
    /// The request limits.
    pub limits: Limits,
    /// Readiness and draining.
    pub lifecycle: Lifecycle,
    /// The server's metrics.
    pub metrics: Metrics,
    admin: AdminToken,
    /// `--keep-inactive-versions` (`None`: all).
    keep_inactive: Option<usize>,
    /// Requests of the HTTP API and gRPC unary calls in progress.
    requests: Arc<Semaphore>,
    /// Open streams.
    streams: Arc<Semaphore>,
    /// The server's span: background work and jobs log under it.
    span: tracing::Span,
    /// The background tasks (the watcher, the job heartbeat, metrics upkeep) and their stop.
    background: TaskTracker,
    stop: CancellationToken,
}

/// Whether new work should come here.
#[derive(Debug, Clone, PartialEq)]
pub enum Readiness {
    /// Serving; `problems`: active versions of the models folder this replica cannot serve
    /// (the previous version serves meanwhile).
    Ready {
        /// Active versions of the models folder this replica cannot serve.
        problems: Vec<SyncProblem>,
    },
    /// Shutting down: finishing the work in progress, taking no new work.
    Draining,
}

/// A place among the requests in progress, held until the request ends.
#[derive(Debug)]
pub struct RequestPermit(#[allow(dead_code)] OwnedSemaphorePermit);

/// A place among the open streams, held until the stream ends.
#[derive(Debug)]
pub struct StreamPermit(#[allow(dead_code)] OwnedSemaphorePermit);

impl App {
    /// Loads the models (on the blocking pool) and starts the background work: the models
    /// folder's watcher, the heartbeat of this replica's jobs, the metrics' upkeep. `span` is
    /// the server's, under which they log. [`App::stop`] ends them.
    pub async fn start(settings: Settings, span: tracing::Span) -> Result<Arc<App>, RegistryError> {
        let dir = settings.models.clone();
        let load_dir = dir.clone();
        let set = crate::blocking::spawn_blocking(move || load_models(load_dir.as_deref()))
            .await
            .map_err(|e| RegistryError::Panicked(e.to_string()))??;
        Ok(Self::with_models(settings, set, span))
    }

    /// [`App::start`] with the models already loaded (`settings.models` is the folder they came
    /// from).
    pub fn with_models(settings: Settings, set: ModelSet, span: tracing::Span) -> Arc<App> {
        let metrics = Metrics::new();
        for m in set.iter() {
            span.in_scope(|| {
                tracing::info!(name = %m.name, version = %m.version, source = %m.source, "model loaded")
            });
        }
        let dir = settings.models.clone();
        let registry = Arc::new(Registry::with_metrics(set, dir, metrics.clone()));
        // Job records go into the models folder, where the other replicas sharing it read them.
        let records = registry
            .dir()
            .map(|d| JobRecords::new(d, settings.replica.clone()));
        let jobs = Arc::new(Jobs::shared(
            settings.max_queued_jobs,
            records,
            settings.replica.clone(),
            metrics.clone(),
        ));
        // Jobs that died with this replica's previous run are failed now, not after a minute.
        span.in_scope(|| crate::blocking::off_the_workers(|| jobs.recover()));
        let app = Arc::new(App {
            registry,
            jobs,
            limits: settings.limits,
            lifecycle: Lifecycle::new(metrics.clone()),
            metrics,
            admin: settings.admin_token.clone(),
            keep_inactive: settings.keep_inactive_versions,
            requests: Arc::new(Semaphore::new(settings.limits.max_concurrency)),
            streams: Arc::new(Semaphore::new(settings.limits.max_streams)),
            span,
            background: TaskTracker::new(),
            stop: CancellationToken::new(),
        });
        app.spawn_background(settings.registry_poll);
        app.span.in_scope(|| {
            tracing::info!(
                admin = if app.admin.is_enabled() { "enabled" } else { "disabled (no token)" },
                folder = %app.registry.dir().map_or("none".into(), |d| d.display().to_string()),
                poll = ?settings.registry_poll,
                replica = %settings.replica,
                "model registry"
            )
        });
        app
    }

    fn spawn_background(self: &Arc<Self>, poll: Duration) {
        use tracing::Instrument;
        let registry = self.registry.clone();
        self.background.spawn(
            self.stop
                .clone()
                .run_until_cancelled_owned(async move {
                    registry.refresh_catalog().await;
                    registry.watch(poll).await;
                })
                .instrument(self.span.clone()),
        );
        // The other replicas take a job whose record is not touched for a minute as lost.
        let jobs = self.jobs.clone();
        self.background.spawn(
            self.stop
                .clone()
                .run_until_cancelled_owned(async move {
                    let mut tick = tokio::time::interval(HEARTBEAT);
                    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                    loop {
                        tick.tick().await;
                        jobs.heartbeat();
                    }
                })
                .instrument(self.span.clone()),
        );
        let metrics = self.metrics.clone();
        self.background
            .spawn(self.stop.clone().run_until_cancelled_owned(async move {
                let mut tick = tokio::time::interval(Duration::from_secs(5));
                loop {
                    tick.tick().await;
                    metrics.upkeep();
                }
            }));
    }

    /// Ends the background work and waits for it.
    pub async fn stop(&self) {
        self.stop.cancel();
        self.background.close();
        self.background.wait().await;
    }

    /// The server's span.
    pub fn span(&self) -> &tracing::Span {
        &self.span
    }

    /// The current model set; a request keeps it until it ends.
    pub fn models(&self) -> Arc<ModelSet> {
        self.registry.snapshot()
    }

    /// A place among the requests in progress, or [`ServiceError::Overloaded`] at once.
    pub fn request_permit(&self) -> Result<RequestPermit, ServiceError> {
        self.requests
            .clone()
            .try_acquire_owned()
            .map(RequestPermit)
            .map_err(|_| ServiceError::Overloaded {
                limit: self.limits.max_concurrency,
            })
    }

    /// A place among the open streams: [`ServiceError::StreamsBusy`] when all are taken,
    /// [`ServiceError::ShuttingDown`] while draining.
    pub fn stream_permit(&self) -> Result<StreamPermit, ServiceError> {
        let permit =
            self.streams
                .clone()
                .try_acquire_owned()
                .map_err(|_| ServiceError::StreamsBusy {
                    limit: self.limits.max_streams,
                })?;
        if !self.lifecycle.is_ready() {
            return Err(ServiceError::ShuttingDown);
        }
        Ok(StreamPermit(permit))
    }

    /// Checks the admin credentials of a call (the value of `Authorization` / `authorization`).
    pub fn authorize<'a>(
        &self,
        authorization: impl IntoIterator<Item = &'a [u8]>,
    ) -> Result<(), ServiceError> {
        self.admin.check(authorization)
    }

    /// Whether new work should come here.
    pub fn readiness(&self) -> Readiness {
        if self.lifecycle.is_ready() {
            Readiness::Ready {
                problems: self.registry.problems(),
            }
        } else {
            Readiness::Draining
        }
    }

    /// Every served model.
    pub fn models_view(&self) -> ModelsView {
        let set = self.registry.snapshot();
        let catalog = self.registry.catalog();
        ModelsView {
            default_model: set.default_name().to_string(),
            models: set.iter().map(|m| model_view(m, &set, &catalog)).collect(),
        }
    }

    /// One served model with its provenance.
    pub fn model_detail(&self, name: &str) -> Result<ModelDetail, ServiceError> {
        let set = self.registry.snapshot();
        let m = set.get(Some(name))?;
        Ok(ModelDetail {
            model: model_view(m, &set, &self.registry.catalog()),
            provenance: m.provenance.clone(),
        })
    }

    /// A scheme that the served model `name` serves: its points, the model's mean shape in it
    /// and its anchors.
    pub fn scheme_detail(&self, name: &str, scheme: &str) -> Result<SchemeDetail, ServiceError> {
        let set = self.registry.snapshot();
        scheme_detail(set.get(Some(name))?, scheme)
    }

    /// The versions of the models folder entry `name` (also of a model not served yet), read
    /// from the folder afresh.
    pub async fn versions(&self, name: &str) -> Result<VersionsView, ServiceError> {
        self.registry.refresh_catalog().await;
        let catalog = self.registry.catalog();
        let set = self.registry.snapshot();
        let stored = catalog
            .models
            .get(name)
            .ok_or_else(|| ServiceError::NotInFolder {
                name: name.into(),
                has_folder: self.registry.dir().is_some(),
            })?;
        Ok(VersionsView {
            name: name.into(),
            active: stored.active.clone(),
            versions: versions_of(Some(stored), set.by_store(name).map(|m| &**m)),
        })
    }

    /// Activates version `version` of `name` (rolling back is activating an older one); the
    /// model now served.
    pub async fn activate(&self, name: &str, version: &str) -> Result<ModelView, ServiceError> {
        let served = self.registry.activate(name, version).await?;
        let set = self.registry.snapshot();
        Ok(model_view(&served, &set, &self.registry.catalog()))
    }

    /// Deletes an inactive version.
    pub async fn delete_version(&self, name: &str, version: &str) -> Result<(), ServiceError> {
        self.registry.delete(name, version).await
    }

    /// A place in the retraining queue for an upload about to be read:
    /// [`ServiceError::ShuttingDown`] while draining (the upload belongs on another replica),
    /// [`ServiceError::QueueFull`] when the queue is full.
    pub fn reserve_job(&self) -> Result<Slot, ServiceError> {
        if !self.lifecycle.is_ready() {
            return Err(ServiceError::ShuttingDown);
        }
        self.jobs.reserve()
    }

    /// Checks an upload (on the blocking pool: it runs a Procrustes analysis of the whole set)
    /// and, if it is usable, starts its job, which holds `slot` until it ends. `upload` turns
    /// the transport's upload into a [`RawUpload`] on the same thread (parsing a body of
    /// megabytes does not belong on the async workers either); its errors are the transport's
    /// (`E`), which the application's convert into.
    pub async fn retrain<E>(
        &self,
        upload: impl FnOnce() -> Result<RawUpload, E> + Send + 'static,
        slot: Slot,
    ) -> Result<Job, E>
    where
        E: From<ServiceError> + Send + 'static,
    {
        let prepared = crate::blocking::spawn_blocking(move || -> Result<_, E> {
            Ok(retrain::prepare(upload()?)?)
        })
        .await
        .map_err(|e| ServiceError::internal(format!("checking the upload failed: {e}")))??;
        Ok(retrain::job::submit(
            &Trainer {
                registry: self.registry.clone(),
                jobs: self.jobs.clone(),
                span: self.span.clone(),
                keep_inactive: self.keep_inactive,
            },
            prepared,
            slot,
        )?)
    }

    /// The job `id`: this replica's, else the models folder's record of another replica's.
    pub async fn job(&self, id: &str) -> Result<Job, ServiceError> {
        let (jobs, id) = (self.jobs.clone(), id.to_string());
        // Another replica's job is read from the models folder: off the async workers.
        on_blocking_pool("job look-up", move || jobs.get(&id)).await
    }

    /// Cancels job `id`, here or through the replica that runs it.
    pub async fn cancel_job(&self, id: &str) -> Result<Cancel, ServiceError> {
        let (jobs, id) = (self.jobs.clone(), id.to_string());
        on_blocking_pool("job cancel", move || jobs.cancel(&id)).await
    }
}
