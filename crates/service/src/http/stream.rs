//! `GET /v1/pose:stream`: the stream of frames over a WebSocket, for browsers (issue 40). Text
//! messages are JSON with the structure of the proto's `Frame` and `FrameResult`, each face in
//! the form of `POST /v1/pose:batch`; the session (tracks, smoothing, gating, the stream slot
//! shared with gRPC's `--max-streams`) is the application's [`StreamSession`], the one gRPC's
//! `EstimateStream` uses.
//!
//! Safe by default: browsers do not apply CORS to WebSockets, so the handshake's `Origin` must
//! be the server's own or one of `--cors-origins` (else 403, against cross-site WebSocket
//! hijacking); a message is at most `--max-body`, a frame at most `--max-batch` faces; a
//! stream that sends no frame for `--ws-idle-timeout` or answers no ping for two
//! `--ws-ping-interval`s is closed; answers wait in a bounded queue and a client that reads
//! too slowly to keep it from filling is closed (1008); the drain closes every stream with
//! 1001. The close codes are in docs/API.md ("WebSocket stream").

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{FromRequestParts, Request, State};
use axum::http::header::{HOST, ORIGIN};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use facepose_app::App;
use facepose_app::error::{ErrorKind, ServiceError};
use facepose_app::estimate::{FaceInput, FaceScratch, Frame, INLINE_BYTES, StreamSession};
use facepose_app::metrics::Transport;
use facepose_app::pose::FaceSpec;
use facepose_app::tracking::{Filter, FilterKind, Smoothed, SmoothingOptions};
use facepose_records::PoseRecord;
use futures_util::{SinkExt, StreamExt};
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;
use tokio_util::task::task_tracker::TaskTrackerToken;

use super::cors::CorsOrigins;
use super::error::{ErrorBody, ErrorCode, ErrorObject, HttpError};
use super::pose::{BatchDefaults, batch_face_spec};
use super::wire::{BatchFace, FaceId};

/// The route's path.
pub const PATH: &str = "/v1/pose:stream";

/// Close codes (RFC 6455 section 7.4.1).
pub mod close {
    /// The client closed, or the server ended the stream normally.
    pub const NORMAL: u16 = 1000;
    /// The server drains (SIGTERM): reconnect, possibly to another replica.
    pub const GOING_AWAY: u16 = 1001;
    /// A binary message: the stream takes JSON text.
    pub const UNSUPPORTED: u16 = 1003;
    /// A text message that is not a frame (bad JSON, unknown field, wrong type).
    pub const INVALID_PAYLOAD: u16 = 1007;
    /// Against the stream's policy: an unusable smoothing, no frame for the idle timeout, no
    /// pong, or a client reading too slowly.
    pub const POLICY: u16 = 1008;
    /// A message over `--max-body` or a frame over `--max-batch` faces.
    pub const TOO_BIG: u16 = 1009;
    /// The server failed.
    pub const INTERNAL: u16 = 1011;
}

/// How the streams are bounded besides `--max-body`, `--max-batch` and `--max-streams`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WsLimits {
    /// A stream with no frame for this long is closed (1008).
    pub idle_timeout: Duration,
    /// The server pings this often; a stream it hears nothing from (pong, frame) for two of
    /// these is closed (1008).
    pub ping_interval: Duration,
    /// Answers waiting for a slow client; one more closes the stream (1008).
    pub queue: usize,
}

impl Default for WsLimits {
    fn default() -> Self {
        WsLimits {
            idle_timeout: Duration::from_secs(60),
            ping_interval: Duration::from_secs(20),
            queue: 64,
        }
    }
}

/// What the route needs besides the application.
#[derive(Clone)]
struct StreamState {
    app: Arc<App>,
    origins: Option<Arc<CorsOrigins>>,
    limits: WsLimits,
}

/// The route, with its state: `origins` are `--cors-origins` (pages of other origins that
/// may open a stream).
pub fn routes(app: &Arc<App>, origins: Option<&CorsOrigins>, limits: WsLimits) -> Router {
    Router::new()
        .route(PATH, get(handshake))
        .with_state(StreamState {
            app: app.clone(),
            origins: origins.cloned().map(Arc::new),
            limits,
        })
}

