//! One `EstimateStream` session: frames in, one result per frame out, per-face errors that do
//! not end the stream, and the optional smoothing of each face track's rotation.
//!
//! Tracks are keyed by `Face.id` (the client's tracker id), or by the face's index in the frame
//! when it has none. A track unseen for [`TRACK_TTL_FRAMES`] frames is forgotten. Smoothing is
//! configured by the `smoothing` field of the first frame (or of a later one, which restarts
//! the filters) and is off by default; the filter is [`RotationOneEuro`] of the core, the
//! angles are re-derived from the smoothed rotation, and `visible` and `residual` stay those of
//! the raw estimate.

use std::collections::HashMap;
use std::time::Instant;

use super::errors::ApiError;
use super::metrics::{self, FaceTally};
use super::pose::estimate_face;
use super::proto;
use super::registry::ModelSet;
use facepose_core::geometry::EulerAngles;
use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};

/// Frames after which an unseen track is forgotten.
pub const TRACK_TTL_FRAMES: u64 = 30;

/// The time step assumed when timestamps are missing or not increasing, seconds.
pub const DEFAULT_DT: f64 = 1.0 / 30.0;

struct Track {
    filter: RotationOneEuro,
    last_seen: u64,
}

/// The state of one stream.
#[derive(Default)]
pub struct Session {
    /// A fresh filter with the stream's parameters, cloned for each new track.
    smoothing: Option<RotationOneEuro>,
    tracks: HashMap<String, Track>,
    frames: u64,
    last_timestamp_us: Option<i64>,
}

/// The smoothing parameters of a `Smoothing` message (zero fields take the defaults), or
/// `None` when it is off.
pub fn smoothing_params(s: &proto::Smoothing) -> Result<Option<OneEuroParams>, ApiError> {
    if !s.enabled {
        return Ok(None);
    }
    let d = OneEuroParams::default();
    let or = |v: f64, default: f64| if v == 0.0 { default } else { v };
    let p = OneEuroParams {
        min_cutoff_hz: or(s.min_cutoff_hz, d.min_cutoff_hz),
        beta: or(s.beta, d.beta),
        d_cutoff_hz: or(s.d_cutoff_hz, d.d_cutoff_hz),
    };
    p.validate()?;
    Ok(Some(p))
}

impl Session {
    /// Applies a frame's `smoothing` field: a change restarts every filter.
    pub fn configure(&mut self, s: &proto::Smoothing) -> Result<(), ApiError> {
        let p = smoothing_params(s)?;
        if p.as_ref() != self.smoothing() {
            self.smoothing = p.map(RotationOneEuro::new).transpose()?;
            self.tracks.clear();
        }
        Ok(())
    }

    /// Whether smoothing is on.
    pub fn smoothing(&self) -> Option<&OneEuroParams> {
        self.smoothing.as_ref().map(RotationOneEuro::params)
    }

    /// Estimates every face of `frame` with the model it names in `models`. Fails (ending the
    /// stream) only for a frame over `max_faces` or an unusable smoothing configuration.
    pub fn frame(
        &mut self,
        models: &ModelSet,
        frame: proto::Frame,
        max_faces: usize,
    ) -> Result<proto::FrameResult, ApiError> {
        if frame.faces.len() > max_faces {
            return Err(ApiError::batch_too_large(frame.faces.len(), max_faces));
        }
        if let Some(s) = &frame.smoothing {
            self.configure(s)?;
        }
        let started = Instant::now();
        self.frames += 1;
        let dt = match self.last_timestamp_us {
            Some(prev) if frame.timestamp_us > prev && frame.timestamp_us > 0 => {
                (frame.timestamp_us - prev) as f64 * 1e-6
            }
            _ => DEFAULT_DT,
        };
        if frame.timestamp_us > 0 {
            self.last_timestamp_us = Some(frame.timestamp_us);
        }
        let mut tally = FaceTally::default();
        let model = models.get(Some(&frame.model));
        let (model_name, model_version) = match &model {
            Ok(m) => (m.name.clone(), m.version.clone()),
            Err(_) => (frame.model.clone(), String::new()),
        };
        let mut faces = Vec::with_capacity(frame.faces.len());
        let mut points = Vec::new();
        for (i, face) in frame.faces.into_iter().enumerate() {
            let result = model.as_ref().map_err(|e| e.clone()).and_then(|m| {
                super::grpc::landmarks_into(&face, &mut points)?;
                estimate_face(m, &super::grpc::face_spec(&face, &points))
            });
            let result = match result {
                Ok(p) => {
                    tally.ok(p.record.method);
                    let mut pose = super::grpc::pose_message(&p);
                    if let Some(template) = &self.smoothing {
                        let key = if face.id.is_empty() {
                            format!("#{i}")
                        } else {
                            face.id.clone()
                        };
                        let frames = self.frames;
                        let track = self.tracks.entry(key).or_insert_with(|| Track {
                            filter: template.clone(),
                            last_seen: frames,
                        });
                        if frames - track.last_seen > TRACK_TTL_FRAMES {
                            track.filter.reset();
                        }
                        track.last_seen = frames;
                        let r = track.filter.filter(&p.rotation, dt);
                        let a = EulerAngles::from_rotation(&r);
                        pose.yaw = a.yaw;
                        pose.pitch = a.pitch;
                        pose.roll = a.roll;
                        pose.rotation = facepose_core::geometry::rotation_rows(&r)
                            .iter()
                            .flatten()
                            .copied()
                            .collect();
                        pose.smoothed = true;
                    }
                    proto::face_result::Result::Pose(pose)
                }
                Err(e) => {
                    tally.err(e.kind);
                    proto::face_result::Result::Error(super::grpc::face_error(&e))
                }
            };
            faces.push(proto::FaceResult {
                id: face.id,
                result: Some(result),
            });
        }
        if self.smoothing.is_some() {
            let now = self.frames;
            self.tracks
                .retain(|_, t| now - t.last_seen <= TRACK_TTL_FRAMES);
        }
        tally.record("grpc");
        metrics::grpc_latency("EstimateStream", started.elapsed());
        Ok(proto::FrameResult {
            frame_id: frame.frame_id,
            timestamp_us: frame.timestamp_us,
            faces,
            model: model_name,
            model_version,
        })
    }
}
