//! The paper's multivariate ridge regression (§4.2, eq. 16-19) from centred, energy-normalized
//! 2D shapes to pose, with three additions:
//!
//! - **Roll.** The query is first de-rolled by its eye line (angle `φ`), as the paper does; the
//!   regression then predicts yaw and pitch of the roll-free pose and the residual in-plane angle
//!   `δ` (the eye line is not horizontal when yaw and pitch combine), and the rotation is
//!   `Rz(φ + δ) · Rx(pitch) · Ry(yaw)`, so roll stays unbiased.
//! - **Missing points without bias.** Training zeroes each sample's hidden points (HPR at its
//!   pose). A query zeroes its missing points, and the ridge system is solved for exactly that
//!   pattern: every training sample is re-normalized with the pattern's points zeroed as well,
//!   so training and query vectors are built the same way. Solutions are cached per pattern.
//!   Points the HPR step finds hidden at a first estimate join the pattern for a second pass.
//! - **View bins.** A coarse model over the whole pose range picks the fine model (bin) whose
//!   yaw range holds the coarse estimate, out to profile views.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use nalgebra::{DMatrix, DVector, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::shape::Shape2;
use crate::synth::PoseGrid;

/// One synthetic training view: pose, projected points (image frame, unit scale) and visibility.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingView {
    pub angles: EulerAngles,
    pub points: Vec<[f64; 2]>,
    pub visible: Vec<bool>,
}

/// The training views of one pose range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewBin {
    pub grid: PoseGrid,
    pub views: Vec<TrainingView>,
}

/// A ridge solution: `[yaw, pitch, roll - φ] = W [f; 1]` (rows of length `2n + 1`).
#[derive(Debug, Clone)]
struct Solution {
    w: DMatrix<f64>,
}

/// Sufficient statistics of one bin under one missing pattern.
#[derive(Debug)]
struct Stats {
    ff: DMatrix<f64>,
    tf: DMatrix<f64>,
    used: usize,
}

type Cache<T> = Mutex<HashMap<(usize, Vec<u64>), Arc<T>>>;

fn insert_bounded<T>(cache: &Cache<T>, k: (usize, Vec<u64>), v: Arc<T>) {
    let mut c = cache.lock().unwrap_or_else(|e| e.into_inner());
    if c.len() >= CACHE_LIMIT {
        c.clear();
    }
    c.insert(k, v);
}

/// The regression over one scheme's points, with its view bins.
#[derive(Debug)]
pub struct RegressionModel {
    n_points: usize,
    eye_left: Vec<usize>,
    eye_right: Vec<usize>,
    /// Bin 0 is the coarse model over the whole range; the others are the fine bins.
    bins: Vec<ViewBin>,
    epsilon: f64,
    cache: Cache<Solution>,
    stats_cache: Cache<Stats>,
}

/// Most patterns kept in the cache before it is cleared.
const CACHE_LIMIT: usize = 1024;

/// A regression answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegressionEstimate {
    pub angles: EulerAngles,
    /// Which bin answered.
    pub bin: usize,
}

fn key(missing: &[bool]) -> Vec<u64> {
    let mut k = vec![0u64; missing.len().div_ceil(64)];
    for (i, &m) in missing.iter().enumerate() {
        if m {
            k[i / 64] |= 1 << (i % 64);
        }
    }
    k
}

