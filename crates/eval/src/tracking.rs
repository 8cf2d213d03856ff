//! Tracking on synthetic head trajectories: what smoothing does to the error and the jitter of
//! a stream of estimates, with and without each estimate's uncertainty.
//!
//! Each trajectory is a face of the model's shape basis (identity and expression drawn from its
//! prior) turning smoothly (yaw, pitch and roll each a sum of sines of random phase: |yaw| up
//! to 65°, speeds up to about 100°/s), seen at 30 frames per second under weak perspective with
//! an inter-ocular distance of 80 px, every landmark with Gaussian noise (3% of the IOD).
//! Some frames are wild (a detector that lost the face for a frame: every point off by 12% of the
//! IOD) and some
//! occluded (one half of the face missing: the points left of the nose line). Every frame is
//! estimated with `auto`; the filters then run on the estimates, frame by frame:
//! - `raw`: the estimates themselves;
//! - `one-euro`: the One Euro filter on the rotation ([`RotationOneEuro`], default parameters),
//!   which knows nothing of the uncertainty;
//! - `kalman, fixed`: the Kalman filter ([`RotationKalman`]) with the same covariance for every
//!   frame (its `default_sd_deg`): the filter without the uncertainty;
//! - `kalman, uncertainty`: the same filter with each estimate's calibrated turn covariance.
//!
//! Errors are geodesic angles to the true rotation; jitter is the RMS over frames of the angle
//! between the output's frame-to-frame turn and the truth's (degrees per frame): what shakes on
//! screen that the head did not do.

use nalgebra::{Rotation3, Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use facepose_core::error::{Error, Result};
use facepose_core::geometry::rotation_kalman::{KalmanParams, RotationKalman};
use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};
use facepose_core::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
use facepose_core::model::PoseModel;
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::Shape2;

/// The landmark noise of a wild frame, share of the IOD (a detector that lost the face for a
/// frame: motion blur, a hand passing).
const WILD_NOISE: f64 = 0.12;

/// The trajectories' settings.
#[derive(Debug, Clone, Serialize)]
pub struct TrackingOptions {
    /// Number of trajectories.
    pub trajectories: usize,
    /// Length of each, seconds.
    pub seconds: f64,
    /// Frames per second.
    pub fps: f64,
    /// Landmark noise, share of the IOD.
    pub noise: f64,
    /// Shares of the frames that are wild and occluded.
    pub wild: f64,
    /// Share of the frames that are occluded.
    pub occluded: f64,
    /// Seed of the random draws.
    pub seed: u64,
    /// Acceleration noises of the Kalman filter to compare, degrees/s².
    pub accelerations: Vec<f64>,
}

impl Default for TrackingOptions {
    fn default() -> Self {
        TrackingOptions {
            trajectories: 20,
            seconds: 20.0,
            fps: 30.0,
            noise: 0.03,
            wild: 0.04,
            occluded: 0.06,
            seed: 2011,
            accelerations: vec![25.0, 50.0, 100.0, 150.0, 200.0, 300.0, 600.0],
        }
    }
}

/// One filter's figures over every frame of every trajectory.
#[derive(Debug, Clone, Serialize)]
pub struct TrackingRow {
    /// The filter's name.
    pub filter: String,
    /// Frames in all.
    pub frames: usize,
    /// Geodesic error to the truth, degrees: RMS, mean, 95th percentile.
    pub rms_error: f64,
    /// Mean geodesic error, degrees.
    pub mean_error: f64,
    /// 95th percentile of the geodesic error, degrees.
    pub p95_error: f64,
    /// Mean error on the wild and on the occluded frames.
    pub wild_error: f64,
    /// Mean error on the occluded frames, degrees.
    pub occluded_error: f64,
    /// RMS of the turn error between consecutive frames, degrees per frame.
    pub jitter: f64,
}

/// One frame of a trajectory.
struct Frame {
    truth: Rotation3<f64>,
    kind: Kind,
    /// The estimate's rotation and turn covariance (none when the estimate failed).
    measured: Option<(Rotation3<f64>, Option<nalgebra::Matrix3<f64>>)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Clean,
    Wild,
    Occluded,
}

