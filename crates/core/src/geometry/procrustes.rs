//! Similarity Procrustes (Umeyama 1991) in 2D and 3D, and generalized Procrustes analysis for
//! a mean 3D shape.

use nalgebra::{Matrix3, Rotation2, Rotation3, Vector2, Vector3};

use crate::error::{Error, Result};

/// `dst ≈ scale · R · src + translation`, the least-squares similarity between two 3D point sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity3 {
    /// Scale factor `scale`.
    pub scale: f64,
    /// Rotation `R`.
    pub rotation: Rotation3<f64>,
    /// Translation, in `dst`'s units.
    pub translation: Vector3<f64>,
}

impl Similarity3 {
    /// Applies the transform to a point.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// `dst ≈ scale · R · src + translation` in the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity2 {
    /// Scale factor `scale`.
    pub scale: f64,
    /// Rotation `R`.
    pub rotation: Rotation2<f64>,
    /// Translation, in `dst`'s units.
    pub translation: Vector2<f64>,
}

impl Similarity2 {
    /// Applies the transform to a point.
    pub fn apply(&self, p: &Vector2<f64>) -> Vector2<f64> {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// Which transforms an alignment may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scaling {
    /// Rotation and translation only.
    Rigid,
    /// Rotation, translation and one isotropic scale.
    Similarity,
}

fn check_pairs(what: &str, a: usize, b: usize, min: usize) -> Result<()> {
    if a != b {
        return Err(Error::PointCount {
            what: what.into(),
            expected: a,
            got: b,
        });
    }
    if a < min {
        return Err(Error::too_few(what, min, a));
    }
    Ok(())
}

/// The proper rotation (det +1) nearest to a 3x3 matrix `m` in the sense of maximizing
/// `trace(R^T m)`, with the singular values and the sign correction of Umeyama's method.
fn umeyama_rotation3(cov: &Matrix3<f64>) -> Result<(Matrix3<f64>, f64)> {
    let svd = cov.svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => {
            return Err(Error::Numerical(
                "SVD of the cross-covariance failed".into(),
            ));
        }
    };
    let d = if (u * vt).determinant() < 0.0 {
        -1.0
    } else {
        1.0
    };
    let s = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    let trace_ds = svd.singular_values[0] + svd.singular_values[1] + d * svd.singular_values[2];
    Ok((u * s * vt, trace_ds))
}

/// Least-squares similarity (or rigid) transform taking `src` onto `dst` (Umeyama). Needs three
/// non-collinear pairs.
pub fn align3(src: &[Vector3<f64>], dst: &[Vector3<f64>], scaling: Scaling) -> Result<Similarity3> {
    check_pairs("3D alignment", src.len(), dst.len(), 3)?;
    let n = src.len() as f64;
    let ms = src.iter().sum::<Vector3<f64>>() / n;
    let md = dst.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (s, d) = (s - ms, d - md);
        cov += d * s.transpose();
        var_s += s.norm_squared();
    }
    if !(var_s.is_finite() && cov.iter().all(|v| v.is_finite())) {
        return Err(Error::non_finite("3D alignment points"));
    }
    if var_s < 1e-18 {
        return Err(Error::Degenerate("the source points all coincide".into()));
    }
    let (r, trace_ds) = umeyama_rotation3(&cov)?;
    let scale = match scaling {
        Scaling::Rigid => 1.0,
        Scaling::Similarity => trace_ds / var_s,
    };
    if scale.is_nan() || scale <= 0.0 {
        return Err(Error::Degenerate("the target points all coincide".into()));
    }
    let rotation = Rotation3::from_matrix_unchecked(r);
    Ok(Similarity3 {
        scale,
        rotation,
        translation: md - scale * (rotation * ms),
    })
}

