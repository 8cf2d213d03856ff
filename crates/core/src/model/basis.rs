//! Shape bases for the shape fit: principal components learned from a population (after rigid
//! alignment to their mean; size variation stays in the basis, in mm), or a given morphable
//! model's identity and expression bases, expressed in the model's frame.

use nalgebra::{DMatrix, SymmetricEigen, Vector3};

use crate::error::{Error, Result};
use crate::estimate::morph_fit::MorphableBasis;
use crate::geometry::{Scaling, align3};

/// A linear morphable model as published: `shape = mean + Σ a_k identity_k + Σ b_k
/// expression_k`, `a_k ~ N(identity_mean_k, 1)`, `b_k ~ N(expression_mean_k, 1)`, bases in mm per
/// standard deviation (e.g. ../shared/data/bfm68/morphable_model.json).
#[derive(Debug, Clone)]
pub struct MorphableModel {
    /// Mean shape, model frame, mm.
    pub mean: Vec<Vector3<f64>>,
    /// Identity components, one shape offset per component (mm per standard deviation).
    pub shape_basis: Vec<Vec<Vector3<f64>>>,
    /// Prior mean of the identity coefficients.
    pub shape_coef_mean: Vec<f64>,
    /// Expression components, one shape offset per component (mm per standard deviation).
    pub expression_basis: Vec<Vec<Vector3<f64>>>,
    /// Prior mean of the expression coefficients.
    pub expression_coef_mean: Vec<f64>,
}

/// The shape fit's basis from a morphable model, moved into the frame of `frame_mean` (a mean
/// shape of the same points, model frame): the rotation and translation that best align the
/// model's prior shape to it are applied to the mean and the bases. Expression coefficients get
/// a prior `expression_spread` times wider than the model states (in-the-wild faces vary more
/// in expression than the fits the model's statistics come from; docs/RESULTS.md).
pub fn morphable_basis(
    model: &MorphableModel,
    frame_mean: &[Vector3<f64>],
    expression_spread: f64,
) -> Result<MorphableBasis> {
    if !(expression_spread.is_finite() && expression_spread > 0.0) {
        return Err(Error::param(
            "expression_spread",
            format!("must be positive, got {expression_spread}"),
        ));
    }
    if model.shape_basis.len() != model.shape_coef_mean.len()
        || model.expression_basis.len() != model.expression_coef_mean.len()
    {
        return Err(Error::param(
            "morphable model",
            "each basis needs one coefficient mean per component",
        ));
    }
    let mut components = model.shape_basis.clone();
    components.extend(
        model
            .expression_basis
            .iter()
            .map(|b| b.iter().map(|v| v * expression_spread).collect::<Vec<_>>()),
    );
    let mut prior = model.shape_coef_mean.clone();
    prior.extend(
        model
            .expression_coef_mean
            .iter()
            .map(|m| m / expression_spread),
    );
    let raw = MorphableBasis::new(model.mean.clone(), components, prior)?;
    if frame_mean.len() != raw.mean().len() {
        return Err(Error::PointCount {
            what: "mean shape for the morphable model's frame".into(),
            expected: raw.mean().len(),
            got: frame_mean.len(),
        });
    }
    let t = align3(raw.prior_shape(), frame_mean, Scaling::Rigid)?;
    let r = t.rotation;
    MorphableBasis::new(
        raw.mean().iter().map(|p| t.apply(p)).collect(),
        raw.components()
            .iter()
            .map(|c| c.iter().map(|v| r * v).collect())
            .collect(),
        raw.prior_mean().to_vec(),
    )
}

