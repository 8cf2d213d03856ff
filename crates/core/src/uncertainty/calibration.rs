//! Calibration: the map from an estimate's raw spread ([`super::covariance`]) to a standard
//! deviation and a 90% interval per angle that hold on real faces.
//!
//! Per method and point class ([`PointClass`]) and per angle, the error `e` of an estimate is
//! modelled as `e ~ N(0, σ²)` with `ln σ = θ · x`, `x = [1, ln raw_sd, u, u², ln misfit]`
//! (`raw_sd` that angle's raw standard deviation in degrees, `u = min(|yaw| / 90, 1)` at the
//! estimate, `misfit` the answer's, [`crate::pose::Estimate::misfit`]).
//! [`fit_angle`] finds `θ` by maximum likelihood (a convex problem, Newton's method). Real
//! errors have heavier tails than a Gaussian, so the interval's half-width is then `c σ` with
//! `c` the split-conformal 90% quantile of `|e| / σ` over the same faces, and the reported
//! standard deviation is `c σ / 1.645`: the interval is always the estimate ± 1.645 standard
//! deviations, as for a Gaussian.
//!
//! A model bundle stores its calibration, fitted on faces with ground truth by
//! [`calibrate`] (`facepose train --calibrate`); `facepose eval --protocol real` measures it by
//! cross-validation (`facepose_eval::uncertainty`).

use nalgebra::{Matrix3, SMatrix, SVector};

type Vector = SVector<f64, N_FEATURES>;
type Matrix = SMatrix<f64, N_FEATURES, N_FEATURES>;
use serde::{Deserialize, Serialize};

use super::covariance::{MIN_RAW_SD_DEG, RawSpread};
use crate::error::{Error, Result};
use crate::pose::Method;
pub use crate::shape::PointClass;

/// The 95% quantile of the standard normal: a central 90% interval is ± this many standard
/// deviations.
pub const Z90: f64 = 1.644_853_626_951_472_2;

/// Widest half-interval, degrees: an angle known no better than this is undetermined.
pub const MAX_HALF_WIDTH_DEG: f64 = 180.0;

/// Share of the faces an interval is built to cover.
pub const COVERAGE: f64 = 0.9;

/// Features of the calibration's model.
pub const N_FEATURES: usize = 5;

/// One angle's model: `ln σ = coefficients · x`, half-width `multiplier · σ`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngleModel {
    /// Coefficients of `ln σ` on the features.
    pub coefficients: [f64; N_FEATURES],
    /// Half-width multiplier on `σ`, for the coverage.
    pub multiplier: f64,
}

/// The models of one method on one point class, pitch, yaw, roll.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationGroup {
    /// The method (resolved).
    pub method: Method,
    /// The point class.
    pub points: PointClass,
    /// Estimates it was fitted on.
    pub samples: usize,
    /// One model per angle (pitch, yaw, roll).
    pub angles: [AngleModel; 3],
}

/// A model's calibration (stored in its bundle).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// What it was fitted on, for people.
    pub data: String,
    /// One group per method and point class.
    pub groups: Vec<CalibrationGroup>,
}

/// An estimate's uncertainty, per angle (pitch, yaw, roll), degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Uncertainty {
    /// Standard deviation: the 90% interval is the angle ± [`Z90`] of them.
    pub sd: [f64; 3],
    /// The 90% interval `[low, high]` around the angle (not wrapped to ±180°).
    pub interval90: [[f64; 2]; 3],
    /// The covariance of the small turn `δ` (`R ← exp([δ]ₓ) R`, radians²): the raw one
    /// ([`RawSpread::turn_cov`]) scaled by the calibration (the geometric mean of the calibrated
    /// to raw standard deviation ratios of the angles it determines), for filters on rotations.
    pub turn_cov: Matrix3<f64>,
}

impl Uncertainty {
    /// The half-width of angle `k`'s 90% interval (pitch, yaw, roll), degrees: an error of at
    /// most this is inside it.
    pub fn half_width(&self, k: usize) -> f64 {
        0.5 * (self.interval90[k][1] - self.interval90[k][0])
    }
}

