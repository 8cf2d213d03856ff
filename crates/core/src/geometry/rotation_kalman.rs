//! A Kalman filter on rotations that weighs each measurement by its uncertainty.
//!
//! State: the rotation `R̂` and the angular velocity `ω` (world frame, rad/s), with the
//! covariance `P` of the error `(δ, ω)` where the true rotation is `exp([δ]ₓ) R̂` (an
//! error-state, or multiplicative, Kalman filter: the rotation itself never goes through Euler
//! angles). Motion model: constant angular velocity driven by white angular acceleration of
//! spectral density `q` ([`KalmanParams::acceleration_deg_s2`]² per second).
//!
//! Each measurement `R` comes with the covariance of its turn (what
//! [`crate::uncertainty::Uncertainty::turn_cov`] gives): the innovation is `ν = log(R R̂ᵀ)`, the
//! short way round, weighed against `P_δδ + C`. So a profile face, whose pitch and roll the
//! landmarks barely determine, moves the track little along those axes and fully along yaw, and a
//! frame with half its landmarks missing counts for less than a full one. A measurement whose
//! Mahalanobis distance `νᵀ S⁻¹ ν` exceeds the gate (a wild frame: a detector glitch) is left
//! out; after [`KalmanParams::max_rejected`] rejections in a row the filter restarts at the
//! measurement (the head really moved that way). Without a covariance the measurement gets
//! [`KalmanParams::default_sd_deg`] on every axis.

use nalgebra::{Matrix3, Matrix6, Rotation3, SMatrix, UnitQuaternion, Vector3};

use crate::error::{Error, Result};

/// Filter parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanParams {
    /// Standard deviation of the white angular acceleration that drives the motion model,
    /// degrees/s² over one second (its spectral density's square root). Higher: follows fast
    /// turns sooner, smooths less.
    pub acceleration_deg_s2: f64,
    /// Mahalanobis distance squared above which a measurement is left out (3 degrees of
    /// freedom: 16.27 keeps 99.9% of measurements the model expects).
    pub gate: f64,
    /// Rejections in a row after which the filter restarts at the measurement.
    pub max_rejected: u32,
    /// The measurement's standard deviation on each axis when it comes without a covariance,
    /// degrees.
    pub default_sd_deg: f64,
}

impl Default for KalmanParams {
    /// 150°/s² acceleration noise (chosen on the sweep of `facepose eval --protocol tracking`,
    /// docs/RESULTS.md: within 3% of the lowest error, with 10% less jitter than there), gate 16.27 (χ²₃ at 99.9%), restart after 5 rejections, 3°
    /// for measurements without a covariance.
    fn default() -> Self {
        KalmanParams {
            acceleration_deg_s2: 150.0,
            gate: 16.27,
            max_rejected: 5,
            default_sd_deg: 3.0,
        }
    }
}

impl KalmanParams {
    /// Fails unless the noise, gate and default deviation are positive and finite and at least
    /// one rejection is allowed.
    pub fn validate(&self) -> Result<()> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !ok(self.acceleration_deg_s2) || !ok(self.gate) || !ok(self.default_sd_deg) {
            return Err(Error::param(
                "smoothing",
                format!(
                    "acceleration_deg_s2, gate and default_sd_deg must be positive and finite, got {}, {}, {}",
                    self.acceleration_deg_s2, self.gate, self.default_sd_deg
                ),
            ));
        }
        if self.max_rejected == 0 {
            return Err(Error::param("smoothing", "max_rejected must be at least 1"));
        }
        Ok(())
    }
}

/// What the filter made of one measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Filtered {
    /// The filtered rotation.
    pub rotation: Rotation3<f64>,
    /// Whether the measurement was taken (false: left out by the gate, the track predicted).
    pub accepted: bool,
}

#[derive(Debug, Clone)]
struct State {
    q: UnitQuaternion<f64>,
    omega: Vector3<f64>,
    p: Matrix6<f64>,
    rejected: u32,
}