/// Least-squares similarity (or rigid) transform taking `src` onto `dst` in the plane.
pub fn align2(src: &[Vector2<f64>], dst: &[Vector2<f64>], scaling: Scaling) -> Result<Similarity2> {
    check_pairs("2D alignment", src.len(), dst.len(), 2)?;
    let n = src.len() as f64;
    let ms = src.iter().sum::<Vector2<f64>>() / n;
    let md = dst.iter().sum::<Vector2<f64>>() / n;
    let (mut a, mut b, mut var_s) = (0.0, 0.0, 0.0);
    for (s, d) in src.iter().zip(dst) {
        let (s, d) = (s - ms, d - md);
        a += s.dot(&d);
        b += s.x * d.y - s.y * d.x;
        var_s += s.norm_squared();
    }
    if !(a.is_finite() && b.is_finite() && var_s.is_finite()) {
        return Err(Error::non_finite("2D alignment points"));
    }
    if var_s < 1e-18 {
        return Err(Error::Degenerate("the source points all coincide".into()));
    }
    let angle = b.atan2(a);
    let scale = match scaling {
        Scaling::Rigid => 1.0,
        Scaling::Similarity => a.hypot(b) / var_s,
    };
    if scale.is_nan() || scale <= 0.0 {
        return Err(Error::Degenerate("the target points all coincide".into()));
    }
    let rotation = Rotation2::new(angle);
    Ok(Similarity2 {
        scale,
        rotation,
        translation: md - scale * (rotation * ms),
    })
}

/// Root-mean-square distance between corresponding points.
pub fn rms_distance3(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    let sum: f64 = a.iter().zip(b).map(|(p, q)| (p - q).norm_squared()).sum();
    (sum / a.len().max(1) as f64).sqrt()
}

/// Options of [`generalized_procrustes`].
#[derive(Debug, Clone, Copy)]
pub struct GpaOptions {
    /// Stop when the mean moves less than this (model units, RMS per point).
    pub tolerance: f64,
    /// Iterations at most.
    pub max_iterations: usize,
}

impl Default for GpaOptions {
    fn default() -> Self {
        GpaOptions {
            tolerance: 1e-9,
            max_iterations: 100,
        }
    }
}

/// Generalized Procrustes analysis: the mean of 3D shapes after iterated similarity alignment.
///
/// Scale is kept in the shapes' own unit (mm for the data here): the mean's centroid size is the
/// average centroid size of the inputs. Its orientation is that of the plain average of the
/// inputs as given (a frontal database keeps its frontal frame); the mean is centred at the
/// origin. Every shape must have the same number of points, all present.
pub fn generalized_procrustes(
    shapes: &[Vec<Vector3<f64>>],
    opts: GpaOptions,
) -> Result<Vec<Vector3<f64>>> {
    let first = shapes
        .first()
        .ok_or_else(|| Error::too_few("generalized Procrustes shapes", 1, 0))?;
    let n = first.len();
    if n < 3 {
        return Err(Error::too_few("generalized Procrustes", 3, n));
    }
    let mut centred = Vec::with_capacity(shapes.len());
    let mut mean_size = 0.0;
    for (k, s) in shapes.iter().enumerate() {
        if s.len() != n {
            return Err(Error::PointCount {
                what: format!("shape {k}"),
                expected: n,
                got: s.len(),
            });
        }
        if s.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite(format!("shape {k}")));
        }
        let c = centre3(s);
        let size = centroid_size3(&c);
        if size < 1e-12 {
            return Err(Error::Degenerate(format!(
                "shape {k} has all its points at one place"
            )));
        }
        mean_size += size;
        centred.push(c);
    }
    mean_size /= shapes.len() as f64;

    // The orientation reference: the plain average of the shapes as given.
    let reference = average(&centred);
    let mut mean = centred[0].clone();
    let mut aligned = centred.clone();
    for _ in 0..opts.max_iterations {
        for (a, s) in aligned.iter_mut().zip(&centred) {
            let t = align3(s, &mean, Scaling::Similarity)?;
            for (dst, p) in a.iter_mut().zip(s) {
                *dst = t.apply(p);
            }
        }
        let mut next = centre3(&average(&aligned));
        let size = centroid_size3(&next);
        if size < 1e-12 {
            return Err(Error::Degenerate(
                "the aligned shapes average to a point".into(),
            ));
        }
        next.iter_mut().for_each(|p| *p *= mean_size / size);
        let moved = rms_distance3(&next, &mean);
        mean = next;
        if moved < opts.tolerance {
            break;
        }
    }
    // Put the mean back in the frame of the input.
    if centroid_size3(&reference) > 1e-12 {
        let t = align3(&mean, &reference, Scaling::Rigid)?;
        mean.iter_mut().for_each(|p| *p = t.rotation * *p);
    }
    Ok(mean)
}

fn average(shapes: &[Vec<Vector3<f64>>]) -> Vec<Vector3<f64>> {
    let n = shapes[0].len();
    let mut out = vec![Vector3::zeros(); n];
    for s in shapes {
        for (o, p) in out.iter_mut().zip(s) {
            *o += p;
        }
    }
    out.iter_mut().for_each(|p| *p /= shapes.len() as f64);
    out
}

