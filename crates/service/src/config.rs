//! `facepose serve` configuration: flags, each with an environment variable, validated once at
//! start into a [`Config`]. Precedence: flag > environment > default.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use clap::{Args, ValueEnum};

pub use facepose_app::Limits;
use facepose_app::Settings;
use facepose_app::auth::{AdminToken, check_token};

pub use crate::http::cors::CorsOrigins;

/// Log line format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per line (for log collectors).
    Json,
}

/// The longest connection duration a flag may set (timeouts, ages).
const MAX_CONNECTION_DURATION: Duration = Duration::from_secs(365 * 24 * 3600);

/// The flags of `facepose serve`.
#[derive(Debug, Clone, Args)]
pub struct ServeArgs {
    /// Address to listen on, HTTP and gRPC on the same port (port 0: any free port; the bound
    /// address is logged as `listening addr=...`).
    #[arg(long, env = "FACEPOSE_ADDR", default_value = "0.0.0.0:8080")]
    pub addr: String,
    /// Models folder: each subfolder `<name>` is a model, served at the version its `ACTIVE`
    /// file names (`versions/<N>/model.json`), else its deployed `model.json` (docs/FORMATS.md).
    /// Default: ./models if it exists. Without a model named `default` there, the embedded
    /// default model serves as `default` (version 1). A broken active bundle stops the start
    /// with a message naming the file and the field.
    #[arg(long, env = "FACEPOSE_MODELS")]
    pub models: Option<PathBuf>,
    /// Most faces in one batch request (HTTP /v1/pose:batch, gRPC EstimateBatch) or one stream
    /// frame.
    #[arg(long, env = "FACEPOSE_MAX_BATCH", default_value_t = 1000)]
    pub max_batch: usize,
    /// Largest request body (HTTP) or message (gRPC), e.g. 8MiB, 512KiB, 1000000.
    #[arg(long, env = "FACEPOSE_MAX_BODY", default_value = "8MiB")]
    pub max_body: String,
    /// Per-request time limit of the HTTP API and of gRPC unary calls, e.g. 10s, 500ms.
    #[arg(long, env = "FACEPOSE_REQUEST_TIMEOUT", default_value = "10s")]
    pub request_timeout: String,
    /// Most requests of the HTTP API and gRPC unary calls in progress at once; above it they
    /// are refused at once (HTTP 429, gRPC UNAVAILABLE) instead of queueing.
    #[arg(long, env = "FACEPOSE_MAX_CONCURRENCY", default_value_t = 512)]
    pub max_concurrency: usize,
    /// Most open streams, gRPC EstimateStream and WebSocket (/v1/pose:stream) together; above it
    /// new streams get UNAVAILABLE (gRPC) or 503 (WebSocket handshake).
    #[arg(long, env = "FACEPOSE_MAX_STREAMS", default_value_t = 1024)]
    pub max_streams: usize,
    /// Most open connections (HTTP/1 and HTTP/2); past it a connection is answered 503 and
    /// closed. Default: the open-file limit (ulimit -n) less 128 for the models folder and the
    /// jobs, at most 10000.
    #[arg(long, env = "FACEPOSE_MAX_CONNECTIONS")]
    pub max_connections: Option<usize>,
    /// HTTP/1: the time a client has to send a request's headers, from the connection's start
    /// or the end of its previous request; slower or idle HTTP/1 connections are closed. Set
    /// a load balancer's idle timeout for its kept-alive connections below it. E.g. 30s.
    #[arg(long, env = "FACEPOSE_HEADER_TIMEOUT", default_value = "30s")]
    pub header_timeout: String,
    /// HTTP/2 (gRPC): a connection with no call or stream in progress this long is closed
    /// (GOAWAY), e.g. 120s.
    #[arg(long, env = "FACEPOSE_IDLE_TIMEOUT", default_value = "120s")]
    pub idle_timeout: String,
    /// HTTP/2: the interval of keep-alive pings; a peer that does not answer one within the
    /// same time is dropped with its streams. Quiet streams stay open. E.g. 20s.
    #[arg(long, env = "FACEPOSE_KEEPALIVE", default_value = "20s")]
    pub keepalive: String,
    /// Connections older than this (±10%, so that they do not all go at once) are asked to
    /// close: HTTP/2 gets a GOAWAY (clients open a new connection for their next call, so
    /// long-lived gRPC channels reach pods added by a scale-out), HTTP/1 is closed after its
    /// current request. E.g. 5m; default: never.
    #[arg(long, env = "FACEPOSE_MAX_CONNECTION_AGE")]
    pub max_connection_age: Option<String>,
    /// With --max-connection-age: how long calls and streams in progress on an aged
    /// connection may go on before it is closed under them, e.g. 30s.
    #[arg(long, env = "FACEPOSE_MAX_CONNECTION_AGE_GRACE", default_value = "30s")]
    pub max_connection_age_grace: String,
    /// On SIGTERM/SIGINT: how long in-flight requests may take to finish before the process
    /// exits anyway, e.g. 10s.
    #[arg(long, env = "FACEPOSE_DRAIN_TIMEOUT", default_value = "10s")]
    pub drain_timeout: String,
    /// WebSocket streams (`GET /v1/pose:stream`): a stream with no frame for this long is
    /// closed (1008), e.g. 60s.
    #[arg(long, env = "FACEPOSE_WS_IDLE_TIMEOUT", default_value = "60s")]
    pub ws_idle_timeout: String,
    /// WebSocket streams: the server pings this often, and closes (1008) a stream it has heard
    /// nothing from (pong or frame) for two intervals, e.g. 20s.
    #[arg(long, env = "FACEPOSE_WS_PING_INTERVAL", default_value = "20s")]
    pub ws_ping_interval: String,
    /// WebSocket streams: answers that may wait for a client reading slowly; one more closes
    /// the stream (1008).
    #[arg(long, env = "FACEPOSE_WS_QUEUE", default_value_t = 64)]
    pub ws_queue: usize,
    /// Worker threads (default: the number of CPUs).
    #[arg(long, env = "FACEPOSE_WORKERS")]
    pub workers: Option<usize>,
    /// Log line format: `text` for people, `json` (one object per line) for log collectors.
    #[arg(long, env = "FACEPOSE_LOG_FORMAT", value_enum, default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
    /// Log filter (tracing EnvFilter syntax), e.g. info, debug, facepose=debug,warn.
    #[arg(long, env = "FACEPOSE_LOG", default_value = "info")]
    pub log: String,
    /// A file holding the admin bearer token (retraining, activation, deletion). The token can
    /// also come from the FACEPOSE_ADMIN_TOKEN environment variable (not both). Without a
    /// token the admin routes answer 403. At least 16 visible ASCII characters; surrounding
    /// whitespace is ignored.
    #[arg(long, env = "FACEPOSE_ADMIN_TOKEN_FILE")]
    pub admin_token_file: Option<PathBuf>,
    /// Largest retraining upload (HTTP body of POST /v1/models; gRPC Retrain stream in all,
    /// each message at most --max-body), e.g. 64MiB.
    #[arg(long, env = "FACEPOSE_MAX_UPLOAD", default_value = "64MiB")]
    pub max_upload: String,
    /// Time limit for receiving and checking a retraining upload (training itself runs in the
    /// background), e.g. 60s.
    #[arg(long, env = "FACEPOSE_UPLOAD_TIMEOUT", default_value = "60s")]
    pub upload_timeout: String,
    /// Retraining jobs that may wait while one trains; more uploads get 429 / UNAVAILABLE.
    #[arg(long, env = "FACEPOSE_MAX_QUEUED_JOBS", default_value_t = 4)]
    pub max_queued_jobs: usize,
    /// How often the models folder's active pointers are read, so that a version activated by
    /// another replica sharing the folder is served here too, e.g. 2s, 500ms.
    #[arg(long, env = "FACEPOSE_REGISTRY_POLL", default_value = "2s")]
    pub registry_poll: String,
    /// This replica's name in the retraining jobs it runs, which every replica sharing the
    /// models folder shows; default: the host name (a pod's name in Kubernetes).
    #[arg(long, env = "FACEPOSE_REPLICA")]
    pub replica: Option<String>,
    /// Inactive versions of a model kept once a retraining job has written a new one: the
    /// newest N (by id) besides the active one stay for rollback, older ones are deleted;
    /// `all` keeps every version.
    #[arg(long, env = "FACEPOSE_KEEP_INACTIVE_VERSIONS", default_value = "10")]
    pub keep_inactive_versions: String,
    /// Origins whose web pages may call the HTTP API from a browser (CORS): a comma-separated
    /// list of `scheme://host[:port]` as browsers send them (e.g.
    /// https://app.example.com,http://localhost:3000), or `*` for every origin. Listed origins
    /// may call every `/v1` route (admin routes still need the token); `*` opens only the routes
    /// that need no admin token. Default: none (no CORS headers).
    #[arg(long, env = "FACEPOSE_CORS_ORIGINS")]
    pub cors_origins: Option<String>,
    /// Serve the demo page at /demo: a pose explorer and a landmark box over this server's
    /// own /v1 routes, for developers (one static page, no external assets; docs/API.md).
    /// `--demo false` (or FACEPOSE_DEMO=false) leaves /demo a 404, e.g. on a public API port.
    #[arg(
        long,
        env = "FACEPOSE_DEMO",
        default_value_t = true,
        action = clap::ArgAction::Set,
        value_name = "true|false",
        value_parser = on_off()
    )]
    pub demo: bool,
}

