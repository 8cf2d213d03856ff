//! Rigid weak-perspective fit of a 3D shape to 2D landmarks (beyond the paper).
//!
//! Minimizes `Σ wᵢ ‖s · P R Xᵢ + t - yᵢ‖²` over the rotation `R`, scale `s` and translation `t`,
//! where `yᵢ = (uᵢ, -vᵢ)` are the landmarks in the y-up plane and `P` drops z:
//! 1. closed-form start: the least-squares affine camera, projected onto the nearest scaled
//!    orthographic one (polar decomposition), its third row the cross product of the first two;
//! 2. Levenberg-Marquardt on `(ω, s)` with `R ← exp([ω]×) R` and the translation kept optimal
//!    (centroid onto centroid). The cost and its normal equations depend on the points only
//!    through their weighted centred moments (`Σ w dx dxᵀ`, `Σ w dx dyᵀ`, `Σ w |dy|²`), so each
//!    weighting costs one pass over the points and each iteration O(1);
//! 3. robust: iteratively reweighted with Tukey's biweight on the residuals (scale from the
//!    median absolute residual, floored at 1% of the face size), so one or two wild points stop
//!    pulling;
//! 4. HPR-aware ([`Hidden`]): points that the visibility map calls hidden at the current
//!    estimate get weight zero (all of them, or only the contour points, the jaw of ibug68, which
//!    2D-style annotations put on the visible outline instead of their 3D place), and the fit is
//!    redone until the visible set settles. Visible contour points weigh `contour_weight`.

use nalgebra::{Matrix4, Rotation3, Vector2, Vector3, Vector4};

use crate::geometry::moments::Moments;

use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::geometry::{EulerAngles, image_to_plane, rotation_from_two_rows};
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
    /// Rotation, model frame to camera axes.
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
    let base_moments = Moments::new(model, &y, &weights);
    // The moments of the current `weights`.
    let mut moments = base_moments;
    let (r0, s0) = affine_start(&moments)?;
    let size = (moments.xx.trace() / moments.sw).sqrt();
    let (mut r, mut s, mut t) = gauss_newton(&moments, r0, s0, opts.iterations);
    if landmarks.n_present() <= FEW_POINTS {
        (r, s, t) = nearer_frontal_branch(&moments, (r, s, t), opts.iterations);
    }

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
                moments = base_moments;
                break;
            }
            moments = Moments::new(model, &y, &weights);
            (r, s, t) = gauss_newton(&moments, r, s, opts.iterations);
        }
    }
    // Robustness: Tukey reweighting, only when some residual stands out; it needs every
    // point's residual. Without it the weighted residual comes from the moments: the cost at
    // the optimal translation, plus what `t` is off it (the points are centred).
    let sse = if opts.robust {
        let mut res2 = Vec::with_capacity(n);
        squared_residuals(model, &y, &r, s, &t, &mut res2);
        let before = weights.clone();
        let mut scratch = Vec::with_capacity(n);
        for _ in 0..2 {
            weights.clone_from(&before);
            if !tukey_weights(&res2, &mut weights, 0.01 * s * size, &mut scratch) {
                break;
            }
            if weights.iter().filter(|&&w| w > 0.0).count() < 4 {
                weights.clone_from(&before);
                break;
            }
            (r, s, t) = gauss_newton(&Moments::new(model, &y, &weights), r, s, opts.iterations);
            squared_residuals(model, &y, &r, s, &t, &mut res2);
        }
        weights.iter().zip(&res2).map(|(w, e)| w * e).sum()
    } else {
        let off = (t - moments.translation(&r, s)).norm_squared();
        (moments.normal_equations(&r, s).0 + moments.sw * off).max(0.0)
    };
    let sw: f64 = weights.iter().sum();
    let rms_px = if sw > 0.0 {
        (sse / sw).sqrt()
    } else {
        f64::NAN
    };
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

/// Up to this many present points, the fit also looks for a second solution nearer frontal
/// pitch ([`nearer_frontal_branch`]).
const FEW_POINTS: usize = 8;

