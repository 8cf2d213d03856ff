//! The rendered ground-truth benchmark (issue 37, item 2): facepose on what real detectors
//! found in renders of textured heads at known poses (`tests/fixtures/rendered/`, whose README
//! describes the renders and what they can fake).
//!
//! - **Inputs** ([`Detector`]): MediaPipe's 478 points (`mediapipe478`, normalized coordinates
//!   scaled by the image size), dlib's 68 (`dlib68`, 2D style: `LandmarkStyle::Contour`), dlib's
//!   own five-point predictor (`dlib5`), the five anchors of dlib's 68 (`five`), and for
//!   reference the oracle: the exact projection of the rendered mesh's 68 points, the hidden
//!   ones sent as missing (`oracle68`, 3D style). dlib's integer pixel indices get +0.5 (pixel
//!   centres); no camera intrinsics are given (weak perspective, as detectors' users send).
//! - **Methods**: each asked method on each input (a method an input does not serve is left
//!   out); and the peer `mediapipe-matrix`: MediaPipe's own facial transformation matrix turned
//!   into a rotation of facepose's model frame (the matrix maps MediaPipe's canonical face,
//!   which the served mesh places in the model frame by a similarity `σ Q`, so `R = M Qᵀ`, the
//!   nearest rotation; `geometry::convention::peers`).
//! - **Scoring** (static renders: sets `grid` and `random`). Errors of pitch, yaw and roll
//!   (wrapped), MAE and their mean, the geodesic error, the MAE by |true yaw| band, the gain
//!   (least-squares slope of the estimated on the true angle, per angle), the answer rate (a
//!   render the detector missed, or the method refused, is not answered) and the 90% coverage
//!   (the share of answers whose interval90 holds the truth). Geometry `bfm` has absolute truth
//!   and is scored as is; both geometries are also scored with a constant rotation per identity
//!   removed: the orthogonal Procrustes rotation `Q` minimizing `Σ‖R_est − Q R_true‖` over that
//!   identity's answered renders of that geometry (per input and method), then `Qᵀ R_est` is
//!   scored. That is the only way to score geometry `mediapipe` (relative truth), and a floor
//!   for a per-identity calibration on `bfm`. It is fitted on the scored renders themselves (a
//!   nuisance of the truth, not a learned correction); nothing here is fitted across
//!   identities, so the train/test split only selects rows. The model's `detector` regression
//!   is fitted on `train` ([`crate::detector_training`]), so only the `test` rows measure it.
//! - **MediaPipe against dlib**: on geometry `bfm` (absolute) renders where both detected, the
//!   mean difference of the angles (MediaPipe − dlib68) and each one's mean signed error.
//! - **Trajectories** (set `trajectory`, 150 frames at 30 fps each): per trajectory and input,
//!   `auto` on every frame, then `raw`, `one-euro` and `kalman` (the core's filters at their
//!   default parameters; the Kalman filter weighs each frame by its calibrated turn covariance
//!   divided by the method's filter trust, as the stream does). Frames are handled as the stream's tracks are
//!   (`facepose_app::tracking`): a frame without an answer emits nothing; the next answer steps
//!   the filter by the time since the track's last update (the timestamps), and a track unseen
//!   for more than [`TRACK_TTL_FRAMES`] frames restarts. Errors are geodesic over the emitted
//!   frames; jitter is the RMS over consecutive frames both emitted of the angle between the
//!   output's frame-to-frame turn and the truth's (degrees per frame), as in
//!   [`crate::tracking`]. On geometry `mediapipe` the trajectory's constant rotation (fitted on
//!   the raw answers as above) is removed from every filter's output.
//!
//! Pure: records and the model in, rows and Markdown out.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Rotation3, Vector2};
use serde::Serialize;

use facepose_core::data::RenderedRecord;
use facepose_core::geometry::convention::camera::nearest_rotation;
use facepose_core::geometry::convention::{MeshFrame, wrap_deg};
use facepose_core::geometry::rotation_kalman::{KalmanParams, RotationKalman};
use facepose_core::geometry::smoothing::{OneEuroParams, RotationOneEuro};
use facepose_core::geometry::{EulerAngles, geodesic_deg};
use facepose_core::model::PoseModel;
use facepose_core::model::mesh::MEDIAPIPE478;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_core::shape::{Shape2, ibug68};

/// Frames after which the stream forgets an unseen track (`facepose_app::tracking`).
pub const TRACK_TTL_FRAMES: usize = 30;

/// The |true yaw| bands, degrees (the last one closed).
pub const YAW_BANDS: [(f64, f64); 5] = [
    (0.0, 15.0),
    (15.0, 30.0),
    (30.0, 45.0),
    (45.0, 60.0),
    (60.0, 80.0),
];

/// The peer scored like a method of `mediapipe478`.
pub const MEDIAPIPE_MATRIX: &str = "mediapipe-matrix";

/// A landmark input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Detector {
    /// MediaPipe's 478 points, normalized, as scheme `mediapipe478`.
    Mediapipe478,
    /// dlib's 68 points as `ibug68`, `landmark_style: contour` (as docs/API.md advises).
    Dlib68,
    /// dlib's 5-point predictor as `dlib5`.
    Dlib5,
    /// The five anchors (eye centres, nose tip, mouth corners) of dlib's 68, as `five`.
    Five,
    /// The rendered mesh's own 68 points, projected exactly: the floor of the landmarks.
    Oracle68,
}

impl Detector {
    /// Every input, in the order of the tables.
    pub const ALL: [Detector; 5] = [
        Detector::Mediapipe478,
        Detector::Dlib68,
        Detector::Dlib5,
        Detector::Five,
        Detector::Oracle68,
    ];

    /// Its name in the tables and the JSON report.
    pub fn name(self) -> &'static str {
        match self {
            Detector::Mediapipe478 => "mediapipe478",
            Detector::Dlib68 => "dlib68",
            Detector::Dlib5 => "dlib5",
            Detector::Five => "five",
            Detector::Oracle68 => "oracle68",
        }
    }
}

static IBUG68: std::sync::LazyLock<facepose_core::shape::Scheme> = std::sync::LazyLock::new(ibug68);