/// The smoothing of a frame: the JSON form of the proto's `Smoothing` (absent or zero fields
/// take the defaults; `filter` is `"kalman"` or `"one_euro"`).
#[derive(Debug, Default, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WsSmoothing {
    /// Smoothing on (the rest is ignored when off).
    #[serde(default)]
    pub enabled: bool,
    /// `"kalman"` or `"one_euro"`; absent: One Euro when one of its fields is set, else Kalman.
    #[serde(default)]
    pub filter: Option<String>,
    /// One Euro: cutoff at rest, Hz (1.0).
    #[serde(default)]
    pub min_cutoff_hz: f64,
    /// One Euro: cutoff increase per degree/second (0.05).
    #[serde(default)]
    pub beta: f64,
    /// One Euro: cutoff of the speed estimate, Hz (1.0).
    #[serde(default)]
    pub d_cutoff_hz: f64,
    /// Kalman: standard deviation of the angular acceleration, degrees/s² (150).
    #[serde(default)]
    pub acceleration_deg_s2: f64,
    /// Kalman: Mahalanobis distance squared above which a frame is left out (16.27).
    #[serde(default)]
    pub gate: f64,
}

/// The filter of a [`WsSmoothing`], or `None` when it is off: the application's reading of
/// a stream's smoothing options, the same as gRPC's `Smoothing` message gets.
pub fn smoothing_filter(s: &WsSmoothing) -> Result<Option<Filter>, ServiceError> {
    let kind = match s.filter.as_deref() {
        Some("kalman") => Some(FilterKind::Kalman),
        Some("one_euro") => Some(FilterKind::OneEuro),
        None | Some("") => None,
        Some(other) => {
            return Err(ServiceError::invalid(format!(
                "smoothing: unknown filter {other:?} (known: \"kalman\", \"one_euro\")"
            )));
        }
    };
    SmoothingOptions {
        enabled: s.enabled,
        kind,
        min_cutoff_hz: s.min_cutoff_hz,
        beta: s.beta,
        d_cutoff_hz: s.d_cutoff_hz,
        acceleration_deg_s2: s.acceleration_deg_s2,
        gate: s.gate,
    }
    .filter()
}

/// One frame of the stream (the proto's `Frame`).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WsFrame {
    /// Echoed.
    #[serde(default)]
    pub frame_id: u64,
    /// Capture time, µs, echoed; smoothing uses the differences (0: 1/30 s after the last).
    #[serde(default)]
    pub timestamp_us: i64,
    /// The faces, each as in `POST /v1/pose:batch`; `id` is the face's track.
    #[serde(default)]
    pub faces: Vec<BatchFace>,
    /// The model by name; absent: the default model.
    #[serde(default)]
    pub model: Option<String>,
    /// Set in the first frame, or a later one to change it (the filters restart).
    #[serde(default)]
    pub smoothing: Option<WsSmoothing>,
}

/// Parses a text message into a frame; the message of the error says where it is wrong.
pub fn parse_frame(text: &str) -> Result<WsFrame, String> {
    // Without the path first: tracking it costs a tenth of a frame's time.
    if let Ok(frame) = serde_json::from_str(text) {
        return Ok(frame);
    }
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        if path == "." {
            format!("not a frame: {inner}")
        } else {
            format!("not a frame: {path}: {inner}")
        }
    })
}

/// A face of a frame with its track id.
struct WsFace {
    face: BatchFace,
    track: String,
}

impl FaceInput for WsFace {
    fn spec<'a>(&'a self, _scratch: &'a mut FaceScratch) -> Result<FaceSpec<'a>, ServiceError> {
        Ok(batch_face_spec(&self.face, &BatchDefaults::NONE))
    }

    fn track_id(&self) -> &str {
        &self.track
    }
}

/// A face's pose in a frame's answer: the HTTP pose with what smoothing did.
#[derive(Debug, Serialize)]
pub struct WsPose {
    /// The pose (smoothed angles and rotation when `smoothed`).
    #[serde(flatten)]
    pub pose: PoseRecord,
    /// The scheme of the input landmarks.
    pub scheme: String,
    /// The angles and rotation are the filter's.
    pub smoothed: bool,
    /// The Kalman filter left this estimate out as an outlier (the pose is its prediction).
    pub gated: bool,
}

/// One face's result in a frame's answer: its pose or its error.
#[derive(Debug, Serialize)]
pub struct WsFaceResult {
    /// The face's `id`, echoed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<FaceId>,
    /// The pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose: Option<WsPose>,
    /// The face's error (the stream goes on).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorObject>,
}

