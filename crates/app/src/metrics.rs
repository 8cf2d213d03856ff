//! Prometheus metrics (`GET /metrics`), one recorder per server: [`Metrics`] holds its own
//! recorder, so that servers embedded in one process (the tests run many) count apart. Every
//! label value comes from a fixed set (route templates, method names, status codes), so the
//! number of series stays bounded whatever clients send.
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

use std::collections::{BTreeMap, HashSet};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use facepose_core::pose::Method;
use metrics::{
    Counter, counter, describe_counter, describe_gauge, describe_histogram, gauge, histogram,
};
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle, PrometheusRecorder};

use crate::error::ErrorKind;

/// Latency buckets, seconds: 50 µs to 10 s.
const BUCKETS: [f64; 17] = [
    5e-5, 1e-4, 2.5e-4, 5e-4, 1e-3, 2.5e-3, 5e-3, 1e-2, 2.5e-2, 5e-2, 0.1, 0.25, 0.5, 1.0, 2.5,
    5.0, 10.0,
];

/// The transport a face came through, a label of the per-face metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    /// HTTP.
    Http,
    /// gRPC.
    Grpc,
    /// The WebSocket stream (`GET /v1/pose:stream`).
    WebSocket,
}

impl Transport {
    /// Every transport, in the order of [`Transport::index`].
    pub const ALL: [Transport; 3] = [Transport::Http, Transport::Grpc, Transport::WebSocket];

    /// The transport's place in [`Transport::ALL`], for tables indexed by transport.
    pub const fn index(self) -> usize {
        match self {
            Transport::Http => 0,
            Transport::Grpc => 1,
            Transport::WebSocket => 2,
        }
    }

    /// The transport's label value.
    pub fn name(self) -> &'static str {
        match self {
            Transport::Http => "http",
            Transport::Grpc => "grpc",
            Transport::WebSocket => "websocket",
        }
    }
}

/// One server's metrics: its recorder and the rendering of the text format. Cheap to clone.
#[derive(Clone)]
pub struct Metrics(Arc<Inner>);

struct Inner {
    recorder: PrometheusRecorder,
    handle: PrometheusHandle,
    /// The `facepose_model_info` series, kept here rather than in the recorder, which cannot
    /// remove a series: a version that stops being served leaves no series behind.
    model_info: Mutex<ModelRows>,
    /// `facepose_poses_total`'s handles by transport and method, each registered on its
    /// first face as the macro would register it: a face's count is then one atomic add,
    /// not a look-up of its labels in the registry (about 1,000 instructions a request).
    poses: [[OnceLock<Counter>; Method::ALL.len()]; Transport::ALL.len()],
}