/// The features of one angle (see the module docs).
pub fn features(raw_sd: f64, yaw_deg: f64, misfit: f64) -> [f64; N_FEATURES] {
    let u = (yaw_deg.abs() / 90.0).min(1.0);
    let m = if misfit.is_finite() {
        misfit.max(MIN_MISFIT)
    } else {
        MIN_MISFIT
    };
    [1.0, raw_sd.max(MIN_RAW_SD_DEG).ln(), u, u * u, m.ln()]
}

/// Smallest misfit the features take (exact landmarks give zero).
const MIN_MISFIT: f64 = 1e-3;

impl AngleModel {
    /// The model's `σ` at `x` (infinite when `x` is).
    pub fn sigma(&self, x: &[f64; N_FEATURES]) -> f64 {
        let z: f64 = self.coefficients.iter().zip(x).map(|(c, v)| c * v).sum();
        if z.is_nan() { f64::INFINITY } else { z.exp() }
    }

    /// The half-width of the 90% interval at `x`, at most [`MAX_HALF_WIDTH_DEG`].
    pub fn half_width(&self, x: &[f64; N_FEATURES]) -> f64 {
        let h = self.multiplier * self.sigma(x);
        if h.is_finite() {
            h.min(MAX_HALF_WIDTH_DEG)
        } else {
            MAX_HALF_WIDTH_DEG
        }
    }
}

impl Calibration {
    /// The group of `method` (as resolved, never `auto`) on `points`.
    pub fn group(&self, method: Method, points: PointClass) -> Option<&CalibrationGroup> {
        self.groups
            .iter()
            .find(|g| g.method == method && g.points == points)
    }

    /// The uncertainty of an estimate at `angles` (pitch, yaw, roll) with raw spread `raw`;
    /// `None` when the calibration has no group for it.
    pub fn uncertainty(
        &self,
        method: Method,
        points: PointClass,
        raw: &RawSpread,
        angles: [f64; 3],
    ) -> Option<Uncertainty> {
        let g = self.group(method, points)?;
        Some(uncertainty_of(&g.angles, raw, angles))
    }

