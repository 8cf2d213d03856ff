//! The raw spread of an estimate: the covariance of a weak-perspective fit's pose, propagated to
//! the angles.
//!
//! At the answer's rotation `R`, with the 3D shape `X` the method stands on (the fitted shape for
//! the shape fit, the mean shape otherwise), the landmarks are `yᵢ = s (R Xᵢ)ₓᵧ + t + εᵢ`. With
//! the best `s` and `t` for that rotation, the residual gives `σ² = Σ wᵢ |εᵢ|² / (2 Σ wᵢ − 6)`
//! (six parameters), and the normal equations of the six (a small turn `δ`, `R ← exp([δ]ₓ) R`,
//! then `s`, `t`) give the covariance `σ² (Jᵀ W J)⁻¹`. Its rotation block, pushed through the
//! derivative of the Euler angles with respect to `δ`, is the angles' covariance, whose diagonal
//! gives a standard deviation per angle.
//!
//! This is the textbook figure for a least-squares fit with independent isotropic landmark
//! noise. Real landmark errors are neither independent nor isotropic, and the shape is never
//! exact, so the figure is only a raw ingredient: [`super::calibration`] maps it to calibrated
//! standard deviations. At |yaw| near 90° pitch and roll turn about nearly the same axis and
//! their derivatives grow without bound, as the raw figure then says.

use nalgebra::{Matrix3, Matrix4, Rotation3, Vector2, Vector3};

use crate::geometry::convention::{angle_turn_jacobian, yaw_turn_gradient};
use crate::geometry::image_to_plane;
use crate::shape::Shape2;

/// Smallest raw standard deviation, degrees: exact landmarks give zero, which no calibration
/// can scale.
pub const MIN_RAW_SD_DEG: f64 = 1e-3;

/// The raw spread of one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawSpread {
    /// Standard deviation of pitch, yaw and roll, degrees, from the fit's covariance (at least
    /// [`MIN_RAW_SD_DEG`]; infinite where the fit leaves an angle undetermined).
    pub sd_deg: [f64; 3],
    /// The residual's standard deviation per coordinate, pixels.
    pub sigma_px: f64,
    /// The landmarks that took part (weight above zero).
    pub points: usize,
    /// The covariance of the small turn `δ` (`R ← exp([δ]ₓ) R`, world frame), radians²: the
    /// rotation's own uncertainty, which has no gimbal lock (what a filter on rotations takes).
    pub turn_cov: Matrix3<f64>,
    /// The answer's misfit ([`crate::pose::Estimate::misfit`]: the share of the landmarks'
    /// spread the mean shape leaves unexplained), filled in by the estimator; NaN until then.
    pub misfit: f64,
}