/// The landmarks of `det` on `rec` (scheme, points in pixels, style); `None` when the
/// detector found no face.
pub fn landmarks(
    rec: &RenderedRecord,
    det: Detector,
) -> Option<(&'static str, Shape2, LandmarkStyle)> {
    let pixels = |pts: &[[f64; 2]]| -> Option<Shape2> {
        Shape2::full(
            pts.iter()
                .map(|p| Vector2::new(p[0] + 0.5, p[1] + 0.5))
                .collect(),
        )
        .ok()
    };
    match det {
        Detector::Mediapipe478 => {
            let m = rec.mediapipe.as_ref()?;
            let pts: Vec<Option<[f64; 2]>> = m.landmarks.iter().map(|p| Some(*p)).collect();
            let size = ImageSize {
                width: rec.image_size[0],
                height: rec.image_size[1],
            };
            let s = pixel_shape(&pts, Some(size)).ok()?;
            Some((MEDIAPIPE478, s, LandmarkStyle::Projected))
        }
        Detector::Dlib68 => {
            let d = rec.dlib.as_ref()?;
            Some(("ibug68", pixels(&d.ibug68)?, LandmarkStyle::Contour))
        }
        Detector::Dlib5 => {
            let d = rec.dlib.as_ref()?;
            Some(("dlib5", pixels(&d.dlib5)?, LandmarkStyle::Contour))
        }
        Detector::Five => {
            let d = rec.dlib.as_ref()?;
            let s = pixels(&d.ibug68)?.to_five(&IBUG68).ok()?;
            Some(("five", s, LandmarkStyle::Contour))
        }
        Detector::Oracle68 => {
            let vis: Vec<bool> = rec.oracle.visible.chars().map(|c| c == '1').collect();
            let pts: Vec<Option<[f64; 2]>> = rec
                .oracle
                .ibug68
                .iter()
                .zip(&vis)
                .map(|(p, v)| v.then_some(*p))
                .collect();
            let s = Shape2::from_options(&pts).ok()?;
            Some(("ibug68", s, LandmarkStyle::Projected))
        }
    }
}

/// One answer: the rotation, and the 90% half-widths and turn covariance when the answer
/// carries an uncertainty.
#[derive(Debug, Clone, Copy)]
pub struct Answer {
    /// The estimated rotation, model frame to camera frame.
    pub rotation: Rotation3<f64>,
    /// Half the 90% interval of pitch, yaw, roll, degrees (with a calibrated uncertainty).
    pub half_width: Option<[f64; 3]>,
    /// The calibrated covariance of the rotation's small turn, radians².
    pub turn_cov: Option<Matrix3<f64>>,
    /// The method that answered (`None`: a peer's answer).
    pub method: Option<Method>,
}

impl Answer {
    /// The covariance the Kalman filter weighs the answer by: the turn covariance divided by
    /// the method's filter trust ([`facepose_core::pose::MethodSpec::filter_trust`]), or by
    /// `detector_trust` for the detector regression's answers when given.
    pub fn filter_cov(&self, detector_trust: Option<f64>) -> Option<Matrix3<f64>> {
        let trust = match (self.method, detector_trust) {
            (Some(Method::Detector), Some(t)) => t,
            (Some(m), _) => m.spec().filter_trust,
            (None, _) => 1.0,
        };
        self.turn_cov.map(|c| c / trust)
    }
}

/// `method` on `det`'s landmarks of `rec`.
pub fn answer(
    model: &PoseModel,
    rec: &RenderedRecord,
    det: Detector,
    method: Method,
) -> Option<Answer> {
    let (scheme, lm, style) = landmarks(rec, det)?;
    let opts = EstimateOptions {
        method,
        camera: None,
        style,
    };
    let e = estimate_with(model, scheme, &lm, &opts).ok()?;
    Some(Answer {
        rotation: e.rotation,
        half_width: e
            .uncertainty
            .as_ref()
            .map(|u| [0, 1, 2].map(|k| u.half_width(k))),
        turn_cov: e.uncertainty.map(|u| u.turn_cov),
        method: Some(e.method),
    })
}

/// MediaPipe's facial transformation matrix of `rec` as a rotation of the model frame.
pub fn mediapipe_matrix(rec: &RenderedRecord, frame: &MeshFrame) -> Option<Answer> {
    let m = &rec.mediapipe.as_ref()?.facial_transformation_matrix;
    let a = Matrix3::from_fn(|i, j| m[i][j]);
    let r = nearest_rotation(&(a * frame.0.rotation.matrix().transpose()));
    Some(Answer {
        rotation: r,
        half_width: None,
        turn_cov: None,
        method: None,
    })
}

/// How the served mesh sits in the model frame (for the MediaPipe matrix), when it has one.
pub fn mesh_frame(model: &PoseModel) -> Option<MeshFrame> {
    model
        .mesh
        .as_ref()
        .and_then(|m| MeshFrame::of_served_mesh(&m.source().vertices).ok())
}

/// The true rotation of a render.
pub fn truth_rotation(rec: &RenderedRecord) -> Rotation3<f64> {
    let t = &rec.truth.rotation;
    nearest_rotation(&Matrix3::from_fn(|i, j| t[i][j]))
}

/// The true angles of a render: pitch, yaw, roll, degrees.
pub fn truth_angles(rec: &RenderedRecord) -> [f64; 3] {
    [rec.truth.pitch, rec.truth.yaw, rec.truth.roll]
}

/// The rotation `Q` minimizing `Σ ‖Rᵢ − Q Tᵢ‖` (Frobenius) over pairs (estimate, truth):
/// the nearest rotation to `Σ Rᵢ Tᵢᵀ`.
pub fn procrustes_offset(pairs: &[(Rotation3<f64>, Rotation3<f64>)]) -> Rotation3<f64> {
    if pairs.is_empty() {
        return Rotation3::identity();
    }
    let m: Matrix3<f64> = pairs
        .iter()
        .map(|(r, t)| r.matrix() * t.matrix().transpose())
        .sum();
    nearest_rotation(&m)
}

/// (estimate, truth).
type Pair = (Rotation3<f64>, Rotation3<f64>);

