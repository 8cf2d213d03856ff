//! The face tracks of one stream: the optional smoothing of each track's rotation, frame by
//! frame. The transport (gRPC's `EstimateStream`) reads frames and writes results; this holds
//! what lasts between them.
//!
//! Tracks are keyed by the client's face id (its tracker's id), or by the face's index in the
//! frame when it has none. A track unseen for [`TRACK_TTL_FRAMES`] frames is forgotten.
//! Smoothing is configured by a frame (the first, or a later one, which restarts the filters)
//! and is off by default; the filter is the core's [`RotationOneEuro`], the angles are
//! re-derived from the smoothed rotation, and `visible` and `residual` stay those of the raw
//! estimate.

use std::collections::HashMap;

use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};
use facepose_core::geometry::{EulerAngles, rotation_rows};

use crate::error::ServiceError;
use crate::pose::FacePose;

/// Frames after which an unseen track is forgotten.
pub const TRACK_TTL_FRAMES: u64 = 30;

/// The time step assumed when timestamps are missing or not increasing, seconds.
pub const DEFAULT_DT: f64 = 1.0 / 30.0;

struct Track {
    filter: RotationOneEuro,
    last_seen: u64,
}

/// The tracks of one stream.
#[derive(Default)]
pub struct Session {
    /// A fresh filter with the stream's parameters, cloned for each new track.
    smoothing: Option<RotationOneEuro>,
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
    pub fn configure(&mut self, params: Option<OneEuroParams>) -> Result<(), ServiceError> {
        if params.as_ref() != self.smoothing() {
            self.smoothing = params.map(RotationOneEuro::new).transpose()?;
            self.tracks.clear();
        }
        Ok(())
    }

    /// The smoothing's parameters when it is on.
    pub fn smoothing(&self) -> Option<&OneEuroParams> {
        self.smoothing.as_ref().map(RotationOneEuro::params)
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
    /// the filtered ones); whether it did.
    pub fn smooth(&mut self, key: String, pose: &mut FacePose) -> bool {
        let Some(template) = &self.smoothing else {
            return false;
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
        let r = track.filter.filter(&pose.rotation, self.dt);
        let a = EulerAngles::from_rotation(&r);
        pose.record.yaw = a.yaw;
        pose.record.pitch = a.pitch;
        pose.record.roll = a.roll;
        pose.record.rotation = rotation_rows(&r);
        pose.rotation = r;
        true
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