/// A frame's answer (the proto's `FrameResult`).
#[derive(Debug, Serialize)]
pub struct WsFrameResult {
    /// The frame's `frame_id`.
    pub frame_id: u64,
    /// The frame's `timestamp_us`.
    pub timestamp_us: i64,
    /// One per face, in order.
    pub faces: Vec<WsFaceResult>,
    /// The model's name.
    pub model: String,
    /// The version that answered (empty when the model is not served).
    pub model_version: String,
}

/// Why a stream ends, as a close frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Close {
    /// The close code ([`close`]).
    pub code: u16,
    /// The reason, at most 123 bytes.
    pub reason: String,
}

impl Close {
    fn new(code: u16, reason: impl Into<String>) -> Self {
        let mut reason = reason.into();
        if reason.len() > 123 {
            let mut end = 120;
            while !reason.is_char_boundary(end) {
                end -= 1;
            }
            reason.truncate(end);
            reason.push_str("...");
        }
        Close { code, reason }
    }

    fn message(&self) -> Message {
        Message::Close(Some(CloseFrame {
            code: self.code,
            reason: Utf8Bytes::from(self.reason.as_str()),
        }))
    }
}

/// The close for an error that ends the stream.
fn close_of(e: &ServiceError) -> Close {
    let code = match e {
        ServiceError::BatchTooLarge { .. } => close::TOO_BIG,
        ServiceError::ShuttingDown => close::GOING_AWAY,
        e if e.kind() == ErrorKind::InvalidArgument => close::POLICY,
        _ => close::INTERNAL,
    };
    Close::new(code, e.to_string())
}

/// Answers one text message in `session`: the answer's JSON, or the close that ends the
/// stream.
pub fn answer_text(session: &mut StreamSession, text: &str) -> Result<String, Close> {
    let frame = parse_frame(text).map_err(|m| Close::new(close::INVALID_PAYLOAD, m))?;
    let smoothing = frame
        .smoothing
        .as_ref()
        .map(smoothing_filter)
        .transpose()
        .map_err(|e| close_of(&e))?;
    let faces = frame
        .faces
        .into_iter()
        .map(|face| {
            let track = match &face.id {
                Some(FaceId::Text(t)) => t.clone(),
                Some(FaceId::Number(n)) => n.get().to_string(),
                None => String::new(),
            };
            WsFace { face, track }
        })
        .collect();
    let answer = session
        .frame(
            Frame {
                model: frame.model.unwrap_or_default(),
                timestamp_us: frame.timestamp_us,
                smoothing,
                faces,
            },
            face_result,
        )
        .map_err(|e| close_of(&e))?;
    serde_json::to_string(&WsFrameResult {
        frame_id: frame.frame_id,
        timestamp_us: frame.timestamp_us,
        faces: answer.faces,
        model: answer.model,
        model_version: answer.model_version,
    })
    .map_err(|e| Close::new(close::INTERNAL, e.to_string()))
}

fn face_result(
    face: WsFace,
    outcome: Result<facepose_app::pose::FacePose, ServiceError>,
    smoothed: Smoothed,
) -> WsFaceResult {
    match outcome {
        Ok(p) => WsFaceResult {
            id: face.face.id,
            pose: Some(WsPose {
                pose: p.record,
                scheme: p.scheme,
                smoothed: smoothed.smoothed,
                gated: smoothed.gated,
            }),
            error: None,
        },
        Err(e) => WsFaceResult {
            id: face.face.id,
            pose: None,
            error: Some(HttpError::from(e).object()),
        },
    }
}

/// Whether a handshake with these headers may open a stream: no `Origin` (not a browser),
/// the server's own origin (its host is `Host`), or one of `--cors-origins`.
pub fn origin_allowed(headers: &HeaderMap, origins: Option<&CorsOrigins>) -> bool {
    let Some(origin) = headers.get(ORIGIN) else {
        return true;
    };
    let same = headers.get(HOST).is_some_and(|host| {
        origin
            .to_str()
            .ok()
            .and_then(|o| o.split_once("://"))
            .is_some_and(|(_, authority)| authority.as_bytes() == host.as_bytes())
    });
    same || match origins {
        Some(CorsOrigins::Any) => true,
        Some(CorsOrigins::List(list)) => list.iter().any(|o| o == origin),
        None => false,
    }
}

