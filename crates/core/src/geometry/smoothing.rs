//! Temporal smoothing of a sequence of rotations: the One Euro filter (Casiez, Roussel and
//! Vogel, "1€ Filter", CHI 2012) done on the rotation itself rather than on angles.
//!
//! For scalars the filter is an exponential smoother `x̂ = x̂' + α (x - x̂')` whose cutoff
//! frequency grows with the (smoothed) speed: `f_c = min_cutoff + beta · |dx̂|`, so that a still
//! signal is smoothed hard (little jitter) and a fast one lightly (little lag). On rotations,
//! `x - x̂'` becomes the rotation vector `δ = log(R̂'ᵀ R)` from the previous output to the new
//! measurement (body frame, shortest way round), the update `R̂ = R̂' · exp(α δ)` turns the
//! previous output a fraction `α` of the way towards the measurement (a slerp), and the speed is
//! the filtered angular velocity `δ / dt`. No Euler angles are involved, so there is no wrap-
//! around at ±180° and no gimbal lock; about a fixed axis it is exactly the scalar filter on the
//! angle.

use nalgebra::{Rotation3, UnitQuaternion, Vector3};

use crate::error::{Error, Result};

/// Filter parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuroParams {
    /// Cutoff frequency at rest, Hz. Lower: steadier, more lag.
    pub min_cutoff_hz: f64,
    /// Cutoff increase per degree/second of angular speed, Hz·s/°. Higher: less lag in fast
    /// turns.
    pub beta: f64,
    /// Cutoff frequency of the speed estimate, Hz.
    pub d_cutoff_hz: f64,
}

impl Default for OneEuroParams {
    /// 1 Hz at rest, +0.05 Hz per °/s (a 100°/s head turn is filtered at 6 Hz), 1 Hz for the
    /// speed.
    fn default() -> Self {
        OneEuroParams {
            min_cutoff_hz: 1.0,
            beta: 0.05,
            d_cutoff_hz: 1.0,
        }
    }
}

impl OneEuroParams {
    /// Fails unless the cutoffs are positive and `beta` non-negative, all finite.
    pub fn validate(&self) -> Result<()> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !ok(self.min_cutoff_hz) || !ok(self.d_cutoff_hz) {
            return Err(Error::param(
                "smoothing",
                format!(
                    "cutoff frequencies must be positive and finite, got min_cutoff_hz {} d_cutoff_hz {}",
                    self.min_cutoff_hz, self.d_cutoff_hz
                ),
            ));
        }
        if !(self.beta.is_finite() && self.beta >= 0.0) {
            return Err(Error::param(
                "smoothing",
                format!(
                    "beta must be zero or positive and finite, got {}",
                    self.beta
                ),
            ));
        }
        Ok(())
    }
}

/// The smoothing factor of an exponential filter with cutoff `cutoff_hz` at time step `dt`.
fn alpha(cutoff_hz: f64, dt: f64) -> f64 {
    let tau = 1.0 / (2.0 * std::f64::consts::PI * cutoff_hz);
    1.0 / (1.0 + tau / dt)
}

/// A One Euro filter over rotations (see the module docs). The first rotation passes through.
#[derive(Debug, Clone)]
pub struct RotationOneEuro {
    params: OneEuroParams,
    /// The previous output and the filtered angular velocity (body frame, rad/s).
    state: Option<(UnitQuaternion<f64>, Vector3<f64>)>,
}

impl RotationOneEuro {
    /// A filter with validated parameters.
    pub fn new(params: OneEuroParams) -> Result<Self> {
        params.validate()?;
        Ok(RotationOneEuro {
            params,
            state: None,
        })
    }

    /// The filter's parameters.
    pub fn params(&self) -> &OneEuroParams {
        &self.params
    }