/// A switch's values, each with its help (`facepose serve --help` lists them): `true` or
/// `false`, also as `on`/`off`, `yes`/`no`, `1`/`0`.
fn on_off() -> impl clap::builder::TypedValueParser<Value = bool> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    PossibleValuesParser::new([
        PossibleValue::new("true")
            .help("on (also: on, yes, 1)")
            .aliases(["on", "yes", "1"]),
        PossibleValue::new("false")
            .help("off (also: off, no, 0)")
            .aliases(["off", "no", "0"]),
    ])
    .map(|v| matches!(v.as_str(), "true" | "on" | "yes" | "1"))
}

/// The environment variable holding the admin token (read directly, never a flag: a flag
/// would show in the process list).
pub const ADMIN_TOKEN_ENV: &str = "FACEPOSE_ADMIN_TOKEN";

/// The validated configuration.
#[derive(Debug, Clone)]
pub struct Config {
    /// Where to listen (`--addr`).
    pub addr: SocketAddr,
    /// The models folder (`--models`), if given.
    pub models: Option<PathBuf>,
    /// The request limits.
    pub limits: Limits,
    /// Longest the drain may take before the server exits anyway (`--drain-timeout`).
    pub drain_timeout: Duration,
    /// The connection bounds.
    pub connections: crate::connections::ConnectionLimits,
    /// Worker threads (`--workers`; default: the number of CPUs).
    pub workers: usize,
    /// Log line format (`--log-format`).
    pub log_format: LogFormat,
    /// Log filter, tracing EnvFilter syntax (`--log`).
    pub log: String,
    /// The admin token, if any (none: admin routes disabled).
    pub admin_token: AdminToken,
    /// Retraining jobs that may wait while one trains (`--max-queued-jobs`).
    pub max_queued_jobs: usize,
    /// How often the models folder's active pointers are read (`--registry-poll`).
    pub registry_poll: Duration,
    /// This replica's name in the retraining jobs it runs (`--replica`).
    pub replica: String,
    /// `None`: every version is kept.
    pub keep_inactive_versions: Option<usize>,
    /// `None`: CORS off.
    pub cors_origins: Option<CorsOrigins>,
    /// Whether `/demo` serves the demo page.
    pub demo: bool,
    /// The WebSocket streams' bounds (`--ws-idle-timeout`, `--ws-ping-interval`, `--ws-queue`).
    pub ws: crate::http::stream::WsLimits,
}

