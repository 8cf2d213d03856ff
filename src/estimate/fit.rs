//! Rigid weak-perspective fit of a 3D shape to 2D landmarks (beyond the paper).
//!
//! Minimizes `Σ wᵢ ‖s · P R Xᵢ + t - yᵢ‖²` over the rotation `R`, scale `s` and translation `t`,
//! where `yᵢ = (uᵢ, -vᵢ)` are the landmarks in the y-up plane and `P` drops z:
//! 1. closed-form start: the least-squares affine camera, projected onto the nearest scaled
//!    orthographic one (polar decomposition), its third row the cross product of the first two;
//! 2. Levenberg-Marquardt on `(ω, s, t)` with `R ← exp([ω]×) R`;
//! 3. robust: iteratively reweighted with Tukey's biweight on the residuals (scale from the
//!    median absolute residual, floored at 1% of the face size), so one or two wild points stop
//!    pulling;
//! 4. HPR-aware ([`Hidden`]): points that the visibility map calls hidden at the current
//!    estimate get weight zero (all of them, or only the contour points, the jaw of ibug68, which
//!    2D-style annotations put on the visible outline instead of their 3D place), and the fit is
//!    redone until the visible set settles. Visible contour points weigh `contour_weight`.

use nalgebra::{Matrix2x3, Matrix3, Matrix6, Rotation3, Vector2, Vector3, Vector6};

use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::geometry::{image_to_plane, rotation_from_two_rows};
use crate::shape::Shape2;

/// What the fit does with points hidden at its estimate (HPR on the shape, through a
/// visibility map over the same points).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Hidden {
    /// Keep them: every landmark is the projection of its 3D point, seen or not (3D-style
    /// annotations and 3DMM fits: AFLW2000-3D, 3DDFA, FAN-3D).
    #[default]
    Keep,
    /// Drop hidden contour points only: 2D-style annotations (300-W, dlib, FAN-2D) put them on
    /// the visible outline.
    DropContour,
    /// Drop every hidden point.
    DropAll,
}

/// Options of [`fit_rigid`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Tukey reweighting against wild points.
    pub robust: bool,
    /// Points hidden at the estimate (used only with a visibility map).
    pub hidden: Hidden,
    /// Weight of visible contour points relative to the others.
    pub contour_weight: f64,
    /// Levenberg-Marquardt iterations per weighting round.
    pub iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            robust: true,
            hidden: Hidden::Keep,
            contour_weight: 1.0,
            iterations: 8,
        }
    }
}

/// The fitted camera.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidFit {
    pub rotation: Rotation3<f64>,
    /// Pixels per model unit.
    pub scale: f64,
    /// In the y-up plane: `[u, -v] = s (R X)[0:2] + t`.
    pub translation: Vector2<f64>,
    /// Final weight of each point (0 for missing, hidden or rejected points).
    pub weights: Vec<f64>,
    /// Weighted RMS reprojection error in pixels.
    pub rms_px: f64,
}

/// Fits `model` (model frame) to `landmarks` (image pixels; missing points ignored).
pub fn fit_rigid(
    model: &[Vector3<f64>],
    landmarks: &Shape2,
    contour: &[usize],
    visibility: Option<&VisibilityMap>,
    opts: FitOptions,
) -> Result<RigidFit> {
    let n = model.len();
    if landmarks.len() != n {
        return Err(Error::PointCount {
            what: "landmarks".into(),
            expected: n,
            got: landmarks.len(),
        });
    }
    let present = landmarks.n_present();
    if present < 4 {
        return Err(Error::too_few("rigid fit", 4, present));
    }
    let y: Vec<Vector2<f64>> = landmarks.points().iter().map(image_to_plane).collect();
    let present = landmarks.present();
    let mut base: Vec<f64> = present.iter().map(|&p| f64::from(u8::from(p))).collect();
    if opts.contour_weight != 1.0 {
        for &i in contour.iter().filter(|&&i| i < n && present[i]) {
            base[i] = opts.contour_weight;
        }
    }
    let mut weights = base.clone();
    let (mut r, mut s, mut t) = affine_start(model, &y, &weights)?;
    let size = model_size(model, &weights);
    (r, s, t) = gauss_newton(model, &y, &weights, r, s, t, opts.iterations);

    // HPR: drop the points hidden at the estimate, refit until the visible set settles.
    let mut hidden: Option<&[bool]> = None;
    let map = visibility.filter(|m| opts.hidden != Hidden::Keep && m.n_points() == n);
    if let Some(map) = map {
        for _ in 0..3 {
            let now = map.lookup(&r);
            if hidden == Some(now) {
                break;
            }
            hidden = Some(now);
            for i in 0..n {
                let droppable = opts.hidden == Hidden::DropAll || contour.contains(&i);
                weights[i] = if now[i] || !droppable { base[i] } else { 0.0 };
            }
            if weights.iter().filter(|&&w| w > 0.0).count() < 4 {
                weights.clone_from(&base);
                break;
            }
            (r, s, t) = gauss_newton(model, &y, &weights, r, s, t, opts.iterations);
        }
    }
    // Robustness: Tukey reweighting, only when some residual stands out.
    if opts.robust {
        let before = weights.clone();
        for _ in 0..2 {
            weights.clone_from(&before);
            if !tukey_reweight(model, &y, &mut weights, &r, s, &t, 0.01 * s * size) {
                break;
            }
            if weights.iter().filter(|&&w| w > 0.0).count() < 4 {
                weights.clone_from(&before);
                break;
            }
            (r, s, t) = gauss_newton(model, &y, &weights, r, s, t, opts.iterations);
        }
    }
    let rms_px = weighted_rms(model, &y, &weights, &r, s, &t);
    if !(rms_px.is_finite() && s.is_finite() && s > 0.0) {
        return Err(Error::Numerical("the rigid fit diverged".into()));
    }
    Ok(RigidFit {
        rotation: r,
        scale: s,
        translation: t,
        weights,
        rms_px,
    })
}