/// One (input, method, split, geometry, scoring) cell.
#[derive(Debug, Clone, Serialize)]
pub struct RenderedRow {
    /// The input ([`Detector::name`]).
    pub detector: String,
    /// The estimation method (`auto`, `fit`, ...), or [`MEDIAPIPE_MATRIX`] for MediaPipe's own
    /// pose.
    pub method: String,
    /// `train`, `test` or `all`.
    pub split: String,
    /// `bfm`, `mediapipe` or `both`.
    pub geometry: String,
    /// A constant rotation per identity removed before scoring (see the module docs).
    pub offset_removed: bool,
    /// Renders in the cell.
    pub renders: usize,
    /// Renders where the detector found a face.
    pub detected: usize,
    /// Renders with an estimate (a face found and the estimator answered).
    pub answered: usize,
    /// Mean absolute error of pitch, yaw, roll, degrees.
    pub mae: [f64; 3],
    /// The mean of the three.
    pub mae_mean: f64,
    /// The mean geodesic error, degrees.
    pub geodesic: f64,
    /// Mean signed error (estimate − truth) of pitch, yaw, roll.
    pub bias: [f64; 3],
    /// Least-squares slope of the estimated on the true angle (pitch, yaw, roll).
    pub gain: [f64; 3],
    /// Per [`YAW_BANDS`] band: answers and the mean of the three MAEs.
    pub bands: Vec<(usize, f64)>,
    /// Answers with an interval.
    pub with_interval: usize,
    /// The share of them whose 90% interval holds the truth, per angle (pitch, yaw, roll).
    pub coverage: [f64; 3],
    /// Mean angle of the removed per-identity rotations, degrees (0 when none).
    pub mean_offset_deg: f64,
}

/// One scored answer.
#[derive(Clone, Copy)]
struct Scored {
    error: [f64; 3],
    estimate: [f64; 3],
    truth: [f64; 3],
    geodesic: f64,
    half_width: Option<[f64; 3]>,
}

fn score(a: &Answer, r: &Rotation3<f64>, rec: &RenderedRecord) -> Scored {
    let e = EulerAngles::from_rotation(r);
    let estimate = [e.pitch, e.yaw, e.roll];
    let truth = truth_angles(rec);
    Scored {
        error: [0, 1, 2].map(|k| wrap_deg(estimate[k] - truth[k])),
        estimate,
        truth,
        geodesic: geodesic_deg(r, &truth_rotation(rec)),
        half_width: a.half_width,
    }
}

fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    if x.len() < 2 {
        return f64::NAN;
    }
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    if sxx < 1e-9 { f64::NAN } else { sxy / sxx }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 { f64::NAN } else { s / n as f64 }
}

struct Key<'a> {
    detector: &'a str,
    method: &'a str,
    split: &'a str,
    geometry: &'a str,
    offset_removed: bool,
}

fn row(
    key: Key,
    renders: usize,
    detected: usize,
    scored: &[Scored],
    offsets: &[f64],
) -> RenderedRow {
    let per =
        |f: &dyn Fn(&Scored, usize) -> f64| [0, 1, 2].map(|k| mean(scored.iter().map(|s| f(s, k))));
    let mae = per(&|s, k| s.error[k].abs());
    let bands = YAW_BANDS
        .iter()
        .enumerate()
        .map(|(b, &(lo, hi))| {
            let inside: Vec<&Scored> = scored
                .iter()
                .filter(|s| {
                    let y = s.truth[1].abs();
                    y >= lo && (y < hi || (b == YAW_BANDS.len() - 1 && y <= hi))
                })
                .collect();
            let m = mean(
                inside
                    .iter()
                    .map(|s| s.error.iter().map(|e| e.abs()).sum::<f64>() / 3.0),
            );
            (inside.len(), m)
        })
        .collect();
    let with: Vec<&Scored> = scored.iter().filter(|s| s.half_width.is_some()).collect();
    RenderedRow {
        detector: key.detector.into(),
        method: key.method.into(),
        split: key.split.into(),
        geometry: key.geometry.into(),
        offset_removed: key.offset_removed,
        renders,
        detected,
        answered: scored.len(),
        mae,
        mae_mean: mae.iter().sum::<f64>() / 3.0,
        geodesic: mean(scored.iter().map(|s| s.geodesic)),
        bias: per(&|s, k| s.error[k]),
        gain: [0, 1, 2].map(|k| {
            let x: Vec<f64> = scored.iter().map(|s| s.truth[k]).collect();
            let y: Vec<f64> = scored.iter().map(|s| s.truth[k] + s.error[k]).collect();
            slope(&x, &y)
        }),
        bands,
        with_interval: with.len(),
        coverage: [0, 1, 2].map(|k| {
            mean(with.iter().map(|s| {
                let h = s.half_width.map_or(0.0, |h| h[k]);
                f64::from(u8::from(s.error[k].abs() <= h))
            }))
        }),
        mean_offset_deg: mean(offsets.iter().copied()),
    }
}

/// facepose on MediaPipe's 478 points against MediaPipe's own facial transformation matrix
/// from the same points (what the `mediapipe` convention would swap in), on geometry `bfm`
/// (absolute truth), renders where both answered: how far apart the two rotations are, and
/// how far each is from the truth.
#[derive(Debug, Clone, Serialize)]
pub struct MatrixAgreementRow {
    /// facepose's estimation method.
    pub method: String,
    /// `train`, `test` or `all`.
    pub split: String,
    /// Renders where both answered.
    pub renders: usize,
    /// Median angle between facepose's rotation and MediaPipe's, degrees.
    pub median_angle: f64,
    /// Mean of that angle, degrees.
    pub mean_angle: f64,
    /// Share of renders where they are within 1 degree.
    pub within_1deg: f64,
    /// facepose's mean geodesic error from the truth, degrees.
    pub error_facepose: f64,
    /// MediaPipe's mean geodesic error from the truth, degrees.
    pub error_mediapipe: f64,
}

/// MediaPipe against dlib on geometry `bfm` (absolute truth), renders where both answered.
#[derive(Debug, Clone, Serialize)]
pub struct DisagreementRow {
    /// The estimation method on both inputs.
    pub method: String,
    /// `train`, `test` or `all`.
    pub split: String,
    /// Renders where both detectors answered.
    pub renders: usize,
    /// Mean of MediaPipe's angle minus dlib68's (pitch, yaw, roll), degrees.
    pub mean_diff: [f64; 3],
    /// Mean of its absolute value, degrees.
    pub mean_abs_diff: [f64; 3],
    /// MediaPipe's mean signed error of pitch, yaw, roll, degrees.
    pub bias_mediapipe: [f64; 3],
    /// dlib68's mean signed error of pitch, yaw, roll, degrees.
    pub bias_dlib: [f64; 3],
}