/// The raw spread of the pose `rotation` of `shape` (model frame) seen as `landmarks` (image
/// pixels). `weights` (one per point, as the fit left them: zero for missing, hidden or
/// rejected points) default to one per present point. `None` when fewer than four points take
/// part (too few to leave a residual).
pub fn raw_spread(
    shape: &[Vector3<f64>],
    landmarks: &Shape2,
    weights: Option<&[f64]>,
    rotation: &Rotation3<f64>,
) -> Option<RawSpread> {
    if shape.len() != landmarks.len() || weights.is_some_and(|w| w.len() != shape.len()) {
        return None;
    }
    // One pass of weighted sums of q = R X and y, relative to the first point (so that image
    // coordinates far from the origin do not cancel away the residual).
    let (i0, y0) = landmarks.iter_present().next()?;
    let (q0, y0) = (rotation * shape[i0], image_to_plane(y0));
    let (mut sw, mut points) = (0.0, 0usize);
    // Σw q, Σw q qᵀ (xx, yy, zz, xy, xz, yz), Σw y, Σw |y|², Σw qₓᵧ·y: scalars, so that the
    // loop is a few dozen flops a point.
    let (mut sq, mut m2, mut sy) = ([0.0; 3], [0.0; 6], [0.0; 2]);
    let (mut yy, mut qy) = (0.0, 0.0);
    for (i, p) in landmarks.iter_present() {
        let w = weights.map_or(1.0, |w| w[i]);
        if !(w > 0.0 && w.is_finite()) {
            continue;
        }
        let q = rotation * shape[i] - q0;
        let y = image_to_plane(p) - y0;
        sw += w;
        points += 1;
        let (wx, wy, wz) = (w * q.x, w * q.y, w * q.z);
        sq[0] += wx;
        sq[1] += wy;
        sq[2] += wz;
        m2[0] += wx * q.x;
        m2[1] += wy * q.y;
        m2[2] += wz * q.z;
        m2[3] += wx * q.y;
        m2[4] += wx * q.z;
        m2[5] += wy * q.z;
        sy[0] += w * y.x;
        sy[1] += w * y.y;
        yy += w * (y.x * y.x + y.y * y.y);
        qy += wx * y.x + wy * y.y;
    }
    let sq = Vector3::from(sq);
    let sy = Vector2::from(sy);
    let qq = Matrix3::new(
        m2[0], m2[3], m2[4], m2[3], m2[1], m2[5], m2[4], m2[5], m2[2],
    );
    let dof = 2.0 * sw - 6.0;
    if points < 4 || dof <= 0.0 {
        return None;
    }
    // Centred moments: the translation's least squares is the centroids' difference, and with
    // centred points its normal equations separate from the others'.
    let m = qq - sq * sq.transpose() / sw;
    let q_xy = m[(0, 0)] + m[(1, 1)];
    let qy = qy - sq.xy().dot(&sy) / sw;
    let yy = yy - sy.norm_squared() / sw;
    if q_xy.is_nan() || q_xy <= 0.0 {
        return None;
    }
    let s = qy / q_xy;
    let sse = (yy - s * qy).max(0.0);
    // Normal equations of (δ, s): Σ w Jᵢᵀ Jᵢ with the rows of point i
    // [0, s z, −s y, x] and [−s z, 0, s x, y] (d(s (exp([δ]ₓ) q)ₓᵧ)/dδ = −s [q]ₓ, first two
    // rows; then q for s), summed through the centred moments.
    let (xx, yy_, zz) = (m[(0, 0)], m[(1, 1)], m[(2, 2)]);
    let (xz, yz) = (m[(0, 2)], m[(1, 2)]);
    let s2 = s * s;
    let jtj = Matrix4::new(
        s2 * zz,
        0.0,
        -s2 * xz,
        -s * yz,
        0.0,
        s2 * zz,
        -s2 * yz,
        s * xz,
        -s2 * xz,
        -s2 * yz,
        s2 * (xx + yy_),
        0.0,
        -s * yz,
        s * xz,
        0.0,
        xx + yy_,
    );
    let sigma2 = sse / dof;
    let inv = jtj.try_inverse()?;
    let cov_delta: Matrix3<f64> = inv.fixed_view::<3, 3>(0, 0) * sigma2;
    let sd_deg = match angle_turn_jacobian(rotation) {
        Some(a) => {
            let cov = a * cov_delta * a.transpose();
            [0, 1, 2].map(|k| {
                let v = cov[(k, k)];
                if v.is_finite() {
                    v.max(0.0).sqrt().max(MIN_RAW_SD_DEG)
                } else {
                    f64::INFINITY
                }
            })
        }
        // At gimbal lock pitch and roll are not separable: only yaw is determined.
        None => {
            let dyaw = yaw_turn_gradient(rotation);
            let v = (dyaw.transpose() * cov_delta * dyaw)[0];
            [
                f64::INFINITY,
                v.max(0.0).sqrt().max(MIN_RAW_SD_DEG),
                f64::INFINITY,
            ]
        }
    };
    Some(RawSpread {
        sd_deg,
        sigma_px: sigma2.sqrt(),
        points,
        turn_cov: cov_delta,
        misfit: f64::NAN,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective};
    use crate::test_faces::face;
    use rand::{SeedableRng, rngs::StdRng};
    use rand_distr::{Distribution, Normal};

    fn project(r: &Rotation3<f64>, s: f64, shape: &[Vector3<f64>]) -> Vec<Vector2<f64>> {
        let cam = WeakPerspective::new(*r, s, Vector2::new(320.0, -240.0)).unwrap();
        shape.iter().map(|x| cam.project(x)).collect()
    }

    #[test]
    fn exact_landmarks_give_the_floor() {
        let r = EulerAngles::new(20.0, -10.0, 5.0).unwrap().to_rotation();
        let lm = Shape2::full(project(&r, 3.0, &face(10))).unwrap();
        let s = raw_spread(&face(10), &lm, None, &r).unwrap();
        assert_eq!(s.sd_deg, [MIN_RAW_SD_DEG; 3]);
        assert!(s.sigma_px < 1e-5, "{s:?}");
        assert_eq!(s.points, 10);
    }

    #[test]
    fn too_few_points_give_none() {
        let r = Rotation3::identity();
        let lm = Shape2::full(project(&r, 3.0, &face(10))).unwrap();
        let three = lm.with_missing(3..10);
        assert!(raw_spread(&face(10), &three, None, &r).is_none());
    }

    /// The predicted standard deviations match the spread of the angles of rigid fits over
    /// many draws of the noise the formula assumes (independent, isotropic, Gaussian).
    #[test]
    fn matches_the_spread_of_fits_under_its_own_noise_model() {
        use crate::estimate::fit::{FitOptions, fit_rigid};
        let shape = face(10);
        let truth = EulerAngles::new(25.0, 10.0, -5.0).unwrap();
        let r = truth.to_rotation();
        let clean = project(&r, 3.0, &shape);
        let noise = Normal::new(0.0, 2.0).unwrap();
        let mut rng = StdRng::seed_from_u64(7);
        let opts = FitOptions {
            robust: false,
            ..FitOptions::default()
        };
        let (mut predicted, mut sq) = ([0.0; 3], [0.0; 3]);
        let n = 400;
        for _ in 0..n {
            let pts = clean
                .iter()
                .map(|p| p + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)))
                .collect();
            let lm = Shape2::full(pts).unwrap();
            let f = fit_rigid(&shape, &lm, &[], None, opts).unwrap();
            let s = raw_spread(&shape, &lm, Some(&f.weights), &f.rotation).unwrap();
            let a = EulerAngles::from_rotation(&f.rotation);
            let e = [
                a.pitch - truth.pitch,
                a.yaw - truth.yaw,
                a.roll - truth.roll,
            ];
            for k in 0..3 {
                predicted[k] += s.sd_deg[k] / n as f64;
                sq[k] += e[k] * e[k] / n as f64;
            }
        }
        for k in 0..3 {
            let observed = sq[k].sqrt();
            let ratio = predicted[k] / observed;
            assert!(
                (0.8..1.25).contains(&ratio),
                "angle {k}: predicted {:.3}°, observed {observed:.3}°",
                predicted[k]
            );
        }
    }

    #[test]
    fn pitch_and_roll_are_undetermined_in_profile() {
        let shape = face(10);
        let mut rng = StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let sd = |yaw: f64, rng: &mut StdRng| {
            let r = EulerAngles::new(yaw, 5.0, 3.0).unwrap().to_rotation();
            let pts = project(&r, 3.0, &shape)
                .iter()
                .map(|p| p + Vector2::new(noise.sample(rng), noise.sample(rng)))
                .collect();
            raw_spread(&shape, &Shape2::full(pts).unwrap(), None, &r)
                .unwrap()
                .sd_deg
        };
        let (front, profile) = (sd(0.0, &mut rng), sd(89.0, &mut rng));
        assert!(profile[0] > 10.0 * front[0], "{profile:?} vs {front:?}");
        assert!(profile[2] > 10.0 * front[2], "{profile:?} vs {front:?}");
    }
}
