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
//!   centre is nearest its estimate, out to profile views.

mod cache;

use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{DMatrix, DVector, Rotation3, Vector2};
use serde::{Deserialize, Serialize};

use self::cache::{BoundedCache, Key, Pattern};
use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::geometry::convention::{rx, ry, rz, wrap_deg};
use crate::shape::Shape2;
use crate::synth::PoseGrid;

/// One synthetic training view: pose, projected points (image frame, unit scale) and visibility.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingView {
    /// The view's pose, degrees.
    pub angles: EulerAngles,
    /// Projected points, image frame (y down), unit scale.
    pub points: Vec<[f64; 2]>,
    /// Per point, whether HPR finds it visible.
    pub visible: Vec<bool>,
}

/// The training views of one pose range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewBin {
    /// The pose range the views cover.
    pub grid: PoseGrid,
    /// The views.
    pub views: Vec<TrainingView>,
}

/// A ridge solution for one bin and missing pattern: `[yaw, pitch, roll - φ] = W [f; 1]`, with
/// the sums of its point columns over the pattern's points, so that a query can be centred and
/// normalized on the fly instead of building its feature vector.
#[derive(Debug, Clone)]
struct Solution {
    /// `3 x (2n + 1)`, column-major: point `i`'s six weights are contiguous at `6i..6i + 6`.
    w: DMatrix<f64>,
    sum_x: [f64; 3],
    sum_y: [f64; 3],
}

impl Solution {
    fn new(w: DMatrix<f64>, missing: &[bool]) -> Self {
        let (mut sum_x, mut sum_y) = ([0.0; 3], [0.0; 3]);
        let ws = w.as_slice();
        for (i, &m) in missing.iter().enumerate() {
            if !m {
                for j in 0..3 {
                    sum_x[j] += ws[6 * i + j];
                    sum_y[j] += ws[6 * i + 3 + j];
                }
            }
        }
        Solution { w, sum_x, sum_y }
    }
}

/// Sufficient statistics of one bin under one missing pattern.
#[derive(Debug)]
struct Stats {
    ff: DMatrix<f64>,
    tf: DMatrix<f64>,
    used: usize,
}

/// Solutions kept per (bin, ε, pattern); the oldest go first.
const SOLUTION_LIMIT: usize = 1024;
/// Sufficient statistics kept: `(2n + 1)²` numbers each, so few.
const STATS_LIMIT: usize = 8;

/// The regression over one scheme's points, with its view bins.
#[derive(Debug)]
pub struct RegressionModel {
    n_points: usize,
    eye_left: Vec<usize>,
    eye_right: Vec<usize>,
    /// Bin 0 is the coarse model over the whole range; the others are the fine bins.
    bins: Vec<ViewBin>,
    epsilon: f64,
    /// The all-points-present solution of each bin at `epsilon`: the common query, lock-free.
    full: Vec<OnceLock<Arc<Solution>>>,
    cache: BoundedCache<Solution>,
    stats_cache: BoundedCache<Stats>,
    /// Serializes the computation of new statistics, so that a burst of queries with one new
    /// pattern computes it once.
    building: Mutex<()>,
}

/// A regression answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegressionEstimate {
    /// Rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// Which bin answered.
    pub bin: usize,
}

