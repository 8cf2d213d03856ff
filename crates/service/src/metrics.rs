//! Prometheus metrics (`GET /metrics`), recorded through the `metrics` facade. Every label value
//! comes from a fixed set (route templates, method names, status codes), so the number of series
//! stays bounded whatever clients send.
//!
//! | metric | type | labels |
//! |---|---|---|
//! | `facepose_http_requests_total` | counter | `route`, `method`, `status` |
//! | `facepose_http_request_duration_seconds` | histogram | `route`, `method` |
//! | `facepose_grpc_requests_total` | counter | `rpc`, `code` |
//! | `facepose_grpc_request_duration_seconds` | histogram | `rpc` (streams: per frame) |
//! | `facepose_poses_total` | counter | `transport`, `method` (the estimator used) |
//! | `facepose_estimate_errors_total` | counter | `transport`, `code` (per face) |
//! | `facepose_streams_active` | gauge | |
//! | `facepose_model_info` | gauge (1; one series per model served, removed when replaced) | `name`, `version`, `checksum`, `default` |
//! | `facepose_model_swaps_total` | counter | `name` |
//! | `facepose_model_load_failures_total` | counter | `name` (the models folder entry) |
//! | `facepose_model_sync_problems` | gauge | (models whose active version is not served here) |
//! | `facepose_retrain_jobs_total` | counter | `outcome` (`succeeded`, `failed`, `cancelled`) |
//! | `facepose_retrain_jobs_waiting` | gauge | |
//! | `facepose_ready` | gauge | |

use std::collections::BTreeMap;
use std::time::Duration;

use metrics::{counter, describe_counter, describe_gauge, describe_histogram, gauge, histogram};
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};

use super::errors::ErrorKind;
use super::registry::{ModelSet, ServedModel};
use facepose_core::pose::Method;

/// Latency buckets, seconds: 50 µs to 10 s.
const BUCKETS: [f64; 17] = [
    5e-5, 1e-4, 2.5e-4, 5e-4, 1e-3, 2.5e-3, 5e-3, 1e-2, 2.5e-2, 5e-2, 0.1, 0.25, 0.5, 1.0, 2.5,
    5.0, 10.0,
];

/// The exporter's handle: renders the text format.
#[derive(Clone)]
pub struct Metrics {
    handle: PrometheusHandle,
}

impl std::fmt::Debug for Metrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Metrics")
    }
}

impl Metrics {
    /// Installs the process-wide recorder (once per process; a second call renders an empty
    /// registry) and describes the metrics.
    pub fn install() -> Metrics {
        let recorder = PrometheusBuilder::new()
            .set_buckets(&BUCKETS)
            .map(|b| b.build_recorder())
            .unwrap_or_else(|_| PrometheusBuilder::new().build_recorder());
        let handle = recorder.handle();
        if metrics::set_global_recorder(recorder).is_err() {
            tracing::warn!("a metrics recorder was already installed; /metrics will be empty");
        }
        describe_counter!(
            "facepose_http_requests_total",
            "HTTP requests by route template, method and status"
        );
        describe_histogram!(
            "facepose_http_request_duration_seconds",
            metrics::Unit::Seconds,
            "HTTP request latency by route template and method"
        );
        describe_counter!(
            "facepose_grpc_requests_total",
            "gRPC calls by method and status code (streams: one per stream)"
        );
        describe_histogram!(
            "facepose_grpc_request_duration_seconds",
            metrics::Unit::Seconds,
            "gRPC latency by method (EstimateStream: per frame)"
        );
        describe_counter!(
            "facepose_poses_total",
            "Faces estimated, by transport and estimator"
        );
        describe_counter!(
            "facepose_estimate_errors_total",
            "Faces that could not be estimated, by transport and error code"
        );
        describe_gauge!("facepose_streams_active", "Open EstimateStream streams");
        describe_gauge!("facepose_ready", "1 when serving, 0 when draining");
        describe_counter!(
            "facepose_model_swaps_total",
            "Model versions swapped in after start (activations here or seen in the models folder)"
        );
        describe_counter!(
            "facepose_model_load_failures_total",
            "Active versions in the models folder that failed to load (the previous one keeps serving)"
        );
        describe_gauge!(
            "facepose_model_sync_problems",
            "Models folder entries whose active version this replica cannot serve (listed by /readyz)"
        );
        describe_counter!(
            "facepose_retrain_jobs_total",
            "Finished retraining jobs by outcome"
        );
        describe_gauge!(
            "facepose_retrain_jobs_waiting",
            "Retraining jobs queued (not the one running)"
        );
        Metrics { handle }
    }