/// Costs closer than this share of the landmarks' own spread (`Σ w |dy|²`) are a tie: a
/// landmark noise of about 4% of the face's size. On the AFLW2000-3D dev faces' dlib5 points,
/// any share from 0.002 to 0.02 gives the same MAE (5.03°, from 5.17° with no second start).
const TIE: f64 = 0.005;

/// Few points leave the pitch two-fold ambiguous: with dlib's five (four eye corners on one
/// line and the base of the nose), only the nose's offset from the eye line depends on pitch,
/// through `Δy cos p - Δz sin p`, which two pitches satisfy; the affine start may land on either.
/// This refits from the same yaw and roll at pitch 0 and keeps that solution when it is nearer
/// frontal and fits about as well (costs within [`TIE`]): the prior that faces are
/// nearer frontal pitch breaks a tie that the points cannot. With enough points the second
/// start converges to the same solution.
fn nearer_frontal_branch(
    m: &Moments,
    (r, s, t): (Rotation3<f64>, f64, Vector2<f64>),
    iterations: usize,
) -> (Rotation3<f64>, f64, Vector2<f64>) {
    let first = EulerAngles::from_rotation(&r);
    if first.pitch.abs() < 10.0 {
        return (r, s, t);
    }
    let start = EulerAngles {
        pitch: 0.0,
        ..first
    }
    .to_rotation();
    let (r2, s2, t2) = gauss_newton(m, start, s, iterations);
    let cost = |r: &Rotation3<f64>, s: f64| m.normal_equations(r, s).0.max(0.0);
    let nearer = EulerAngles::from_rotation(&r2).pitch.abs() < first.pitch.abs() - 5.0;
    if nearer && cost(&r2, s2) <= cost(&r, s) + TIE * m.yy {
        (r2, s2, t2)
    } else {
        (r, s, t)
    }
}

/// The closed-form start: the rotation and scale of the nearest scaled orthographic camera to
/// the least-squares affine one.
fn affine_start(m: &Moments) -> Result<(Rotation3<f64>, f64)> {
    if !m.yy.is_finite() {
        return Err(Error::non_finite("landmarks"));
    }
    let inv =
        m.xx.try_inverse()
            .ok_or_else(|| Error::Degenerate("the model points in use are coplanar".into()))?;
    let a = m.xy.transpose() * inv;
    // Polar decomposition of the 2x3 camera: A = S^½ [r1; r2] with S = A Aᵀ (2x2), in closed form.
    let aat = a * a.transpose();
    let (tr, det) = (aat.trace(), aat.determinant());
    if m.yy <= 1e-18 || det.is_nan() || det <= 1e-18 * tr * tr {
        return Err(Error::Degenerate(
            "the landmarks are all at one place or on one line".into(),
        ));
    }
    let sq = det.sqrt();
    let root_sum = (tr + 2.0 * sq).sqrt(); // σ1 + σ2
    // (S^½)⁻¹ = (S + √det I)⁻¹ · (σ1 + σ2).
    let inv_sqrt = (aat + nalgebra::Matrix2::identity() * sq)
        .try_inverse()
        .ok_or_else(|| Error::Numerical("polar decomposition failed".into()))?
        * root_sum;
    let rows = inv_sqrt * a;
    let rot = rotation_from_two_rows(&rows.row(0).transpose(), &rows.row(1).transpose());
    Ok((rot, 0.5 * root_sum))
}