impl Config {
    /// What the application starts from: the models folder resolved (`--models`, else
    /// `./models` if it exists, else none: the embedded default model only).
    pub fn app_settings(&self) -> Settings {
        Settings {
            models: match &self.models {
                Some(d) => Some(d.clone()),
                None => Some(PathBuf::from("models")).filter(|d| d.is_dir()),
            },
            limits: self.limits,
            admin_token: self.admin_token.clone(),
            max_queued_jobs: self.max_queued_jobs,
            registry_poll: self.registry_poll,
            replica: self.replica.clone(),
            keep_inactive_versions: self.keep_inactive_versions,
        }
    }
}

/// A flag or variable with an unusable value.
#[derive(Debug, thiserror::Error)]
#[error("{setting}: {reason}")]
pub struct ConfigError {
    /// `--flag`, or the environment variable that has no flag.
    pub setting: String,
    /// What is wrong with the value.
    pub reason: String,
}

/// The most requests in progress or streams open that the flags may allow.
pub const MAX_COUNT: usize = 1 << 20;
/// The most retraining jobs that may wait behind the one training.
pub const MAX_QUEUED_JOBS: usize = 1024;

fn bad(flag: &str, reason: impl Into<String>) -> ConfigError {
    ConfigError {
        setting: format!("--{flag}"),
        reason: reason.into(),
    }
}