impl RegressionModel {
    /// A model over bins (bin 0 coarse) with ridge parameter `epsilon`.
    pub fn new(
        n_points: usize,
        eye_left: Vec<usize>,
        eye_right: Vec<usize>,
        bins: Vec<ViewBin>,
        epsilon: f64,
    ) -> Result<Self> {
        if bins.is_empty() {
            return Err(Error::param(
                "bins",
                "a regression model needs at least one view bin",
            ));
        }
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(Error::param(
                "epsilon",
                format!("must be positive, got {epsilon}"),
            ));
        }
        for (b, bin) in bins.iter().enumerate() {
            if bin.views.len() < 3 {
                return Err(Error::too_few(
                    format!("training views of bin {b}"),
                    3,
                    bin.views.len(),
                ));
            }
            if let Some(v) = bin
                .views
                .iter()
                .find(|v| v.points.len() != n_points || v.visible.len() != n_points)
            {
                return Err(Error::PointCount {
                    what: format!("training view of bin {b}"),
                    expected: n_points,
                    got: v.points.len(),
                });
            }
        }
        if eye_left.iter().chain(&eye_right).any(|&i| i >= n_points)
            || eye_left.is_empty()
            || eye_right.is_empty()
        {
            return Err(Error::param("eye anchors", "out of range or empty"));
        }
        Ok(RegressionModel {
            n_points,
            eye_left,
            eye_right,
            bins,
            epsilon,
            cache: Mutex::new(HashMap::new()),
            stats_cache: Mutex::new(HashMap::new()),
        })
    }

    /// The ridge parameter.
    pub fn epsilon(&self) -> f64 {
        self.epsilon
    }

    /// The view bins (bin 0 is the coarse one).
    pub fn bins(&self) -> &[ViewBin] {
        &self.bins
    }

    /// Sets the ridge parameter (solutions cached for the old one are dropped).
    pub fn set_epsilon(&mut self, epsilon: f64) -> Result<()> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(Error::param(
                "epsilon",
                format!("must be positive, got {epsilon}"),
            ));
        }
        self.epsilon = epsilon;
        self.cache.lock().unwrap_or_else(|e| e.into_inner()).clear();
        Ok(())
    }

    /// Number of points of the scheme it works on.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// The eye-line angle φ (degrees, clockwise on screen; eyes from the points not flagged in
    /// `eyes_from`) and the de-rolled, centred, energy-normalized feature vector with the
    /// `missing` points zeroed and `1` appended; `None` when an eye or the shape is missing.
    fn features(
        &self,
        points: &[Vector2<f64>],
        eyes_from: &[bool],
        missing: &[bool],
    ) -> Option<(f64, DVector<f64>)> {
        let anchor = |idx: &[usize]| {
            let (mut s, mut k) = (Vector2::zeros(), 0);
            for &i in idx {
                if !eyes_from[i] {
                    s += points[i];
                    k += 1;
                }
            }
            (k > 0).then(|| s / k as f64)
        };
        let d = anchor(&self.eye_right)? - anchor(&self.eye_left)?;
        let phi = d.y.atan2(d.x);
        let (s, c) = phi.sin_cos();
        let mut f = DVector::zeros(2 * self.n_points + 1);
        let (mut cx, mut cy, mut k) = (0.0, 0.0, 0);
        for (i, p) in points.iter().enumerate() {
            if !missing[i] {
                let (x, y) = (c * p.x + s * p.y, -s * p.x + c * p.y);
                f[2 * i] = x;
                f[2 * i + 1] = y;
                cx += x;
                cy += y;
                k += 1;
            }
        }
        if k < 2 {
            return None;
        }
        let (cx, cy) = (cx / k as f64, cy / k as f64);
        let mut norm = 0.0;
        for (i, &m) in missing.iter().enumerate() {
            if !m {
                f[2 * i] -= cx;
                f[2 * i + 1] -= cy;
                norm += f[2 * i] * f[2 * i] + f[2 * i + 1] * f[2 * i + 1];
            }
        }
        let norm = norm.sqrt();
        if norm.is_nan() || norm <= 1e-12 {
            return None;
        }
        f.rows_mut(0, 2 * self.n_points).scale_mut(1.0 / norm);
        f[2 * self.n_points] = 1.0;
        Some((phi.to_degrees(), f))
    }

    /// The sufficient statistics `(F Fᵀ, T Fᵀ, count)` of bin `b` for a missing pattern: every
    /// training view re-normalized with the pattern's points zeroed, plus its own hidden points.
    fn stats(&self, b: usize, missing: &[bool]) -> Result<Arc<Stats>> {
        let k = (b, key(missing));
        if let Some(s) = self
            .stats_cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&k)
        {
            return Ok(s.clone());
        }
        let d = 2 * self.n_points + 1;
        let mut ff = DMatrix::<f64>::zeros(d, d);
        let mut tf = DMatrix::<f64>::zeros(3, d);
        let mut used = 0;
        let mut mask = vec![false; self.n_points];
        let mut pts = vec![Vector2::zeros(); self.n_points];
        // The eye line of a training view comes from all its projected eye points, as a client
        // that sends both eyes gives it.
        let all = vec![false; self.n_points];
        for v in &self.bins[b].views {
            for i in 0..self.n_points {
                mask[i] = missing[i] || !v.visible[i];
                pts[i] = Vector2::new(v.points[i][0], v.points[i][1]);
            }
            let Some((phi, f)) = self.features(&pts, &all, &mask) else {
                continue;
            };
            ff.syger(1.0, &f, &f, 1.0);
            let target =
                nalgebra::Vector3::new(v.angles.yaw, v.angles.pitch, wrap180(v.angles.roll - phi));
            tf.ger(1.0, &target, &f, 1.0);
            used += 1;
        }
        if used < 3 {
            return Err(Error::too_few(
                "training views usable with these points",
                3,
                used,
            ));
        }
        ff.fill_upper_triangle_with_lower_triangle();
        let stats = Arc::new(Stats { ff, tf, used });
        insert_bounded(&self.stats_cache, k, stats.clone());
        Ok(stats)
    }

    /// The ridge solution of bin `b` for a missing pattern and ridge parameter `epsilon`.
    fn solve(&self, b: usize, missing: &[bool], epsilon: f64) -> Result<Arc<Solution>> {
        let k = (b, key(missing));
        if epsilon == self.epsilon
            && let Some(s) = self.cache.lock().unwrap_or_else(|e| e.into_inner()).get(&k)
        {
            return Ok(s.clone());
        }
        let st = self.stats(b, missing)?;
        let d = st.ff.nrows();
        let mut ff = st.ff.clone();
        for i in 0..d - 1 {
            ff[(i, i)] += epsilon * st.used as f64;
        }
        // The intercept is not penalized beyond a tiny jitter.
        ff[(d - 1, d - 1)] += 1e-12 * st.used as f64;
        let chol = ff
            .cholesky()
            .ok_or_else(|| Error::Numerical("the ridge system is not positive definite".into()))?;
        let sol = Arc::new(Solution {
            w: chol.solve(&st.tf.transpose()).transpose(),
        });
        if epsilon == self.epsilon {
            insert_bounded(&self.cache, k, sol.clone());
        }
        Ok(sol)
    }

    /// The stored solution for the pattern with every point present, per bin (rows of length
    /// `2n + 1`): the paper's regression matrices.
    pub fn full_pattern_matrices(&self) -> Result<Vec<DMatrix<f64>>> {
        let none = vec![false; self.n_points];
        (0..self.bins.len())
            .map(|b| Ok(self.solve(b, &none, self.epsilon)?.w.clone()))
            .collect()
    }

    /// Seeds the all-present solutions (as stored in a bundle) so that they are not re-solved.
    pub fn seed_full_pattern(&self, matrices: Vec<DMatrix<f64>>) -> Result<()> {
        if matrices.len() != self.bins.len() {
            return Err(Error::param(
                "regression matrices",
                format!("{} for {} bins", matrices.len(), self.bins.len()),
            ));
        }
        let none = vec![false; self.n_points];
        for (b, w) in matrices.into_iter().enumerate() {
            if w.nrows() != 3
                || w.ncols() != 2 * self.n_points + 1
                || w.iter().any(|v| !v.is_finite())
            {
                return Err(Error::param(
                    "regression matrices",
                    format!(
                        "bin {b}: {}x{}, expected 3x{}",
                        w.nrows(),
                        w.ncols(),
                        2 * self.n_points + 1
                    ),
                ));
            }
            insert_bounded(&self.cache, (b, key(&none)), Arc::new(Solution { w }));
        }
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn predict(
        &self,
        b: usize,
        points: &[Vector2<f64>],
        absent: &[bool],
        missing: &[bool],
        epsilon: f64,
    ) -> Result<EulerAngles> {
        let (phi, f) = self.features(points, absent, missing).ok_or_else(|| {
            Error::Degenerate("regression needs both eyes and two or more distinct points".into())
        })?;
        let sol = self.solve(b, missing, epsilon)?;
        let out = &sol.w * f;
        // The de-rolled shape looks like the roll-free pose Rx(pitch) Ry(yaw) turned in the
        // image plane by out[2]; undoing the de-roll turns it by φ more: R = Rz(φ + δ) Rx Ry.
        let roll_free = EulerAngles {
            yaw: out[0],
            pitch: out[1],
            roll: 0.0,
        }
        .to_rotation();
        let in_plane = EulerAngles {
            yaw: 0.0,
            pitch: 0.0,
            roll: phi + out[2],
        }
        .to_rotation();
        Ok(EulerAngles::from_rotation(&(in_plane * roll_free)))
    }

    /// Estimates the pose of `landmarks` (image pixels) with `missing` as the points to ignore
    /// in addition to the shape's own missing ones; `hidden_at` gives the points hidden at a
    /// pose (HPR), for the second pass.
    pub fn estimate(
        &self,
        landmarks: &Shape2,
        hidden_at: &dyn Fn(&EulerAngles) -> Vec<bool>,
    ) -> Result<RegressionEstimate> {
        self.estimate_with(landmarks, hidden_at, self.epsilon)
    }

    /// [`RegressionModel::estimate`] with another ridge parameter (for choosing it: the
    /// sufficient statistics are shared, only the small solve is repeated).
    pub fn estimate_with(
        &self,
        landmarks: &Shape2,
        hidden_at: &dyn Fn(&EulerAngles) -> Vec<bool>,
        epsilon: f64,
    ) -> Result<RegressionEstimate> {
        if landmarks.len() != self.n_points {
            return Err(Error::PointCount {
                what: "landmarks".into(),
                expected: self.n_points,
                got: landmarks.len(),
            });
        }
        let points = landmarks.points();
        let missing: Vec<bool> = landmarks.present().iter().map(|p| !p).collect();
        // Coarse pass on bin 0, then the fine bin that holds it.
        let coarse = self.predict(0, points, &missing, &missing, epsilon)?;
        let bin = self.pick_bin(&coarse);
        let first = if bin == 0 {
            coarse
        } else {
            self.predict(bin, points, &missing, &missing, epsilon)?
        };
        let hidden = hidden_at(&first);
        let mut second_missing = missing.clone();
        for (m, h) in second_missing.iter_mut().zip(&hidden) {
            *m |= *h;
        }
        // An empty answer means: no second pass.
        if second_missing == missing || second_missing.iter().filter(|m| !**m).count() < 3 {
            return Ok(RegressionEstimate { angles: first, bin });
        }
        let angles = self.predict(bin, points, &missing, &second_missing, epsilon)?;
        Ok(RegressionEstimate { angles, bin })
    }

    fn pick_bin(&self, a: &EulerAngles) -> usize {
        if self.bins.len() == 1 {
            return 0;
        }
        (1..self.bins.len())
            .min_by(|&i, &j| {
                let d = |b: usize| {
                    let g = &self.bins[b].grid;
                    (a.yaw - 0.5 * (g.yaw.min + g.yaw.max)).abs()
                        + (a.pitch - 0.5 * (g.pitch.min + g.pitch.max)).abs()
                };
                d(i).total_cmp(&d(j))
            })
            .unwrap_or(0)
    }
}

