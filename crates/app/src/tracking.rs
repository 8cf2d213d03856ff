//! The face tracks of one stream: the optional smoothing of each track's rotation, frame by
//! frame. The transport (gRPC's `EstimateStream`) reads frames and writes results; this holds
//! what lasts between them.
//!
//! Tracks are keyed by the client's face id (its tracker's id), or by the face's index in the
//! frame when it has none. A track unseen for [`TRACK_TTL_FRAMES`] frames is forgotten.
//! Smoothing is configured by a frame (the first, or a later one, which restarts the filters)
//! and is off by default. The filter is the core's [`RotationKalman`], which weighs each frame
//! by its uncertainty, or its [`RotationOneEuro`]; the angles are re-derived from the smoothed
//! rotation, and `visible`, `residual` and the uncertainty stay those of the raw estimate.

use std::collections::HashMap;

use facepose_core::geometry::rotation_kalman::{KalmanParams, RotationKalman};
use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};
use facepose_core::geometry::{EulerAngles, rotation_rows};

use crate::error::ServiceError;
use crate::pose::FacePose;

/// Frames after which an unseen track is forgotten.
pub const TRACK_TTL_FRAMES: u64 = 30;

/// The time step assumed when timestamps are missing or not increasing, seconds.
pub const DEFAULT_DT: f64 = 1.0 / 30.0;

/// A stream's smoothing filter and its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Filter {
    Kalman(KalmanParams),
    OneEuro(OneEuroParams),
}

/// One track's filter state.
#[derive(Debug, Clone)]
enum TrackFilter {
    // Boxed: its 6 x 6 covariance makes it five times the One Euro filter's size.
    Kalman(Box<RotationKalman>),
    OneEuro(RotationOneEuro),
}

impl TrackFilter {
    fn new(f: &Filter) -> Result<Self, ServiceError> {
        Ok(match f {
            Filter::Kalman(p) => TrackFilter::Kalman(Box::new(RotationKalman::new(*p)?)),
            Filter::OneEuro(p) => TrackFilter::OneEuro(RotationOneEuro::new(*p)?),
        })
    }

    fn reset(&mut self) {
        match self {
            TrackFilter::Kalman(k) => k.reset(),
            TrackFilter::OneEuro(e) => e.reset(),
        }
    }
}

struct Track {
    filter: TrackFilter,
    last_seen: u64,
}

/// What smoothing did to one pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Smoothed {
    /// The pose's angles and rotation are the filter's.
    pub smoothed: bool,
    /// The Kalman filter left the estimate out as an outlier (the pose is the prediction).
    pub gated: bool,
}

/// The tracks of one stream.
#[derive(Default)]
pub struct Session {
    /// The stream's filter and a fresh state of it, cloned for each new track.
    smoothing: Option<(Filter, TrackFilter)>,
    tracks: HashMap<String, Track>,
    frames: u64,
    last_timestamp_us: Option<i64>,
    /// The time step of the current frame, seconds.
    dt: f64,
}

/// A face's track: its client id, else its place in the frame.
pub fn track_key(id: &str, index: usize) -> String {
    if id.is_empty() {
        format!("#{index}")
    } else {
        id.to_string()
    }
}

impl Session {
    /// Sets the smoothing (`None`: off); a change restarts every filter.
    pub fn configure(&mut self, filter: Option<Filter>) -> Result<(), ServiceError> {
        if filter.as_ref() != self.smoothing() {
            self.smoothing = filter
                .map(|f| TrackFilter::new(&f).map(|t| (f, t)))
                .transpose()?;
            self.tracks.clear();
        }
        Ok(())
    }

    /// The smoothing filter when it is on.
    pub fn smoothing(&self) -> Option<&Filter> {
        self.smoothing.as_ref().map(|(f, _)| f)
    }

    /// Starts a frame taken at `timestamp_us` (0: not given): its time step is the time since
    /// the last stamped frame, else [`DEFAULT_DT`].
    pub fn begin_frame(&mut self, timestamp_us: i64) {
        self.frames += 1;
        self.dt = match self.last_timestamp_us {
            Some(prev) if timestamp_us > prev && timestamp_us > 0 => {
                (timestamp_us - prev) as f64 * 1e-6
            }
            _ => DEFAULT_DT,
        };
        if timestamp_us > 0 {
            self.last_timestamp_us = Some(timestamp_us);
        }
    }

    /// Smooths `pose` on the track `key` when smoothing is on (its angles and rotation become
    /// the filtered ones).
    pub fn smooth(&mut self, key: String, pose: &mut FacePose) -> Smoothed {
        let Some((_, template)) = &self.smoothing else {
            return Smoothed::default();
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
        let (r, gated) = match &mut track.filter {
            TrackFilter::Kalman(k) => {
                let out = k.filter(&pose.rotation, pose.turn_cov.as_ref(), self.dt);
                (out.rotation, !out.accepted)
            }
            TrackFilter::OneEuro(e) => (e.filter(&pose.rotation, self.dt), false),
        };
        let a = EulerAngles::from_rotation(&r);
        pose.record.yaw = a.yaw;
        pose.record.pitch = a.pitch;
        pose.record.roll = a.roll;
        pose.record.rotation = rotation_rows(&r);
        pose.rotation = r;
        Smoothed {
            smoothed: true,
            gated,
        }
    }

    /// Ends the frame: tracks unseen for [`TRACK_TTL_FRAMES`] are forgotten.
    pub fn end_frame(&mut self) {
        if self.smoothing.is_some() {
            let now = self.frames;
            self.tracks
                .retain(|_, t| now - t.last_seen <= TRACK_TTL_FRAMES);
        }
    }
}