    /// Forgets the past: the next rotation passes through.
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// The smoothed rotation for `r`, observed `dt` seconds after the previous one. A
    /// non-positive or non-finite `dt` restarts the filter at `r`; a non-finite `r` passes
    /// through and leaves the filter as it was.
    pub fn filter(&mut self, r: &Rotation3<f64>, dt: f64) -> Rotation3<f64> {
        if !r.matrix().iter().all(|v| v.is_finite()) {
            return *r;
        }
        let q = UnitQuaternion::from_rotation_matrix(r);
        let usable = dt.is_finite() && dt > 0.0;
        let (prev, dprev) = match self.state {
            Some(s) if usable => s,
            _ => {
                self.state = Some((q, Vector3::zeros()));
                return *r;
            }
        };
        let mut d = prev.inverse() * q;
        if d.w < 0.0 {
            // The same rotation; this sign gives the short way round (angle <= 180°).
            d = UnitQuaternion::new_unchecked(-d.into_inner());
        }
        let delta = d.scaled_axis();
        let velocity = delta / dt;
        let dhat = dprev + alpha(self.params.d_cutoff_hz, dt) * (velocity - dprev);
        let cutoff = self.params.min_cutoff_hz + self.params.beta * dhat.norm().to_degrees();
        let a = alpha(cutoff, dt);
        let mut out = prev * UnitQuaternion::from_scaled_axis(delta * a);
        out.renormalize();
        self.state = Some((out, dhat));
        out.to_rotation_matrix()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, geodesic_deg};
    use approx::assert_relative_eq;
    use rand::{SeedableRng, rngs::StdRng};
    use rand_distr::{Distribution, Normal};

    fn rot(yaw: f64, pitch: f64, roll: f64) -> Rotation3<f64> {
        EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation()
    }

    /// The scalar One Euro filter of the paper, written out independently.
    struct Scalar {
        p: OneEuroParams,
        x: Option<(f64, f64)>,
    }

    impl Scalar {
        fn filter(&mut self, x: f64, dt: f64) -> f64 {
            let Some((xp, dp)) = self.x else {
                self.x = Some((x, 0.0));
                return x;
            };
            let tau = |fc: f64| 1.0 / (2.0 * std::f64::consts::PI * fc);
            let a = |fc: f64| 1.0 / (1.0 + tau(fc) / dt);
            let dx = (x - xp) / dt;
            let d = dp + a(self.p.d_cutoff_hz) * (dx - dp);
            let fc = self.p.min_cutoff_hz + self.p.beta * d.abs();
            let out = xp + a(fc) * (x - xp);
            self.x = Some((out, d));
            out
        }
    }

    #[test]
    fn about_one_axis_it_is_the_scalar_filter_on_the_angle() {
        let p = OneEuroParams::default();
        let mut f = RotationOneEuro::new(p).unwrap();
        let mut s = Scalar { p, x: None };
        let mut rng = StdRng::seed_from_u64(7);
        let noise = Normal::new(0.0, 2.0).unwrap();
        for k in 0..200 {
            // A yaw sweep with jitter; the scalar filter works in degrees, so its beta is per
            // degree/second like the rotation filter's.
            let yaw = 30.0 * (k as f64 * 0.05).sin() + noise.sample(&mut rng);
            let dt = if k % 3 == 0 { 1.0 / 30.0 } else { 1.0 / 60.0 };
            let out = EulerAngles::from_rotation(&f.filter(&rot(yaw, 0.0, 0.0), dt));
            let want = s.filter(yaw, dt);
            assert_relative_eq!(out.yaw, want, epsilon = 1e-9);
            assert!(out.pitch.abs() < 1e-9 && out.roll.abs() < 1e-9);
        }
    }