    /// The Prometheus text exposition.
    pub fn render(&self) -> String {
        let mut text = self.handle.render();
        render_model_info(&mut text);
        text
    }

    /// Drains histogram samples into their buckets every few seconds, so that memory stays
    /// flat between scrapes.
    pub fn spawn_upkeep(&self) {
        let handle = self.handle.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(5));
            loop {
                tick.tick().await;
                handle.run_upkeep();
            }
        });
    }
}

pub fn http_request(route: &'static str, method: &'static str, status: u16, elapsed: Duration) {
    counter!("facepose_http_requests_total", "route" => route, "method" => method, "status" => status_label(status))
        .increment(1);
    histogram!("facepose_http_request_duration_seconds", "route" => route, "method" => method)
        .record(elapsed.as_secs_f64());
}

pub fn grpc_request(rpc: &'static str, code: tonic::Code, elapsed: Option<Duration>) {
    counter!("facepose_grpc_requests_total", "rpc" => rpc, "code" => grpc_code_label(code))
        .increment(1);
    if let Some(d) = elapsed {
        grpc_latency(rpc, d);
    }
}

pub fn grpc_latency(rpc: &'static str, elapsed: Duration) {
    histogram!("facepose_grpc_request_duration_seconds", "rpc" => rpc)
        .record(elapsed.as_secs_f64());
}

/// Per-face outcomes of one request, recorded at once.
#[derive(Debug, Default)]
pub struct FaceTally {
    by_method: [u64; 5],
    by_error: Vec<(ErrorKind, u64)>,
}

impl FaceTally {
    pub fn ok(&mut self, m: Method) {
        self.by_method[method_index(m)] += 1;
    }

    pub fn err(&mut self, k: ErrorKind) {
        match self.by_error.iter_mut().find(|(e, _)| *e == k) {
            Some((_, n)) => *n += 1,
            None => self.by_error.push((k, 1)),
        }
    }

    pub fn succeeded(&self) -> u64 {
        self.by_method.iter().sum()
    }

    pub fn failed(&self) -> u64 {
        self.by_error.iter().map(|(_, n)| n).sum()
    }

    pub fn record(&self, transport: &'static str) {
        for (i, &n) in self.by_method.iter().enumerate() {
            if n > 0 {
                counter!("facepose_poses_total", "transport" => transport, "method" => Method::NAMES[i])
                    .increment(n);
            }
        }
        for &(k, n) in &self.by_error {
            counter!("facepose_estimate_errors_total", "transport" => transport, "code" => k.name())
                .increment(n);
        }
    }
}

fn method_index(m: Method) -> usize {
    match m {
        Method::Auto => 0,
        Method::Fit => 1,
        Method::FitShape => 2,
        Method::Regression => 3,
        Method::Geometry => 4,
    }
}

pub fn stream_opened() {
    gauge!("facepose_streams_active").increment(1.0);
}

pub fn stream_closed() {
    gauge!("facepose_streams_active").decrement(1.0);
}

pub fn ready(on: bool) {
    gauge!("facepose_ready").set(if on { 1.0 } else { 0.0 });
}

/// The `facepose_model_info` series: one per model served, by name (`version`, `checksum`,
/// `default`). Kept here rather than in the recorder, which cannot remove a series: a version
/// that stops being served leaves no series behind.
static MODEL_INFO: std::sync::Mutex<ModelRows> = std::sync::Mutex::new(BTreeMap::new());

fn model_info() -> std::sync::MutexGuard<'static, ModelRows> {
    MODEL_INFO.lock().unwrap_or_else(|e| e.into_inner())
}

fn model_info_row(m: &ServedModel, default: &str) -> (String, String, bool) {
    (m.version.clone(), m.checksum.clone(), m.name == default)
}

/// A label value in the text format.
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

type ModelRows = BTreeMap<String, (String, String, bool)>;

fn render_model_info(text: &mut String) {
    write_model_info(text, &model_info());
}

fn write_model_info(text: &mut String, rows: &ModelRows) {
    use std::fmt::Write;
    if rows.is_empty() {
        return;
    }
    if !text.is_empty() && !text.ends_with("\n\n") {
        text.push('\n');
    }
    text.push_str(
        "# HELP facepose_model_info Models served (value 1), with their version and checksum\n\
         # TYPE facepose_model_info gauge\n",
    );
    for (name, (version, checksum, default)) in rows.iter() {
        let _ = writeln!(
            text,
            "facepose_model_info{{name=\"{}\",version=\"{}\",checksum=\"{}\",default=\"{default}\"}} 1",
            label(name),
            label(version),
            label(checksum)
        );
    }
}