/// One filter on one input over one trajectory (or pooled over a split's trajectories).
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryRow {
    /// The trajectory's id, or `all <split>` for a pooled row.
    pub trajectory: String,
    /// The trajectory's identity (empty for a pooled row).
    pub identity: String,
    /// Its split.
    pub split: String,
    /// Its geometry (`bfm` or `mediapipe`).
    pub geometry: String,
    /// Its camera (`ortho` or `perspective`).
    pub camera: String,
    /// The input.
    pub detector: String,
    /// `raw`, `one-euro` or `kalman` (the stream's defaults).
    pub filter: String,
    /// Frames in the trajectory.
    pub frames: usize,
    /// Frames with an answer (what the stream emits).
    pub emitted: usize,
    /// Geodesic error over the emitted frames: RMS and mean, degrees.
    pub rms_error: f64,
    /// The mean geodesic error, degrees.
    pub mean_error: f64,
    /// RMS turn error between consecutive emitted frames, degrees per frame.
    pub jitter: f64,
    #[serde(skip)]
    sq_error: f64,
    #[serde(skip)]
    sum_error: f64,
    #[serde(skip)]
    turn_sq: f64,
    #[serde(skip)]
    turns: usize,
}

/// Everything the protocol measures.
#[derive(Debug, Clone, Serialize)]
pub struct RenderedReport {
    /// Records read.
    pub records: usize,
    /// Grid and random renders (the static tables).
    pub static_renders: usize,
    /// Trajectory frames (the tracking table).
    pub trajectory_frames: usize,
    /// The methods evaluated.
    pub methods: Vec<String>,
    /// The static cells.
    pub rows: Vec<RenderedRow>,
    /// MediaPipe against dlib.
    pub disagreement: Vec<DisagreementRow>,
    /// facepose against MediaPipe's own matrix.
    pub matrix_agreement: Vec<MatrixAgreementRow>,
    /// The trajectories, per filter.
    pub trajectories: Vec<TrajectoryRow>,
}

/// The filters of the trajectories.
pub const FILTERS: [&str; 3] = ["raw", "one-euro", "kalman"];

/// Runs the protocol on `records` with `methods` (on every input) and the MediaPipe matrix,
/// the trajectories' Kalman filter with `kalman` (the stream's default:
/// `KalmanParams::default()`) weighing the detector regression's answers with `detector_trust`
/// (`None`: the method's [`facepose_core::pose::MethodSpec::filter_trust`]). Fails when `kalman`
/// is not valid or the trust is not positive and finite.
pub fn rendered_protocol(
    model: &PoseModel,
    records: &[RenderedRecord],
    methods: &[Method],
    kalman: KalmanParams,
    detector_trust: Option<f64>,
) -> facepose_core::error::Result<RenderedReport> {
    kalman.validate()?;
    if let Some(t) = detector_trust.filter(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(facepose_core::error::Error::param(
            "detector_trust",
            format!("must be positive and finite, got {t}"),
        ));
    }
    let frame = mesh_frame(model);
    let statics: Vec<&RenderedRecord> = records
        .iter()
        .filter(|r| r.set == "grid" || r.set == "random")
        .collect();
    // (detector, method label) -> per static render, its answer.
    let mut answers: Vec<(Detector, String, Vec<Option<Answer>>)> = Vec::new();
    for det in Detector::ALL {
        for &m in methods {
            let v: Vec<Option<Answer>> = statics.iter().map(|r| answer(model, r, det, m)).collect();
            if v.iter().any(Option::is_some) {
                answers.push((det, m.to_string(), v));
            }
        }
        if det == Detector::Mediapipe478
            && let Some(f) = &frame
        {
            let v = statics.iter().map(|r| mediapipe_matrix(r, f)).collect();
            answers.push((det, MEDIAPIPE_MATRIX.into(), v));
        }
    }
    let mut rows = Vec::new();
    for (det, method, v) in &answers {
        // Per render: (scored absolute, scored with its identity's offset removed).
        let mut offsets: BTreeMap<(&str, &str), (Rotation3<f64>, f64)> = BTreeMap::new();
        let mut groups: BTreeMap<(&str, &str), Vec<Pair>> = BTreeMap::new();
        for (r, a) in statics.iter().zip(v) {
            if let Some(a) = a {
                groups
                    .entry((r.identity.as_str(), r.geometry.as_str()))
                    .or_default()
                    .push((a.rotation, truth_rotation(r)));
            }
        }
        for (k, pairs) in &groups {
            let q = procrustes_offset(pairs);
            offsets.insert(*k, (q, q.angle().to_degrees()));
        }
        for split in ["train", "test", "all"] {
            for (geometry, offset_removed) in [
                ("bfm", false),
                ("bfm", true),
                ("mediapipe", true),
                ("both", true),
            ] {
                let sel: Vec<(&RenderedRecord, &Option<Answer>)> = statics
                    .iter()
                    .zip(v)
                    .filter(|(r, _)| split == "all" || r.split == split)
                    .filter(|(r, _)| geometry == "both" || r.geometry == geometry)
                    .map(|(r, a)| (*r, a))
                    .collect();
                if sel.is_empty() {
                    continue;
                }
                let detected = sel
                    .iter()
                    .filter(|(r, _)| landmarks(r, *det).is_some())
                    .count();
                let scored: Vec<Scored> = sel
                    .iter()
                    .filter_map(|(r, a)| {
                        let a = a.as_ref()?;
                        let rot = if offset_removed {
                            let (q, _) = offsets[&(r.identity.as_str(), r.geometry.as_str())];
                            q.inverse() * a.rotation
                        } else {
                            a.rotation
                        };
                        Some(score(a, &rot, r))
                    })
                    .collect();
                let offs: Vec<f64> = if offset_removed {
                    let mut ids: Vec<(&str, &str)> = sel
                        .iter()
                        .map(|(r, _)| (r.identity.as_str(), r.geometry.as_str()))
                        .collect();
                    ids.sort();
                    ids.dedup();
                    ids.iter()
                        .filter_map(|k| offsets.get(k).map(|o| o.1))
                        .collect()
                } else {
                    vec![0.0]
                };
                rows.push(row(
                    Key {
                        detector: det.name(),
                        method,
                        split,
                        geometry,
                        offset_removed,
                    },
                    sel.len(),
                    detected,
                    &scored,
                    &offs,
                ));
            }
        }
    }
    // MediaPipe against dlib68, absolute truth.
    let mut disagreement = Vec::new();
    for &m in methods {
        let find = |d: Detector| {
            answers
                .iter()
                .find(|(det, meth, _)| *det == d && *meth == m.to_string())
                .map(|x| &x.2)
        };
        let (Some(mp), Some(dl)) = (find(Detector::Mediapipe478), find(Detector::Dlib68)) else {
            continue;
        };
        for split in ["train", "test", "all"] {
            let both: Vec<(Scored, Scored)> = statics
                .iter()
                .zip(mp.iter().zip(dl))
                .filter(|(r, _)| r.geometry == "bfm" && (split == "all" || r.split == split))
                .filter_map(|(r, (a, b))| {
                    let (a, b) = (a.as_ref()?, b.as_ref()?);
                    Some((score(a, &a.rotation, r), score(b, &b.rotation, r)))
                })
                .collect();
            if both.is_empty() {
                continue;
            }
            let per = |f: &dyn Fn(&(Scored, Scored), usize) -> f64| {
                [0, 1, 2].map(|k| mean(both.iter().map(|p| f(p, k))))
            };
            disagreement.push(DisagreementRow {
                method: m.to_string(),
                split: split.into(),
                renders: both.len(),
                mean_diff: per(&|(a, b), k| wrap_deg(a.estimate[k] - b.estimate[k])),
                mean_abs_diff: per(&|(a, b), k| wrap_deg(a.estimate[k] - b.estimate[k]).abs()),
                bias_mediapipe: per(&|(a, _), k| a.error[k]),
                bias_dlib: per(&|(_, b), k| b.error[k]),
            });
        }
    }
    let matrix_agreement = matrix_agreement(&statics, &answers, methods);
    let trajectories = trajectory_rows(model, records, frame.as_ref(), kalman, detector_trust);
    Ok(RenderedReport {
        records: records.len(),
        static_renders: statics.len(),
        trajectory_frames: records.iter().filter(|r| r.set == "trajectory").count(),
        methods: methods.iter().map(|m| m.to_string()).collect(),
        rows,
        disagreement,
        matrix_agreement,
        trajectories,
    })
}

