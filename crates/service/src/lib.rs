//! `facepose serve`: HTTP JSON (axum) and gRPC (tonic) on one port.
//!
//! [`run`] builds the runtime and calls [`serve`], which does three things: build the state
//! (models, limits, lifecycle, metrics), build the routers (HTTP API, gRPC services, health,
//! reflection, one fallback), and serve them on one listener until a signal drains it.
//!
//! The service converts between wire types and the core's types and nothing more: estimation,
//! rotations and angle conventions are the core's (`estimate`, `geometry`).

pub mod auth;
pub mod config;
pub mod errors;
pub mod grpc;
pub mod health;
pub mod http;
pub mod http_registry;
pub mod http_retrain;
pub mod job_records;
pub mod jobs;
pub mod metrics;
pub mod pose;
pub mod proto;
pub mod registry;
pub mod request_json;
pub mod retrain;
pub mod shutdown;
pub mod stream;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use axum::Router;
use axum::serve::ListenerExt;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;
use tower::ServiceExt;

use config::{Config, Limits, LogFormat, ServeArgs};
use registry::{Registry, RegistryError, load_models};
use shutdown::Lifecycle;

/// What the handlers of both transports share.
#[derive(Debug)]
pub struct AppState {
    pub registry: Arc<Registry>,
    /// The admin bearer token (retraining, activation, deletion).
    pub admin: auth::AdminToken,
    /// Retraining jobs.
    pub jobs: jobs::Jobs,
    pub limits: Limits,
    pub lifecycle: Lifecycle,
    pub metrics: metrics::Metrics,
    /// Requests of the HTTP API and gRPC unary calls in progress.
    pub permits: Arc<Semaphore>,
    /// Open streams.
    pub streams: Arc<Semaphore>,
    /// The OpenAPI document, rendered once.
    pub openapi: String,
}

impl AppState {
    /// A place in the retraining queue for an upload about to be read: 503 / UNAVAILABLE while
    /// draining (the upload belongs on another replica), 429 when the queue is full.
    pub fn reserve_job(&self) -> Result<jobs::Slot, errors::ApiError> {
        if !self.lifecycle.is_ready() {
            return Err(errors::ApiError::shutting_down());
        }
        self.jobs.reserve()
    }
}

/// Why the service could not start or serve.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    #[error(transparent)]
    Models(#[from] RegistryError),
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: std::net::SocketAddr,
        source: std::io::Error,
    },
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("reflection service: {0}")]
    Reflection(String),
    /// The drain reached `--drain-timeout` with connections still open (they were closed, so
    /// their requests went unanswered) or retraining jobs unfinished (their uploads are lost).
    #[error(
        "the drain reached --drain-timeout ({cap:?}) and was cut short: {}",
        cut_clause(*.connections_open, .abandoned_jobs)
    )]
    DrainCut {
        cap: std::time::Duration,
        /// Whether connections were still open (else only jobs were left).
        connections_open: bool,
        abandoned_jobs: Vec<String>,
    },
}

/// What [`ServeError::DrainCut`] cut: open connections, abandoned jobs, or both.
fn cut_clause(connections_open: bool, jobs: &[String]) -> String {
    let connections = connections_open.then(|| "open connections were closed".to_string());
    let jobs = (!jobs.is_empty()).then(|| {
        format!(
            "retraining jobs {} were abandoned (send their uploads again)",
            jobs.join(", ")
        )
    });
    match (connections, jobs) {
        (Some(c), Some(j)) => format!("{c}, and {j}"),
        (Some(c), None) => c,
        (None, Some(j)) => j,
        (None, None) => "nothing was left".to_string(),
    }
}

impl ServeError {
    /// The process's exit status for this error: 3 for a drain cut short (the service ran,
    /// and stopped with work cut off), 2 for everything else (it could not run).
    pub fn exit_status(&self) -> u8 {
        match self {
            ServeError::DrainCut { .. } => 3,
            _ => 2,
        }
    }
}

/// Validates the flags, starts logging and the runtime, and serves until SIGTERM/SIGINT.
pub fn run(args: ServeArgs) -> Result<(), ServeError> {
    let started = Instant::now();
    let cfg = args.validate()?;
    init_logging(&cfg);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(cfg.workers)
        // CPU batches take up to one blocking thread per core; the rest is for the work that
        // waits (a training job, models-folder locks and fsyncs, the watcher's reads), so that
        // a slow volume or a long training never leaves batches without a thread.
        .max_blocking_threads(cfg.workers + 4)
        .thread_name("facepose")
        .enable_all()
        .build()?;
    let result = runtime.block_on(serve(cfg, started));
    // Blocking batch tasks cut off by the drain cap are not waited for.
    runtime.shutdown_timeout(std::time::Duration::from_millis(100));
    result
}

fn init_logging(cfg: &Config) {
    let filter = tracing_subscriber::EnvFilter::try_new(&cfg.log)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match cfg.log_format {
        LogFormat::Json => builder.json().with_current_span(true).try_init(),
        LogFormat::Text => builder
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .try_init(),
    };
}

/// The models folder: `--models`, else `./models` if it exists, else none (the embedded
/// default model only).
fn models_dir(flag: Option<&Path>) -> Option<PathBuf> {
    match flag {
        Some(d) => Some(d.to_path_buf()),
        None => Some(PathBuf::from("models")).filter(|d| d.is_dir()),
    }
}