fn wrap180(d: f64) -> f64 {
    let r = (d + 180.0).rem_euclid(360.0) - 180.0;
    if r == -180.0 { 180.0 } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hpr::PaperHpr;
    use crate::synth::{AngleRange, ViewSynthesizer};
    use nalgebra::Vector3;

    fn face() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(-32.0, 35.0, 0.0),
            Vector3::new(32.0, 35.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 8.0),
            Vector3::new(25.0, -30.0, 8.0),
            Vector3::new(-60.0, 10.0, -60.0),
            Vector3::new(60.0, 10.0, -60.0),
            Vector3::new(0.0, -70.0, 10.0),
            Vector3::new(0.0, 40.0, 20.0),
            Vector3::new(-15.0, 50.0, 10.0),
        ]
    }

    fn bin(grid: PoseGrid) -> ViewBin {
        let shape = face();
        let hpr = PaperHpr::from_frontal(&shape).unwrap();
        let mut synth = ViewSynthesizer::new(&shape, &hpr).unwrap();
        let views = synth
            .views(&grid)
            .map(|v| {
                let v = v.unwrap();
                TrainingView {
                    angles: v.angles,
                    points: v.projected.iter().map(|p| [p.x, p.y]).collect(),
                    visible: vec![true; 10],
                }
            })
            .collect();
        ViewBin { grid, views }
    }

    fn model() -> RegressionModel {
        let g = PoseGrid {
            yaw: AngleRange::new(-30.0, 30.0, 2.0).unwrap(),
            pitch: AngleRange::new(-30.0, 30.0, 2.0).unwrap(),
            roll: AngleRange::fixed(0.0),
        };
        RegressionModel::new(10, vec![0], vec![1], vec![bin(g)], 1e-6).unwrap()
    }

    fn view(a: EulerAngles, s: f64) -> Shape2 {
        let cam =
            crate::geometry::WeakPerspective::new(a.to_rotation(), s, Vector2::new(300.0, -200.0))
                .unwrap();
        Shape2::full(face().iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    #[test]
    fn recovers_poses_of_its_own_shape_including_roll() {
        let m = model();
        let none = |_: &EulerAngles| vec![false; 10];
        for (yaw, pitch, roll) in [
            (0.0, 0.0, 0.0),
            (13.0, -7.0, 0.0),
            (-21.0, 17.0, 25.0),
            (18.0, 12.0, -40.0),
        ] {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let e = m.estimate(&view(a, 3.0), &none).unwrap().angles;
            assert!(
                (e.yaw - yaw).abs() < 1.5 && (e.pitch - pitch).abs() < 1.5,
                "{a:?} -> {e:?}"
            );
            assert!((e.roll - roll).abs() < 1.5, "{a:?} -> {e:?}");
        }
    }

    #[test]
    fn a_missing_point_does_not_bias_the_estimate() {
        let m = model();
        let none = |_: &EulerAngles| vec![false; 10];
        let a = EulerAngles::new(12.0, -9.0, 0.0).unwrap();
        let full = m.estimate(&view(a, 2.0), &none).unwrap().angles;
        let part = m
            .estimate(&view(a, 2.0).with_missing([2, 7]), &none)
            .unwrap()
            .angles;
        assert!(
            (full.yaw - part.yaw).abs() < 1.0 && (full.pitch - part.pitch).abs() < 1.0,
            "{full:?} vs {part:?}"
        );
        assert_eq!(m.cache.lock().unwrap().len(), 2);
    }

    #[test]
    fn missing_eyes_is_an_error() {
        let none = |_: &EulerAngles| vec![false; 10];
        let v = view(EulerAngles::new(0.0, 0.0, 0.0).unwrap(), 2.0).with_missing([0]);
        assert!(model().estimate(&v, &none).is_err());
    }
}
