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

use nalgebra::{Matrix3, Rotation3, Vector3};

use crate::geometry::convention::{angle_turn_jacobian, yaw_turn_gradient};
use crate::geometry::moments::Moments;
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
    // The weighted moments of the shape against the landmarks, in the model frame: the fit's
    // residual and normal equations at this rotation follow from them.
    let m = Moments::of_landmarks(shape, landmarks, weights);
    let (points, dof) = (m.n, 2.0 * m.sw - 6.0);
    if points < 4 || dof <= 0.0 {
        return None;
    }
    // The best scale and translation for the rotation, and the normal equations of (δ, s)
    // there (the translation separates from them once the points are centred).
    let (s, sse) = m.best_scale(rotation)?;
    let (_, jtj, _) = m.normal_equations(rotation, s);
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
    use nalgebra::Vector2;
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
