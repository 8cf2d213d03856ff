//! The detector regression: the paper's ridge regression (§4.2), trained not on projections of
//! 3D shapes but on one landmark detector's own output over renders of textured heads at known
//! poses (issue 37; `tests/fixtures/rendered/`). A detector does not put its points where the
//! face's points project: MediaPipe's mesh, for one, moves less than the face when the head
//! pitches or turns far, so that any fit of a 3D face to its points under-reads the rotation.
//! A regression from the detector's points to the true rotation learns that bias.
//!
//! The input is the 2D shape (every point present, y up) turned in the image plane by minus
//! the in-plane angle of a reference rotation (the rigid fit's, [`in_plane_angle`]), centred
//! and energy-normalized (as `crate::shape::normalized_vector` does), and a constant; the output the first two rows
//! of the de-rolled rotation, made orthonormal (Gram-Schmidt) and completed by their cross
//! product, then turned back. The rigid fit turns with the image exactly, so the answer does
//! too: a camera rolled by θ changes the answer's roll by θ and nothing else (a regression on
//! raw coordinates moved by 6-7° under a 20° turn of the image). Trained by [`fit`] with the ridge
//! parameter chosen by leave-one-group-out cross-validation, the groups being identities, so that the choice is never made on a face it is scored on.

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::geometry::geodesic_deg;
use crate::shape::Shape2;

/// Outputs of the regression: the rotation's first two rows.
const OUTPUTS: usize = 6;

/// A detector regression (stored in a model bundle).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorRegression {
    /// The scheme it reads (`mediapipe478`).
    pub scheme: String,
    /// The detector whose output it was trained on, for people.
    pub detector: String,
    /// The ridge parameter, chosen by cross-validation over identities.
    pub epsilon: f64,
    /// The `(2n + 1) x 6` weights, one row per input (x and y of each point, then the
    /// constant): the rotation's first two rows are `input · weights`.
    pub weights: Vec<[f64; OUTPUTS]>,
    /// What it was trained on.
    pub training: DetectorTraining,
}

/// What a detector regression was trained on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorTraining {
    /// The data, for people.
    pub data: String,
    /// The identities (groups) of the training faces.
    pub identities: Vec<String>,
    /// How many faces.
    pub samples: usize,
    /// Mean geodesic error (degrees) of the cross-validated answers at the chosen `epsilon`.
    pub cv_error_deg: f64,
}

/// One training face: the detector's landmarks, the reference rotation, the true rotation and
/// its group (identity).
#[derive(Debug, Clone)]
pub struct DetectorSample {
    /// The detector's points, image pixels.
    pub landmarks: Shape2,
    /// The reference rotation the input is de-rolled by (the rigid fit's on these points).
    pub reference: Rotation3<f64>,
    /// The true rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// The identity, an index into [`DetectorTraining::identities`].
    pub group: usize,
}

/// The angle (radians, anticlockwise on screen) of the image of the model's x axis under `r`:
/// the rotation about the camera's axis that [`DetectorRegression::estimate`] takes out.
pub fn in_plane_angle(r: &Rotation3<f64>) -> f64 {
    let m = r.matrix();
    m[(1, 0)].atan2(m[(0, 0)])
}

/// The rotation by `angle` (radians) about the camera's z axis (anticlockwise on screen).
fn about_camera_axis(angle: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), angle)
}

/// The input vector of a face: its shape turned by `-angle` in the image plane (y up),
/// normalized, and a constant. Every point must be present (a detector gives them all).
pub fn input(landmarks: &Shape2, angle: f64) -> Result<Vec<f64>> {
    let t = Normalization::of(landmarks, angle)?;
    let mut v = Vec::with_capacity(2 * landmarks.len() + 1);
    for p in landmarks.points() {
        let (x, y) = t.apply(p);
        v.extend([x, y]);
    }
    v.push(1.0);
    Ok(v)
}

/// How [`input`] maps a point: turned by `-angle` (y up), centred, over the norm of the whole
/// centred vector (as `crate::shape::normalized_vector`).
struct Normalization {
    centre: (f64, f64),
    cos: f64,
    sin: f64,
}