impl std::fmt::Debug for Metrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Metrics")
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    /// A recorder of its own, with every metric described.
    pub fn new() -> Metrics {
        let recorder = PrometheusBuilder::new()
            .set_buckets(&BUCKETS)
            .map(|b| b.build_recorder())
            .unwrap_or_else(|_| PrometheusBuilder::new().build_recorder());
        let handle = recorder.handle();
        let m = Metrics(Arc::new(Inner {
            recorder,
            handle,
            model_info: Mutex::new(BTreeMap::new()),
            poses: Default::default(),
        }));
        m.with(describe);
        m
    }

    /// Runs `f` with this server's recorder as the one the `metrics` macros record into.
    fn with<T>(&self, f: impl FnOnce() -> T) -> T {
        metrics::with_local_recorder(&self.0.recorder, f)
    }

    /// The Prometheus text exposition.
    pub fn render(&self) -> String {
        let mut text = self.0.handle.render();
        write_model_info(&mut text, &lock(&self.0.model_info));
        text
    }

    /// Drains histogram samples into their buckets, so that memory stays flat between scrapes
    /// (every few seconds, from a background task).
    pub fn upkeep(&self) {
        self.0.handle.run_upkeep();
    }

    /// An HTTP request's outcome; `route` is its route template (bounded: the router's).
    pub fn http_request(&self, route: &str, method: &'static str, status: u16, elapsed: Duration) {
        let route = intern(route);
        self.with(|| {
            counter!("facepose_http_requests_total", "route" => route, "method" => method, "status" => status_label(status))
                .increment(1);
            histogram!("facepose_http_request_duration_seconds", "route" => route, "method" => method)
                .record(elapsed.as_secs_f64());
        });
    }

    /// A gRPC call's outcome (`code`: the standard upper-case name), with its latency if timed.
    pub fn grpc_request(&self, rpc: &'static str, code: &'static str, elapsed: Option<Duration>) {
        self.with(|| {
            counter!("facepose_grpc_requests_total", "rpc" => rpc, "code" => code).increment(1);
        });
        if let Some(d) = elapsed {
            self.grpc_latency(rpc, d);
        }
    }

    /// A gRPC call's latency.
    pub fn grpc_latency(&self, rpc: &'static str, elapsed: Duration) {
        self.with(|| {
            histogram!("facepose_grpc_request_duration_seconds", "rpc" => rpc)
                .record(elapsed.as_secs_f64());
        });
    }

    /// The per-face outcomes of one request.
    pub fn faces(&self, tally: &FaceTally, transport: Transport) {
        let poses = &self.0.poses[transport.index()];
        let transport = transport.name();
        for ((m, &n), slot) in Method::ALL.iter().zip(&tally.by_method).zip(poses) {
            if n > 0 {
                slot.get_or_init(|| {
                    self.with(|| {
                        counter!("facepose_poses_total", "transport" => transport, "method" => m.name())
                    })
                })
                .increment(n);
            }
        }
        if !tally.by_error.is_empty() {
            self.with(|| {
                for &(k, n) in &tally.by_error {
                    counter!("facepose_estimate_errors_total", "transport" => transport, "code" => k)
                        .increment(n);
                }
            });
        }
    }

    /// A stream opened.
    pub fn stream_opened(&self) {
        self.with(|| gauge!("facepose_streams_active").increment(1.0));
    }

    /// A stream closed.
    pub fn stream_closed(&self) {
        self.with(|| gauge!("facepose_streams_active").decrement(1.0));
    }

    /// A connection asked to close for its age (`--max-connection-age`).
    pub fn connection_aged(&self) {
        self.with(|| counter!("facepose_connections_aged_total").increment(1));
    }

    /// Whether the server is ready (the `facepose_ready` gauge).
    pub fn ready(&self, on: bool) {
        self.with(|| gauge!("facepose_ready").set(if on { 1.0 } else { 0.0 }));
    }

    /// The models served at start: one `facepose_model_info` series each; the registry gauges
    /// at zero.
    pub fn models<'a>(&self, served: impl IntoIterator<Item = ModelInfo<'a>>, default: &str) {
        let mut rows = lock(&self.0.model_info);
        rows.clear();
        for m in served {
            rows.insert(m.name.to_string(), model_info_row(m, default));
        }
        drop(rows);
        self.sync_problems(0);
        self.retrain_jobs_waiting(0);
    }

    /// A version swapped in: its info series replaces the replaced one's (which is removed).
    pub fn model_swapped(&self, old: Option<ModelInfo<'_>>, new: ModelInfo<'_>, default: &str) {
        swap_row(&mut lock(&self.0.model_info), old, new, default);
        let name = new.name.to_string();
        self.with(|| counter!("facepose_model_swaps_total", "name" => name).increment(1));
    }

    /// An active version of the models folder that failed to load (counted once per problem).
    pub fn model_load_failed(&self, store: &str) {
        let name = store.to_string();
        self.with(|| counter!("facepose_model_load_failures_total", "name" => name).increment(1));
    }

    /// How many models folder entries the watcher currently cannot follow.
    pub fn sync_problems(&self, n: usize) {
        self.with(|| gauge!("facepose_model_sync_problems").set(n as f64));
    }

    /// A retraining job ended with `outcome`.
    pub fn retrain_job_finished(&self, outcome: &'static str) {
        self.with(|| counter!("facepose_retrain_jobs_total", "outcome" => outcome).increment(1));
    }

    /// Retraining jobs queued or running.
    pub fn retrain_jobs_waiting(&self, n: usize) {
        self.with(|| gauge!("facepose_retrain_jobs_waiting").set(n as f64));
    }
}

fn describe() {
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
    describe_counter!(
        "facepose_connections_aged_total",
        "Connections asked to close for their age (--max-connection-age)"
    );
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
}

/// Per-face outcomes of one request, recorded at once ([`Metrics::faces`]).
#[derive(Debug, Default)]
pub struct FaceTally {
    by_method: [u64; Method::ALL.len()],
    /// Error codes (the transport's names) and their counts.
    by_error: Vec<(&'static str, u64)>,
}

impl FaceTally {
    /// A face answered by method `m`.
    pub fn ok(&mut self, m: Method) {
        self.by_method[m.index()] += 1;
    }

    /// A face that failed with an error of `kind`.
    pub fn err(&mut self, kind: ErrorKind) {
        let code = kind.name();
        match self.by_error.iter_mut().find(|(c, _)| *c == code) {
            Some((_, n)) => *n += 1,
            None => self.by_error.push((code, 1)),
        }
    }