/// Root of the weighted mean squared distance of the model points to their weighted centroid.
pub(crate) fn model_size(model: &[Vector3<f64>], w: &[f64]) -> f64 {
    let sw: f64 = w.iter().sum();
    let c = model
        .iter()
        .zip(w)
        .map(|(x, &w)| x * w)
        .sum::<Vector3<f64>>()
        / sw;
    (model
        .iter()
        .zip(w)
        .map(|(x, &w)| w * (x - c).norm_squared())
        .sum::<f64>()
        / sw)
        .sqrt()
}

fn affine_start(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
) -> Result<(Rotation3<f64>, f64, Vector2<f64>)> {
    let sw: f64 = w.iter().sum();
    let cx = model
        .iter()
        .zip(w)
        .map(|(x, &w)| x * w)
        .sum::<Vector3<f64>>()
        / sw;
    let cy = y.iter().zip(w).map(|(p, &w)| p * w).sum::<Vector2<f64>>() / sw;
    let mut xx = Matrix3::zeros();
    let mut yx = Matrix2x3::zeros();
    let mut spread = 0.0;
    for ((x, p), &wi) in model.iter().zip(y).zip(w) {
        if wi > 0.0 {
            let (dx, dp) = (x - cx, p - cy);
            xx += wi * dx * dx.transpose();
            yx += wi * dp * dx.transpose();
            spread += wi * dp.norm_squared();
        }
    }
    if !spread.is_finite() {
        return Err(Error::non_finite("landmarks"));
    }
    let inv = xx
        .try_inverse()
        .ok_or_else(|| Error::Degenerate("the model points in use are coplanar".into()))?;
    let a = yx * inv;
    // Polar decomposition of the 2x3 camera: A = S^½ [r1; r2] with S = A Aᵀ (2x2), in closed form.
    let m = a * a.transpose();
    let (tr, det) = (m.trace(), m.determinant());
    if spread <= 1e-18 || det.is_nan() || det <= 1e-18 * tr * tr {
        return Err(Error::Degenerate(
            "the landmarks are all at one place or on one line".into(),
        ));
    }
    let sq = det.sqrt();
    let root_sum = (tr + 2.0 * sq).sqrt(); // σ1 + σ2
    // (S^½)⁻¹ = (S + √det I)⁻¹ · (σ1 + σ2).
    let inv_sqrt = (m + nalgebra::Matrix2::identity() * sq)
        .try_inverse()
        .ok_or_else(|| Error::Numerical("polar decomposition failed".into()))?
        * root_sum;
    let rows = inv_sqrt * a;
    let rot = rotation_from_two_rows(&rows.row(0).transpose(), &rows.row(1).transpose());
    let s = 0.5 * root_sum;
    let t = cy - s * (rot * cx).xy();
    Ok((rot, s, t))
}

