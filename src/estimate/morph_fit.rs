//! Weak-perspective fit of a linear morphable shape model: the rigid camera and the identity /
//! expression coefficients under a Gaussian prior, by alternation.
//!
//! Shape: `X(c) = mean + Σ_k c_k B_k` with `c ~ N(prior_mean, I)` (coefficients in standard
//! deviations, bases in mm per standard deviation). Each round fits the camera to the current
//! shape ([`fit_rigid`]) and then solves the coefficients in closed form:
//! `min Σ wᵢ ‖s P R Xᵢ(c) + t - yᵢ‖² + σ² ‖c - prior_mean‖²`, a ridge system with one unknown per
//! basis shape; `σ` is the assumed landmark noise in pixels.

use nalgebra::{DMatrix, DVector, Vector2, Vector3};

use super::fit::{FitOptions, RigidFit, fit_rigid};
use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::shape::Shape2;

/// A linear shape model over a scheme's points.
#[derive(Debug, Clone, PartialEq)]
pub struct MorphableBasis {
    pub mean: Vec<Vector3<f64>>,
    /// Basis shapes (identity then expression), mm per standard deviation.
    pub basis: Vec<Vec<Vector3<f64>>>,
    /// The prior mean of each coefficient, in standard deviations.
    pub prior_mean: Vec<f64>,
}

impl MorphableBasis {
    /// Validates sizes and finiteness.
    pub fn new(
        mean: Vec<Vector3<f64>>,
        basis: Vec<Vec<Vector3<f64>>>,
        prior_mean: Vec<f64>,
    ) -> Result<Self> {
        if basis.len() != prior_mean.len() {
            return Err(Error::param(
                "prior_mean",
                format!(
                    "{} values for {} basis shapes",
                    prior_mean.len(),
                    basis.len()
                ),
            ));
        }
        if let Some(k) = basis.iter().position(|b| b.len() != mean.len()) {
            return Err(Error::PointCount {
                what: format!("basis shape {k}"),
                expected: mean.len(),
                got: basis[k].len(),
            });
        }
        let finite = mean
            .iter()
            .chain(basis.iter().flatten())
            .all(|p| p.iter().all(|v| v.is_finite()))
            && prior_mean.iter().all(|v| v.is_finite());
        if !finite {
            return Err(Error::non_finite("morphable model"));
        }
        Ok(MorphableBasis {
            mean,
            basis,
            prior_mean,
        })
    }

    /// The shape for coefficients `c`.
    pub fn shape(&self, c: &[f64]) -> Vec<Vector3<f64>> {
        let mut out = self.mean.clone();
        for (b, &ck) in self.basis.iter().zip(c) {
            for (o, v) in out.iter_mut().zip(b) {
                *o += ck * v;
            }
        }
        out
    }

    /// The shape at the prior mean.
    pub fn prior_shape(&self) -> Vec<Vector3<f64>> {
        self.shape(&self.prior_mean)
    }
}

/// Options of [`fit_morphable`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MorphOptions {
    pub rigid: FitOptions,
    /// Alternation rounds.
    pub rounds: usize,
    /// Assumed landmark noise as a fraction of the face's projected size (its RMS radius).
    pub noise: f64,
}

impl Default for MorphOptions {
    fn default() -> Self {
        MorphOptions {
            rigid: FitOptions {
                hpr_aware: false,
                ..FitOptions::default()
            },
            rounds: 4,
            noise: 0.01,
        }
    }
}

/// The fitted camera and coefficients.
#[derive(Debug, Clone)]
pub struct MorphFit {
    pub camera: RigidFit,
    pub coefficients: Vec<f64>,
    pub shape: Vec<Vector3<f64>>,
}

/// Fits the morphable model to `landmarks` (image pixels).
pub fn fit_morphable(
    model: &MorphableBasis,
    landmarks: &Shape2,
    contour: &[usize],
    visibility: Option<&VisibilityMap>,
    opts: MorphOptions,
) -> Result<MorphFit> {
    let n = model.mean.len();
    let k = model.basis.len();
    let mut c = model.prior_mean.clone();
    let mut shape = model.shape(&c);
    let mut camera = fit_rigid(&shape, landmarks, contour, visibility, opts.rigid)?;
    let y: Vec<Vector2<f64>> = landmarks
        .points()
        .iter()
        .map(|p| Vector2::new(p.x, -p.y))
        .collect();
    for _ in 0..opts.rounds {
        let (r, s, t) = (camera.rotation, camera.scale, camera.translation);
        let w = &camera.weights;
        let sw: f64 = w.iter().sum();
        let radius = {
            let c2 = shape
                .iter()
                .zip(w)
                .map(|(x, &wi)| wi * (r * x).xy())
                .sum::<Vector2<f64>>()
                / sw;
            (shape
                .iter()
                .zip(w)
                .map(|(x, &wi)| wi * ((r * x).xy() - c2).norm_squared())
                .sum::<f64>()
                / sw)
                .sqrt()
                * s
        };
        let sigma2 = (opts.noise * radius).powi(2);
        // Normal equations of the coefficient ridge.
        let mut a = DMatrix::<f64>::zeros(k, k);
        let mut b = DVector::<f64>::zeros(k);
        let mut cols = vec![Vector2::zeros(); k];
        for i in 0..n {
            let wi = w[i];
            if wi == 0.0 {
                continue;
            }
            let res = y[i] - t - s * (r * model.mean[i]).xy();
            for (col, basis) in cols.iter_mut().zip(&model.basis) {
                *col = s * (r * basis[i]).xy();
            }
            for p in 0..k {
                b[p] += wi * cols[p].dot(&res);
                for q in p..k {
                    a[(p, q)] += wi * cols[p].dot(&cols[q]);
                }
            }
        }
        for p in 0..k {
            for q in 0..p {
                a[(p, q)] = a[(q, p)];
            }
            a[(p, p)] += sigma2;
            b[p] += sigma2 * model.prior_mean[p];
        }
        let sol = a
            .cholesky()
            .ok_or_else(|| {
                Error::Numerical("the coefficient system is not positive definite".into())
            })?
            .solve(&b);
        c = sol.iter().copied().collect();
        shape = model.shape(&c);
        camera = fit_rigid(&shape, landmarks, contour, visibility, opts.rigid)?;
    }
    Ok(MorphFit {
        camera,
        coefficients: c,
        shape,
    })
}