/// The [`MatrixAgreementRow`]s: per method answering MediaPipe's points, per split.
fn matrix_agreement(
    statics: &[&RenderedRecord],
    answers: &[(Detector, String, Vec<Option<Answer>>)],
    methods: &[Method],
) -> Vec<MatrixAgreementRow> {
    let find = |label: &str| {
        answers
            .iter()
            .find(|(det, meth, _)| *det == Detector::Mediapipe478 && meth == label)
            .map(|x| &x.2)
    };
    let Some(peer) = find(MEDIAPIPE_MATRIX) else {
        return Vec::new();
    };
    let mut rows = Vec::new();
    for &m in methods {
        let Some(ours) = find(&m.to_string()) else {
            continue;
        };
        for split in ["train", "test", "all"] {
            // (angle between them, facepose's error, MediaPipe's error)
            let mut v: Vec<(f64, f64, f64)> = statics
                .iter()
                .zip(ours.iter().zip(peer))
                .filter(|(r, _)| r.geometry == "bfm" && (split == "all" || r.split == split))
                .filter_map(|(r, (a, b))| {
                    let (a, b) = (a.as_ref()?, b.as_ref()?);
                    let truth = truth_rotation(r);
                    Some((
                        geodesic_deg(&a.rotation, &b.rotation),
                        geodesic_deg(&a.rotation, &truth),
                        geodesic_deg(&b.rotation, &truth),
                    ))
                })
                .collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(|x, y| x.0.total_cmp(&y.0));
            let n = v.len();
            let median = if n % 2 == 1 {
                v[n / 2].0
            } else {
                (v[n / 2 - 1].0 + v[n / 2].0) / 2.0
            };
            rows.push(MatrixAgreementRow {
                method: m.to_string(),
                split: split.into(),
                renders: n,
                median_angle: median,
                mean_angle: mean(v.iter().map(|x| x.0)),
                within_1deg: v.iter().filter(|x| x.0 <= 1.0).count() as f64 / n as f64,
                error_facepose: mean(v.iter().map(|x| x.1)),
                error_mediapipe: mean(v.iter().map(|x| x.2)),
            });
        }
    }
    rows
}

/// A stream's track: the filter's output per frame (`None`: not emitted), as
/// `facepose_app::tracking::Session` runs it.
fn track(
    frames: &[&RenderedRecord],
    measured: &[Option<Answer>],
    mut step: impl FnMut(&Answer, f64) -> Rotation3<f64>,
    mut reset: impl FnMut(),
) -> Vec<Option<Rotation3<f64>>> {
    let default_dt = 1.0 / 30.0;
    let mut last: Option<(usize, f64)> = None;
    let mut prev_ts: Option<i64> = None;
    let mut clock = 0.0;
    frames
        .iter()
        .zip(measured)
        .enumerate()
        .map(|(k, (f, m))| {
            let ts = f.trajectory.as_ref().map_or(0, |t| t.timestamp_us);
            clock += match prev_ts {
                Some(p) if ts > p && ts > 0 => (ts - p) as f64 * 1e-6,
                _ => default_dt,
            };
            if ts > 0 {
                prev_ts = Some(ts);
            }
            let a = m.as_ref()?;
            let dt = match last {
                Some((seen, c)) => {
                    if k - seen > TRACK_TTL_FRAMES {
                        reset();
                    }
                    if clock - c > 0.0 {
                        clock - c
                    } else {
                        default_dt
                    }
                }
                None => default_dt,
            };
            last = Some((k, clock));
            Some(step(a, dt))
        })
        .collect()
}