/// One `facepose_model_info` series per loaded model; the registry gauges at zero.
pub fn models(set: &ModelSet) {
    let mut rows = model_info();
    rows.clear();
    for m in set.iter() {
        rows.insert(m.name.clone(), model_info_row(m, set.default_name()));
    }
    drop(rows);
    sync_problems(0);
    retrain_jobs_waiting(0);
}

/// A version swapped in: its info series replaces the replaced one's (which is removed).
pub fn model_swapped(old: Option<&ServedModel>, new: &ServedModel, default: &str) {
    swap_row(&mut model_info(), old, new, default);
    counter!("facepose_model_swaps_total", "name" => new.name.clone()).increment(1);
}

fn swap_row(rows: &mut ModelRows, old: Option<&ServedModel>, new: &ServedModel, default: &str) {
    if let Some(o) = old {
        rows.remove(&o.name);
    }
    rows.insert(new.name.clone(), model_info_row(new, default));
}

/// An active version of the models folder that failed to load (counted once per problem).
pub fn model_load_failed(store: &str) {
    counter!("facepose_model_load_failures_total", "name" => store.to_string()).increment(1);
}

/// How many models folder entries the watcher currently cannot follow.
pub fn sync_problems(n: usize) {
    gauge!("facepose_model_sync_problems").set(n as f64);
}

pub fn retrain_job_finished(outcome: &'static str) {
    counter!("facepose_retrain_jobs_total", "outcome" => outcome).increment(1);
}

pub fn retrain_jobs_waiting(n: usize) {
    gauge!("facepose_retrain_jobs_waiting").set(n as f64);
}

fn status_label(status: u16) -> &'static str {
    match status {
        200 => "200",
        202 => "202",
        204 => "204",
        400 => "400",
        401 => "401",
        403 => "403",
        404 => "404",
        409 => "409",
        405 => "405",
        413 => "413",
        415 => "415",
        422 => "422",
        429 => "429",
        500 => "500",
        503 => "503",
        s if s < 300 => "2xx",
        s if s < 400 => "3xx",
        s if s < 500 => "4xx",
        _ => "5xx",
    }
}

/// The standard upper-case code names.
pub fn grpc_code_label(code: tonic::Code) -> &'static str {
    use tonic::Code as C;
    match code {
        C::Ok => "OK",
        C::Cancelled => "CANCELLED",
        C::Unknown => "UNKNOWN",
        C::InvalidArgument => "INVALID_ARGUMENT",
        C::DeadlineExceeded => "DEADLINE_EXCEEDED",
        C::NotFound => "NOT_FOUND",
        C::AlreadyExists => "ALREADY_EXISTS",
        C::PermissionDenied => "PERMISSION_DENIED",
        C::ResourceExhausted => "RESOURCE_EXHAUSTED",
        C::FailedPrecondition => "FAILED_PRECONDITION",
        C::Aborted => "ABORTED",
        C::OutOfRange => "OUT_OF_RANGE",
        C::Unimplemented => "UNIMPLEMENTED",
        C::Internal => "INTERNAL",
        C::Unavailable => "UNAVAILABLE",
        C::DataLoss => "DATA_LOSS",
        C::Unauthenticated => "UNAUTHENTICATED",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registry::load_models;

    #[test]
    fn a_replaced_version_leaves_no_info_series() {
        let set = load_models(None).unwrap();
        let old = set.get(None).unwrap();
        let mut rows = ModelRows::new();
        swap_row(&mut rows, None, old, "default");
        let mut new = load_models(None).unwrap().get(None).unwrap().clone();
        std::sync::Arc::get_mut(&mut new).unwrap().version = "2".into();
        swap_row(&mut rows, Some(old), &new, "default");
        let mut text = String::new();
        write_model_info(&mut text, &rows);
        let series: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with("facepose_model_info{"))
            .collect();
        assert_eq!(series.len(), 1, "{text}");
        assert!(
            series[0].starts_with(r#"facepose_model_info{name="default",version="2",checksum=""#),
            "{text}"
        );
        assert!(series[0].ends_with(r#",default="true"} 1"#), "{text}");
        assert!(text.contains("# TYPE facepose_model_info gauge\n"));
        assert_eq!(label("a\"b\\c\nd"), r#"a\"b\\c\nd"#);
    }
}