/// Gauss-Newton on `(ω, s)` with `R ← exp([ω]×) R` and the translation kept optimal, damped
/// (Levenberg-Marquardt) only after a step that raised the cost, which is then undone; stops
/// when the step is negligible. The iterations work on the moments: O(1) each.
fn gauss_newton(
    m: &Moments,
    mut r: Rotation3<f64>,
    mut s: f64,
    iterations: usize,
) -> (Rotation3<f64>, f64, Vector2<f64>) {
    // The cost comes from sums of the size of `Σ w |dy|²` that cancel at the optimum: a change
    // below their rounding is no change.
    let tol = 1e-12 * m.yy;
    let mut lambda = 0.0;
    let mut best = (r, s);
    let (mut best_cost, mut jtj, mut jtr) = m.normal_equations(&r, s);
    for _ in 0..3 * iterations {
        let mut a = jtj;
        for k in 0..4 {
            a[(k, k)] *= 1.0 + lambda;
        }
        let Some(delta) = solve_spd4(&a, &(-jtr)) else {
            lambda = (lambda * 10.0).max(1e-6);
            continue;
        };
        let (br, bs) = best;
        r = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])) * br;
        s = bs + delta[3];
        if delta.fixed_rows::<3>(0).norm() < 1e-6 && delta[3].abs() < 1e-6 * bs {
            if s > 0.0 {
                best = (r, s);
            }
            break;
        }
        if s <= 0.0 {
            lambda = (lambda * 10.0).max(1e-6);
            continue;
        }
        let (cost, j, g) = m.normal_equations(&r, s);
        if cost <= best_cost + tol {
            (best, best_cost, jtj, jtr) = ((r, s), cost.min(best_cost), j, g);
            lambda *= 0.1;
        } else {
            lambda = (lambda * 10.0).max(1e-6);
        }
    }
    let (r, s) = best;
    let r = r.renormalize_copy();
    (r, s, m.translation(&r, s))
}