/// The raw output of one bin: yaw and pitch of the roll-free pose and the in-plane residual.
#[derive(Debug, Clone, Copy)]
struct RollFree {
    yaw: f64,
    pitch: f64,
    delta: f64,
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
        check_epsilon(epsilon)?;
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
        let full = (0..bins.len()).map(|_| OnceLock::new()).collect();
        Ok(RegressionModel {
            n_points,
            eye_left,
            eye_right,
            bins,
            epsilon,
            full,
            cache: BoundedCache::new(SOLUTION_LIMIT),
            stats_cache: BoundedCache::new(STATS_LIMIT),
            building: Mutex::new(()),
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
        check_epsilon(epsilon)?;
        self.epsilon = epsilon;
        self.full = (0..self.bins.len()).map(|_| OnceLock::new()).collect();
        self.cache.clear();
        Ok(())
    }

    /// Number of points of the scheme it works on.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// Solutions cached for patterns other than all-present (for tests and metrics).
    pub fn cached_patterns(&self) -> usize {
        self.cache.len()
    }

    /// The eye-line angle φ (degrees, clockwise on screen; eyes from the points not flagged in
    /// `eyes_from`) and the de-rolled, centred, energy-normalized feature vector with the
    /// `missing` points zeroed and `1` appended; `None` when an eye or the shape is missing.
    /// Training builds its vectors with it; queries compute the same thing on the fly.
    fn features(
        &self,
        points: &[Vector2<f64>],
        eyes_from: &[bool],
        missing: &[bool],
    ) -> Option<(f64, DVector<f64>)> {
        let phi = self.eye_line(points, eyes_from)?;
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

    /// The eye-line angle in radians (image frame: clockwise on screen), eyes from the points
    /// not flagged in `absent`.
    fn eye_line(&self, points: &[Vector2<f64>], absent: &[bool]) -> Option<f64> {
        let anchor = |idx: &[usize]| {
            let (mut s, mut k) = (Vector2::zeros(), 0);
            for &i in idx {
                if !absent[i] {
                    s += points[i];
                    k += 1;
                }
            }
            (k > 0).then(|| s / k as f64)
        };
        let d = anchor(&self.eye_right)? - anchor(&self.eye_left)?;
        (d.norm_squared() > 0.0).then(|| d.y.atan2(d.x))
    }

    /// The sufficient statistics `(F Fᵀ, T Fᵀ, count)` of bin `b` for a missing pattern: every
    /// training view re-normalized with the pattern's points zeroed, plus its own hidden points.
    fn stats(&self, b: usize, missing: &[bool]) -> Result<Arc<Stats>> {
        let key = Key {
            bin: b,
            epsilon_bits: 0,
            pattern: Pattern::of(missing),
        };
        if let Some(s) = self.stats_cache.get(&key) {
            return Ok(s);
        }
        let d = 2 * self.n_points + 1;
        let views = &self.bins[b].views;
        // The feature vectors as the columns of F and the targets as the columns of T; the
        // statistics are then two matrix products (blocked and vectorized), far faster than
        // one rank-one update per view.
        let mut f_all = DMatrix::<f64>::zeros(d, views.len());
        let mut t_all = DMatrix::<f64>::zeros(3, views.len());
        let mut used = 0;
        let mut mask = vec![false; self.n_points];
        let mut pts = vec![Vector2::zeros(); self.n_points];
        // The eye line of a training view comes from all its projected eye points, as a client
        // that sends both eyes gives it.
        let all = vec![false; self.n_points];
        for v in views {
            for i in 0..self.n_points {
                mask[i] = missing[i] || !v.visible[i];
                pts[i] = Vector2::new(v.points[i][0], v.points[i][1]);
            }
            let Some((phi, f)) = self.features(&pts, &all, &mask) else {
                continue;
            };
            f_all.column_mut(used).copy_from(&f);
            t_all[(0, used)] = v.angles.yaw;
            t_all[(1, used)] = v.angles.pitch;
            t_all[(2, used)] = wrap_deg(v.angles.roll - phi);
            used += 1;
        }
        if used < 3 {
            return Err(Error::too_few(
                "training views usable with these points",
                3,
                used,
            ));
        }
        let f_used = f_all.columns(0, used);
        let ff = f_used * f_used.transpose();
        let tf = t_all.columns(0, used) * f_used.transpose();
        let stats = Arc::new(Stats { ff, tf, used });
        self.stats_cache.insert(key, stats.clone());
        Ok(stats)
    }

    /// The ridge solution of bin `b` for a missing pattern and ridge parameter `epsilon`:
    /// cached per (bin, ε, pattern); the all-present one at the model's ε without a lock.
    fn solution(&self, b: usize, missing: &[bool], epsilon: f64) -> Result<Arc<Solution>> {
        let all_present = !missing.iter().any(|&m| m);
        if all_present
            && epsilon == self.epsilon
            && let Some(s) = self.full[b].get()
        {
            return Ok(s.clone());
        }
        let key = Key {
            bin: b,
            epsilon_bits: epsilon.to_bits(),
            pattern: Pattern::of(missing),
        };
        if let Some(s) = self.cache.get(&key) {
            return Ok(s);
        }
        // One builder at a time; another may have finished while this one waited.
        let _guard = self.building.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = self.cache.get(&key) {
            return Ok(s);
        }
        let sol = Arc::new(Solution::new(self.solve(b, missing, epsilon)?, missing));
        if all_present && epsilon == self.epsilon {
            let _ = self.full[b].set(sol.clone());
        } else {
            self.cache.insert(key, sol.clone());
        }
        Ok(sol)
    }

    /// Solves the ridge system (paper eq. 18) of bin `b` for a pattern.
    fn solve(&self, b: usize, missing: &[bool], epsilon: f64) -> Result<DMatrix<f64>> {
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
        Ok(chol.solve(&st.tf.transpose()).transpose())
    }

    /// The all-present solution per bin (rows of length `2n + 1`): the paper's regression
    /// matrices, as a bundle stores them.
    pub fn full_pattern_matrices(&self) -> Result<Vec<DMatrix<f64>>> {
        let none = vec![false; self.n_points];
        (0..self.bins.len())
            .map(|b| Ok(self.solution(b, &none, self.epsilon)?.w.clone()))
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
            let _ = self.full[b].set(Arc::new(Solution::new(w, &none)));
        }
        Ok(())
    }

    /// Applies a solution to de-rolled points (`derolled[i]`, zero where `missing`; `present`
    /// of them): the query is centred and energy-normalized over its present points on the
    /// fly, exactly as [`Self::features`] builds training vectors. Zeroed points add nothing to
    /// any sum, so the loop needs no branch.
    fn apply(sol: &Solution, derolled: &[[f64; 2]], present: usize) -> Option<RollFree> {
        if present < 2 {
            return None;
        }
        let ws = sol.w.as_slice();
        let n = derolled.len();
        let (mut sx, mut sy, mut sq) = (0.0, 0.0, 0.0);
        let mut dot = [0.0; 3];
        for (p, wi) in derolled.iter().zip(ws.chunks_exact(6)) {
            let [x, y] = *p;
            dot[0] += wi[0] * x + wi[3] * y;
            dot[1] += wi[1] * x + wi[4] * y;
            dot[2] += wi[2] * x + wi[5] * y;
            sx += x;
            sy += y;
            sq += x * x + y * y;
        }
        let k = present as f64;
        let (cx, cy) = (sx / k, sy / k);
        let norm2 = sq - k * (cx * cx + cy * cy);
        // Relative to the points' spread from the origin, so that a shape far from the image
        // origin is not called degenerate by rounding.
        if norm2.is_nan() || norm2 <= 1e-18 * sq.max(1e-300) {
            return None;
        }
        let inv = 1.0 / norm2.sqrt();
        let out: [f64; 3] = std::array::from_fn(|j| {
            (dot[j] - cx * sol.sum_x[j] - cy * sol.sum_y[j]) * inv + ws[6 * n + j]
        });
        Some(RollFree {
            yaw: out[0],
            pitch: out[1],
            delta: out[2],
        })
    }

    /// Estimates the pose of `landmarks` (image pixels; missing points ignored). `hidden_at`
    /// marks in its buffer the points hidden at a roll-free (yaw, pitch) (HPR), for the second
    /// pass.
    pub fn estimate(
        &self,
        landmarks: &Shape2,
        hidden_at: &dyn Fn(f64, f64, &mut [bool]),
    ) -> Result<RegressionEstimate> {
        self.estimate_with(landmarks, hidden_at, self.epsilon)
    }

    /// [`RegressionModel::estimate`] with another ridge parameter (for choosing it: the
    /// sufficient statistics are shared, only the small solve is repeated).
    pub fn estimate_with(
        &self,
        landmarks: &Shape2,
        hidden_at: &dyn Fn(f64, f64, &mut [bool]),
        epsilon: f64,
    ) -> Result<RegressionEstimate> {
        let n = self.n_points;
        if landmarks.len() != n {
            return Err(Error::PointCount {
                what: "landmarks".into(),
                expected: n,
                got: landmarks.len(),
            });
        }
        SCRATCH.with(|cell| match cell.try_borrow_mut() {
            Ok(mut scratch) => {
                scratch.prepare(n);
                self.query(landmarks, hidden_at, epsilon, &mut scratch)
            }
            // Re-entered from `hidden_at`: use fresh buffers.
            Err(_) => {
                let mut scratch = Scratch::default();
                scratch.prepare(n);
                self.query(landmarks, hidden_at, epsilon, &mut scratch)
            }
        })
    }

    fn query(
        &self,
        landmarks: &Shape2,
        hidden_at: &dyn Fn(f64, f64, &mut [bool]),
        epsilon: f64,
        scratch: &mut Scratch,
    ) -> Result<RegressionEstimate> {
        let degenerate = || {
            Error::Degenerate("regression needs both eyes and two or more distinct points".into())
        };
        let Scratch {
            missing,
            derolled,
            hidden,
        } = scratch;
        let points = landmarks.points();
        for (m, p) in missing.iter_mut().zip(landmarks.present()) {
            *m = !p;
        }
        let phi = self.eye_line(points, missing).ok_or_else(degenerate)?;
        let (s, c) = phi.sin_cos();
        let mut present = 0;
        for ((d, p), &m) in derolled.iter_mut().zip(points).zip(missing.iter()) {
            *d = if m {
                [0.0; 2]
            } else {
                present += 1;
                [c * p.x + s * p.y, -s * p.x + c * p.y]
            };
        }
        // Coarse pass on bin 0: it picks the fine bin and the points hidden at its pose (HPR),
        // which join the missing ones for the fine pass (when enough points stay).
        let coarse = Self::apply(&*self.solution(0, missing, epsilon)?, derolled, present)
            .ok_or_else(degenerate)?;
        let bin = self.pick_bin(coarse.yaw, coarse.pitch);
        hidden_at(coarse.yaw, coarse.pitch, hidden);
        let newly = hidden
            .iter()
            .zip(missing.iter())
            .filter(|(h, m)| **h && !**m)
            .count();
        let grows = newly > 0 && present - newly >= 3;
        if grows {
            for ((m, d), &h) in missing
                .iter_mut()
                .zip(derolled.iter_mut())
                .zip(hidden.iter())
            {
                if h && !*m {
                    *m = true;
                    *d = [0.0; 2];
                }
            }
            present -= newly;
        }
        let result = if bin == 0 && !grows {
            coarse
        } else {
            Self::apply(&*self.solution(bin, missing, epsilon)?, derolled, present)
                .ok_or_else(degenerate)?
        };
        Ok(RegressionEstimate {
            rotation: compose(phi.to_degrees() + result.delta, result.pitch, result.yaw),
            bin,
        })
    }

    /// The fine bin whose centre is nearest the coarse estimate. A fine bin extrapolating a
    /// little past its grid (a face at 50° of pitch, fine grids to 40°) still beats the coarse
    /// model there: falling back to the coarse model outside every fine grid raised the
    /// regression's error at |yaw| > 60° on AFLW2000-3D (fitted landmarks) from 18° to 21°
    /// (the coarse pitch is loose in profile).
    fn pick_bin(&self, yaw: f64, pitch: f64) -> usize {
        let centre_distance = |b: usize| {
            let g = &self.bins[b].grid;
            (yaw - 0.5 * (g.yaw.min + g.yaw.max)).abs()
                + (pitch - 0.5 * (g.pitch.min + g.pitch.max)).abs()
        };
        (1..self.bins.len())
            .min_by(|&i, &j| centre_distance(i).total_cmp(&centre_distance(j)))
            .unwrap_or(0)
    }
}

/// Per-thread buffers of the query path, so that a query does not allocate.
#[derive(Default)]
struct Scratch {
    missing: Vec<bool>,
    derolled: Vec<[f64; 2]>,
    hidden: Vec<bool>,
}

impl Scratch {
    fn prepare(&mut self, n: usize) {
        self.missing.clear();
        self.missing.resize(n, false);
        self.derolled.clear();
        self.derolled.resize(n, [0.0; 2]);
        self.hidden.clear();
        self.hidden.resize(n, false);
    }
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// `Rz(in_plane) · Rx(pitch) · Ry(yaw)`: the de-rolled shape looks like the roll-free pose
/// turned in the image plane by the regression's residual; undoing the de-roll turns it by the
/// eye-line angle more (angles in degrees, the convention's matrices).
fn compose(in_plane: f64, pitch: f64, yaw: f64) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(rz(in_plane) * rx(pitch) * ry(yaw))
}

fn check_epsilon(epsilon: f64) -> Result<()> {
    if epsilon.is_finite() && epsilon > 0.0 {
        Ok(())
    } else {
        Err(Error::param(
            "epsilon",
            format!("must be positive, got {epsilon}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hpr::PaperHpr;
    use crate::synth::{AngleRange, ViewSynthesizer};
    use nalgebra::Vector3;

    fn face() -> Vec<Vector3<f64>> {
        crate::test_faces::face(10)
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
        let none = |_: f64, _: f64, _: &mut [bool]| {};
        for (yaw, pitch, roll) in [
            (0.0, 0.0, 0.0),
            (13.0, -7.0, 0.0),
            (-21.0, 17.0, 25.0),
            (18.0, 12.0, -40.0),
        ] {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let e = EulerAngles::from_rotation(&m.estimate(&view(a, 3.0), &none).unwrap().rotation);
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
        let none = |_: f64, _: f64, _: &mut [bool]| {};
        let a = EulerAngles::new(12.0, -9.0, 0.0).unwrap();
        let angles =
            |s: &Shape2| EulerAngles::from_rotation(&m.estimate(s, &none).unwrap().rotation);
        let full = angles(&view(a, 2.0));
        let part = angles(&view(a, 2.0).with_missing([2, 7]));
        assert!(
            (full.yaw - part.yaw).abs() < 1.0 && (full.pitch - part.pitch).abs() < 1.0,
            "{full:?} vs {part:?}"
        );
        // One new pattern solved (the all-present one is not in the pattern cache).
        assert_eq!(m.cached_patterns(), 1);
    }

    #[test]
    fn missing_eyes_is_an_error() {
        let none = |_: f64, _: f64, _: &mut [bool]| {};
        let v = view(EulerAngles::new(0.0, 0.0, 0.0).unwrap(), 2.0).with_missing([0]);
        assert!(model().estimate(&v, &none).is_err());
    }
}