fn trajectory_rows(
    model: &PoseModel,
    records: &[RenderedRecord],
    frame: Option<&MeshFrame>,
    kalman: KalmanParams,
    detector_trust: Option<f64>,
) -> Vec<TrajectoryRow> {
    let mut by_id: BTreeMap<&str, Vec<&RenderedRecord>> = BTreeMap::new();
    for r in records.iter().filter(|r| r.set == "trajectory") {
        if let Some(t) = &r.trajectory {
            by_id.entry(t.id.as_str()).or_default().push(r);
        }
    }
    let mut rows = Vec::new();
    for (id, mut frames) in by_id {
        frames.sort_by_key(|r| r.trajectory.as_ref().map_or(0, |t| t.frame));
        let first = frames[0];
        let truth: Vec<Rotation3<f64>> = frames.iter().map(|r| truth_rotation(r)).collect();
        let mut inputs: Vec<(String, Vec<Option<Answer>>)> = Detector::ALL
            .iter()
            .map(|&d| {
                let v = frames
                    .iter()
                    .map(|r| answer(model, r, d, Method::Auto))
                    .collect();
                (d.name().to_string(), v)
            })
            .collect();
        if let Some(f) = frame {
            inputs.push((
                MEDIAPIPE_MATRIX.into(),
                frames.iter().map(|r| mediapipe_matrix(r, f)).collect(),
            ));
        }
        for (det, measured) in &inputs {
            // Relative truth: the trajectory's constant rotation, from the raw answers.
            let q = if first.truth_absolute && det != MEDIAPIPE_MATRIX {
                Rotation3::identity()
            } else {
                let pairs: Vec<_> = measured
                    .iter()
                    .zip(&truth)
                    .filter_map(|(a, t)| a.map(|a| (a.rotation, *t)))
                    .collect();
                procrustes_offset(&pairs)
            };
            for filter in FILTERS {
                let out = match filter {
                    "raw" => track(&frames, measured, |a, _| a.rotation, || {}),
                    "one-euro" => {
                        let f = std::cell::RefCell::new(
                            RotationOneEuro::new(OneEuroParams::default())
                                .expect("default parameters"),
                        );
                        track(
                            &frames,
                            measured,
                            |a, dt| f.borrow_mut().filter(&a.rotation, dt),
                            || f.borrow_mut().reset(),
                        )
                    }
                    _ => {
                        let f = std::cell::RefCell::new(
                            RotationKalman::new(kalman).expect("validated parameters"),
                        );
                        track(
                            &frames,
                            measured,
                            |a, dt| {
                                f.borrow_mut()
                                    .filter(&a.rotation, a.filter_cov(detector_trust).as_ref(), dt)
                                    .rotation
                            },
                            || f.borrow_mut().reset(),
                        )
                    }
                };
                let out: Vec<Option<Rotation3<f64>>> = out
                    .into_iter()
                    .map(|o| o.map(|r| q.inverse() * r))
                    .collect();
                let mut row = TrajectoryRow {
                    trajectory: id.into(),
                    identity: first.identity.clone(),
                    split: first.split.clone(),
                    geometry: first.geometry.clone(),
                    camera: first.camera.kind.clone(),
                    detector: det.clone(),
                    filter: filter.into(),
                    frames: frames.len(),
                    emitted: 0,
                    rms_error: 0.0,
                    mean_error: 0.0,
                    jitter: 0.0,
                    sq_error: 0.0,
                    sum_error: 0.0,
                    turn_sq: 0.0,
                    turns: 0,
                };
                for (k, o) in out.iter().enumerate() {
                    let Some(r) = o else { continue };
                    let e = geodesic_deg(r, &truth[k]);
                    row.emitted += 1;
                    row.sq_error += e * e;
                    row.sum_error += e;
                    if k > 0
                        && let Some(p) = out[k - 1]
                    {
                        let turn_out = r * p.inverse();
                        let turn_true = truth[k] * truth[k - 1].inverse();
                        row.turn_sq += geodesic_deg(&turn_out, &turn_true).powi(2);
                        row.turns += 1;
                    }
                }
                finish(&mut row);
                rows.push(row);
            }
        }
    }
    // Pooled per split.
    let mut pooled: Vec<TrajectoryRow> = Vec::new();
    for split in ["train", "test", "all"] {
        for r in rows.iter().filter(|r| split == "all" || r.split == split) {
            let label = format!("all {split}");
            match pooled
                .iter_mut()
                .find(|p| p.trajectory == label && p.detector == r.detector && p.filter == r.filter)
            {
                Some(p) => {
                    p.frames += r.frames;
                    p.emitted += r.emitted;
                    p.sq_error += r.sq_error;
                    p.sum_error += r.sum_error;
                    p.turn_sq += r.turn_sq;
                    p.turns += r.turns;
                }
                None => {
                    let mut p = r.clone();
                    p.trajectory = label;
                    p.identity = "-".into();
                    p.split = split.into();
                    p.geometry = "-".into();
                    p.camera = "-".into();
                    pooled.push(p);
                }
            }
        }
    }
    for p in &mut pooled {
        finish(p);
    }
    rows.extend(pooled);
    rows
}

fn finish(row: &mut TrajectoryRow) {
    let n = row.emitted.max(1) as f64;
    row.rms_error = if row.emitted == 0 {
        f64::NAN
    } else {
        (row.sq_error / n).sqrt()
    };
    row.mean_error = if row.emitted == 0 {
        f64::NAN
    } else {
        row.sum_error / n
    };
    row.jitter = if row.turns == 0 {
        f64::NAN
    } else {
        (row.turn_sq / row.turns as f64).sqrt()
    };
}

fn f1(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1}")
    } else {
        "-".into()
    }
}

fn f2(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2}")
    } else {
        "-".into()
    }
}

fn pct(v: f64) -> String {
    if v.is_finite() {
        format!("{:.0}", 100.0 * v)
    } else {
        "-".into()
    }
}