    #[test]
    fn a_still_pose_stays_put_and_jitter_shrinks() {
        let truth = rot(20.0, -10.0, 5.0);
        let mut f = RotationOneEuro::new(OneEuroParams::default()).unwrap();
        assert_relative_eq!(f.filter(&truth, 0.1), truth, epsilon = 1e-12);
        for _ in 0..10 {
            assert_relative_eq!(f.filter(&truth, 1.0 / 30.0), truth, epsilon = 1e-9);
        }
        f.reset();
        let mut rng = StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1.5).unwrap();
        let (mut raw, mut smooth) = (0.0, 0.0);
        for k in 0..300 {
            let m = rot(
                20.0 + noise.sample(&mut rng),
                -10.0 + noise.sample(&mut rng),
                5.0 + noise.sample(&mut rng),
            );
            let out = f.filter(&m, 1.0 / 30.0);
            if k >= 30 {
                raw += geodesic_deg(&m, &truth).powi(2);
                smooth += geodesic_deg(&out, &truth).powi(2);
            }
        }
        // Squared error at least four times smaller: the RMS error at least halved.
        assert!(
            smooth < raw / 4.0,
            "squared error smoothed {smooth} raw {raw}"
        );
    }

    #[test]
    fn fast_turns_lag_less_with_a_larger_beta() {
        let lag = |beta: f64| {
            let mut f = RotationOneEuro::new(OneEuroParams {
                beta,
                ..OneEuroParams::default()
            })
            .unwrap();
            let mut err = 0.0;
            for k in 0..60 {
                // 120°/s about a tilted axis.
                let t = k as f64 / 30.0;
                let m = Rotation3::from_axis_angle(
                    &nalgebra::Unit::new_normalize(Vector3::new(0.2, 1.0, 0.1)),
                    (120.0 * t - 60.0).to_radians(),
                );
                err = geodesic_deg(&f.filter(&m, 1.0 / 30.0), &m);
            }
            err
        };
        let (slow, fast) = (lag(0.0), lag(0.05));
        assert!(fast < slow / 3.0, "lag beta=0 {slow}°, beta=0.05 {fast}°");
        assert!(fast < 4.0, "{fast}");
    }

    #[test]
    fn goes_the_short_way_round() {
        let mut f = RotationOneEuro::new(OneEuroParams::default()).unwrap();
        let a = Rotation3::from_axis_angle(&Vector3::z_axis(), 179f64.to_radians());
        let b = Rotation3::from_axis_angle(&Vector3::z_axis(), -179f64.to_radians());
        f.filter(&a, 1.0 / 30.0);
        let out = f.filter(&b, 1.0 / 30.0);
        // The output lies between a and b across 180°, not back through 0°.
        assert!(geodesic_deg(&out, &a) <= 2.0 + 1e-9);
        assert!(geodesic_deg(&out, &b) <= 2.0 + 1e-9);
    }

    #[test]
    fn bad_time_steps_restart_and_bad_params_are_refused() {
        let mut f = RotationOneEuro::new(OneEuroParams::default()).unwrap();
        f.filter(&rot(0.0, 0.0, 0.0), 0.1);
        let r = rot(40.0, 0.0, 0.0);
        for dt in [0.0, -1.0, f64::NAN] {
            assert_relative_eq!(f.filter(&r, dt), r, epsilon = 1e-12);
        }
        // A non-finite rotation passes through without poisoning the next frames.
        let bad = Rotation3::from_matrix_unchecked(r.matrix().map(|_| f64::NAN));
        assert!(f.filter(&bad, 0.1).matrix()[(0, 0)].is_nan());
        let next = f.filter(&r, 0.1);
        assert!(next.matrix().iter().all(|v| v.is_finite()));
        assert_relative_eq!(next, r, epsilon = 1e-9);
        for p in [
            OneEuroParams {
                min_cutoff_hz: 0.0,
                ..OneEuroParams::default()
            },
            OneEuroParams {
                beta: -1.0,
                ..OneEuroParams::default()
            },
            OneEuroParams {
                d_cutoff_hz: f64::INFINITY,
                ..OneEuroParams::default()
            },
        ] {
            assert!(RotationOneEuro::new(p).is_err());
        }
    }
}