/// Accumulates one filter's errors.
#[derive(Default)]
struct Acc {
    errors: Vec<f64>,
    wild: Vec<f64>,
    occluded: Vec<f64>,
    turn_sq: f64,
    turns: usize,
}

impl Acc {
    fn add_trajectory(&mut self, frames: &[Frame], out: &[Rotation3<f64>]) {
        for (k, (f, r)) in frames.iter().zip(out).enumerate() {
            let e = geodesic_deg(r, &f.truth);
            self.errors.push(e);
            match f.kind {
                Kind::Wild => self.wild.push(e),
                Kind::Occluded => self.occluded.push(e),
                Kind::Clean => {}
            }
            if k > 0 {
                let turn_out = r * out[k - 1].inverse();
                let turn_true = f.truth * frames[k - 1].truth.inverse();
                self.turn_sq += geodesic_deg(&turn_out, &turn_true).powi(2);
                self.turns += 1;
            }
        }
    }

    fn row(mut self, filter: &str) -> TrackingRow {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        self.errors.sort_by(f64::total_cmp);
        let n = self.errors.len();
        TrackingRow {
            filter: filter.into(),
            frames: n,
            rms_error: (self.errors.iter().map(|e| e * e).sum::<f64>() / n.max(1) as f64).sqrt(),
            mean_error: mean(&self.errors),
            p95_error: self
                .errors
                .get(((n as f64 - 1.0) * 0.95).round() as usize)
                .copied()
                .unwrap_or(f64::NAN),
            wild_error: mean(&self.wild),
            occluded_error: mean(&self.occluded),
            jitter: (self.turn_sq / self.turns.max(1) as f64).sqrt(),
        }
    }
}

/// A smooth random trajectory: the true rotation at time `t`.
struct Trajectory {
    phases: [f64; 5],
}

impl Trajectory {
    fn at(&self, t: f64) -> Rotation3<f64> {
        let w = |f: f64, k: usize| (2.0 * std::f64::consts::PI * f * t + self.phases[k]).sin();
        let yaw = 45.0 * w(0.13, 0) + 20.0 * w(0.37, 1);
        let pitch = 15.0 * w(0.21, 2) + 8.0 * w(0.53, 3);
        let roll = 10.0 * w(0.17, 4);
        EulerAngles { pitch, yaw, roll }.to_rotation()
    }
}

/// The frames of one trajectory, estimated.
fn frames(model: &PoseModel, opts: &TrackingOptions, rng: &mut StdRng) -> Result<Vec<Frame>> {
    let morph = model.morph.as_ref().ok_or_else(|| {
        Error::param(
            "model",
            "the tracking protocol needs a model with a shape basis",
        )
    })?;
    let unit = Normal::new(0.0, 1.0).map_err(|e| Error::param("noise", e.to_string()))?;
    let c: Vec<f64> = morph
        .prior_mean()
        .iter()
        .map(|m| m + unit.sample(rng))
        .collect();
    let shape: Vec<Vector3<f64>> = morph.shape(&c);
    let eye =
        |idx: &[usize]| idx.iter().map(|&i| shape[i]).sum::<Vector3<f64>>() / idx.len() as f64;
    let a = &model.scheme.anchors;
    let iod_mm = (eye(&a.eye_right) - eye(&a.eye_left)).norm();
    let iod_px = 80.0;
    let scale = iod_px / iod_mm;
    let traj = Trajectory {
        phases: std::array::from_fn(|_| rng.random_range(0.0..std::f64::consts::TAU)),
    };
    let nose_x = eye(&a.nose_tip).x;
    let left: Vec<usize> = (0..shape.len()).filter(|&i| shape[i].x < nose_x).collect();
    let n = (opts.seconds * opts.fps).round() as usize;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 / opts.fps;
        let truth = traj.at(t);
        let cam = WeakPerspective::new(truth, scale, Vector2::new(320.0, -240.0))?;
        let sd = opts.noise * iod_px;
        let mut pts: Vec<Vector2<f64>> = shape
            .iter()
            .map(|x| cam.project(x) + Vector2::new(sd * unit.sample(rng), sd * unit.sample(rng)))
            .collect();
        let draw: f64 = rng.random();
        let kind = if draw < opts.wild {
            Kind::Wild
        } else if draw < opts.wild + opts.occluded {
            Kind::Occluded
        } else {
            Kind::Clean
        };
        let mut lm = Shape2::full(pts.clone())?;
        match kind {
            Kind::Wild => {
                for p in &mut pts {
                    *p += Vector2::new(unit.sample(rng), unit.sample(rng)) * WILD_NOISE * iod_px;
                }
                lm = Shape2::full(pts)?;
            }
            Kind::Occluded => lm = lm.with_missing(left.iter().copied()),
            Kind::Clean => {}
        }
        let measured = estimate(model, &model.scheme.name, &lm, Method::Auto)
            .ok()
            .map(|e| (e.rotation, e.filter_cov()));
        out.push(Frame {
            truth,
            kind,
            measured,
        });
    }
    Ok(out)
}

