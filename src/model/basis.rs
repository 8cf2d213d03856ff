//! A shape basis learned from a population: principal components of the shapes after rigid
//! alignment to their mean (size variation stays in the basis, in mm).

use nalgebra::{DMatrix, SymmetricEigen, Vector3};

use crate::error::{Error, Result};
use crate::estimate::morph_fit::MorphableBasis;
use crate::geometry::{Scaling, align3};

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
        assert_eq!(b.basis.len(), 1);
        let norm: f64 = b.basis[0]
            .iter()
            .map(|v| v.norm_squared())
            .sum::<f64>()
            .sqrt();
        assert!((norm - 2.5f64.sqrt()).abs() < 1e-9, "{norm}");
        assert_eq!(b.prior_mean, vec![0.0]);
    }
}
