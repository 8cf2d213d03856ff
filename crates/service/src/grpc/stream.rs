//! `EstimateStream`: frames in, one result per frame out, per-face errors that do not end the
//! stream, the optional smoothing of each face track (the application's stream session,
//! [`StreamSession`]). A stream ends with UNAVAILABLE when the server drains, and with its
//! error for a frame over `--max-batch` or an unusable smoothing configuration.

use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use facepose_app::App;
use facepose_app::error::ServiceError;
use facepose_app::estimate::{Frame, StreamSession};
use facepose_app::metrics::Transport;
use facepose_app::tracking::{Filter, FilterKind, SmoothingOptions};
use futures_util::Stream;
use tonic::{Status, Streaming};

use super::convert::face_result;
use super::error::{self, code_name, inbound_error};
use crate::proto;

/// The results of an `EstimateStream` call, one per frame.
pub type FrameStream = Pin<Box<dyn Stream<Item = Result<proto::FrameResult, Status>> + Send>>;

/// The smoothing filter of a `Smoothing` message (zero fields take the defaults), or `None`
/// when it is off. An unspecified filter is the One Euro filter when any of its parameters is
/// set (as the message meant before the Kalman filter), else the Kalman filter.
pub fn smoothing_params(s: &proto::Smoothing) -> Result<Option<Filter>, ServiceError> {
    let kind = match proto::SmoothingFilter::try_from(s.filter) {
        Ok(proto::SmoothingFilter::Kalman) => Some(FilterKind::Kalman),
        Ok(proto::SmoothingFilter::OneEuro) => Some(FilterKind::OneEuro),
        Ok(proto::SmoothingFilter::Unspecified) => None,
        Err(_) => {
            return Err(ServiceError::invalid(format!(
                "smoothing: unknown filter {} (known: 1 SMOOTHING_FILTER_KALMAN, 2 SMOOTHING_FILTER_ONE_EURO)",
                s.filter
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

/// Answers one frame in `session`. Fails (ending the stream) only for a frame over
/// `--max-batch` faces or an unusable smoothing configuration.
pub fn answer_frame(
    session: &mut StreamSession,
    frame: proto::Frame,
) -> Result<proto::FrameResult, ServiceError> {
    let smoothing = frame.smoothing.as_ref().map(smoothing_params).transpose()?;
    let answer = session.frame(
        Frame {
            model: frame.model,
            timestamp_us: frame.timestamp_us,
            smoothing,
            faces: frame.faces,
        },
        face_result,
    )?;
    Ok(proto::FrameResult {
        frame_id: frame.frame_id,
        timestamp_us: frame.timestamp_us,
        faces: answer.faces,
        model: answer.model,
        model_version: answer.model_version,
    })
}

/// What a stream carries between frames.
struct StreamState {
    app: Arc<App>,
    inbound: Streaming<proto::Frame>,
    session: StreamSession,
    drained: Pin<Box<dyn Future<Output = ()> + Send>>,
    guard: StreamGuard,
    done: bool,
}

/// Records the call with its code when the stream ends, however it ends.
struct StreamGuard {
    app: Arc<App>,
    code: tonic::Code,
}

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.app
            .metrics
            .grpc_request("EstimateStream", code_name(self.code), None);
    }
}

/// Opens a stream over `inbound`, or refuses it (all stream slots taken, or draining).
pub fn open(app: &Arc<App>, inbound: Streaming<proto::Frame>) -> Result<FrameStream, Status> {
    let session = match app.open_stream(Transport::Grpc) {
        Ok(s) => s,
        Err(e) => {
            if matches!(e, ServiceError::StreamsBusy { .. }) {
                app.metrics.grpc_request(
                    "EstimateStream",
                    code_name(tonic::Code::Unavailable),
                    None,
                );
            }
            return Err(error::status(&e));
        }
    };
    let st = StreamState {
        app: app.clone(),
        inbound,
        session,
        drained: Box::pin(app.lifecycle.drained()),
        guard: StreamGuard {
            app: app.clone(),
            code: tonic::Code::Ok,
        },
        done: false,
    };
    let out = futures_util::stream::unfold(st, |mut st| async move {
        if st.done {
            return None;
        }
        let item = tokio::select! {
            biased;
            _ = &mut st.drained => Err(error::status(&ServiceError::ShuttingDown)),
            msg = st.inbound.message() => match msg {
                Ok(Some(frame)) => {
                    let started = Instant::now();
                    let result = answer_frame(&mut st.session, frame)
                        .map_err(|e| error::status(&e));
                    st.app.metrics.grpc_latency("EstimateStream", started.elapsed());
                    result
                }
                Ok(None) => return None,
                Err(status) => Err(inbound_error(status, st.app.limits.max_body)),
            },
        };
        if let Err(s) = &item {
            st.done = true;
            st.guard.code = s.code();
            tracing::debug!(code = ?s.code(), message = s.message(), "stream ended by the server");
        }
        Some((item, st))
    });
    Ok(Box::pin(out))
}