/// Solves `a x = b` for a symmetric positive definite 4x4 `a` (its lower triangle read) by an
/// unrolled Cholesky factorization; `None` when `a` is not numerically positive definite. The
/// rigid fit solves one such system an iteration, where nalgebra's general factorization costs
/// more in its loops than in its arithmetic.
fn solve_spd4(a: &Matrix4<f64>, b: &Vector4<f64>) -> Option<Vector4<f64>> {
    let root = |d: f64| (d > 0.0 && d.is_finite()).then(|| d.sqrt());
    let l00 = root(a[(0, 0)])?;
    let (l10, l20, l30) = (a[(1, 0)] / l00, a[(2, 0)] / l00, a[(3, 0)] / l00);
    let l11 = root(a[(1, 1)] - l10 * l10)?;
    let l21 = (a[(2, 1)] - l20 * l10) / l11;
    let l31 = (a[(3, 1)] - l30 * l10) / l11;
    let l22 = root(a[(2, 2)] - l20 * l20 - l21 * l21)?;
    let l32 = (a[(3, 2)] - l30 * l20 - l31 * l21) / l22;
    let l33 = root(a[(3, 3)] - l30 * l30 - l31 * l31 - l32 * l32)?;
    // L y = b, then Lᵀ x = y.
    let y0 = b[0] / l00;
    let y1 = (b[1] - l10 * y0) / l11;
    let y2 = (b[2] - l20 * y0 - l21 * y1) / l22;
    let y3 = (b[3] - l30 * y0 - l31 * y1 - l32 * y2) / l33;
    let x3 = y3 / l33;
    let x2 = (y2 - l32 * x3) / l22;
    let x1 = (y1 - l21 * x2 - l31 * x3) / l11;
    let x0 = (y0 - l10 * x1 - l20 * x2 - l30 * x3) / l00;
    Some(Vector4::new(x0, x1, x2, x3))
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

/// `|s (R xᵢ)ₓᵧ + t - yᵢ|²` for every point, into `out`.
fn squared_residuals(
    model: &[Vector3<f64>],
    y: &[Vector2<f64>],
    r: &Rotation3<f64>,
    s: f64,
    t: &Vector2<f64>,
    out: &mut Vec<f64>,
) {
    out.clear();
    out.extend(
        model
            .iter()
            .zip(y)
            .map(|(x, p)| (s * (r * x).xy() + t - p).norm_squared()),
    );
}

/// Tukey biweight on the residual norms (c = 4.685 σ, σ = 1.4826 · median, floored), from the
/// squared residuals `res2` (`scratch` holds the ones in use for the median). Leaves the
/// weights alone and returns false when no residual exceeds 2.5 σ (nothing stands out). Works
/// on squares throughout: one square root, for the median.
pub(crate) fn tukey_weights(
    res2: &[f64],
    w: &mut [f64],
    floor: f64,
    scratch: &mut Vec<f64>,
) -> bool {
    // σ is at least `floor`: when no residual in use exceeds 2.5 · floor, none exceeds 2.5 σ,
    // and the median is not needed (the common case of clean landmarks).
    let floor_limit = (2.5 * floor).powi(2);
    if res2
        .iter()
        .zip(w.iter())
        .all(|(e, w)| *w <= 0.0 || *e <= floor_limit)
    {
        return false;
    }
    scratch.clear();
    scratch.extend(
        res2.iter()
            .zip(w.iter())
            .filter(|(_, w)| **w > 0.0)
            .map(|(e, _)| *e),
    );
    if scratch.len() < 4 {
        return false;
    }
    let mid = scratch.len() / 2;
    // Nothing stands out when the largest residual is within 2.5 σ ≥ 2.5 · 1.4826 · median,
    // that is when the median's square is at least `max / 3.7065²`: true when at most `mid`
    // squares lie below that (with a margin against rounding), which a count tells without
    // the selection of the median (the common case of clean landmarks).
    let max = scratch.iter().fold(0.0f64, |a, &b| a.max(b));
    let enough = max / (2.5f64 * 1.4826).powi(2) * (1.0 + 1e-9);
    if scratch.iter().filter(|&&e| e < enough).count() <= mid {
        return false;
    }
    let median = scratch.select_nth_unstable_by(mid, f64::total_cmp).1.sqrt();
    let sigma = (1.4826 * median).max(floor);
    let limit = (2.5 * sigma).powi(2);
    if scratch.iter().all(|&e| e <= limit) {
        return false;
    }
    let c2 = (4.685 * sigma).powi(2);
    for (wi, e) in w.iter_mut().zip(res2) {
        if *wi > 0.0 {
            let u2 = e / c2;
            *wi *= if u2 >= 1.0 { 0.0 } else { (1.0 - u2).powi(2) };
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

    /// The cost summed point by point, against which the moments are checked.
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

    fn project(shape: &[Vector3<f64>], a: EulerAngles, s: f64) -> Shape2 {
        let cam = WeakPerspective::new(a.to_rotation(), s, Vector2::new(200.0, -220.0)).unwrap();
        Shape2::full(shape.iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    /// Tukey's weights with the median always taken (no shortcut), as the rule reads.
    fn tukey_by_the_rule(res2: &[f64], w: &mut [f64], floor: f64) -> bool {
        let mut used: Vec<f64> = res2
            .iter()
            .zip(&*w)
            .filter(|(_, w)| **w > 0.0)
            .map(|(e, _)| *e)
            .collect();
        if used.len() < 4 {
            return false;
        }
        used.sort_by(f64::total_cmp);
        let sigma = (1.4826 * used[used.len() / 2].sqrt()).max(floor);
        if used.iter().all(|&e| e <= (2.5 * sigma).powi(2)) {
            return false;
        }
        let c2 = (4.685 * sigma).powi(2);
        for (wi, e) in w.iter_mut().zip(res2) {
            if *wi > 0.0 {
                *wi *= (1.0 - (e / c2).min(1.0)).powi(2);
            }
        }
        true
    }

    proptest! {
        /// The shortcut that skips the median (no residual over 2.5 x the floor) changes nothing.
        #[test]
        fn tukey_weights_follow_the_rule(
            res in prop::collection::vec((0.0f64..6.0, prop::bool::weighted(0.9)), 0..80),
            floor in 0.2f64..3.0,
        ) {
            let res2: Vec<f64> = res.iter().map(|(e, _)| e * e).collect();
            let w0: Vec<f64> = res.iter().map(|&(_, on)| if on { 1.0 } else { 0.0 }).collect();
            let (mut got, mut want) = (w0.clone(), w0);
            let changed = tukey_weights(&res2, &mut got, floor, &mut Vec::new());
            prop_assert_eq!(changed, tukey_by_the_rule(&res2, &mut want, floor));
            prop_assert_eq!(got, want);
        }

        #[test]
        fn recovers_a_known_pose(yaw in -80.0f64..80.0, pitch in -60.0f64..60.0, roll in -90.0f64..90.0, s in 0.5f64..5.0) {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let fit = fit_rigid(&face(), &project(&face(), a, s), &[], None, FitOptions::default()).unwrap();
            prop_assert!(geodesic_deg(&fit.rotation, &a.to_rotation()) < 1e-6);
            prop_assert!((fit.scale - s).abs() < 1e-8 * s);
            prop_assert!(fit.rms_px < 1e-6);
        }
    }

    /// The cost from the moments is the direct sum over the points at the optimal translation,
    /// and the gradient (`Jᵀr`) matches central differences of that direct sum in `(ω, s)`.
    #[test]
    fn moment_cost_and_gradient_match_the_direct_sums() {
        let model = face();
        let a = EulerAngles::new(35.0, -20.0, 10.0).unwrap();
        let lm = project(&model, a, 2.0);
        let y: Vec<Vector2<f64>> = lm
            .points()
            .iter()
            .enumerate()
            .map(|(i, p)| image_to_plane(p) + Vector2::new((i % 3) as f64, -((i % 5) as f64)))
            .collect();
        let w: Vec<f64> = (0..model.len()).map(|i| 0.5 + (i % 4) as f64).collect();
        let m = Moments::new(&model, &y, &w);
        let r0 = EulerAngles::new(30.0, -15.0, 4.0).unwrap().to_rotation();
        let direct = |dw: Vector3<f64>, s: f64| {
            let r = Rotation3::new(dw) * r0;
            let t = m.translation(&r, s);
            weighted_cost(&model, &y, &w, &r, s, &t)
        };
        let s0 = 1.7;
        let (cost, _, g) = m.normal_equations(&r0, s0);
        let want = direct(Vector3::zeros(), s0);
        assert!((cost - want).abs() < 1e-9 * want, "{cost} vs {want}");
        let h = 1e-6;
        for k in 0..4 {
            let (mut dp, mut dm) = (Vector3::zeros(), Vector3::zeros());
            let (mut sp, mut sm) = (s0, s0);
            if k < 3 {
                dp[k] = h;
                dm[k] = -h;
            } else {
                sp += h;
                sm -= h;
            }
            // d(cost)/dθ = 2 Jᵀr.
            let numeric = (direct(dp, sp) - direct(dm, sm)) / (2.0 * h) / 2.0;
            assert!(
                (numeric - g[k]).abs() < 1e-5 * want.sqrt().max(1.0),
                "component {k}: {numeric} vs {}",
                g[k]
            );
        }
    }

    proptest! {
        /// The unrolled 4x4 solve agrees with nalgebra's Cholesky on positive definite
        /// matrices (`m mᵀ` plus a ridge), and refuses what is not positive definite.
        #[test]
        fn spd4_solve_matches_nalgebra(
            m in prop::array::uniform16(-3.0f64..3.0),
            b in prop::array::uniform4(-5.0f64..5.0),
            ridge in 1e-3f64..2.0,
        ) {
            let m = Matrix4::from_column_slice(&m);
            let a = m * m.transpose() + Matrix4::identity() * ridge;
            let b = Vector4::from(b);
            let want = a.cholesky().unwrap().solve(&b);
            let got = solve_spd4(&a, &b).unwrap();
            prop_assert!((got - want).norm() <= 1e-8 * want.norm().max(1.0), "{got} vs {want}");
            prop_assert!((a * got - b).norm() <= 1e-8 * b.norm().max(1.0) * a.norm());
            prop_assert!(solve_spd4(&(-a), &b).is_none());
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
        // Each fit's RMS is its weighted residual, summed point by point (the plain fit's
        // comes from its moments).
        let y: Vec<Vector2<f64>> = lm.points().iter().map(image_to_plane).collect();
        for f in [&robust, &plain] {
            let sse = weighted_cost(
                &face(),
                &y,
                &f.weights,
                &f.rotation,
                f.scale,
                &f.translation,
            );
            let sw: f64 = f.weights.iter().sum();
            let want = (sse / sw).sqrt();
            assert!(
                (f.rms_px - want).abs() < 1e-9 * want,
                "{} vs {want}",
                f.rms_px
            );
        }
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
