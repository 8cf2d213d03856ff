//! The server in one screen: [`serve`] builds the application (`facepose_app::App`), the
//! routers (the HTTP API, the gRPC services, health, reflection, one fallback) and serves them
//! on a listener it is given until a shutdown future it is given resolves, then drains.
//! [`run`] is `facepose serve`: it builds the runtime, binds `--addr` and passes SIGTERM /
//! SIGINT as the shutdown. Tests and embedders call [`serve`] with their own listener and
//! shutdown, several servers to a process if they like.
//!
//! The drain, in order: readiness and gRPC health flip (load balancers stop sending), the
//! listener stops accepting, open streams are told to end (UNAVAILABLE), in-flight requests
//! finish, new retraining uploads are refused, and [`serve`] returns once every connection is
//! closed, every WebSocket stream has finished its closing handshake and every accepted
//! retraining job has ended (Ok), or the drain's cap has passed ([`ServeError::DrainCut`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use axum::Router;
use facepose_app::App;
use facepose_app::jobs::Unfinished;
use facepose_app::registry::RegistryError;
use tokio::net::TcpListener;
use tracing::Instrument;

use crate::config::{Config, ConfigError, LogFormat, ServeArgs};
use crate::http::cors::CorsOrigins;
use crate::{grpc, http, proto};

/// Why the service could not start or serve.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The models could not be loaded.
    #[error(transparent)]
    Models(#[from] RegistryError),
    /// The address could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address.
        addr: std::net::SocketAddr,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Another I/O error.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The reflection service could not be built.
    #[error("reflection service: {0}")]
    Reflection(String),
    /// The drain reached `--drain-timeout` with connections still open (they were closed, so
    /// their requests went unanswered) or retraining jobs unfinished (their uploads are lost).
    #[error(
        "the drain reached --drain-timeout ({cap:?}) and was cut short: {}",
        cut_clause(*.connections_open, .abandoned_jobs)
    )]
    DrainCut {
        /// `--drain-timeout`.
        cap: std::time::Duration,
        /// Whether connections were still open (else only jobs were left).
        connections_open: bool,
        /// The ids of the retraining jobs left unfinished.
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

/// `facepose serve`: validates the flags, starts logging and the runtime, binds `--addr` and
/// serves until SIGTERM or SIGINT.
pub fn run(args: ServeArgs) -> Result<(), ServeError> {
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
    let result = runtime.block_on(async {
        let listener = TcpListener::bind(cfg.addr)
            .await
            .map_err(|source| ServeError::Bind {
                addr: cfg.addr,
                source,
            })?;
        let signal = async {
            let signal = termination_signal().await;
            tracing::info!(signal, "signal received");
        };
        serve(cfg, listener, signal).await
    });
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

/// Serves HTTP and gRPC on `listener` until `shutdown` resolves, then drains (see the module
/// docs). Everything the server logs is under a `server` span naming its replica.
pub async fn serve(
    cfg: Config,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServeError> {
    let span = tracing::info_span!("server", replica = %cfg.replica);
    let started = Instant::now();
    let app = App::start(cfg.app_settings(), span.clone())
        .instrument(span.clone())
        .await?;
    let result = serve_app(&app, &cfg, listener, shutdown, started)
        .instrument(span)
        .await;
    app.stop().await;
    result
}

/// The routers of `app`: gRPC from an empty axum router (tonic's default fallback would answer
/// unknown REST paths with gRPC errors), merged with the HTTP API, one fallback for both, the
/// request observer around everything. With `cors` (`--cors-origins`), the HTTP routes answer
/// browsers of those origins (`http::cors`); the gRPC routes never see that layer. With
/// `pages`, the demo page joins the HTTP routes (`--demo`, `http::demo`).
pub fn routers(
    app: &Arc<App>,
    cors: Option<&CorsOrigins>,
    pages: Pages,
    ws: http::stream::WsLimits,
) -> Result<Router, ServeError> {
    let max_body = app.limits.max_body;
    let pose = proto::pose_service_server::PoseServiceServer::new(grpc::PoseApi::new(app.clone()))
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
            grpc::health::HealthApi::new(app.clone()),
        ))
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .into_axum_router()
        .route_service(
            &format!("/{}/{{*rest}}", grpc::health::POSE_SERVICE),
            tower::ServiceBuilder::new()
                .layer(axum::middleware::from_fn_with_state(
                    app.clone(),
                    grpc::edge::edge,
                ))
                .map_request(|req: axum::http::Request<axum::body::Body>| {
                    req.map(tonic::body::Body::new)
                })
                .service(pose),
        );
    let (api, doc) = http::router(app);
    let api = match cors {
        Some(origins) => http::cors::layer(api, http::cors::CorsPolicy::new(&doc, origins)),
        None => api,
    };
    let api = match pages {
        Pages::Demo => api.merge(http::demo::routes()),
        Pages::None => api,
    };
    // The WebSocket stream checks the handshake's origin itself (browsers apply no CORS to
    // WebSockets), so it stays outside the CORS layer.
    let api = api.merge(http::stream::routes(app, cors, ws));
    Ok(api
        .merge(grpc)
        .fallback(http::fallback)
        .layer(axum::middleware::from_fn_with_state(
            app.clone(),
            http::middleware::observe,
        )))
}

/// The web pages a server serves beside its API.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pages {
    /// The demo page at `/demo` (`--demo true`, the default).
    Demo,
    /// None (`--demo false`).
    None,
}