    /// Fails unless every figure is finite, multipliers positive, and no group repeats.
    pub fn validate(&self) -> Result<()> {
        for (i, g) in self.groups.iter().enumerate() {
            let finite = g.angles.iter().all(|a| {
                a.coefficients.iter().all(|c| c.is_finite())
                    && a.multiplier.is_finite()
                    && a.multiplier > 0.0
            });
            if !finite {
                return Err(Error::param(
                    "calibration",
                    format!(
                        "group {i} ({} on {}) has a non-finite or non-positive figure",
                        g.method,
                        g.points.name()
                    ),
                ));
            }
            if g.method == Method::Auto {
                return Err(Error::param(
                    "calibration",
                    format!(
                        "group {i} names method auto; groups are for the methods auto resolves to"
                    ),
                ));
            }
            if self.groups[..i]
                .iter()
                .any(|h| h.method == g.method && h.points == g.points)
            {
                return Err(Error::param(
                    "calibration",
                    format!(
                        "group {i} ({} on {}) repeats an earlier one",
                        g.method,
                        g.points.name()
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The uncertainty at `angles` from per-angle models.
pub fn uncertainty_of(models: &[AngleModel; 3], raw: &RawSpread, angles: [f64; 3]) -> Uncertainty {
    let yaw = angles[1];
    let half = [0, 1, 2].map(|k| models[k].half_width(&features(raw.sd_deg[k], yaw, raw.misfit)));
    let sd = half.map(|h| h / Z90);
    // The scale of the turn's covariance, from the angles the fit determines (not those at the
    // cap, nor those the gimbal lock leaves undetermined).
    let logs: Vec<f64> = (0..3)
        .filter(|&k| half[k] < MAX_HALF_WIDTH_DEG && raw.sd_deg[k].is_finite())
        .map(|k| (sd[k] / raw.sd_deg[k]).ln())
        .filter(|v| v.is_finite())
        .collect();
    let turn_cov = if logs.is_empty() || !raw.turn_cov.iter().all(|v| v.is_finite()) {
        Matrix3::identity() * (MAX_HALF_WIDTH_DEG / Z90).to_radians().powi(2)
    } else {
        let g = (logs.iter().sum::<f64>() / logs.len() as f64).exp();
        raw.turn_cov * (g * g)
    };
    Uncertainty {
        sd,
        interval90: [0, 1, 2].map(|k| [angles[k] - half[k], angles[k] + half[k]]),
        turn_cov,
    }
}

/// Smallest absolute error the fit takes, degrees: an exact estimate would pull `σ` to zero.
const MIN_ERROR_DEG: f64 = 1e-3;

/// Fits one angle's model to `(x, |error|)` samples (see the module docs). Fails on fewer than
/// 20 samples or non-finite ones.
pub fn fit_angle(samples: &[([f64; N_FEATURES], f64)]) -> Result<AngleModel> {
    if samples.len() < 20 {
        return Err(Error::too_few("calibration samples", 20, samples.len()));
    }
    if samples
        .iter()
        .any(|(x, e)| !e.is_finite() || x.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::non_finite("calibration samples"));
    }
    let data: Vec<(Vector, f64)> = samples
        .iter()
        .map(|(x, e)| (Vector::from(*x), e.abs().max(MIN_ERROR_DEG).powi(2)))
        .collect();
    // Negative log-likelihood (up to constants) with a light ridge on the slopes, which keeps
    // the problem strictly convex when a feature barely varies.
    const RIDGE: f64 = 1e-3;
    let ridge = |t: &Vector| 0.5 * RIDGE * t.rows(1, N_FEATURES - 1).norm_squared();
    let cost = |t: &Vector| {
        data.iter()
            .map(|(x, e2)| {
                let z = t.dot(x);
                z + 0.5 * e2 * (-2.0 * z).exp()
            })
            .sum::<f64>()
            + ridge(t)
    };
    let mean_e2 = data.iter().map(|d| d.1).sum::<f64>() / data.len() as f64;
    let mut theta = Vector::zeros();
    theta[0] = 0.5 * mean_e2.ln();
    let mut c = cost(&theta);
    for _ in 0..100 {
        let (mut g, mut h) = (Vector::zeros(), Matrix::zeros());
        for (x, e2) in &data {
            let k = e2 * (-2.0 * theta.dot(x)).exp();
            g += x * (1.0 - k);
            h += 2.0 * k * x * x.transpose();
        }
        for i in 1..N_FEATURES {
            g[i] += RIDGE * theta[i];
            h[(i, i)] += RIDGE;
        }
        let Some(step) = h.cholesky().map(|ch| ch.solve(&g)) else {
            break;
        };
        let mut a = 1.0;
        let mut moved = false;
        while a > 1e-8 {
            let next = theta - a * step;
            let cn = cost(&next);
            if cn <= c {
                (theta, c, moved) = (next, cn, true);
                break;
            }
            a *= 0.5;
        }
        if !moved || (a * step).norm() < 1e-10 {
            break;
        }
    }
    let mut m = AngleModel {
        coefficients: theta.into(),
        multiplier: 1.0,
    };
    let mut ratios: Vec<f64> = samples.iter().map(|(x, e)| e.abs() / m.sigma(x)).collect();
    ratios.sort_by(f64::total_cmp);
    // Split-conformal: the ⌈(n + 1) · 0.9⌉-th smallest ratio.
    let n = ratios.len();
    let rank = (((n + 1) as f64 * COVERAGE).ceil() as usize).clamp(1, n);
    m.multiplier = ratios[rank - 1];
    if !(m.multiplier.is_finite() && m.multiplier > 0.0)
        || m.coefficients.iter().any(|v| !v.is_finite())
    {
        return Err(Error::Numerical("the calibration fit diverged".into()));
    }
    Ok(m)
}

/// One estimate's figures for calibrating: its method (resolved) and point class, the raw
/// spread, the estimated angles and the true ones (pitch, yaw, roll, degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The method (resolved).
    pub method: Method,
    /// The point class.
    pub points: PointClass,
    /// The raw spread of the estimate.
    pub raw: RawSpread,
    /// Estimated angles: pitch, yaw, roll, degrees.
    pub estimate: [f64; 3],
    /// True angles: pitch, yaw, roll, degrees.
    pub truth: [f64; 3],
}

impl Sample {
    /// The absolute error of angle `k`, wrapped to ±180°.
    pub fn error(&self, k: usize) -> f64 {
        crate::geometry::convention::wrap_deg(self.estimate[k] - self.truth[k]).abs()
    }

    /// The features of angle `k`.
    pub fn features(&self, k: usize) -> [f64; N_FEATURES] {
        features(self.raw.sd_deg[k], self.estimate[1], self.raw.misfit)
    }
}

/// Fits the group of `method` on `points` from the samples that belong to it.
pub fn fit_group(
    samples: &[Sample],
    method: Method,
    points: PointClass,
) -> Result<CalibrationGroup> {
    let mine: Vec<&Sample> = samples
        .iter()
        .filter(|s| s.method == method && s.points == points)
        .collect();
    let angle = |k: usize| {
        let data: Vec<_> = mine.iter().map(|s| (s.features(k), s.error(k))).collect();
        fit_angle(&data)
    };
    Ok(CalibrationGroup {
        method,
        points,
        samples: mine.len(),
        angles: [angle(0)?, angle(1)?, angle(2)?],
    })
}

/// A calibration with a group for every (method, point class) the samples hold with at least
/// 20 samples, in the order of [`PointClass::ALL`] then [`Method::ALL`].
pub fn calibrate(samples: &[Sample], data: &str) -> Result<Calibration> {
    let mut groups = Vec::new();
    for points in PointClass::ALL {
        for method in Method::ALL {
            let n = samples
                .iter()
                .filter(|s| s.method == method && s.points == points)
                .count();
            if n >= 20 {
                groups.push(fit_group(samples, method, points)?);
            }
        }
    }
    if groups.is_empty() {
        return Err(Error::too_few(
            "calibration samples of any method",
            20,
            samples.len(),
        ));
    }
    Ok(Calibration {
        data: data.into(),
        groups,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{SeedableRng, rngs::StdRng};
    use rand_distr::{Distribution, Normal};

    /// The share of `samples` whose error is inside `m`'s interval.
    fn coverage(m: &AngleModel, samples: &[([f64; N_FEATURES], f64)]) -> f64 {
        let inside = samples
            .iter()
            .filter(|(x, e)| e.abs() <= m.half_width(x))
            .count();
        inside as f64 / samples.len() as f64
    }

    /// Errors drawn with a known `σ = 0.5 · raw_sd^1.5 · e^u · misfit^0.5`: the fit finds the
    /// law and the intervals cover 90% of fresh draws.
    #[test]
    fn recovers_a_known_heteroscedastic_law() {
        let mut rng = StdRng::seed_from_u64(11);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let mut draw = |n: usize| -> Vec<([f64; N_FEATURES], f64)> {
            (0..n)
                .map(|i| {
                    let raw = 0.2 + 3.0 * ((i * 7919) % 1000) as f64 / 1000.0;
                    let yaw = ((i * 104729) % 90) as f64;
                    let misfit = 0.02 + 0.2 * ((i * 31) % 101) as f64 / 101.0;
                    let x = features(raw, yaw, misfit);
                    let sigma = 0.5 * raw.powf(1.5) * x[2].exp() * misfit.sqrt();
                    (x, sigma * unit.sample(&mut rng))
                })
                .collect()
        };
        let m = fit_angle(&draw(4000)).unwrap();
        // The slopes of the log raw sd and the log misfit, and σ itself across the range (|yaw|
        // and |yaw|² trade off against each other and the intercept, so σ is what to hold).
        let c = m.coefficients;
        assert!(
            (c[1] - 1.5).abs() < 0.1 && (c[4] - 0.5).abs() < 0.1,
            "{c:?}"
        );
        for (raw, yaw, misfit) in [(0.3, 0.0, 0.05), (1.0, 45.0, 0.1), (3.0, 85.0, 0.2)] {
            let x = features(raw, yaw, misfit);
            let want = 0.5 * f64::powf(raw, 1.5) * x[2].exp() * f64::sqrt(misfit);
            let ratio = m.sigma(&x) / want;
            assert!(
                (0.9..1.1).contains(&ratio),
                "σ ratio {ratio} at {raw} {yaw} {misfit}: {c:?}"
            );
        }
        assert!((m.multiplier - Z90).abs() < 0.1, "{}", m.multiplier);
        let fresh = draw(4000);
        let covered = coverage(&m, &fresh);
        assert!((0.88..=0.92).contains(&covered), "{covered}");
    }

    /// Heavy tails (Student t with 3 degrees of freedom): the conformal multiplier, not the
    /// Gaussian's 1.645, makes the coverage.
    #[test]
    fn heavy_tails_still_cover_ninety_percent() {
        let mut rng = StdRng::seed_from_u64(5);
        let t = rand_distr::StudentT::new(3.0).unwrap();
        let mut draw = |n: usize| -> Vec<([f64; N_FEATURES], f64)> {
            (0..n)
                .map(|i| {
                    let raw = 0.5 + (i % 10) as f64 / 5.0;
                    (features(raw, 0.0, 0.1), raw * t.sample(&mut rng))
                })
                .collect()
        };
        let m = fit_angle(&draw(5000)).unwrap();
        let fresh = draw(5000);
        let covered = coverage(&m, &fresh);
        assert!((0.88..=0.92).contains(&covered), "{covered}");
    }

    #[test]
    fn interval_is_centred_and_capped() {
        let models = [AngleModel {
            coefficients: [0.0, 1.0, 0.0, 0.0, 0.0],
            multiplier: 2.0,
        }; 3];
        let raw = RawSpread {
            sd_deg: [1.0, 2.0, f64::INFINITY],
            sigma_px: 1.0,
            points: 68,
            turn_cov: Matrix3::identity() * 1e-4,
            misfit: 0.1,
        };
        let u = uncertainty_of(&models, &raw, [10.0, -20.0, 30.0]);
        assert_eq!(u.interval90[0], [8.0, 12.0]);
        assert_eq!(u.interval90[1], [-24.0, -16.0]);
        assert_eq!(u.interval90[2], [30.0 - 180.0, 30.0 + 180.0]);
        assert!((u.sd[0] - 2.0 / Z90).abs() < 1e-12);
    }

    #[test]
    fn validate_refuses_bad_groups() {
        let g = CalibrationGroup {
            method: Method::Fit,
            points: PointClass::Dense,
            samples: 100,
            angles: [AngleModel {
                coefficients: [0.0; N_FEATURES],
                multiplier: 1.6,
            }; 3],
        };
        let ok = Calibration {
            data: "test".into(),
            groups: vec![g.clone()],
        };
        assert!(ok.validate().is_ok());
        let twice = Calibration {
            groups: vec![g.clone(), g.clone()],
            ..ok.clone()
        };
        assert!(twice.validate().is_err());
        let mut nan = g.clone();
        nan.angles[1].multiplier = f64::NAN;
        assert!(
            Calibration {
                groups: vec![nan],
                ..ok.clone()
            }
            .validate()
            .is_err()
        );
        let auto = CalibrationGroup {
            method: Method::Auto,
            ..g
        };
        assert!(
            Calibration {
                groups: vec![auto],
                ..ok
            }
            .validate()
            .is_err()
        );
    }
}