/// The points moved so that their centroid is the origin.
pub fn centre3(points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let c = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    points.iter().map(|p| p - c).collect()
}

/// Root of the summed squared distances to the centroid (assumes centred points).
pub fn centroid_size3(centred: &[Vector3<f64>]) -> f64 {
    centred.iter().map(|p| p.norm_squared()).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    fn cloud() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(-30.0, 20.0, 0.0),
            Vector3::new(30.0, 20.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-20.0, -30.0, 5.0),
            Vector3::new(20.0, -30.0, 5.0),
            Vector3::new(0.0, -60.0, -10.0),
        ]
    }

    proptest! {
        #[test]
        fn recovers_a_known_similarity(yaw in -90.0f64..90.0, pitch in -90.0f64..90.0, roll in -180.0f64..180.0,
                                       s in 0.1f64..10.0, tx in -100.0f64..100.0, ty in -100.0f64..100.0) {
            let r = EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation();
            let t = Vector3::new(tx, ty, 7.0);
            let src = cloud();
            let dst: Vec<_> = src.iter().map(|p| s * (r * p) + t).collect();
            let sim = align3(&src, &dst, Scaling::Similarity).unwrap();
            prop_assert!((sim.scale - s).abs() < 1e-9 * s);
            prop_assert!((sim.rotation.matrix() - r.matrix()).abs().max() < 1e-9);
            prop_assert!((sim.translation - t).norm() < 1e-7);
        }

        #[test]
        fn recovers_a_known_2d_similarity(angle in -3.1f64..3.1, s in 0.1f64..10.0) {
            let r = Rotation2::new(angle);
            let src: Vec<_> = cloud().iter().map(|p| p.xy()).collect();
            let dst: Vec<_> = src.iter().map(|p| s * (r * p) + Vector2::new(3.0, -4.0)).collect();
            let sim = align2(&src, &dst, Scaling::Similarity).unwrap();
            prop_assert!((sim.scale - s).abs() < 1e-9 * s);
            prop_assert!((sim.rotation.angle() - angle).abs() < 1e-9);
        }
    }

    #[test]
    fn never_returns_a_reflection() {
        let src = cloud();
        let dst: Vec<_> = src.iter().map(|p| Vector3::new(-p.x, p.y, p.z)).collect();
        let sim = align3(&src, &dst, Scaling::Similarity).unwrap();
        assert_relative_eq!(sim.rotation.matrix().determinant(), 1.0, epsilon = 1e-12);
    }

    #[test]
    fn degenerate_and_mismatched_inputs_are_errors() {
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 4];
        assert!(matches!(
            align3(&same, &cloud()[..4], Scaling::Similarity),
            Err(Error::Degenerate(_))
        ));
        assert!(matches!(
            align3(&cloud(), &cloud()[..4], Scaling::Rigid),
            Err(Error::PointCount { .. })
        ));
        let nan = vec![Vector3::new(f64::NAN, 0.0, 0.0); 6];
        assert!(matches!(
            align3(&nan, &cloud(), Scaling::Rigid),
            Err(Error::NonFinite { .. })
        ));
    }

    #[test]
    fn gpa_of_rotated_scaled_copies_is_the_shape_in_the_input_frame() {
        let base = centre3(&cloud());
        let mut shapes = vec![base.clone()];
        for (k, (yaw, s)) in [(10.0, 1.1), (-8.0, 0.9), (3.0, 1.0)].iter().enumerate() {
            let r = EulerAngles::new(*yaw, 2.0 * k as f64, -1.0)
                .unwrap()
                .to_rotation();
            shapes.push(
                base.iter()
                    .map(|p| *s * (r * p) + Vector3::new(5.0, 1.0, 2.0))
                    .collect(),
            );
        }
        let mean = generalized_procrustes(&shapes, GpaOptions::default()).unwrap();
        // Same shape; size = the average centroid size; orientation near the input frame.
        let sim = align3(&mean, &base, Scaling::Similarity).unwrap();
        let aligned: Vec<_> = mean.iter().map(|p| sim.apply(p)).collect();
        assert!(rms_distance3(&aligned, &base) < 1e-9);
        let expected = centroid_size3(&base) * (1.0 + 1.1 + 0.9 + 1.0) / 4.0;
        assert_relative_eq!(centroid_size3(&mean), expected, epsilon = 1e-9);
        assert!(sim.rotation.angle().to_degrees() < 3.0);
    }
}