fn forbidden(message: String) -> Response {
    let body = ErrorBody {
        error: ErrorObject {
            code: ErrorCode::Forbidden,
            message,
            details: None,
        },
    };
    (
        StatusCode::FORBIDDEN,
        [(axum::http::header::CONTENT_TYPE, "application/json")],
        serde_json::to_vec(&body).unwrap_or_default(),
    )
        .into_response()
}

/// The handshake: checks the origin, takes a stream slot, upgrades.
async fn handshake(State(st): State<StreamState>, req: Request) -> Response {
    let (mut parts, _body) = req.into_parts();
    if !origin_allowed(&parts.headers, st.origins.as_deref()) {
        let origin = parts
            .headers
            .get(ORIGIN)
            .and_then(|o| o.to_str().ok())
            .unwrap_or("?")
            .to_string();
        return forbidden(format!(
            "origin {origin:?} may not open a stream: it is neither this server's nor one of \
             --cors-origins"
        ));
    }
    let upgrade = match WebSocketUpgrade::from_request_parts(&mut parts, &()).await {
        Ok(u) => u,
        Err(rejection) => {
            let status = rejection.status();
            let mut resp =
                HttpError::invalid(format!("{PATH} is a WebSocket: {}", rejection.body_text()))
                    .into_response();
            *resp.status_mut() = status;
            return resp;
        }
    };
    let session = match st.app.open_stream(Transport::WebSocket) {
        Ok(s) => s,
        Err(e) => return HttpError::from(e).into_response(),
    };
    // Held by the stream until its closing handshake is over: the drain waits for it.
    let token = st.app.lifecycle.stream_token();
    let max = st.app.limits.max_body;
    // tungstenite reads in chunks of 128 KiB by default, held for the stream's life: 1,024
    // open streams took 140 MB (scripts/abuse.sh, case w2). Frames are read in 16 KiB chunks.
    upgrade
        .read_buffer_size(16 * 1024)
        .max_message_size(max)
        .max_frame_size(max)
        .on_upgrade(move |socket| run(socket, st.app, session, st.limits, token))
}

/// Sends `msg`s in order until the queue ends or `now` says to close at once.
async fn writer(
    mut sink: futures_util::stream::SplitSink<WebSocket, Message>,
    mut queue: mpsc::Receiver<Message>,
    mut now: oneshot::Receiver<Close>,
) {
    loop {
        let msg = tokio::select! {
            biased;
            c = &mut now => {
                if let Ok(c) = c {
                    let _ = tokio::time::timeout(CLOSE_WAIT, sink.send(c.message())).await;
                }
                return;
            }
            m = queue.recv() => match m {
                Some(m) => m,
                None => {
                    // Flushes what the protocol queued (the answer to a client's close).
                    let _ = tokio::time::timeout(CLOSE_WAIT, sink.close()).await;
                    return;
                }
            },
        };
        // The message and those already waiting behind it in one write.
        let mut closing = matches!(msg, Message::Close(_));
        let write = async {
            sink.feed(msg).await?;
            while !closing && let Ok(m) = queue.try_recv() {
                closing = matches!(m, Message::Close(_));
                sink.feed(m).await?;
            }
            sink.flush().await
        };
        tokio::select! {
            biased;
            c = &mut now => {
                if let Ok(c) = c {
                    let _ = tokio::time::timeout(CLOSE_WAIT, sink.send(c.message())).await;
                }
                return;
            }
            r = write => {
                if r.is_err() {
                    // Refused after the client's close (tungstenite sends nothing after it
                    // but the reply to the close, which this flushes).
                    let _ = tokio::time::timeout(CLOSE_WAIT, sink.close()).await;
                    return;
                }
                if closing {
                    return;
                }
            }
        }
    }
}