/// Cost, `JᵀWJ` and `JᵀWr` at `(r, s, t)` in one pass over the points.
///
/// With `q = R X`, `a = s q_z`, `b = s q_y`, `c = s q_x`, the two Jacobian rows of a point are
/// `jx = (0, a, -b, q_x, 1, 0)` and `jy = (-a, 0, c, q_y, 0, 1)` (rotation `ω`, then `s`, `t`);
/// their sparsity leaves 14 distinct sums, accumulated directly.
fn normal_equations(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
) -> (f64, Matrix6<f64>, Vector6<f64>) {
    let m = r.matrix();
    let (mut cost, mut aa, mut ac, mut aqy, mut sa, mut ab, mut aqx, mut bbcc) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut cross, mut sb, mut sc, mut qq, mut sqx, mut sqy, mut sw) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut g = [0.0; 6];
    for ((x, p), &wi) in model.iter().zip(y).zip(w) {
        if wi == 0.0 {
            continue;
        }
        let qx = m[(0, 0)] * x.x + m[(0, 1)] * x.y + m[(0, 2)] * x.z;
        let qy = m[(1, 0)] * x.x + m[(1, 1)] * x.y + m[(1, 2)] * x.z;
        let qz = m[(2, 0)] * x.x + m[(2, 1)] * x.y + m[(2, 2)] * x.z;
        let (rx, ry) = (s * qx + t.x - p.x, s * qy + t.y - p.y);
        let (a, b, c) = (s * qz, s * qy, s * qx);
        cost += wi * (rx * rx + ry * ry);
        aa += wi * a * a;
        ac += wi * a * c;
        aqy += wi * a * qy;
        sa += wi * a;
        ab += wi * a * b;
        aqx += wi * a * qx;
        bbcc += wi * (b * b + c * c);
        cross += wi * (c * qy - b * qx);
        sb += wi * b;
        sc += wi * c;
        qq += wi * (qx * qx + qy * qy);
        sqx += wi * qx;
        sqy += wi * qy;
        sw += wi;
        g[0] -= wi * a * ry;
        g[1] += wi * a * rx;
        g[2] += wi * (c * ry - b * rx);
        g[3] += wi * (qx * rx + qy * ry);
        g[4] += wi * rx;
        g[5] += wi * ry;
    }
    #[rustfmt::skip]
    let jtj = Matrix6::new(
        aa,   0.0,  -ac,   -aqy,  0.0, -sa,
        0.0,  aa,   -ab,   aqx,   sa,  0.0,
        -ac,  -ab,  bbcc,  cross, -sb, sc,
        -aqy, aqx,  cross, qq,    sqx, sqy,
        0.0,  sa,   -sb,   sqx,   sw,  0.0,
        -sa,  0.0,  sc,    sqy,   0.0, sw,
    );
    (cost, jtj, Vector6::from(g))
}

/// Gauss-Newton on `(ω, s, t)` with `R ← exp([ω]×) R`, damped (Levenberg-Marquardt) only after a
/// step that raised the cost, which is then undone; stops when the step is negligible. Each
/// iteration is one pass over the points.
#[allow(clippy::too_many_arguments)]
fn gauss_newton(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    mut r: Rotation3<f64>,
    mut s: f64,
    mut t: Vector2<f64>,
    iterations: usize,
) -> (Rotation3<f64>, f64, Vector2<f64>) {
    let mut lambda = 0.0;
    let mut best = (r, s, t);
    let (mut best_cost, mut jtj, mut jtr) = normal_equations(model, y, w, &r, s, &t);
    for _ in 0..3 * iterations {
        let mut a = jtj;
        for k in 0..6 {
            a[(k, k)] *= 1.0 + lambda;
        }
        let Some(delta) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
            lambda = (lambda * 10.0).max(1e-6);
            continue;
        };
        let (br, bs, bt) = best;
        r = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])) * br;
        s = bs + delta[3];
        t = bt + Vector2::new(delta[4], delta[5]);
        if delta.fixed_rows::<3>(0).norm() < 1e-7
            && delta[3].abs() < 1e-7 * bs
            && delta[4].hypot(delta[5]) < 1e-5 * bs
        {
            break;
        }
        if s <= 0.0 {
            lambda = (lambda * 10.0).max(1e-6);
            continue;
        }
        let (cost, j, g) = normal_equations(model, y, w, &r, s, &t);
        if cost <= best_cost {
            (best, best_cost, jtj, jtr) = ((r, s, t), cost, j, g);
            lambda *= 0.1;
        } else {
            lambda = (lambda * 10.0).max(1e-6);
        }
    }
    let (r, s, t) = best;
    (r.renormalize_copy(), s, t)
}

trait Renormalize {
    fn renormalize_copy(self) -> Self;
}

impl Renormalize for Rotation3<f64> {
    fn renormalize_copy(mut self) -> Self {
        self.renormalize();
        self
    }
}

fn weighted_cost(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
) -> f64 {
    model
        .iter()
        .zip(y)
        .zip(w)
        .filter(|(_, w)| **w > 0.0)
        .map(|((x, p), &wi)| wi * (s * (r * x).xy() + t - p).norm_squared())
        .sum()
}