/// Loads the models, binds, and serves HTTP and gRPC on one port until a signal, then drains.
pub async fn serve(cfg: Config, started: Instant) -> Result<(), ServeError> {
    // State.
    let dir = models_dir(cfg.models.as_deref());
    let load_dir = dir.clone();
    let set = tokio::task::spawn_blocking(move || load_models(load_dir.as_deref()))
        .await
        .map_err(|e| ServeError::Io(std::io::Error::other(e)))??;
    let metrics = metrics::Metrics::install();
    metrics.spawn_upkeep();
    metrics::models(&set);
    for m in set.iter() {
        tracing::info!(name = %m.name, version = %m.version, source = %m.source, "model loaded");
    }
    let registry = Arc::new(Registry::with_dir(set, dir));
    registry.refresh_catalog().await;
    registry.spawn_watcher(cfg.registry_poll);
    tracing::info!(
        admin = if cfg.admin_token.is_enabled() { "enabled" } else { "disabled (no token)" },
        folder = %registry.dir().map_or("none".into(), |d| d.display().to_string()),
        poll = ?cfg.registry_poll,
        "model registry"
    );
    let replica = cfg.replica.clone();
    // Job records go into the models folder, where the other replicas sharing it read them.
    let job_records = registry
        .dir()
        .map(|d| job_records::JobRecords::new(d, replica.clone()));
    let state = Arc::new(AppState {
        registry,
        admin: cfg.admin_token.clone(),
        jobs: jobs::Jobs::shared(cfg.max_queued_jobs, job_records, replica),
        limits: cfg.limits,
        lifecycle: Lifecycle::default(),
        metrics,
        permits: Arc::new(Semaphore::new(cfg.limits.max_concurrency)),
        streams: Arc::new(Semaphore::new(cfg.limits.max_streams)),
        openapi: http::openapi_json(),
    });
    // The other replicas take a job whose record is not touched for a minute as lost.
    let beating = state.clone();
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(job_records::HEARTBEAT);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            beating.jobs.heartbeat();
        }
    });

    // Routers: gRPC from an empty axum router (tonic's default fallback would answer unknown
    // REST paths with gRPC errors), merged with the HTTP API, one fallback for both.
    let max_body = cfg.limits.max_body;
    let pose =
        proto::pose_service_server::PoseServiceServer::new(grpc::PoseApi::new(state.clone()))
            .max_decoding_message_size(max_body);
    fn reflection() -> tonic_reflection::server::Builder<'static> {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    }
    let reflection_v1 = reflection()
        .build_v1()
        .map_err(|e| ServeError::Reflection(e.to_string()))?;
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .map_err(|e| ServeError::Reflection(e.to_string()))?;
    let grpc = tonic::service::Routes::from(Router::new())
        .add_service(tonic_health::pb::health_server::HealthServer::new(
            health::HealthApi::new(state.clone()),
        ))
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .into_axum_router()
        .route_service(
            &format!("/{}/{{*rest}}", health::POSE_SERVICE),
            pose.map_request(|req: axum::http::Request<axum::body::Body>| {
                req.map(tonic::body::Body::new)
            })
            .map_response(move |resp| grpc::remap_trailers_only(resp, max_body)),
        );
    let app = http::router(state.clone())
        .merge(grpc)
        .fallback(http::fallback)
        .layer(axum::middleware::from_fn(http::observe));

    // Serve.
    let listener = TcpListener::bind(cfg.addr)
        .await
        .map_err(|source| ServeError::Bind {
            addr: cfg.addr,
            source,
        })?;
    let addr = listener.local_addr()?;
    state.lifecycle.serving();
    tracing::info!(
        %addr,
        startup_ms = started.elapsed().as_millis() as u64,
        workers = cfg.workers,
        "listening (HTTP and gRPC)"
    );
    let listener = listener.tap_io(|tcp| {
        let _ = tcp.set_nodelay(true);
    });
    let drain_state = state.clone();
    let server = axum::serve(listener, app).with_graceful_shutdown(async move {
        let signal = shutdown::termination_signal().await;
        tracing::info!(
            signal,
            "draining: not ready, no new connections, streams told to end"
        );
        drain_state.lifecycle.begin_drain();
    });
    let drained = state.lifecycle.drained();
    let cap = cfg.drain_timeout;
    // The drain ends when every connection is closed and every accepted retraining job has
    // ended, or at the cap.
    let jobs_state = state.clone();
    let connections_done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let done = connections_done.clone();
    let finish = async move {
        server.into_future().await?;
        done.store(true, std::sync::atomic::Ordering::Release);
        let left = jobs_state.jobs.unfinished();
        if !left.is_empty() {
            tracing::info!(
                jobs = left.len(),
                "waiting for the accepted retraining jobs"
            );
        }
        jobs_state.jobs.idle().await;
        Ok::<(), std::io::Error>(())
    };
    tokio::select! {
        result = finish => result?,
        _ = async { drained.await; tokio::time::sleep(cap).await } => {
            // Jobs already cancelled and finishing their stage lose nothing.
            let abandoned_jobs: Vec<String> = state
                .jobs
                .unfinished()
                .into_iter()
                .filter(|(_, s)| *s != "cancelled, stopping")
                .map(|(id, _)| id)
                .collect();
            let connections_open = !connections_done.load(std::sync::atomic::Ordering::Acquire);
            tracing::error!(
                ?cap,
                connections_open,
                abandoned = ?abandoned_jobs,
                "drain timed out; closing what is left"
            );
            // Their records say so, for the other replicas; within a bound, as the volume may
            // be what held the drain.
            let (jobs, ids) = (state.clone(), abandoned_jobs.clone());
            let marked = tokio::task::spawn_blocking(move || jobs.jobs.abandon(&ids, cap));
            if tokio::time::timeout(std::time::Duration::from_secs(2), marked).await.is_err() {
                tracing::warn!("could not mark the abandoned jobs in the models folder in time");
            }
            // Not a clean stop: the exit status says so (the error is printed by main).
            return Err(ServeError::DrainCut { cap, connections_open, abandoned_jobs });
        }
    }
    tracing::info!("stopped");
    Ok(())
}