/// The principal components of `shapes` around `mean` (both model frame, same points): at most
/// `max_components`, stopping once `variance` of the total is explained. Each basis shape is in
/// mm per standard deviation; the prior mean of every coefficient is 0.
pub fn pca_basis(
    shapes: &[Vec<Vector3<f64>>],
    mean: &[Vector3<f64>],
    max_components: usize,
    variance: f64,
) -> Result<MorphableBasis> {
    let n = mean.len();
    if shapes.len() < 2 {
        return Err(Error::too_few("shape basis (shapes)", 2, shapes.len()));
    }
    let d = 3 * n;
    let mut data = DMatrix::<f64>::zeros(shapes.len(), d);
    for (k, s) in shapes.iter().enumerate() {
        let t = align3(s, mean, Scaling::Rigid)?;
        for (i, p) in s.iter().enumerate() {
            let q = t.apply(p) - mean[i];
            data[(k, 3 * i)] = q.x;
            data[(k, 3 * i + 1)] = q.y;
            data[(k, 3 * i + 2)] = q.z;
        }
    }
    // Centre on the aligned shapes' own mean, which becomes the basis mean.
    let centre = data.row_mean();
    for mut row in data.row_iter_mut() {
        row -= &centre;
    }
    let cov = data.transpose() * &data / (shapes.len() - 1) as f64;
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..d).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let total: f64 = eig.eigenvalues.iter().filter(|v| **v > 0.0).sum();
    let mut basis = Vec::new();
    let mut explained = 0.0;
    for &j in &order {
        let lambda = eig.eigenvalues[j];
        if basis.len() >= max_components || lambda <= 1e-12 * total || explained >= variance * total
        {
            break;
        }
        explained += lambda;
        let v = eig.eigenvectors.column(j) * lambda.sqrt();
        basis.push(
            (0..n)
                .map(|i| Vector3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]))
                .collect(),
        );
    }
    let base_mean: Vec<Vector3<f64>> = (0..n)
        .map(|i| mean[i] + Vector3::new(centre[3 * i], centre[3 * i + 1], centre[3 * i + 2]))
        .collect();
    let k = basis.len();
    MorphableBasis::new(base_mean, basis, vec![0.0; k])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;

    #[test]
    fn a_morphable_model_moves_into_the_mean_frame() {
        // A model whose prior shape is the frame mean turned by 5° of yaw and shifted: the basis
        // must come back into the frame, components turned alike, expression spread applied.
        let frame: Vec<Vector3<f64>> = (0..8)
            .map(|i| {
                let a = i as f64 * 0.8;
                Vector3::new(40.0 * a.cos(), 30.0 * a.sin(), 10.0 * (i % 3) as f64)
            })
            .collect();
        let c = frame.iter().sum::<Vector3<f64>>() / 8.0;
        let frame: Vec<Vector3<f64>> = frame.iter().map(|p| p - c).collect();
        let turn = EulerAngles::new(5.0, 0.0, 0.0).unwrap().to_rotation();
        let shift = Vector3::new(3.0, -2.0, 7.0);
        let id: Vec<Vector3<f64>> = (0..8).map(|i| Vector3::new(0.0, 0.0, i as f64)).collect();
        let ex: Vec<Vector3<f64>> = (0..8).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        let model = MorphableModel {
            // mean + 1.0 * id (identity prior mean 1) is the turned frame shape.
            mean: frame
                .iter()
                .zip(&id)
                .map(|(p, b)| turn * p + shift - turn * b)
                .collect(),
            shape_basis: vec![id.iter().map(|b| turn * b).collect()],
            shape_coef_mean: vec![1.0],
            expression_basis: vec![ex.iter().map(|b| turn * b).collect()],
            expression_coef_mean: vec![0.0],
        };
        let b = morphable_basis(&model, &frame, 3.0).unwrap();
        for (p, q) in b.prior_shape().iter().zip(&frame) {
            assert!((p - q).norm() < 1e-9, "{p} vs {q}");
        }
        for (v, e) in b.components()[1].iter().zip(&ex) {
            assert!((v - 3.0 * e).norm() < 1e-9);
        }
        assert!(morphable_basis(&model, &frame, 0.0).is_err());
        assert!(morphable_basis(&model, &frame[..7], 1.0).is_err());
    }

    #[test]
    fn recovers_a_one_dimensional_family() {
        // Shapes = base + a * dir with a size mode (rigid alignment keeps size): one component
        // whose norm is the spread of a, sqrt(2.5), since |dir| = 1.
        let raw: Vec<Vector3<f64>> = (0..6)
            .map(|i| Vector3::new(i as f64 * 10.0, (i * i) as f64, (i % 3) as f64 * 7.0))
            .collect();
        let c = raw.iter().sum::<Vector3<f64>>() / 6.0;
        let base: Vec<Vector3<f64>> = raw.iter().map(|p| p - c).collect();
        let len = base.iter().map(|p| p.norm_squared()).sum::<f64>().sqrt();
        let shapes: Vec<Vec<Vector3<f64>>> = [-2.0, -1.0, 0.0, 1.0, 2.0]
            .iter()
            .map(|a| base.iter().map(|p| p + *a * p / len).collect())
            .collect();
        let b = pca_basis(&shapes, &base, 10, 0.9999).unwrap();
        assert_eq!(b.components().len(), 1);
        let norm: f64 = b.components()[0]
            .iter()
            .map(|v| v.norm_squared())
            .sum::<f64>()
            .sqrt();
        assert!((norm - 2.5f64.sqrt()).abs() < 1e-9, "{norm}");
        assert_eq!(b.prior_mean(), &[0.0]);
    }
}
