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
//! 4. HPR-aware: points that the visibility map calls hidden at the current estimate get weight
//!    zero, and the fit is redone until the visible set settles. Contour points (the jaw of
//!    ibug68) that are visible keep a weight of `contour_weight`: in 2D annotations they follow
//!    the silhouette rather than a fixed 3D point.

use nalgebra::{Matrix2x3, Matrix3, Matrix6, Rotation3, Vector2, Vector3, Vector6};

use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::shape::Shape2;

/// Options of [`fit_rigid`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Tukey reweighting against wild points.
    pub robust: bool,
    /// Drop points hidden at the estimate (needs a visibility map).
    pub hpr_aware: bool,
    /// Weight of visible contour points relative to the others.
    pub contour_weight: f64,
    /// Levenberg-Marquardt iterations per weighting round.
    pub iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            robust: true,
            hpr_aware: true,
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
    let y: Vec<Vector2<f64>> = landmarks
        .points()
        .iter()
        .map(|p| Vector2::new(p.x, -p.y))
        .collect();
    let mut base = vec![0.0; n];
    for (i, w) in base.iter_mut().enumerate() {
        if landmarks.present()[i] {
            *w = if contour.contains(&i) {
                opts.contour_weight
            } else {
                1.0
            };
        }
    }
    let mut weights = base.clone();
    let (mut r, mut s, mut t) = affine_start(model, &y, &weights)?;
    let size = model_size(model, &weights);

    let rounds =
        1 + usize::from(opts.robust) * 2 + usize::from(opts.hpr_aware && visibility.is_some()) * 2;
    let mut hidden_mask: Option<Vec<bool>> = None;
    for round in 0..rounds {
        (r, s, t) = levenberg_marquardt(model, &y, &weights, r, s, t, opts.iterations);
        if round + 1 == rounds {
            break;
        }
        // Reweight: visibility first, then robustness on what is left.
        if let (true, Some(map)) = (opts.hpr_aware, visibility) {
            hidden_mask = Some(map.lookup(&r).iter().map(|v| !v).collect());
        }
        for i in 0..n {
            weights[i] = base[i];
            if hidden_mask.as_ref().is_some_and(|h| h[i]) {
                weights[i] = 0.0;
            }
        }
        if opts.robust {
            tukey_reweight(model, &y, &mut weights, &r, s, &t, 0.01 * s * size);
        }
        if weights.iter().filter(|&&w| w > 0.0).count() < 4 {
            // Too few points left: fall back to every present point.
            weights.clone_from(&base);
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
fn model_size(model: &[Vector3<f64>], w: &[f64]) -> f64 {
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
    let svd = a.svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => return Err(Error::Numerical("SVD of the affine camera failed".into())),
    };
    let (s1, s2) = (svd.singular_values[0], svd.singular_values[1]);
    if spread <= 1e-18 || s2 <= 1e-9 * s1.max(1e-300) {
        return Err(Error::Degenerate(
            "the landmarks are all at one place or on one line".into(),
        ));
    }
    let rows = u * vt;
    let r1: Vector3<f64> = rows.row(0).transpose();
    let r2: Vector3<f64> = rows.row(1).transpose();
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        r1.transpose(),
        r2.transpose(),
        r1.cross(&r2).transpose(),
    ]));
    let s = 0.5 * (s1 + s2);
    let t = cy - s * (rot * cx).xy();
    Ok((rot, s, t))
}

#[allow(clippy::too_many_arguments)]
fn levenberg_marquardt(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    mut r: Rotation3<f64>,
    mut s: f64,
    mut t: Vector2<f64>,
    iterations: usize,
) -> (Rotation3<f64>, f64, Vector2<f64>) {
    let mut lambda = 1e-3;
    let mut cost = weighted_cost(model, y, w, &r, s, &t);
    for _ in 0..iterations {
        let mut jtj = Matrix6::zeros();
        let mut jtr = Vector6::zeros();
        for ((x, p), &wi) in model.iter().zip(y).zip(w) {
            if wi == 0.0 {
                continue;
            }
            let q = r * x;
            let res = s * q.xy() + t - p;
            // d(res)/d(ω) = s P (-[q]×): rows x and y of -[q]×.
            let jx = Vector6::new(0.0, s * q.z, -s * q.y, q.x, 1.0, 0.0);
            let jy = Vector6::new(-s * q.z, 0.0, s * q.x, q.y, 0.0, 1.0);
            jtj += wi * (jx * jx.transpose() + jy * jy.transpose());
            jtr += wi * (jx * res.x + jy * res.y);
        }
        let mut improved = false;
        for _ in 0..6 {
            let mut a = jtj;
            for k in 0..6 {
                a[(k, k)] *= 1.0 + lambda;
            }
            let Some(delta) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let rn = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])) * r;
            let sn = s + delta[3];
            let tn = t + Vector2::new(delta[4], delta[5]);
            let cn = weighted_cost(model, y, w, &rn, sn, &tn);
            if sn > 0.0 && cn <= cost {
                let small = cost - cn <= 1e-14 * cost.max(1e-300);
                (r, s, t, cost) = (rn, sn, tn, cn);
                lambda = (lambda * 0.3).max(1e-9);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
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

/// Tukey biweight on the residual norms (c = 4.685 σ, σ = 1.4826 · median, floored).
fn tukey_reweight(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &mut [f64],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
    floor: f64,
) {
    let mut res: Vec<f64> = model
        .iter()
        .zip(y)
        .zip(w.iter())
        .filter(|(_, w)| **w > 0.0)
        .map(|((x, p), _)| (s * (r * x).xy() + t - p).norm())
        .collect();
    if res.len() < 4 {
        return;
    }
    res.sort_by(f64::total_cmp);
    let sigma = (1.4826 * res[res.len() / 2]).max(floor);
    let c = 4.685 * sigma;
    for ((x, p), wi) in model.iter().zip(y).zip(w.iter_mut()) {
        if *wi > 0.0 {
            let e = (s * (r * x).xy() + t - p).norm() / c;
            *wi *= if e >= 1.0 { 0.0 } else { (1.0 - e * e).powi(2) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
    use proptest::prelude::*;

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