/// The table of the rows of `split` and `geometry` (offset removed or not): answers, MAE,
/// geodesic, gain, coverage, and MAE by |yaw| band.
pub fn rows_markdown(
    report: &RenderedReport,
    split: &str,
    geometry: &str,
    offset_removed: bool,
) -> String {
    let mut out = String::from(
        "| input | method | answered / renders (detected) | MAE pitch | yaw | roll | mean | geodesic | bias pitch | gain pitch | yaw | roll | coverage90 pitch | yaw | roll (%) |",
    );
    for (lo, hi) in YAW_BANDS {
        out.push_str(&format!(" \\|yaw\\| {lo:.0}-{hi:.0} |"));
    }
    out.push_str("\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    out.push_str(&"---|".repeat(YAW_BANDS.len()));
    out.push('\n');
    for r in report.rows.iter().filter(|r| {
        r.split == split && r.geometry == geometry && r.offset_removed == offset_removed
    }) {
        let cov = |k: usize| {
            if r.with_interval == 0 {
                "-".to_string()
            } else {
                pct(r.coverage[k])
            }
        };
        out.push_str(&format!(
            "| {} | {} | {} / {} ({}) | {} | {} | {} | **{}** | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.detector,
            r.method,
            r.answered,
            r.renders,
            r.detected,
            f2(r.mae[0]),
            f2(r.mae[1]),
            f2(r.mae[2]),
            f2(r.mae_mean),
            f2(r.geodesic),
            f2(r.bias[0]),
            f2(r.gain[0]),
            f2(r.gain[1]),
            f2(r.gain[2]),
            cov(0),
            cov(1),
            cov(2),
        ));
        for (n, m) in &r.bands {
            out.push_str(&format!(" {} ({n}) |", f1(*m)));
        }
        out.push('\n');
    }
    out
}

/// The MediaPipe-against-dlib table.
pub fn disagreement_markdown(report: &RenderedReport) -> String {
    let mut out = String::from(
        "| method | split | renders | mean MediaPipe − dlib68 pitch | yaw | roll | mean \\|diff\\| pitch | yaw | roll | bias pitch MediaPipe | dlib68 |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for d in &report.disagreement {
        out.push_str(&format!(
            "| {} | {} | {} | **{}** | {} | {} | {} | {} | {} | {} | {} |\n",
            d.method,
            d.split,
            d.renders,
            f2(d.mean_diff[0]),
            f2(d.mean_diff[1]),
            f2(d.mean_diff[2]),
            f2(d.mean_abs_diff[0]),
            f2(d.mean_abs_diff[1]),
            f2(d.mean_abs_diff[2]),
            f2(d.bias_mediapipe[0]),
            f2(d.bias_dlib[0]),
        ));
    }
    out
}

/// The facepose-against-MediaPipe's-matrix table.
pub fn matrix_agreement_markdown(report: &RenderedReport) -> String {
    let mut out = String::from(
        "| method | split | renders | median angle between them | mean | within 1° | facepose's error | MediaPipe's error |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for a in &report.matrix_agreement {
        out.push_str(&format!(
            "| {} | {} | {} | **{}** | {} | {:.0}% | {} | {} |\n",
            a.method,
            a.split,
            a.renders,
            f2(a.median_angle),
            f2(a.mean_angle),
            100.0 * a.within_1deg,
            f2(a.error_facepose),
            f2(a.error_mediapipe),
        ));
    }
    out
}

/// The trajectories: pooled rows (one per split, input and filter), then per trajectory.
pub fn trajectories_markdown(report: &RenderedReport, pooled: bool) -> String {
    let mut out = String::from(
        "| trajectory | identity (split, geometry, camera) | input | filter | emitted / frames | RMS error | mean error | jitter (°/frame) |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for r in report
        .trajectories
        .iter()
        .filter(|r| r.trajectory.starts_with("all ") == pooled)
    {
        let who = if pooled {
            "-".to_string()
        } else {
            format!("{} ({}, {}, {})", r.identity, r.split, r.geometry, r.camera)
        };
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} / {} | {} | {} | {:.3} |\n",
            r.trajectory,
            who,
            r.detector,
            r.filter,
            r.emitted,
            r.frames,
            f2(r.rms_error),
            f2(r.mean_error),
            r.jitter,
        ));
    }
    out
}