    /// Faces answered.
    pub fn succeeded(&self) -> u64 {
        self.by_method.iter().sum()
    }

    /// Faces that failed.
    pub fn failed(&self) -> u64 {
        self.by_error.iter().map(|(_, n)| n).sum()
    }
}

/// A route template as a `'static` label: each distinct template is kept once (the router has
/// a fixed set of them).
fn intern(route: &str) -> &'static str {
    static SEEN: OnceLock<Mutex<HashSet<&'static str>>> = OnceLock::new();
    let mut seen = lock(SEEN.get_or_init(Default::default));
    if let Some(&s) = seen.get(route) {
        return s;
    }
    let s: &'static str = Box::leak(route.to_string().into_boxed_str());
    seen.insert(s);
    s
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

type ModelRows = BTreeMap<String, (String, String, bool)>;

/// What the metrics show of a served model (`facepose_model_info`).
#[derive(Debug, Clone, Copy)]
pub struct ModelInfo<'a> {
    /// The model's name.
    pub name: &'a str,
    /// The version served.
    pub version: &'a str,
    /// The bundle's checksum, `sha256:<hex>`.
    pub checksum: &'a str,
}

fn model_info_row(m: ModelInfo<'_>, default: &str) -> (String, String, bool) {
    (
        m.version.to_string(),
        m.checksum.to_string(),
        m.name == default,
    )
}

fn swap_row(rows: &mut ModelRows, old: Option<ModelInfo<'_>>, new: ModelInfo<'_>, default: &str) {
    if let Some(o) = old {
        rows.remove(o.name);
    }
    rows.insert(new.name.to_string(), model_info_row(new, default));
}

/// A label value in the text format.
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registry::load_models;

    #[test]
    fn a_replaced_version_leaves_no_info_series() {
        let set = load_models(None).unwrap();
        let old = set.get(None).unwrap();
        let mut rows = ModelRows::new();
        swap_row(&mut rows, None, old.info(), "default");
        let mut new = load_models(None).unwrap().get(None).unwrap().clone();
        Arc::get_mut(&mut new).unwrap().version = "2".into();
        swap_row(&mut rows, Some(old.info()), new.info(), "default");
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

    #[test]
    fn two_servers_count_apart() {
        let (a, b) = (Metrics::new(), Metrics::new());
        a.http_request("/v1/pose", "POST", 200, Duration::from_millis(1));
        a.http_request("/v1/pose", "POST", 200, Duration::from_millis(1));
        b.http_request("/v1/pose", "POST", 422, Duration::from_millis(1));
        let count = |m: &Metrics, status: &str| {
            m.render()
                .lines()
                .find(|l| {
                    l.starts_with("facepose_http_requests_total{")
                        && l.contains(&format!("status=\"{status}\""))
                })
                .and_then(|l| l.rsplit(' ').next()?.parse::<u64>().ok())
        };
        assert_eq!(count(&a, "200"), Some(2));
        assert_eq!(count(&a, "422"), None);
        assert_eq!(count(&b, "422"), Some(1));
        let mut tally = FaceTally::default();
        tally.ok(Method::Fit);
        tally.ok(Method::Fit);
        tally.err(ErrorKind::InvalidArgument);
        assert_eq!((tally.succeeded(), tally.failed()), (2, 1));
        a.faces(&tally, Transport::Http);
        let text = a.render();
        assert!(
            text.contains(r#"facepose_poses_total{transport="http",method="fit"} 2"#),
            "{text}"
        );
        assert!(
            text.contains(
                r#"facepose_estimate_errors_total{transport="http",code="invalid_argument"} 1"#
            ),
            "{text}"
        );
        // The handles kept per transport and method count on, each in its own series, and
        // the other server's stay apart.
        a.faces(&tally, Transport::Http);
        let mut grpc = FaceTally::default();
        grpc.ok(Method::FitShape);
        a.faces(&grpc, Transport::Grpc);
        b.faces(&grpc, Transport::WebSocket);
        let (ta, tb) = (a.render(), b.render());
        for (text, series) in [
            (
                &ta,
                r#"facepose_poses_total{transport="http",method="fit"} 4"#,
            ),
            (
                &ta,
                r#"facepose_poses_total{transport="grpc",method="fit-shape"} 1"#,
            ),
            (
                &tb,
                r#"facepose_poses_total{transport="websocket",method="fit-shape"} 1"#,
            ),
        ] {
            assert!(text.contains(series), "{series} in {text}");
        }
        assert!(!tb.contains(r#"transport="http""#) && !ta.contains("websocket"));
        for (i, t) in Transport::ALL.into_iter().enumerate() {
            assert_eq!(t.index(), i);
        }
    }
}