async fn serve_app(
    app: &Arc<App>,
    cfg: &Config,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
    started: Instant,
) -> Result<(), ServeError> {
    let pages = if cfg.demo { Pages::Demo } else { Pages::None };
    let router = routers(app, cfg.cors_origins.as_ref(), pages, cfg.ws)?;
    let addr = listener.local_addr()?;
    app.lifecycle.serving();
    tracing::info!(
        %addr,
        startup_ms = started.elapsed().as_millis() as u64,
        workers = cfg.workers,
        max_connections = cfg.connections.max_connections,
        "listening (HTTP and gRPC)"
    );
    let drain_app = app.clone();
    let aged = {
        let metrics = app.metrics.clone();
        move || metrics.connection_aged()
    };
    let server = crate::connections::serve(listener, router, cfg.connections, aged, async move {
        shutdown.await;
        tracing::info!("draining: not ready, no new connections, streams told to end");
        drain_app.lifecycle.begin_drain();
    });
    let drained = app.lifecycle.drained();
    let cap = cfg.drain_timeout;
    // The drain ends when every connection is closed and every accepted retraining job has
    // ended, or at the cap.
    let connections_done = Arc::new(AtomicBool::new(false));
    let done = connections_done.clone();
    let jobs = app.jobs.clone();
    let streams = app.clone();
    let finish = async move {
        server.await;
        // WebSocket streams run apart from their connections once upgraded: their closes.
        streams.lifecycle.streams_ended().await;
        done.store(true, Ordering::Release);
        let left = jobs.unfinished();
        if !left.is_empty() {
            tracing::info!(
                jobs = left.len(),
                "waiting for the accepted retraining jobs"
            );
        }
        jobs.idle().await;
        Ok::<(), std::io::Error>(())
    };
    tokio::select! {
        result = finish => result?,
        _ = async { drained.await; tokio::time::sleep(cap).await } => {
            // Jobs already cancelled and finishing their stage lose nothing.
            let abandoned_jobs: Vec<String> = app
                .jobs
                .unfinished()
                .into_iter()
                .filter(|(_, s)| *s != Unfinished::Stopping)
                .map(|(id, _)| id)
                .collect();
            let connections_open = !connections_done.load(Ordering::Acquire);
            tracing::error!(
                ?cap,
                connections_open,
                abandoned = ?abandoned_jobs,
                "drain timed out; closing what is left"
            );
            // Their records say so, for the other replicas; within a bound, as the volume may
            // be what held the drain.
            let (jobs, ids) = (app.jobs.clone(), abandoned_jobs.clone());
            let marked = facepose_app::blocking::spawn_blocking(move || jobs.abandon(&ids, cap));
            if tokio::time::timeout(std::time::Duration::from_secs(2), marked).await.is_err() {
                tracing::warn!("could not mark the abandoned jobs in the models folder in time");
            }
            // Not a clean stop: the caller says so (main prints it and exits with its status).
            return Err(ServeError::DrainCut { cap, connections_open, abandoned_jobs });
        }
    }
    tracing::info!("stopped");
    Ok(())
}

/// Resolves on SIGTERM or SIGINT (Ctrl-C) with the signal's name.
pub async fn termination_signal() -> &'static str {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match (
            signal(SignalKind::terminate()),
            signal(SignalKind::interrupt()),
        ) {
            (Ok(mut term), Ok(mut int)) => tokio::select! {
                _ = term.recv() => "SIGTERM",
                _ = int.recv() => "SIGINT",
            },
            _ => {
                let _ = tokio::signal::ctrl_c().await;
                "SIGINT"
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
        "SIGINT"
    }
}
