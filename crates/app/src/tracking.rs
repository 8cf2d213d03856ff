//! The face tracks of one stream: the optional smoothing of each track's rotation, frame by
//! frame. The transport (gRPC's `EstimateStream`) reads frames and writes results; this holds
//! what lasts between them.
//!
//! Tracks are keyed by the client's face id (its tracker's id), or by the face's index in the
//! frame when it has none. A track unseen for [`TRACK_TTL_FRAMES`] frames is forgotten.
//! Smoothing is configured by a frame (the first, or a later one, which restarts the filters)
//! and is off by default. The filter is the core's [`RotationKalman`], which weighs each frame
//! by its uncertainty ([`FacePose::turn_cov`]: the estimate's `filter_cov`), or its
//! [`RotationOneEuro`]; the angles are re-derived from the smoothed
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
    /// A Kalman filter on the rotation.
    Kalman(KalmanParams),
    /// A One Euro filter on the rotation.
    OneEuro(OneEuroParams),
}

/// Which filter a stream's smoothing options name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilterKind {
    /// The Kalman filter on the rotation.
    Kalman,
    /// The One Euro filter.
    OneEuro,
}

/// A stream's smoothing as its transport received it (gRPC's `Smoothing` message, the
/// WebSocket's `smoothing` object): zero parameters take the defaults.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SmoothingOptions {
    /// Smoothing on.
    pub enabled: bool,
    /// The filter named (`None`: unspecified, see [`SmoothingOptions::filter`]).
    pub kind: Option<FilterKind>,
    /// One Euro: minimum cutoff, Hz.
    pub min_cutoff_hz: f64,
    /// One Euro: cutoff increase per degree/second.
    pub beta: f64,
    /// One Euro: cutoff of the speed estimate, Hz.
    pub d_cutoff_hz: f64,
    /// Kalman: standard deviation of the angular acceleration, degrees/s².
    pub acceleration_deg_s2: f64,
    /// Kalman: Mahalanobis distance squared above which a frame is left out.
    pub gate: f64,
}

impl SmoothingOptions {
    /// The filter, or `None` when smoothing is off. An unspecified filter is the One Euro
    /// filter when any of its parameters is set (as streams meant before the Kalman filter),
    /// else the Kalman filter; zero parameters take the defaults, and the result is checked.
    pub fn filter(&self) -> Result<Option<Filter>, ServiceError> {
        if !self.enabled {
            return Ok(None);
        }
        let or = |v: f64, default: f64| if v == 0.0 { default } else { v };
        let one_euro_set = [self.min_cutoff_hz, self.beta, self.d_cutoff_hz]
            .iter()
            .any(|&v| v != 0.0);
        let kind = self.kind.unwrap_or(if one_euro_set {
            FilterKind::OneEuro
        } else {
            FilterKind::Kalman
        });
        let filter = match kind {
            FilterKind::Kalman => {
                let d = KalmanParams::default();
                let p = KalmanParams {
                    acceleration_deg_s2: or(self.acceleration_deg_s2, d.acceleration_deg_s2),
                    gate: or(self.gate, d.gate),
                    ..d
                };
                p.validate()?;
                Filter::Kalman(p)
            }
            FilterKind::OneEuro => {
                let d = OneEuroParams::default();
                let p = OneEuroParams {
                    min_cutoff_hz: or(self.min_cutoff_hz, d.min_cutoff_hz),
                    beta: or(self.beta, d.beta),
                    d_cutoff_hz: or(self.d_cutoff_hz, d.d_cutoff_hz),
                };
                p.validate()?;
                Filter::OneEuro(p)
            }
        };
        Ok(Some(filter))
    }
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
    /// The stream's clock ([`Session::clock`]) at the track's last update, seconds.
    last_clock: f64,
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
    /// The stream's time at the current frame, seconds since its first: each frame advances it
    /// by the time since the previous stamped frame, else by [`DEFAULT_DT`]. A track steps its
    /// filter by the time since its own last update on this clock, so a face the detector lost
    /// for some frames is predicted across the whole gap, not one frame.
    clock: f64,
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