fn weighted_rms(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
) -> f64 {
    let sw: f64 = w.iter().sum();
    if sw <= 0.0 {
        return f64::NAN;
    }
    (weighted_cost(model, y, w, r, s, t) / sw).sqrt()
}

/// Tukey biweight on the residual norms (c = 4.685 σ, σ = 1.4826 · median, floored). Leaves the
/// weights alone and returns false when no residual exceeds 2.5 σ (nothing stands out).
pub(crate) fn tukey_reweight(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &mut [f64],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
    floor: f64,
) -> bool {
    let res: Vec<f64> = model
        .iter()
        .zip(y)
        .map(|(x, p)| (s * (r * x).xy() + t - p).norm())
        .collect();
    let mut active: Vec<f64> = res
        .iter()
        .zip(w.iter())
        .filter(|(_, w)| **w > 0.0)
        .map(|(e, _)| *e)
        .collect();
    if active.len() < 4 {
        return false;
    }
    let mid = active.len() / 2;
    let median = *active.select_nth_unstable_by(mid, f64::total_cmp).1;
    let sigma = (1.4826 * median).max(floor);
    if active.iter().all(|&e| e <= 2.5 * sigma) {
        return false;
    }
    let c = 4.685 * sigma;
    for (wi, e) in w.iter_mut().zip(&res) {
        if *wi > 0.0 {
            let u = e / c;
            *wi *= if u >= 1.0 { 0.0 } else { (1.0 - u * u).powi(2) };
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
    use proptest::prelude::*;

    fn face() -> Vec<Vector3<f64>> {
        crate::test_faces::face(10)
    }

    fn project(shape: &[Vector3<f64>], a: EulerAngles, s: f64) -> Shape2 {
        let cam = WeakPerspective::new(a.to_rotation(), s, Vector2::new(200.0, -220.0)).unwrap();
        Shape2::full(shape.iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    proptest! {
        #[test]
        fn recovers_a_known_pose(yaw in -80.0f64..80.0, pitch in -60.0f64..60.0, roll in -90.0f64..90.0, s in 0.5f64..5.0) {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let fit = fit_rigid(&face(), &project(&face(), a, s), &[], None, FitOptions::default()).unwrap();
            prop_assert!(geodesic_deg(&fit.rotation, &a.to_rotation()) < 1e-6);
            prop_assert!((fit.scale - s).abs() < 1e-8 * s);
            prop_assert!(fit.rms_px < 1e-6);
        }
    }

    #[test]
    fn one_wild_point_does_not_pull() {
        let a = EulerAngles::new(25.0, -10.0, 5.0).unwrap();
        let mut pts = project(&face(), a, 2.0).points().to_vec();
        pts[7] += Vector2::new(80.0, -60.0);
        let lm = Shape2::full(pts).unwrap();
        let robust = fit_rigid(&face(), &lm, &[], None, FitOptions::default()).unwrap();
        assert!(geodesic_deg(&robust.rotation, &a.to_rotation()) < 0.01);
        assert_eq!(robust.weights[7], 0.0);
        let plain = fit_rigid(
            &face(),
            &lm,
            &[],
            None,
            FitOptions {
                robust: false,
                ..FitOptions::default()
            },
        )
        .unwrap();
        assert!(geodesic_deg(&plain.rotation, &a.to_rotation()) > 1.0);
    }

    #[test]
    fn missing_points_are_ignored_and_too_few_is_an_error() {
        let a = EulerAngles::new(-30.0, 15.0, -8.0).unwrap();
        let lm = project(&face(), a, 1.5).with_missing([0, 4, 9]);
        let fit = fit_rigid(&face(), &lm, &[], None, FitOptions::default()).unwrap();
        assert!(geodesic_deg(&fit.rotation, &a.to_rotation()) < 1e-6);
        let few = lm.with_missing([1, 2, 3, 5]);
        assert!(matches!(
            fit_rigid(&face(), &few, &[], None, FitOptions::default()),
            Err(Error::TooFewPoints { .. })
        ));
    }

    #[test]
    fn degenerate_landmarks_are_errors() {
        let same = Shape2::full(vec![Vector2::new(5.0, 5.0); 10]).unwrap();
        assert!(matches!(
            fit_rigid(&face(), &same, &[], None, FitOptions::default()),
            Err(Error::Degenerate(_))
        ));
        let line = Shape2::full(
            (0..10)
                .map(|i| Vector2::new(i as f64, 2.0 * i as f64))
                .collect(),
        )
        .unwrap();
        assert!(matches!(
            fit_rigid(&face(), &line, &[], None, FitOptions::default()),
            Err(Error::Degenerate(_))
        ));
    }
}