/// A filter over a trajectory: its output per frame (a frame without an estimate holds the
/// last output; before the first estimate, the identity).
fn run(
    frames: &[Frame],
    dt: f64,
    mut step: impl FnMut(&Rotation3<f64>, Option<&nalgebra::Matrix3<f64>>, f64) -> Rotation3<f64>,
) -> Vec<Rotation3<f64>> {
    let mut last = Rotation3::identity();
    let mut since = dt;
    frames
        .iter()
        .map(|f| {
            if let Some((r, cov)) = &f.measured {
                last = step(r, cov.as_ref(), since);
                since = dt;
            } else {
                since += dt;
            }
            last
        })
        .collect()
}

/// Runs the protocol: the rows for raw, One Euro and the Kalman filter (fixed covariance and
/// uncertainty) at each of `opts.accelerations`, and how many frames had no estimate.
pub fn tracking_protocol(
    model: &PoseModel,
    opts: &TrackingOptions,
) -> Result<(Vec<TrackingRow>, usize)> {
    let dt = 1.0 / opts.fps;
    let mut rng = StdRng::seed_from_u64(opts.seed);
    let names: Vec<String> = ["raw".to_string(), "one-euro".to_string()]
        .into_iter()
        .chain(opts.accelerations.iter().flat_map(|a| {
            [
                format!("kalman, fixed, {a}°/s²"),
                format!("kalman, uncertainty, {a}°/s²"),
            ]
        }))
        .collect();
    let mut accs: Vec<Acc> = names.iter().map(|_| Acc::default()).collect();
    let mut failed = 0;
    for _ in 0..opts.trajectories {
        let fr = frames(model, opts, &mut rng)?;
        failed += fr.iter().filter(|f| f.measured.is_none()).count();
        accs[0].add_trajectory(&fr, &run(&fr, dt, |r, _, _| *r));
        let mut euro = RotationOneEuro::new(OneEuroParams::default())?;
        accs[1].add_trajectory(&fr, &run(&fr, dt, |r, _, dt| euro.filter(r, dt)));
        for (i, &a) in opts.accelerations.iter().enumerate() {
            let params = KalmanParams {
                acceleration_deg_s2: a,
                ..KalmanParams::default()
            };
            let mut fixed = RotationKalman::new(params)?;
            accs[2 + 2 * i].add_trajectory(
                &fr,
                &run(&fr, dt, |r, _, dt| fixed.filter(r, None, dt).rotation),
            );
            let mut weighed = RotationKalman::new(params)?;
            accs[3 + 2 * i].add_trajectory(
                &fr,
                &run(&fr, dt, |r, cov, dt| weighed.filter(r, cov, dt).rotation),
            );
        }
    }
    let rows = accs
        .into_iter()
        .zip(&names)
        .map(|(a, n)| a.row(n))
        .collect();
    Ok((rows, failed))
}

/// The table.
pub fn tracking_markdown(rows: &[TrackingRow]) -> String {
    let mut out = String::from(
        "| filter | frames | RMS error | mean error | p95 error | wild frames | occluded frames | jitter (°/frame) |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        out.push_str(&format!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} |\n",
            r.filter,
            r.frames,
            r.rms_error,
            r.mean_error,
            r.p95_error,
            r.wild_error,
            r.occluded_error,
            r.jitter
        ));
    }
    out
}