/// The default `--max-connections` when the open-file limit is unknown or unlimited.
pub const DEFAULT_MAX_CONNECTIONS: usize = 10_000;

/// File descriptors kept back from `--max-connections`'s default: the models folder's files,
/// the jobs' records, the listener, logs.
const RESERVED_FILES: usize = 128;

/// The soft limit on open files (`ulimit -n`), if there is one.
fn open_file_limit() -> Option<usize> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes one rlimit through the valid pointer it is given.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0;
    (ok && limit.rlim_cur != libc::RLIM_INFINITY).then_some(limit.rlim_cur as usize)
}

impl ServeArgs {
    fn connection_limits(&self) -> Result<crate::connections::ConnectionLimits, ConfigError> {
        let duration = |flag: &str, text: &str| {
            let d = parse_duration(text).map_err(|r| bad(flag, r))?;
            if d < Duration::from_millis(100) {
                return Err(bad(flag, "must be at least 100ms"));
            }
            // Far past any use, and far from what a timer's arithmetic can overflow.
            if d > MAX_CONNECTION_DURATION {
                return Err(bad(flag, "must be at most 365 days"));
            }
            Ok(d)
        };
        let max_connections = match self.max_connections {
            Some(n) if n > MAX_COUNT => {
                return Err(bad(
                    "max-connections",
                    format!("must be at most {MAX_COUNT}, got {n}"),
                ));
            }
            Some(0) => return Err(bad("max-connections", "must be at least 1")),
            Some(n) => n,
            None => open_file_limit().map_or(DEFAULT_MAX_CONNECTIONS, |files| {
                files
                    .saturating_sub(RESERVED_FILES)
                    .clamp(1, DEFAULT_MAX_CONNECTIONS)
            }),
        };
        Ok(crate::connections::ConnectionLimits {
            max_connections,
            header_timeout: duration("header-timeout", &self.header_timeout)?,
            idle_timeout: duration("idle-timeout", &self.idle_timeout)?,
            keepalive: duration("keepalive", &self.keepalive)?,
            max_age: self
                .max_connection_age
                .as_deref()
                .map(|a| duration("max-connection-age", a))
                .transpose()?,
            age_grace: duration("max-connection-age-grace", &self.max_connection_age_grace)?,
        })
    }