    /// Starts a frame taken at `timestamp_us` (0: not given): the stream's clock advances by
    /// the time since the last stamped frame, else by [`DEFAULT_DT`].
    pub fn begin_frame(&mut self, timestamp_us: i64) {
        self.frames += 1;
        self.clock += match self.last_timestamp_us {
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
        let (frames, clock) = (self.frames, self.clock);
        let track = self.tracks.entry(key).or_insert_with(|| Track {
            filter: template.clone(),
            last_seen: frames,
            last_clock: clock,
        });
        if frames - track.last_seen > TRACK_TTL_FRAMES {
            track.filter.reset();
        }
        // A new track's first step has no time before it: the filters start from the estimate
        // whatever the step, and a positive one keeps their checks quiet.
        let dt = match clock - track.last_clock {
            dt if dt > 0.0 => dt,
            _ => DEFAULT_DT,
        };
        track.last_seen = frames;
        track.last_clock = clock;
        let (r, gated) = match &mut track.filter {
            TrackFilter::Kalman(k) => {
                let out = k.filter(&pose.rotation, pose.turn_cov.as_ref(), dt);
                (out.rotation, !out.accepted)
            }
            TrackFilter::OneEuro(e) => (e.filter(&pose.rotation, dt), false),
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

#[cfg(test)]
mod tests {
    use super::*;
    use facepose_core::geometry::Rotation;
    use facepose_core::pose::Method;
    use facepose_records::PoseRecord;

    /// A pose turned `yaw` degrees, as an estimate would give it, with no uncertainty (the
    /// Kalman filter then takes its default deviation).
    fn pose(yaw: f64) -> FacePose {
        let rotation: Rotation = EulerAngles::new(yaw, 0.0, 0.0).unwrap().to_rotation();
        FacePose {
            record: PoseRecord {
                yaw,
                pitch: 0.0,
                roll: 0.0,
                rotation: rotation_rows(&rotation),
                visible: vec![],
                residual: 0.0,
                method: Method::Fit,
                translation: None,
                warnings: vec![],
                uncertainty: None,
                conventions: None,
            },
            rotation,
            turn_cov: None,
            scheme: "five".into(),
        }
    }

    /// A track the detector lost for some frames is stepped across the whole gap when it comes
    /// back, as a filter fed only that track's frames at their own times would be: the
    /// reference is the core's filter itself, given the true time since the track's last frame.
    #[test]
    fn a_track_that_skips_frames_is_predicted_across_its_gap() {
        let params = KalmanParams::default();
        let mut session = Session::default();
        session.configure(Some(Filter::Kalman(params))).unwrap();
        let mut reference = RotationKalman::new(params).unwrap();
        // 30 frames a second; the face turns 60°/s and is lost for frames 10 to 35 (26
        // frames) while another face stays in view.
        let (fps, speed) = (30.0, 60.0);
        let stamp = |frame: u32| 1_000_000 + (f64::from(frame) / fps * 1e6).round() as i64;
        let mut last_seen_frame = None;
        let mut checked = 0;
        for frame in 0..60u32 {
            let t = f64::from(frame) / fps;
            session.begin_frame(stamp(frame));
            let mut other = pose(-10.0);
            session.smooth("other".into(), &mut other);
            if (10..36).contains(&frame) {
                session.end_frame();
                continue;
            }
            let mut p = pose(speed * t);
            let got = session.smooth("face".into(), &mut p);
            assert!(got.smoothed);
            let dt =
                last_seen_frame.map_or(DEFAULT_DT, |f| (stamp(frame) - stamp(f)) as f64 * 1e-6);
            let want = reference.filter(&pose(speed * t).rotation, None, dt);
            let error = facepose_core::geometry::geodesic_deg(&p.rotation, &want.rotation);
            assert!(
                error < 1e-9,
                "frame {frame}: the track's output is {error}° from the filter stepped by {dt} s"
            );
            last_seen_frame = Some(frame);
            checked += 1;
            session.end_frame();
        }
        assert_eq!(checked, 34);
    }

    /// Without timestamps every frame is one [`DEFAULT_DT`], and a track's step still counts
    /// the frames it missed.
    #[test]
    fn without_timestamps_a_gap_is_counted_in_frames() {
        let mut session = Session::default();
        session
            .configure(Some(Filter::Kalman(KalmanParams::default())))
            .unwrap();
        for _ in 0..3 {
            session.begin_frame(0);
        }
        let mut first = pose(0.0);
        session.smooth("face".into(), &mut first);
        let before = session.tracks["face"].last_clock;
        for _ in 0..5 {
            session.begin_frame(0);
        }
        let mut back = pose(5.0);
        session.smooth("face".into(), &mut back);
        let gap = session.tracks["face"].last_clock - before;
        assert!((gap - 5.0 * DEFAULT_DT).abs() < 1e-12, "{gap}");
    }
}