impl Normalization {
    fn of(landmarks: &Shape2, angle: f64) -> Result<Self> {
        let missing = landmarks.len() - landmarks.n_present();
        if missing > 0 {
            return Err(Error::param(
                "landmarks",
                format!(
                    "method detector needs every point of the scheme (a detector gives them all); \
                     {missing} of {} are missing: use fit",
                    landmarks.len()
                ),
            ));
        }
        let pts = landmarks.points();
        if pts.len() < 2 {
            return Err(Error::too_few("normalized shape", 2, pts.len()));
        }
        let n = pts.len() as f64;
        let (sx, sy) = pts.iter().fold((0.0, 0.0), |(a, b), p| (a + p.x, b - p.y));
        let (cx, cy) = (sx / n, sy / n);
        let norm = pts
            .iter()
            .map(|p| (p.x - cx).powi(2) + (-p.y - cy).powi(2))
            .sum::<f64>()
            .sqrt();
        // A turn keeps the norm and the centroid's distance; the check is normalized_vector's.
        if norm.is_nan() || norm <= 1e-12 * (1.0 + cx.hypot(cy)) {
            return Err(Error::Degenerate(
                "all present points are at the same place".into(),
            ));
        }
        Ok(Normalization {
            centre: (cx, cy),
            cos: (-angle).cos() / norm,
            sin: (-angle).sin() / norm,
        })
    }

    /// The two inputs of a point (image pixels, y down).
    #[inline]
    fn apply(&self, p: &nalgebra::Vector2<f64>) -> (f64, f64) {
        let (x, y) = (p.x - self.centre.0, -p.y - self.centre.1);
        (self.cos * x - self.sin * y, self.sin * x + self.cos * y)
    }
}

/// The rotation whose first two rows are nearest `out` (Gram-Schmidt).
fn rotation_of(out: &[f64; OUTPUTS]) -> Result<Rotation3<f64>> {
    let a = Vector3::new(out[0], out[1], out[2]);
    let b = Vector3::new(out[3], out[4], out[5]);
    let a = a.try_normalize(1e-9).ok_or_else(|| {
        Error::Degenerate("the detector regression's answer is degenerate".into())
    })?;
    let b = (b - a * a.dot(&b)).try_normalize(1e-9).ok_or_else(|| {
        Error::Degenerate("the detector regression's answer is degenerate".into())
    })?;
    let c = a.cross(&b);
    Ok(Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        a.transpose(),
        b.transpose(),
        c.transpose(),
    ])))
}

impl DetectorRegression {
    /// The rotation of `landmarks` (all present, in [`DetectorRegression::scheme`]), de-rolled
    /// by `reference`'s in-plane angle (the rigid fit's rotation on the same points).
    pub fn estimate(
        &self,
        landmarks: &Shape2,
        reference: &Rotation3<f64>,
    ) -> Result<Rotation3<f64>> {
        if 2 * landmarks.len() + 1 != self.weights.len() {
            return Err(Error::PointCount {
                what: format!("landmarks for the {} detector regression", self.scheme),
                expected: (self.weights.len() - 1) / 2,
                got: landmarks.len(),
            });
        }
        let angle = in_plane_angle(reference);
        let t = Normalization::of(landmarks, angle)?;
        // input · weights, a point (two rows) at a time, then the constant's row: the same
        // sums in the same order as over `input`'s vector.
        let mut out = [0.0; OUTPUTS];
        let (rows, constant) = self.weights.split_at(self.weights.len() - 1);
        for (p, w) in landmarks.points().iter().zip(rows.chunks_exact(2)) {
            let (x, y) = t.apply(p);
            for k in 0..OUTPUTS {
                out[k] += x * w[0][k];
                out[k] += y * w[1][k];
            }
        }
        for k in 0..OUTPUTS {
            out[k] += constant[0][k];
        }
        Ok(about_camera_axis(angle) * rotation_of(&out)?)
    }

    /// Fails unless the weights are finite and the shape is consistent.
    pub fn validate(&self) -> Result<()> {
        if self.weights.len() < 3 || self.weights.len().is_multiple_of(2) {
            return Err(Error::param(
                "detector_regressions",
                format!(
                    "{}: {} weight rows; expected 2n + 1",
                    self.scheme,
                    self.weights.len()
                ),
            ));
        }
        if !(self.epsilon.is_finite() && self.epsilon > 0.0)
            || self.weights.iter().flatten().any(|w| !w.is_finite())
        {
            return Err(Error::param(
                "detector_regressions",
                format!("{}: a weight or epsilon is not finite", self.scheme),
            ));
        }
        Ok(())
    }
}