/// The filter (see the module docs). The first measurement passes through.
#[derive(Debug, Clone)]
pub struct RotationKalman {
    params: KalmanParams,
    state: Option<State>,
}

/// The angular speed assumed unknown at a start, rad/s (one standard deviation: 90°/s).
const START_SPEED_SD: f64 = std::f64::consts::FRAC_PI_2;

impl RotationKalman {
    /// A filter with validated parameters.
    pub fn new(params: KalmanParams) -> Result<Self> {
        params.validate()?;
        Ok(RotationKalman {
            params,
            state: None,
        })
    }

    /// The filter's parameters.
    pub fn params(&self) -> &KalmanParams {
        &self.params
    }

    /// Forgets the past: the next measurement passes through.
    pub fn reset(&mut self) {
        self.state = None;
    }

    fn start(&mut self, q: UnitQuaternion<f64>, c: &Matrix3<f64>) {
        let mut p = Matrix6::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(c);
        p.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(Matrix3::identity() * START_SPEED_SD.powi(2)));
        self.state = Some(State {
            q,
            omega: Vector3::zeros(),
            p,
            rejected: 0,
        });
    }

    /// The filtered rotation for the measurement `r` with the covariance `cov` of its turn
    /// (radians²; `None`: [`KalmanParams::default_sd_deg`]), taken `dt` seconds after the
    /// previous one. A non-positive or non-finite `dt`, or an unusable covariance, restarts the
    /// filter at `r`; a non-finite `r` passes through and leaves the filter as it was.
    pub fn filter(&mut self, r: &Rotation3<f64>, cov: Option<&Matrix3<f64>>, dt: f64) -> Filtered {
        let pass = Filtered {
            rotation: *r,
            accepted: true,
        };
        if !r.matrix().iter().all(|v| v.is_finite()) {
            return pass;
        }
        let c = match cov {
            Some(c) if c.iter().all(|v| v.is_finite()) && c.cholesky().is_some() => *c,
            Some(_) => {
                // Not a covariance: restart rather than weigh by it.
                let c0 = self.default_cov();
                self.start(UnitQuaternion::from_rotation_matrix(r), &c0);
                return pass;
            }
            None => self.default_cov(),
        };
        let m = UnitQuaternion::from_rotation_matrix(r);
        let usable = dt.is_finite() && dt > 0.0;
        let Some(st) = self.state.as_mut().filter(|_| usable) else {
            self.start(m, &c);
            return pass;
        };
        // Predict.
        st.q = UnitQuaternion::from_scaled_axis(st.omega * dt) * st.q;
        let mut f = Matrix6::identity();
        f.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(Matrix3::identity() * dt));
        let qa = self.params.acceleration_deg_s2.to_radians().powi(2);
        let mut q = Matrix6::zeros();
        for i in 0..3 {
            q[(i, i)] = qa * dt.powi(3) / 3.0;
            q[(i, i + 3)] = qa * dt.powi(2) / 2.0;
            q[(i + 3, i)] = qa * dt.powi(2) / 2.0;
            q[(i + 3, i + 3)] = qa * dt;
        }
        st.p = f * st.p * f.transpose() + q;
        // Innovation, the short way round.
        let mut d = m * st.q.inverse();
        if d.w < 0.0 {
            d = UnitQuaternion::new_unchecked(-d.into_inner());
        }
        let nu = d.scaled_axis();
        let s = st.p.fixed_view::<3, 3>(0, 0) + c;
        let Some(s_inv) = s.try_inverse() else {
            let c0 = c;
            self.start(m, &c0);
            return pass;
        };
        let d2 = (nu.transpose() * s_inv * nu)[0];
        if d2.is_nan() || d2 > self.params.gate {
            st.rejected += 1;
            if st.rejected >= self.params.max_rejected {
                self.start(m, &c);
                return pass;
            }
            return Filtered {
                rotation: st.q.to_rotation_matrix(),
                accepted: false,
            };
        }
        st.rejected = 0;
        // Update (Joseph form).
        let k: SMatrix<f64, 6, 3> = st.p.fixed_view::<6, 3>(0, 0) * s_inv;
        let x = k * nu;
        st.q = UnitQuaternion::from_scaled_axis(x.fixed_rows::<3>(0).into_owned()) * st.q;
        st.q.renormalize();
        st.omega += x.fixed_rows::<3>(3);
        let mut ikh = Matrix6::identity();
        ikh.fixed_view_mut::<6, 3>(0, 0).copy_from(&(-k));
        for i in 0..3 {
            ikh[(i, i)] += 1.0;
        }
        st.p = ikh * st.p * ikh.transpose() + k * c * k.transpose();
        Filtered {
            rotation: st.q.to_rotation_matrix(),
            accepted: true,
        }
    }

    fn default_cov(&self) -> Matrix3<f64> {
        Matrix3::identity() * self.params.default_sd_deg.to_radians().powi(2)
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

    fn iso(sd_deg: f64) -> Matrix3<f64> {
        Matrix3::identity() * sd_deg.to_radians().powi(2)
    }

    /// Noise of a known standard deviation on a still pose: the filtered error is far below
    /// the raw one, and a measurement declared noisier moves the track less.
    #[test]
    fn a_still_pose_is_held_and_noisy_frames_count_less() {
        let truth = rot(20.0, -10.0, 5.0);
        let mut rng = StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 2.0).unwrap();
        let mut f = RotationKalman::new(KalmanParams {
            acceleration_deg_s2: 10.0,
            ..KalmanParams::default()
        })
        .unwrap();
        let (mut raw, mut smooth) = (0.0, 0.0);
        for k in 0..300 {
            let m = rot(
                20.0 + noise.sample(&mut rng),
                -10.0 + noise.sample(&mut rng),
                5.0 + noise.sample(&mut rng),
            );
            let out = f.filter(&m, Some(&iso(2.0)), 1.0 / 30.0);
            if k >= 30 {
                raw += geodesic_deg(&m, &truth).powi(2);
                smooth += geodesic_deg(&out.rotation, &truth).powi(2);
            }
        }
        assert!(
            smooth < raw / 4.0,
            "squared error smoothed {smooth} raw {raw}"
        );
        // One step 5° off from a settled track: a measurement declared at 1° pulls it further
        // than one declared at 10°.
        let pull = |sd: f64| {
            let mut f = RotationKalman::new(KalmanParams::default()).unwrap();
            for _ in 0..60 {
                f.filter(&truth, Some(&iso(1.0)), 1.0 / 30.0);
            }
            let off = rot(25.0, -10.0, 5.0);
            geodesic_deg(&f.filter(&off, Some(&iso(sd)), 1.0 / 30.0).rotation, &truth)
        };
        assert!(
            pull(1.0) > 2.0 * pull(10.0),
            "{} vs {}",
            pull(1.0),
            pull(10.0)
        );
    }

    /// A steady turn is followed without a lasting lag (the velocity is part of the state).
    #[test]
    fn a_steady_turn_is_followed() {
        let mut f = RotationKalman::new(KalmanParams::default()).unwrap();
        let axis = nalgebra::Unit::new_normalize(Vector3::new(0.2, 1.0, 0.1));
        let mut err = 0.0;
        for k in 0..90 {
            let t = k as f64 / 30.0;
            let m = Rotation3::from_axis_angle(&axis, (60.0 * t - 60.0).to_radians());
            err = geodesic_deg(&f.filter(&m, Some(&iso(1.0)), 1.0 / 30.0).rotation, &m);
        }
        assert!(err < 0.5, "lag after 3 s at 60°/s: {err}°");
    }

    /// A wild frame is gated out; a real jump is taken after `max_rejected` frames.
    #[test]
    fn wild_frames_are_left_out_and_real_jumps_taken() {
        let p = KalmanParams::default();
        let mut f = RotationKalman::new(p).unwrap();
        let a = rot(0.0, 0.0, 0.0);
        for _ in 0..30 {
            f.filter(&a, Some(&iso(1.0)), 1.0 / 30.0);
        }
        let wild = rot(40.0, 0.0, 0.0);
        let out = f.filter(&wild, Some(&iso(1.0)), 1.0 / 30.0);
        assert!(!out.accepted);
        assert!(geodesic_deg(&out.rotation, &a) < 0.5);
        let mut last = out;
        for _ in 1..p.max_rejected {
            last = f.filter(&wild, Some(&iso(1.0)), 1.0 / 30.0);
        }
        assert!(last.accepted);
        assert_relative_eq!(last.rotation, wild, epsilon = 1e-9);
    }

    /// A profile measurement uncertain about pitch and roll (the axes of x and z at yaw 90°
    /// both turn the face about the same line) moves the track along yaw only.
    #[test]
    fn an_anisotropic_covariance_weighs_per_axis() {
        let mut f = RotationKalman::new(KalmanParams::default()).unwrap();
        let start = rot(0.0, 0.0, 0.0);
        for _ in 0..60 {
            f.filter(&start, Some(&iso(1.0)), 1.0 / 30.0);
        }
        // Sure about a turn about y, unsure about x.
        let cov = Matrix3::from_diagonal(&Vector3::new(
            30f64.to_radians().powi(2),
            1f64.to_radians().powi(2),
            1f64.to_radians().powi(2),
        ));
        let m = rot(4.0, 4.0, 0.0);
        let out = EulerAngles::from_rotation(&f.filter(&m, Some(&cov), 1.0 / 30.0).rotation);
        assert!(out.yaw > 1.0, "{out:?}");
        assert!(out.pitch.abs() < 0.1, "{out:?}");
    }

    #[test]
    fn bad_input_restarts_or_is_refused() {
        let mut f = RotationKalman::new(KalmanParams::default()).unwrap();
        f.filter(&rot(0.0, 0.0, 0.0), None, 0.1);
        let r = rot(40.0, 0.0, 0.0);
        for dt in [0.0, -1.0, f64::NAN] {
            assert_relative_eq!(f.filter(&r, None, dt).rotation, r, epsilon = 1e-12);
        }
        let bad = Rotation3::from_matrix_unchecked(r.matrix().map(|_| f64::NAN));
        assert!(f.filter(&bad, None, 0.1).rotation.matrix()[(0, 0)].is_nan());
        // Absurd time steps (a client's timestamps) keep the output finite, and the track
        // comes back to the measurements.
        for dt in [1e12, 1e300] {
            for _ in 0..10 {
                let out = f.filter(&r, Some(&iso(1.0)), dt).rotation;
                assert!(out.matrix().iter().all(|v| v.is_finite()), "{dt}");
            }
        }
        for _ in 0..20 {
            f.filter(&r, Some(&iso(1.0)), 1.0 / 30.0);
        }
        assert!(geodesic_deg(&f.filter(&r, Some(&iso(1.0)), 1.0 / 30.0).rotation, &r) < 0.1);
        let not_cov = Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0));
        assert_relative_eq!(
            f.filter(&r, Some(&not_cov), 0.1).rotation,
            r,
            epsilon = 1e-12
        );
        for p in [
            KalmanParams {
                acceleration_deg_s2: 0.0,
                ..KalmanParams::default()
            },
            KalmanParams {
                gate: f64::NAN,
                ..KalmanParams::default()
            },
            KalmanParams {
                max_rejected: 0,
                ..KalmanParams::default()
            },
        ] {
            assert!(RotationKalman::new(p).is_err());
        }
    }
}