    /// Checks every value and returns the configuration.
    pub fn validate(&self) -> Result<Config, ConfigError> {
        let addr = self.addr.parse().map_err(|e| {
            bad(
                "addr",
                format!("{:?} is not an IP:port address ({e})", self.addr),
            )
        })?;
        let positive = |flag, v: usize| {
            if v == 0 {
                Err(bad(flag, "must be at least 1"))
            } else {
                Ok(v)
            }
        };
        // Counts held by semaphores, which take at most `usize::MAX >> 3` permits.
        let count = |flag, v: usize, max: usize| {
            if v > max {
                Err(bad(flag, format!("must be at most {max}, got {v}")))
            } else {
                positive(flag, v)
            }
        };
        let limits = Limits {
            max_batch: positive("max-batch", self.max_batch)?,
            max_body: parse_size(&self.max_body).map_err(|r| bad("max-body", r))?,
            request_timeout: parse_duration(&self.request_timeout)
                .map_err(|r| bad("request-timeout", r))?,
            max_concurrency: count("max-concurrency", self.max_concurrency, MAX_COUNT)?,
            max_streams: count("max-streams", self.max_streams, MAX_COUNT)?,
            max_upload: parse_size(&self.max_upload).map_err(|r| bad("max-upload", r))?,
            upload_timeout: parse_duration(&self.upload_timeout)
                .map_err(|r| bad("upload-timeout", r))?,
        };
        if limits.max_upload < 1024 {
            return Err(bad("max-upload", "must be at least 1KiB"));
        }
        if limits.upload_timeout.is_zero() {
            return Err(bad("upload-timeout", "must be positive"));
        }
        // Every queued job holds its upload (up to --max-upload) in memory.
        if self.max_queued_jobs > MAX_QUEUED_JOBS {
            return Err(bad(
                "max-queued-jobs",
                format!(
                    "must be at most {MAX_QUEUED_JOBS}, got {} (each queued job holds its upload \
                     in memory)",
                    self.max_queued_jobs
                ),
            ));
        }
        let registry_poll =
            parse_duration(&self.registry_poll).map_err(|r| bad("registry-poll", r))?;
        if registry_poll < Duration::from_millis(50) {
            return Err(bad("registry-poll", "must be at least 50ms"));
        }
        if limits.max_body < 1024 {
            return Err(bad("max-body", "must be at least 1KiB"));
        }
        if limits.request_timeout.is_zero() {
            return Err(bad("request-timeout", "must be positive"));
        }
        let keep_inactive_versions = match self.keep_inactive_versions.trim() {
            "all" => None,
            n => Some(n.parse::<usize>().map_err(|_| {
                bad(
                    "keep-inactive-versions",
                    format!("{n:?}: give a number of versions (0 or more) or \"all\""),
                )
            })?),
        };
        let cors_origins = match &self.cors_origins {
            Some(text) => CorsOrigins::parse(text).map_err(|r| bad("cors-origins", r))?,
            None => None,
        };
        let connections = self.connection_limits()?;
        let workers = match self.workers {
            Some(w) => positive("workers", w)?,
            None => std::thread::available_parallelism().map_or(2, |n| n.get()),
        };
        tracing_subscriber::EnvFilter::try_new(&self.log)
            .map_err(|e| bad("log", format!("{:?}: {e}", self.log)))?;
        let ws_duration = |flag: &str, text: &str| {
            let d = parse_duration(text).map_err(|r| bad(flag, r))?;
            if d.is_zero() {
                return Err(bad(flag, "must be more than 0"));
            }
            Ok::<_, ConfigError>(d)
        };
        let ws = crate::http::stream::WsLimits {
            idle_timeout: ws_duration("ws-idle-timeout", &self.ws_idle_timeout)?,
            ping_interval: ws_duration("ws-ping-interval", &self.ws_ping_interval)?,
            queue: positive("ws-queue", self.ws_queue)?,
        };
        Ok(Config {
            ws,
            addr,
            keep_inactive_versions,
            cors_origins,
            demo: self.demo,
            models: self.models.clone(),
            limits,
            drain_timeout: parse_duration(&self.drain_timeout)
                .map_err(|r| bad("drain-timeout", r))?,
            connections,
            workers,
            log_format: self.log_format,
            log: self.log.clone(),
            admin_token: self.admin_token(std::env::var(ADMIN_TOKEN_ENV).ok())?,
            max_queued_jobs: self.max_queued_jobs,
            registry_poll,
            replica: match &self.replica {
                Some(r) if r.trim().is_empty() || r.len() > 253 => {
                    return Err(bad("replica", "must be 1 to 253 characters"));
                }
                Some(r) => r.trim().to_string(),
                None => facepose_app::jobs::records::replica_name(),
            },
        })
    }