/// The Gram matrix `XᵀX` and `XᵀY` of some samples' inputs and outputs.
struct Moments {
    xtx: DMatrix<f64>,
    xty: DMatrix<f64>,
}

impl Moments {
    fn zeros(p: usize) -> Self {
        Moments {
            xtx: DMatrix::zeros(p, p),
            xty: DMatrix::zeros(p, OUTPUTS),
        }
    }

    fn of(inputs: &[(Vec<f64>, [f64; OUTPUTS])]) -> Self {
        let p = inputs.first().map_or(0, |(x, _)| x.len());
        let x = DMatrix::from_fn(inputs.len(), p, |i, j| inputs[i].0[j]);
        let y = DMatrix::from_fn(inputs.len(), OUTPUTS, |i, k| inputs[i].1[k]);
        Moments {
            xtx: x.tr_mul(&x),
            xty: x.tr_mul(&y),
        }
    }

    /// The ridge solution `(XᵀX + ε I')⁻¹ XᵀY`, the constant (last input) not penalized.
    fn solve(&self, epsilon: f64) -> Result<Vec<[f64; OUTPUTS]>> {
        let p = self.xtx.nrows();
        let mut a = self.xtx.clone();
        for i in 0..p - 1 {
            a[(i, i)] += epsilon;
        }
        let chol = a.cholesky().ok_or_else(|| {
            Error::Numerical("the detector regression's normal equations are singular".into())
        })?;
        let w = chol.solve(&self.xty);
        Ok((0..p).map(|i| std::array::from_fn(|k| w[(i, k)])).collect())
    }
}

/// The input and target of a training face.
fn example(s: &DetectorSample) -> Result<(Vec<f64>, [f64; OUTPUTS])> {
    let angle = in_plane_angle(&s.reference);
    Ok((
        input(&s.landmarks, angle)?,
        target(&(about_camera_axis(-angle) * s.rotation)),
    ))
}

/// The target of a rotation: its first two rows.
fn target(r: &Rotation3<f64>) -> [f64; OUTPUTS] {
    let m = r.matrix();
    [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
    ]
}

/// A regression from solved weights (no training record: for cross-validation's folds).
fn bare(epsilon: f64, weights: Vec<[f64; OUTPUTS]>) -> DetectorRegression {
    DetectorRegression {
        scheme: String::new(),
        detector: String::new(),
        epsilon,
        weights,
        training: DetectorTraining {
            data: String::new(),
            identities: vec![],
            samples: 0,
            cv_error_deg: 0.0,
        },
    }
}

/// Leave-one-group-out cross-validation: for each group, the moments of every other group's
/// samples, from which each `epsilon`'s fold regression is solved.
struct Folds {
    /// Per group, its samples' indices.
    by_group: Vec<Vec<usize>>,
    /// Per group, the moments without it.
    rest: Vec<Moments>,
    /// The moments of every sample.
    total: Moments,
}

impl Folds {
    fn new(samples: &[DetectorSample], inputs: &[(Vec<f64>, [f64; OUTPUTS])]) -> Result<Self> {
        let groups = samples.iter().map(|s| s.group + 1).max().unwrap_or(0);
        let by_group: Vec<Vec<usize>> = (0..groups)
            .map(|g| {
                (0..samples.len())
                    .filter(|&i| samples[i].group == g)
                    .collect()
            })
            .collect();
        let non_empty = by_group.iter().filter(|g| !g.is_empty()).count();
        if non_empty < 2 {
            return Err(Error::too_few(
                "identities to cross-validate the detector regression",
                2,
                non_empty,
            ));
        }
        let p = inputs[0].0.len();
        let parts: Vec<Moments> = by_group
            .iter()
            .map(|idx| {
                let mine: Vec<_> = idx.iter().map(|&i| inputs[i].clone()).collect();
                if mine.is_empty() {
                    Moments::zeros(p)
                } else {
                    Moments::of(&mine)
                }
            })
            .collect();
        let mut total = Moments::zeros(p);
        for m in &parts {
            total.xtx += &m.xtx;
            total.xty += &m.xty;
        }
        let rest = parts
            .iter()
            .map(|m| Moments {
                xtx: &total.xtx - &m.xtx,
                xty: &total.xty - &m.xty,
            })
            .collect();
        Ok(Folds {
            by_group,
            rest,
            total,
        })
    }