/// A stream, from its upgrade to its close.
///
/// `token` ([`facepose_app::lifecycle::Lifecycle::stream_token`]) is dropped once the stream's
/// last message, its close, has been written: the drain waits for that, not for the client's
/// reply, which a client may be slow to send.
async fn run(
    socket: WebSocket,
    app: Arc<App>,
    session: StreamSession,
    limits: WsLimits,
    token: TaskTrackerToken,
) {
    let (sink, mut stream) = socket.split();
    let (tx, rx) = mpsc::channel::<Message>(limits.queue.max(1));
    let (now_tx, now_rx) = oneshot::channel::<Close>();
    let writer = tokio::spawn(writer(sink, rx, now_rx));
    let mut drained = std::pin::pin!(app.lifecycle.drained());
    let mut session = Some(session);
    let mut last_frame = Instant::now();
    let mut last_heard = Instant::now();
    let mut ping =
        tokio::time::interval_at(Instant::now() + limits.ping_interval, limits.ping_interval);
    // How the stream ends: a close sent after the queued answers, or at once.
    enum End {
        Queued(Close),
        Now(Close),
        Quiet,
    }
    let end = loop {
        let idle_at = last_frame + limits.idle_timeout;
        let msg = tokio::select! {
            biased;
            _ = &mut drained => break End::Now(Close::new(close::GOING_AWAY, ServiceError::ShuttingDown.to_string())),
            _ = tokio::time::sleep_until(idle_at) => break End::Queued(Close::new(
                close::POLICY,
                format!("no frame for {:?} (--ws-idle-timeout)", limits.idle_timeout),
            )),
            _ = ping.tick() => {
                if last_heard.elapsed() > 2 * limits.ping_interval {
                    break End::Now(Close::new(close::POLICY, "no pong: the client stopped answering pings"));
                }
                if tx.try_send(Message::Ping(Bytes::new())).is_err() {
                    break End::Now(slow());
                }
                continue;
            }
            m = stream.next() => m,
        };
        let text = match msg {
            Some(Err(e)) if too_long(&e) => {
                break End::Now(Close::new(
                    close::TOO_BIG,
                    format!("a message over {} bytes (--max-body)", app.limits.max_body),
                ));
            }
            None | Some(Err(_)) | Some(Ok(Message::Close(_))) => break End::Quiet,
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => {
                last_heard = Instant::now();
                continue;
            }
            Some(Ok(Message::Binary(_))) => {
                break End::Queued(Close::new(
                    close::UNSUPPORTED,
                    "binary messages are not taken: send frames as JSON text",
                ));
            }
            Some(Ok(Message::Text(t))) => t,
        };
        last_heard = Instant::now();
        last_frame = last_heard;
        let Some(mut s) = session.take() else {
            break End::Quiet;
        };
        let inline = text.len() <= INLINE_BYTES;
        let done = facepose_app::blocking::run_maybe_blocking(inline, move || {
            let r = answer_text(&mut s, text.as_str());
            (s, r)
        })
        .await;
        let answer = match done {
            Ok((s, r)) => {
                session = Some(s);
                r
            }
            Err(e) => Err(close_of(&e)),
        };
        match answer {
            Ok(json) => {
                if tx.try_send(Message::Text(json.into())).is_err() {
                    break End::Now(slow());
                }
            }
            Err(c) => break End::Queued(c),
        }
    };
    match end {
        End::Queued(c) => {
            tracing::debug!(code = c.code, reason = %c.reason, "WebSocket stream closed by the server");
            if let Err(mpsc::error::TrySendError::Full(_)) = tx.try_send(c.message()) {
                let _ = now_tx.send(slow());
            }
        }
        End::Now(c) => {
            tracing::debug!(code = c.code, reason = %c.reason, "WebSocket stream closed by the server");
            let _ = now_tx.send(c);
        }
        End::Quiet => {}
    }
    drop(tx);
    drop(session);
    // The closing handshake: read (and drop) what the client still sends until its close,
    // so that the socket is not dropped with unread data (a reset, which would lose the
    // answers and the close still in flight to the client).
    let rest = async move {
        while let Some(Ok(m)) = stream.next().await {
            if matches!(m, Message::Close(_)) {
                break;
            }
        }
    };
    let written = async move {
        let _ = writer.await;
        drop(token);
    };
    let _ = tokio::time::timeout(CLOSE_WAIT, async {
        tokio::join!(written, rest);
    })
    .await;
}

/// How long a close may wait for room in a slow client's socket, and for the client's close.
const CLOSE_WAIT: Duration = Duration::from_secs(5);

/// Whether a read failed on a message or frame over the size limit. axum does not expose
/// tungstenite's error type, so this reads its message ("Space limit exceeded: Message too
/// long: ..." or "... Message frame too long ...").
fn too_long(e: &axum::Error) -> bool {
    let text = e.to_string();
    text.contains("too long") || text.contains("Space limit exceeded")
}

/// The close for a client that reads too slowly.
fn slow() -> Close {
    Close::new(
        close::POLICY,
        "the client reads too slowly: its answers filled the server's queue",
    )
}