    /// The admin token from `--admin-token-file` or the environment's value `env`.
    fn admin_token(&self, env: Option<String>) -> Result<AdminToken, ConfigError> {
        let env = env.filter(|t| !t.is_empty());
        let token = match (&self.admin_token_file, env) {
            (Some(_), Some(_)) => {
                return Err(bad(
                    "admin-token-file",
                    format!("{ADMIN_TOKEN_ENV} is set too; give the token one way only"),
                ));
            }
            (Some(path), None) => {
                let text = std::fs::read_to_string(path).map_err(|e| {
                    bad(
                        "admin-token-file",
                        format!("cannot read {}: {e}", path.display()),
                    )
                })?;
                let t = text.trim().to_string();
                check_token(&t)
                    .map_err(|r| bad("admin-token-file", format!("{}: {r}", path.display())))?;
                t
            }
            (None, Some(t)) => {
                let t = t.trim().to_string();
                check_token(&t).map_err(|reason| ConfigError {
                    setting: ADMIN_TOKEN_ENV.into(),
                    reason,
                })?;
                t
            }
            (None, None) => return Ok(AdminToken::disabled()),
        };
        Ok(AdminToken::new(&token))
    }
}

/// `10s`, `500ms`, `1m`, `1.5s`; a bare number is seconds.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let t = s.trim();
    let (num, unit) = split_unit(t);
    let v: f64 = num
        .parse()
        .map_err(|_| format!("{s:?} is not a duration (e.g. 10s, 500ms, 1m)"))?;
    let secs = match unit {
        "" | "s" => v,
        "ms" => v / 1e3,
        "us" | "µs" => v / 1e6,
        "m" | "min" => v * 60.0,
        "h" => v * 3600.0,
        _ => return Err(format!("{s:?}: unknown unit {unit:?} (use ms, s, m or h)")),
    };
    Duration::try_from_secs_f64(secs).map_err(|_| format!("{s:?} is not a non-negative duration"))
}

/// `8MiB`, `512KiB`, `1MB`, `1000000`; bytes.
pub fn parse_size(s: &str) -> Result<usize, String> {
    let t = s.trim();
    let (num, unit) = split_unit(t);
    let v: f64 = num
        .parse()
        .map_err(|_| format!("{s:?} is not a size (e.g. 8MiB, 512KiB, 1000000)"))?;
    let mult = match unit.to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "kib" => 1024.0,
        "m" | "mb" => 1e6,
        "mib" => 1024.0 * 1024.0,
        "g" | "gb" => 1e9,
        "gib" => 1024.0 * 1024.0 * 1024.0,
        _ => {
            return Err(format!(
                "{s:?}: unknown unit {unit:?} (use KiB, MiB or bytes)"
            ));
        }
    };
    let bytes = v * mult;
    if !(bytes.is_finite() && bytes >= 0.0 && bytes <= (1u64 << 40) as f64) {
        return Err(format!("{s:?} is out of range"));
    }
    Ok(bytes as usize)
}