    /// Each group's fold regression at `epsilon` (an empty group's is fitted on everything).
    fn regressions(&self, epsilon: f64) -> Result<Vec<DetectorRegression>> {
        self.by_group
            .iter()
            .zip(&self.rest)
            .map(|(idx, rest)| {
                let m = if idx.is_empty() { &self.total } else { rest };
                Ok(bare(epsilon, m.solve(epsilon)?))
            })
            .collect()
    }
}

/// The ridge parameters [`fit`] chooses among (the inputs have unit norm).
pub const EPSILONS: [f64; 7] = [1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0];

/// A fitted regression and its cross-validation's fold regressions at the chosen `epsilon`.
pub struct Fitted {
    /// The regression, fitted on every sample.
    pub regression: DetectorRegression,
    /// Per group (identity), the regression fitted without it: the answers a calibration of
    /// the uncertainty is fitted on.
    pub folds: Vec<DetectorRegression>,
}

/// Fits the regression of `detector`'s points in `scheme` on `samples` (groups named by
/// `identities`), with the [`EPSILONS`] value of least mean geodesic error in leave-one-
/// identity-out cross-validation. Fails when a sample lacks a point or names no identity, or
/// fewer than two identities have samples.
pub fn fit(
    scheme: &str,
    detector: &str,
    data: &str,
    identities: &[String],
    samples: &[DetectorSample],
) -> Result<Fitted> {
    if samples.iter().any(|s| s.group >= identities.len()) {
        return Err(Error::param(
            "detector samples",
            "a sample's group names no identity",
        ));
    }
    let inputs = samples.iter().map(example).collect::<Result<Vec<_>>>()?;
    let folds = Folds::new(samples, &inputs)?;
    let mut best: Option<(f64, f64, Vec<DetectorRegression>)> = None;
    for eps in EPSILONS {
        let regs = folds.regressions(eps)?;
        let mut sum = 0.0;
        for (idx, reg) in folds.by_group.iter().zip(&regs) {
            for &i in idx {
                let s = &samples[i];
                sum += geodesic_deg(&reg.estimate(&s.landmarks, &s.reference)?, &s.rotation);
            }
        }
        let err = sum / samples.len() as f64;
        if best.as_ref().is_none_or(|b| err < b.1) {
            best = Some((eps, err, regs));
        }
    }
    let (epsilon, cv_error_deg, fold_regs) =
        best.ok_or_else(|| Error::Numerical("no ridge parameter to choose from".into()))?;
    Ok(Fitted {
        regression: DetectorRegression {
            scheme: scheme.into(),
            detector: detector.into(),
            epsilon,
            weights: folds.total.solve(epsilon)?,
            training: DetectorTraining {
                data: data.into(),
                identities: identities.to_vec(),
                samples: samples.len(),
                cv_error_deg,
            },
        },
        folds: fold_regs
            .into_iter()
            .map(|r| DetectorRegression {
                scheme: scheme.into(),
                detector: detector.into(),
                ..r
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    /// A rigid 3D point set seen at `r` under weak perspective, with a detector that reads
    /// every rotation angle at `gain` times its size (the bias the regression is for).
    fn faces(gain: f64, n: usize) -> Vec<DetectorSample> {
        let pts: Vec<Vector3<f64>> = (0..12)
            .map(|i| {
                let t = i as f64;
                Vector3::new(
                    40.0 * (0.7 * t).sin(),
                    30.0 * (1.3 * t).cos(),
                    20.0 * (0.4 * t + 1.0).sin(),
                )
            })
            .collect();
        (0..n)
            .map(|i| {
                let t = i as f64;
                let angles = Vector3::new(
                    0.5 * (0.37 * t).sin(),
                    0.8 * (0.23 * t).cos(),
                    0.3 * (0.71 * t).sin(),
                );
                let truth = Rotation3::new(angles);
                let seen = Rotation3::new(angles * gain);
                let lm = pts
                    .iter()
                    .map(|p| {
                        let q = seen * p;
                        Vector2::new(300.0 + 2.0 * q.x, 200.0 - 2.0 * q.y)
                    })
                    .collect();
                DetectorSample {
                    landmarks: Shape2::full(lm).unwrap(),
                    reference: seen,
                    rotation: truth,
                    group: i % 4,
                }
            })
            .collect()
    }

    #[test]
    fn it_learns_a_detector_that_under_reads_the_rotation() {
        let ids: Vec<String> = (0..4).map(|i| format!("id{i}")).collect();
        let train = faces(0.7, 600);
        let f = fit("toy", "toy", "toy", &ids, &train).unwrap();
        // Unseen poses: the regression's answer is near the truth, where the detector's
        // own rotation is 30% short.
        let test = faces(0.7, 660);
        let mut err = 0.0;
        let mut naive = 0.0;
        for s in &test[600..] {
            let r = f.regression.estimate(&s.landmarks, &s.reference).unwrap();
            err += geodesic_deg(&r, &s.rotation) / 60.0;
            naive +=
                geodesic_deg(&Rotation3::new(s.rotation.scaled_axis() * 0.7), &s.rotation) / 60.0;
        }
        assert!(err < 0.4 * naive, "error {err:.2}° against {naive:.2}°");
        assert_eq!(f.folds.len(), 4);
        f.regression.validate().unwrap();
    }

    #[test]
    fn the_input_is_the_normalized_vector_of_the_turned_shape() {
        let s = &faces(1.0, 3)[2];
        let t: f64 = 0.3;
        // The shape with y up, turned by -t: normalized_vector keeps y as given.
        let turned: Vec<Vector2<f64>> = s
            .landmarks
            .points()
            .iter()
            .map(|p| {
                let (x, y) = (p.x, -p.y);
                let (c, n) = ((-t).cos(), (-t).sin());
                Vector2::new(c * x - n * y, n * x + c * y)
            })
            .collect();
        let (want, _) = crate::shape::normalized_vector(&Shape2::full(turned).unwrap()).unwrap();
        let got = input(&s.landmarks, t).unwrap();
        assert_eq!(got.len(), want.len() + 1);
        assert_eq!(got[want.len()], 1.0);
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-12, "{g} {w}");
        }
    }

    #[test]
    fn a_missing_point_is_refused_with_the_remedy() {
        let ids: Vec<String> = (0..4).map(|i| format!("id{i}")).collect();
        let f = fit("toy", "toy", "toy", &ids, &faces(1.0, 80)).unwrap();
        let s = &faces(1.0, 1)[0];
        let holed = s.landmarks.with_missing([3]);
        let e = f
            .regression
            .estimate(&holed, &s.reference)
            .unwrap_err()
            .to_string();
        assert!(e.contains("1 of 12 are missing: use fit"), "{e}");
    }

    #[test]
    fn turning_the_image_turns_the_answer_about_the_camera_axis_only() {
        let ids: Vec<String> = (0..4).map(|i| format!("id{i}")).collect();
        let f = fit("toy", "toy", "toy", &ids, &faces(0.8, 120)).unwrap();
        for s in &faces(0.8, 130)[120..] {
            let r = f.regression.estimate(&s.landmarks, &s.reference).unwrap();
            for deg in [-40.0_f64, 20.0, 90.0] {
                let t = deg.to_radians();
                // Anticlockwise on screen by t about the image point (300, 200), y down.
                let turned: Vec<Vector2<f64>> = s
                    .landmarks
                    .points()
                    .iter()
                    .map(|p| {
                        let (x, y) = (p.x - 300.0, 200.0 - p.y);
                        let (c, n) = (t.cos(), t.sin());
                        Vector2::new(300.0 + c * x - n * y, 200.0 - (n * x + c * y))
                    })
                    .collect();
                let turn = about_camera_axis(t);
                let rt = f
                    .regression
                    .estimate(&Shape2::full(turned).unwrap(), &(turn * s.reference))
                    .unwrap();
                assert!(geodesic_deg(&rt, &(turn * r)) < 1e-9, "{deg}°");
            }
        }
    }
}