/// The report's section: headline tables for `split` (`train`, `test` or `all`), the other
/// split's summary, MediaPipe against dlib, the trajectories.
pub fn rendered_markdown(report: &RenderedReport, split: &str) -> String {
    let other = if split == "train" { "test" } else { "train" };
    format!(
        "### Split `{split}`: both geometries, a constant rotation per identity removed\n\n\
         The figures item 4 targets. Answered = the detector found a face and the method answered; \
         MAE and gain over the answers; coverage90 over the answers that carry an interval; the last \
         columns: mean of the three MAEs per |true yaw| band (answers in parentheses).\n\n{}\n\
         ### Split `{split}`: geometry `bfm`, absolute\n\n{}\n\
         ### Split `{split}`: geometry `bfm`, a constant rotation per identity removed\n\n{}\n\
         ### Split `{split}`: geometry `mediapipe`, a constant rotation per identity removed\n\n{}\n\
         ### Split `{other}`: both geometries, a constant rotation per identity removed\n\n{}\n\
         ### MediaPipe against dlib (geometry `bfm`, absolute)\n\n\
         Renders where both MediaPipe and dlib answered; differences of the estimated angles, degrees.\n\n{}\n\
         ### facepose against MediaPipe's own matrix (geometry `bfm`, absolute)\n\n\
         facepose on MediaPipe's 478 points against MediaPipe's facial transformation matrix from \
         the same points (the rotation the `mediapipe` convention would replace): the angle between \
         the two rotations, and each one's geodesic error from the truth, degrees.\n\n{}\n\
         ### Trajectories (`auto`), pooled\n\n{}\n\
         ### Trajectories, each\n\n{}",
        rows_markdown(report, split, "both", true),
        rows_markdown(report, split, "bfm", false),
        rows_markdown(report, split, "bfm", true),
        rows_markdown(report, split, "mediapipe", true),
        rows_markdown(report, other, "both", true),
        disagreement_markdown(report),
        matrix_agreement_markdown(report),
        trajectories_markdown(report, true),
        trajectories_markdown(report, false),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use facepose_core::geometry::EulerAngles;
    use facepose_core::model::default_model;
    use std::path::Path;

    /// One grid file (a test identity, both geometries, orthographic and perspective renders)
    /// and one trajectory (`traj2`: insightface/t1#1, geometry bfm, orthographic).
    fn subset() -> Vec<RenderedRecord> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/rendered");
        facepose_files::rendered::load_rendered(
            &dir,
            Some(&["grid-t1-2.jsonl.gz", "traj2.jsonl.gz"]),
        )
        .unwrap()
    }

    #[test]
    fn procrustes_offset_recovers_a_constant_rotation() {
        let q = EulerAngles {
            pitch: 6.0,
            yaw: -2.0,
            roll: 1.0,
        }
        .to_rotation();
        let pairs: Vec<_> = [(10.0, 30.0, 0.0), (-20.0, -60.0, 5.0), (0.0, 0.0, -30.0)]
            .iter()
            .map(|&(p, y, r)| {
                let t = EulerAngles {
                    pitch: p,
                    yaw: y,
                    roll: r,
                }
                .to_rotation();
                (q * t, t)
            })
            .collect();
        assert!(geodesic_deg(&procrustes_offset(&pairs), &q) < 1e-9);
    }

    /// A detector trust that is not a positive finite number is refused before any work; a
    /// higher trust follows the detector's answers more closely on the trajectories (less
    /// smoothing: the Kalman output's jitter rises toward the raw answers').
    #[test]
    fn the_detector_trust_is_checked_and_moves_the_kalman_filter() {
        let records = subset();
        let (_, model) = default_model().unwrap();
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(
                rendered_protocol(
                    &model,
                    &records,
                    &[Method::Auto],
                    KalmanParams::default(),
                    Some(bad)
                )
                .is_err(),
                "{bad}"
            );
        }
        let jitter = |trust| {
            let report = rendered_protocol(
                &model,
                &records,
                &[Method::Auto],
                KalmanParams::default(),
                Some(trust),
            )
            .unwrap();
            let row = |filter: &str| {
                report
                    .trajectories
                    .iter()
                    .find(|r| r.detector == "mediapipe478" && r.filter == filter)
                    .map(|r| r.jitter)
                    .unwrap()
            };
            (row("kalman"), row("raw"))
        };
        let (low, raw) = jitter(1.0);
        let (high, _) = jitter(64.0);
        assert!(
            low < high && high <= raw * 1.05,
            "trust 1: {low}, 64: {high}, raw {raw}"
        );
    }

    #[test]
    fn the_subset_scores_every_input() {
        let records = subset();
        let (_, model) = default_model().unwrap();
        let report = rendered_protocol(
            &model,
            &records,
            &[Method::Auto, Method::Fit],
            KalmanParams::default(),
            None,
        )
        .unwrap();
        assert_eq!(report.static_renders, 102);
        assert_eq!(report.trajectory_frames, 150);
        let get = |det: &str, method: &str, geometry: &str, off: bool| {
            report
                .rows
                .iter()
                .find(|r| {
                    r.detector == det
                        && r.method == method
                        && r.split == "test"
                        && r.geometry == geometry
                        && r.offset_removed == off
                })
                .unwrap_or_else(|| panic!("no row {det} {method} {geometry} {off}"))
        };
        // The oracle sees every render; the detectors' figures are finite and their gains
        // computed.
        let oracle = get("oracle68", "auto", "both", true);
        assert_eq!(oracle.answered, oracle.renders);
        for det in ["mediapipe478", "dlib68", "dlib5", "five"] {
            let r = get(det, "auto", "both", true);
            assert!(r.answered > 10 && r.answered <= r.renders, "{det}: {r:?}");
            assert!(
                r.mae.iter().all(|v| v.is_finite() && *v < 60.0),
                "{det}: {r:?}"
            );
            assert!(r.gain.iter().take(2).all(|g| g.is_finite()), "{det}: {r:?}");
            let b = get(det, "auto", "bfm", false);
            assert!(b.mae_mean.is_finite());
        }
        assert!(report.rows.iter().any(|r| r.method == MEDIAPIPE_MATRIX));
        // facepose against MediaPipe's matrix: a row per method; the angle between
        // them bounds the difference of their errors (the geodesic angle is a metric).
        for m in ["auto", "fit"] {
            assert!(
                report
                    .matrix_agreement
                    .iter()
                    .any(|a| a.method == m && a.split == "all"),
                "{m}"
            );
        }
        for a in &report.matrix_agreement {
            assert!(a.renders > 0 && a.median_angle.is_finite(), "{a:?}");
            assert!(
                (a.error_facepose - a.error_mediapipe).abs() <= a.mean_angle + 1e-9,
                "{a:?}"
            );
        }
        // Trajectories: one per input and filter, and the pooled ones.
        let traj: Vec<&TrajectoryRow> = report
            .trajectories
            .iter()
            .filter(|r| r.trajectory == "traj2")
            .collect();
        assert_eq!(traj.len(), (Detector::ALL.len() + 1) * FILTERS.len());
        assert!(traj.iter().all(|r| r.frames == 150));
        // The oracle's stream is far steadier than any detector's.
        let jitter = |det: &str| {
            traj.iter()
                .find(|r| r.detector == det && r.filter == "raw")
                .unwrap()
                .jitter
        };
        assert!(
            jitter("oracle68") < 0.5 * jitter("dlib68"),
            "{}",
            jitter("oracle68")
        );
    }

    /// On orthographic renders the oracle's visible points are an exact weak-perspective view
    /// of the rendered face: the rigid fit of the model's mean shape is off only by how that
    /// face differs from the mean (no detector, no perspective).
    #[test]
    fn the_oracle_is_near_exact_on_orthographic_renders() {
        let records = subset();
        let (_, model) = default_model().unwrap();
        let mut errors = Vec::new();
        for r in records
            .iter()
            .filter(|r| r.camera.kind == "ortho" && r.geometry == "bfm")
        {
            assert_eq!(r.oracle.weak_perspective_deg, 0.0);
            if r.truth.yaw.abs() > 60.0 {
                continue;
            }
            let a = answer(&model, r, Detector::Oracle68, Method::Fit).unwrap();
            errors.push(geodesic_deg(&a.rotation, &truth_rotation(r)));
        }
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let worst = errors.iter().copied().fold(0.0, f64::max);
        // 2.3° mean, 3.5° worst when written: the rendered face is the identity's bfm fit, not
        // the model's mean shape.
        assert!(errors.len() >= 10);
        assert!(
            mean < 3.0 && worst < 5.0,
            "mean {mean:.2}, worst {worst:.2}"
        );
    }
}
