//! `EstimateStream`: frames in, one result per frame out, per-face errors that do not end the
//! stream, the optional smoothing of each face track (the application's
//! [`Session`]). A stream ends with UNAVAILABLE when the server drains, and with its error
//! for a frame over `--max-batch` or an unusable smoothing configuration.

use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use facepose_app::error::ServiceError;
use facepose_app::metrics::{FaceTally, Transport};
use facepose_app::pose::estimate_face;
use facepose_app::registry::ModelSet;
use facepose_app::tracking::{Filter, Session, track_key};
use facepose_app::{App, StreamPermit};
use facepose_core::geometry::rotation_kalman::KalmanParams;
use facepose_core::geometry::smoothing::OneEuroParams;
use futures_util::Stream;
use tonic::{Status, Streaming};

use super::convert::{face_error, face_spec, landmarks_into, pose_message};
use super::error::{self, code_name, inbound_error};
use crate::proto;

pub type FrameStream = Pin<Box<dyn Stream<Item = Result<proto::FrameResult, Status>> + Send>>;

/// The smoothing filter of a `Smoothing` message (zero fields take the defaults), or `None`
/// when it is off. An unspecified filter is the One Euro filter when any of its parameters is
/// set (as the message meant before the Kalman filter), else the Kalman filter.
pub fn smoothing_params(s: &proto::Smoothing) -> Result<Option<Filter>, ServiceError> {
    if !s.enabled {
        return Ok(None);
    }
    let or = |v: f64, default: f64| if v == 0.0 { default } else { v };
    let one_euro_set = [s.min_cutoff_hz, s.beta, s.d_cutoff_hz]
        .iter()
        .any(|&v| v != 0.0);
    let kalman = match proto::SmoothingFilter::try_from(s.filter) {
        Ok(proto::SmoothingFilter::Kalman) => true,
        Ok(proto::SmoothingFilter::OneEuro) => false,
        Ok(proto::SmoothingFilter::Unspecified) => !one_euro_set,
        Err(_) => {
            return Err(ServiceError::invalid(format!(
                "smoothing: unknown filter {} (known: 1 SMOOTHING_FILTER_KALMAN, 2 SMOOTHING_FILTER_ONE_EURO)",
                s.filter
            )));
        }
    };
    let filter = if kalman {
        let d = KalmanParams::default();
        let p = KalmanParams {
            acceleration_deg_s2: or(s.acceleration_deg_s2, d.acceleration_deg_s2),
            gate: or(s.gate, d.gate),
            ..d
        };
        p.validate()?;
        Filter::Kalman(p)
    } else {
        let d = OneEuroParams::default();
        let p = OneEuroParams {
            min_cutoff_hz: or(s.min_cutoff_hz, d.min_cutoff_hz),
            beta: or(s.beta, d.beta),
            d_cutoff_hz: or(s.d_cutoff_hz, d.d_cutoff_hz),
        };
        p.validate()?;
        Filter::OneEuro(p)
    };
    Ok(Some(filter))
}

/// Estimates every face of `frame` with the model it names in `models`, smoothing each track
/// when the session says so. Fails (ending the stream) only for a frame over `max_faces` or an
/// unusable smoothing configuration.
pub fn answer_frame(
    session: &mut Session,
    models: &ModelSet,
    frame: proto::Frame,
    max_faces: usize,
    tally: &mut FaceTally,
) -> Result<proto::FrameResult, ServiceError> {
    if frame.faces.len() > max_faces {
        return Err(ServiceError::BatchTooLarge {
            faces: frame.faces.len(),
            limit: max_faces,
        });
    }
    if let Some(s) = &frame.smoothing {
        session.configure(smoothing_params(s)?)?;
    }
    session.begin_frame(frame.timestamp_us);
    let model = models.get(Some(&frame.model));
    let (model_name, model_version) = match &model {
        Ok(m) => (m.name.clone(), m.version.clone()),
        Err(_) => (frame.model.clone(), String::new()),
    };
    let mut faces = Vec::with_capacity(frame.faces.len());
    let mut points = Vec::new();
    for (i, face) in frame.faces.into_iter().enumerate() {
        let result = model.as_ref().map_err(|e| e.clone()).and_then(|m| {
            landmarks_into(&face, &mut points)?;
            estimate_face(m, &face_spec(&face, &points))
        });
        let result = match result {
            Ok(mut p) => {
                tally.ok(p.record.method);
                let smoothed = session.smooth(track_key(&face.id, i), &mut p);
                proto::face_result::Result::Pose(pose_message(&p, smoothed))
            }
            Err(e) => {
                tally.err(e.kind());
                proto::face_result::Result::Error(face_error(&e))
            }
        };
        faces.push(proto::FaceResult {
            id: face.id,
            result: Some(result),
        });
    }
    session.end_frame();
    Ok(proto::FrameResult {
        frame_id: frame.frame_id,
        timestamp_us: frame.timestamp_us,
        faces,
        model: model_name,
        model_version,
    })
}

/// What a stream carries between frames.
struct StreamState {
    app: Arc<App>,
    inbound: Streaming<proto::Frame>,
    session: Session,
    drained: Pin<Box<dyn Future<Output = ()> + Send>>,
    guard: StreamGuard,
    done: bool,
}

/// Releases the stream's slot and records it when the stream ends, however it ends.
struct StreamGuard {
    app: Arc<App>,
    _permit: StreamPermit,
    code: tonic::Code,
}

impl Drop for StreamGuard {
    fn drop(&mut self) {
        self.app.metrics.stream_closed();
        self.app
            .metrics
            .grpc_request("EstimateStream", code_name(self.code), None);
    }
}

/// Opens a stream over `inbound`, or refuses it (all stream slots taken, or draining).
pub fn open(app: &Arc<App>, inbound: Streaming<proto::Frame>) -> Result<FrameStream, Status> {
    let permit = match app.stream_permit() {
        Ok(p) => p,
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
    app.metrics.stream_opened();
    let st = StreamState {
        app: app.clone(),
        inbound,
        session: Session::default(),
        drained: Box::pin(app.lifecycle.drained()),
        guard: StreamGuard {
            app: app.clone(),
            _permit: permit,
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
                    let models = st.app.models();
                    let mut tally = FaceTally::default();
                    let result = answer_frame(
                        &mut st.session,
                        &models,
                        frame,
                        st.app.limits.max_batch,
                        &mut tally,
                    )
                    .map_err(|e| error::status(&e));
                    st.app.metrics.faces(&tally, Transport::Grpc);
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