fn split_unit(t: &str) -> (&str, &str) {
    let i = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    (t[..i].trim(), t[i..].trim())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        serve: ServeArgs,
    }

    #[test]
    fn defaults_parse_and_validate() {
        let c = Cli::try_parse_from(["facepose"]).unwrap().serve;
        // The environment may set FACEPOSE_* variables; the defaults must validate either way.
        let cfg = c.validate().unwrap();
        if std::env::var_os("FACEPOSE_ADDR").is_none() {
            assert_eq!(cfg.addr, "0.0.0.0:8080".parse().unwrap());
        }
        if std::env::var_os("FACEPOSE_MAX_BATCH").is_none() {
            assert_eq!(cfg.limits.max_batch, 1000);
        }
        if std::env::var_os("FACEPOSE_DRAIN_TIMEOUT").is_none() {
            assert_eq!(cfg.drain_timeout, Duration::from_secs(10));
        }
        assert!(cfg.workers >= 1);
    }

    #[test]
    fn bad_values_name_the_flag() {
        let parse = |args: &[&str]| {
            let mut v = vec!["facepose"];
            v.extend_from_slice(args);
            Cli::try_parse_from(v).unwrap().serve.validate()
        };
        for (args, want) in [
            (&["--addr", "localhost"][..], "--addr"),
            (&["--max-batch", "0"][..], "--max-batch"),
            (&["--max-body", "lots"][..], "--max-body"),
            (&["--request-timeout", "5 parsecs"][..], "--request-timeout"),
            (&["--request-timeout", "0s"][..], "--request-timeout"),
            (&["--log", "=="][..], "--log"),
            (&["--max-upload", "1"][..], "--max-upload"),
            (&["--registry-poll", "1ms"][..], "--registry-poll"),
            (
                &["--max-concurrency", "18446744073709551615"][..],
                "--max-concurrency",
            ),
            (&["--max-streams", "0"][..], "--max-streams"),
            (
                &["--max-connection-age", "1e19s"][..],
                "--max-connection-age",
            ),
            (
                &["--max-connection-age-grace", "50ms"][..],
                "--max-connection-age-grace",
            ),
            (
                &["--cors-origins", "https://app.example.com/"][..],
                "--cors-origins",
            ),
            (
                &["--max-queued-jobs", "18446744073709551615"][..],
                "--max-queued-jobs",
            ),
            (
                &["--admin-token-file", "/nonexistent/token"][..],
                "--admin-token-file",
            ),
        ] {
            let err = parse(args).unwrap_err().to_string();
            assert!(err.starts_with(want), "{args:?}: {err}");
        }
    }

    #[test]
    fn the_demo_page_is_on_unless_turned_off() {
        let demo = |args: &[&str]| {
            let mut v = vec!["facepose"];
            v.extend_from_slice(args);
            Cli::try_parse_from(v).map(|c| c.serve.demo)
        };
        if std::env::var_os("FACEPOSE_DEMO").is_none() {
            assert!(demo(&[]).unwrap());
        }
        for (value, want) in [
            ("false", false),
            ("true", true),
            ("off", false),
            ("on", true),
            ("0", false),
            ("yes", true),
        ] {
            assert_eq!(demo(&["--demo", value]).unwrap(), want, "{value}");
        }
        assert!(demo(&["--demo", "maybe"]).is_err());
    }

    #[test]
    fn admin_token_sources() {
        let args = |file: Option<&std::path::Path>| {
            let mut v = vec!["facepose".to_string()];
            if let Some(f) = file {
                v.push("--admin-token-file".into());
                v.push(f.display().to_string());
            }
            Cli::try_parse_from(v).unwrap().serve
        };
        let token = "0123456789abcdef0123";
        assert!(!args(None).admin_token(None).unwrap().is_enabled());
        assert!(
            args(None)
                .admin_token(Some(token.into()))
                .unwrap()
                .is_enabled()
        );
        let e = args(None).admin_token(Some("short".into())).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("FACEPOSE_ADMIN_TOKEN: the admin token has 5"),
            "{e}"
        );
        let file = std::env::temp_dir().join(format!("facepose-token-{}", std::process::id()));
        std::fs::write(&file, format!("{token}\n")).unwrap();
        let t = args(Some(&file)).admin_token(None).unwrap();
        assert!(t.check([format!("Bearer {token}").as_bytes()]).is_ok());
        let e = args(Some(&file))
            .admin_token(Some(token.into()))
            .unwrap_err();
        assert!(e.to_string().contains("one way only"), "{e}");
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn units() {
        assert_eq!(parse_duration("250ms").unwrap(), Duration::from_millis(250));
        assert_eq!(parse_duration("1.5s").unwrap(), Duration::from_millis(1500));
        assert_eq!(parse_duration("2m").unwrap(), Duration::from_secs(120));
        assert_eq!(parse_duration("3").unwrap(), Duration::from_secs(3));
        assert_eq!(parse_size("8MiB").unwrap(), 8 << 20);
        assert_eq!(parse_size("512KiB").unwrap(), 512 << 10);
        assert_eq!(parse_size("1000").unwrap(), 1000);
        assert!(parse_size("-1").is_err());
        assert!(parse_duration("-1s").is_err());
    }
}
