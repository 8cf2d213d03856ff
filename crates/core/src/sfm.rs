//! Structure from motion under weak perspective (paper §3.1): Tomasi-Kanade factorization with
//! the metric upgrade, for several 2D views of one face.
//!
//! 1. The views (image pixels, y down) are turned to the y-up plane and stacked into the
//!    `2F x n` measurement matrix `W`; each row is centred on its mean.
//! 2. Rank-3 factorization `W ≈ M̂ Ŝ` by SVD.
//! 3. Metric upgrade: find `L = Q Qᵀ` (symmetric) such that every camera `(a_f, b_f)` of
//!    `M = M̂ Q` has orthogonal rows of equal length (weak perspective: the scaled orthographic
//!    constraints `a_fᵀ L a_f = b_fᵀ L b_f`, `a_fᵀ L b_f = 0`, solved as the null vector of the
//!    linear system, then scaled so that the mean camera scale is 1). When noise makes `L`
//!    indefinite, its nearest positive semidefinite matrix is used (negative eigenvalues raised
//!    to a small positive floor so that `Q` stays invertible).
//! 4. Refinement by alternation: each camera is re-fitted as a scaled orthographic projection,
//!    each point as the least-squares intersection of its observations, using observed entries
//!    only, until the residual stops falling.
//! 5. The shape is expressed in the frame of view 0 (its camera's rows are the x and y axes),
//!    centred; the reflection ambiguity (`z -> -z`) is resolved so that the nose tip points to
//!    the camera (+z relative to the centroid).
//!
//! Missing points: a view may lack some points (`present == false`). Each point must be seen
//! in at least two views and each view must see at least four points. The factorization starts
//! with the missing entries of `W` set to the row means and re-imputes them from the current
//! rank-3 fit until they settle; the alternation of step 4 then uses observed entries only.
//!
//! Units: the shape comes out in the views' pixels at the mean camera scale (scale is not
//! observable); align it to a reference or rescale it to millimetres as needed.

use nalgebra::{DMatrix, Matrix2x3, Matrix3, Rotation3, SymmetricEigen, Vector2, Vector3, Vector6};

use crate::error::{Error, Result};
use crate::geometry::WeakPerspective;
use crate::geometry::{image_to_plane, rotation_from_two_rows};
use crate::shape::Shape2;

/// Options of [`reconstruct`].
#[derive(Debug, Clone, Copy)]
pub struct SfmOptions {
    /// Index of the nose tip, used to resolve the reflection.
    pub nose_tip: usize,
    /// Iteration cap of the imputation and of the alternation.
    pub max_iterations: usize,
    /// Stop when the RMS residual (pixels) changes by less than this, relative.
    pub tolerance: f64,
}

impl SfmOptions {
    /// Defaults with the nose tip at `nose_tip` (30 for ibug68).
    pub fn with_nose_tip(nose_tip: usize) -> Self {
        SfmOptions {
            nose_tip,
            max_iterations: 2000,
            tolerance: 1e-14,
        }
    }
}

/// The result of [`reconstruct`].
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// The 3D shape in the frame of view 0 (x right, y up, z towards the camera), centred.
    pub shape: Vec<Vector3<f64>>,
    /// One weak-perspective camera per view, mapping `shape` onto that view's pixels.
    pub cameras: Vec<WeakPerspective>,
    /// Root-mean-square reprojection error over the observed points, in pixels.
    pub rms_residual: f64,
    /// How many entries were missing and imputed.
    pub missing_entries: usize,
}

/// Rebuilds a 3D shape from `views` of the same face. Needs at least three views (the metric
/// upgrade has six unknowns and two constraints per view) of at least four points.
pub fn reconstruct(views: &[Shape2], opts: SfmOptions) -> Result<Reconstruction> {
    let f = views.len();
    if f < 3 {
        return Err(Error::too_few("structure from motion (views)", 3, f));
    }
    let n = views[0].len();
    if n < 4 {
        return Err(Error::too_few(
            "structure from motion (points per view)",
            4,
            n,
        ));
    }
    if opts.nose_tip >= n {
        return Err(Error::param(
            "nose_tip",
            format!("point {} of {n}", opts.nose_tip),
        ));
    }
    for (k, v) in views.iter().enumerate() {
        if v.len() != n {
            return Err(Error::PointCount {
                what: format!("view {k}"),
                expected: n,
                got: v.len(),
            });
        }
        if v.n_present() < 4 {
            return Err(Error::too_few(format!("view {k}"), 4, v.n_present()));
        }
    }
    for j in 0..n {
        let seen = views.iter().filter(|v| v.present()[j]).count();
        if seen < 2 {
            return Err(Error::too_few(
                format!("point {j} (views that see it)"),
                2,
                seen,
            ));
        }
    }

    // Measurement matrix in the y-up plane, missing entries at the row means.
    let mut w = DMatrix::<f64>::zeros(2 * f, n);
    let mut mask = vec![vec![false; n]; f];
    let mut missing_entries = 0;
    for (k, v) in views.iter().enumerate() {
        let c = v.centroid()?;
        for j in 0..n {
            match v.get(j) {
                Some(p) => {
                    w[(2 * k, j)] = p.x;
                    w[(2 * k + 1, j)] = -p.y;
                    mask[k][j] = true;
                }
                None => {
                    w[(2 * k, j)] = c.x;
                    w[(2 * k + 1, j)] = -c.y;
                    missing_entries += 1;
                }
            }
        }
    }
    let spread = centred(&w).norm() / ((2 * f * n) as f64).sqrt();
    if spread.is_nan() || spread <= 1e-9 {
        return Err(Error::Degenerate(
            "every view has all its points at one place".into(),
        ));
    }

    // Factorization, re-imputing missing entries from the rank-3 fit.
    let mut fit = rank3(&centred(&w))?;
    if missing_entries > 0 {
        for _ in 0..opts.max_iterations {
            let approx = &fit.0 * &fit.1 + row_means(&w);
            let mut change = 0.0f64;
            for (k, row) in mask.iter().enumerate() {
                for (j, &seen) in row.iter().enumerate() {
                    if !seen {
                        for r in [2 * k, 2 * k + 1] {
                            change = change.max((approx[(r, j)] - w[(r, j)]).abs());
                            w[(r, j)] = approx[(r, j)];
                        }
                    }
                }
            }
            fit = rank3(&centred(&w))?;
            if change < 1e-10 * spread {
                break;
            }
        }
    }
    let (m_hat, s_hat) = fit;
    let q = metric_upgrade(&m_hat)?;
    let q_inv = q
        .try_inverse()
        .ok_or_else(|| Error::Numerical("the metric upgrade is singular".into()))?;
    let motion = &m_hat * q;
    let shape_m = q_inv * s_hat;
    let mut shape: Vec<Vector3<f64>> = (0..n)
        .map(|j| shape_m.fixed_view::<3, 1>(0, j).into_owned())
        .collect();
    let means = row_means(&w);
    let mut cameras: Vec<(Matrix2x3<f64>, Vector2<f64>)> = (0..f)
        .map(|k| {
            let p = Matrix2x3::from_rows(&[
                motion.row(2 * k).clone_owned(),
                motion.row(2 * k + 1).clone_owned(),
            ]);
            (
                nearest_scaled_orthographic(&p),
                Vector2::new(means[(2 * k, 0)], means[(2 * k + 1, 0)]),
            )
        })
        .collect();

    // Alternation on the observed entries only.
    let obs: Vec<Vec<Option<Vector2<f64>>>> = views
        .iter()
        .map(|v| (0..n).map(|j| v.get(j).map(image_to_plane)).collect())
        .collect();
    let mut rms = residual(&obs, &cameras, &shape);
    for _ in 0..opts.max_iterations {
        for (k, cam) in cameras.iter_mut().enumerate() {
            if let Some(c) = fit_camera(&obs[k], &shape) {
                *cam = c;
            }
        }
        for (j, x) in shape.iter_mut().enumerate() {
            if let Some(p) = fit_point(&obs, &cameras, j) {
                *x = p;
            }
        }
        let next = residual(&obs, &cameras, &shape);
        let done = (rms - next).abs() <= opts.tolerance * rms.max(spread * 1e-12);
        rms = next;
        if done {
            break;
        }
    }

    // Frame of view 0, centred; mean camera scale 1; nose to the camera.
    let (p0, _) = cameras[0];
    let r0 = camera_rotation(&p0);
    let mean_scale = cameras.iter().map(|(p, _)| p.row(0).norm()).sum::<f64>() / f as f64;
    let centroid = shape.iter().sum::<Vector3<f64>>() / n as f64;
    let mut out: Vec<Vector3<f64>> = shape
        .iter()
        .map(|x| r0 * (x - centroid) * mean_scale)
        .collect();
    let mirror = out[opts.nose_tip].z < 0.0;
    if mirror {
        out.iter_mut().for_each(|p| p.z = -p.z);
    }
    let cams = cameras
        .iter()
        .map(|(p, t)| {
            // p x = p r0ᵀ (out / s) + p centroid: rotation p r0ᵀ (z column negated if mirrored).
            let mut rows = p * r0.matrix().transpose() / mean_scale;
            if mirror {
                rows.column_mut(2).neg_mut();
            }
            let s = rows.row(0).norm();
            let r = camera_rotation(&(rows / s));
            let t = t + p * centroid;
            WeakPerspective::new(r, s, t)
        })
        .collect::<Result<Vec<_>>>()?;
    if !rms.is_finite() || out.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(Error::Numerical("structure from motion diverged".into()));
    }
    Ok(Reconstruction {
        shape: out,
        cameras: cams,
        rms_residual: rms,
        missing_entries,
    })
}

fn row_means(w: &DMatrix<f64>) -> DMatrix<f64> {
    let means = w.column_mean();
    DMatrix::from_fn(w.nrows(), w.ncols(), |r, _| means[r])
}

fn centred(w: &DMatrix<f64>) -> DMatrix<f64> {
    w - row_means(w)
}

/// `W ≈ M̂ Ŝ` with `M̂ = U₃ Σ₃^½`, `Ŝ = Σ₃^½ V₃ᵀ`.
fn rank3(w: &DMatrix<f64>) -> Result<(DMatrix<f64>, DMatrix<f64>)> {
    let svd = w.clone().svd(true, true);
    let (u, vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => {
            return Err(Error::Numerical(
                "SVD of the measurement matrix failed".into(),
            ));
        }
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    if order.len() < 3 || svd.singular_values[order[2]] <= 1e-12 * svd.singular_values[order[0]] {
        return Err(Error::Degenerate(
            "the views do not span three dimensions (too few distinct viewpoints, or a flat shape)"
                .into(),
        ));
    }
    let mut m = DMatrix::zeros(w.nrows(), 3);
    let mut s = DMatrix::zeros(3, w.ncols());
    for (c, &i) in order.iter().take(3).enumerate() {
        let root = svd.singular_values[i].sqrt();
        m.set_column(c, &(u.column(i) * root));
        s.set_row(c, &(vt.row(i) * root));
    }
    Ok((m, s))
}

/// The coefficients of `xᵀ L y` in the six unknowns of the symmetric `L`.
fn sym_coeffs(x: &Vector3<f64>, y: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(
        x[0] * y[0],
        x[0] * y[1] + x[1] * y[0],
        x[0] * y[2] + x[2] * y[0],
        x[1] * y[1],
        x[1] * y[2] + x[2] * y[1],
        x[2] * y[2],
    )
}

/// `Q` with `(M̂ Q)` weak-perspective cameras of mean squared scale 1.
fn metric_upgrade(m_hat: &DMatrix<f64>) -> Result<Matrix3<f64>> {
    let f = m_hat.nrows() / 2;
    let mut a = DMatrix::<f64>::zeros(2 * f, 6);
    let mut norm_row = Vector6::zeros();
    for k in 0..f {
        let ak: Vector3<f64> = m_hat.row(2 * k).transpose().fixed_rows::<3>(0).into_owned();
        let bk: Vector3<f64> = m_hat
            .row(2 * k + 1)
            .transpose()
            .fixed_rows::<3>(0)
            .into_owned();
        a.set_row(
            2 * k,
            &(sym_coeffs(&ak, &ak) - sym_coeffs(&bk, &bk)).transpose(),
        );
        a.set_row(2 * k + 1, &sym_coeffs(&ak, &bk).transpose());
        norm_row += (sym_coeffs(&ak, &ak) + sym_coeffs(&bk, &bk)) / (2.0 * f as f64);
    }
    // Null vector of A: the right singular vector of the smallest singular value.
    let svd = a.svd(false, true);
    let vt = svd
        .v_t
        .ok_or_else(|| Error::Numerical("SVD of the metric constraints failed".into()))?;
    let imin = (0..svd.singular_values.len())
        .min_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]))
        .unwrap_or(0);
    let l = vt.row(imin).transpose();
    let scale = norm_row.dot(&l);
    if scale.abs() < 1e-300 {
        return Err(Error::Degenerate(
            "the metric upgrade has no solution (views too similar)".into(),
        ));
    }
    let l = l / scale;
    let lm = Matrix3::new(l[0], l[1], l[2], l[1], l[3], l[4], l[2], l[4], l[5]);
    let eig = SymmetricEigen::new(lm);
    let top = eig.eigenvalues.max();
    if top <= 0.0 {
        return Err(Error::Numerical(
            "the metric upgrade is negative definite".into(),
        ));
    }
    let floor = 1e-8 * top;
    let roots = eig.eigenvalues.map(|v| v.max(floor).sqrt());
    Ok(eig.eigenvectors * Matrix3::from_diagonal(&roots))
}

/// The scaled orthographic camera `s [r1; r2]` nearest to a 2x3 matrix (polar decomposition).
fn nearest_scaled_orthographic(p: &Matrix2x3<f64>) -> Matrix2x3<f64> {
    let svd = p.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let s = 0.5 * (svd.singular_values[0] + svd.singular_values[1]);
            u * vt * s
        }
        _ => *p,
    }
}

/// The rotation whose first two rows are the (normalized) rows of a scaled orthographic camera.
fn camera_rotation(p: &Matrix2x3<f64>) -> Rotation3<f64> {
    rotation_from_two_rows(&p.row(0).transpose(), &p.row(1).transpose())
}

/// Least-squares scaled orthographic camera and translation for one view, observed points only.
fn fit_camera(
    obs: &[Option<Vector2<f64>>],
    shape: &[Vector3<f64>],
) -> Option<(Matrix2x3<f64>, Vector2<f64>)> {
    let pts: Vec<(Vector3<f64>, Vector2<f64>)> = obs
        .iter()
        .zip(shape)
        .filter_map(|(o, x)| o.map(|o| (*x, o)))
        .collect();
    let n = pts.len() as f64;
    let mx = pts.iter().map(|(x, _)| x).sum::<Vector3<f64>>() / n;
    let mo = pts.iter().map(|(_, o)| o).sum::<Vector2<f64>>() / n;
    let mut xx = Matrix3::zeros();
    let mut ox = Matrix2x3::zeros();
    for (x, o) in &pts {
        let (dx, doo) = (x - mx, o - mo);
        xx += dx * dx.transpose();
        ox += doo * dx.transpose();
    }
    let p = ox * xx.try_inverse()?;
    let p = nearest_scaled_orthographic(&p);
    Some((p, mo - p * mx))
}

/// Least-squares 3D point from its observations.
fn fit_point(
    obs: &[Vec<Option<Vector2<f64>>>],
    cams: &[(Matrix2x3<f64>, Vector2<f64>)],
    j: usize,
) -> Option<Vector3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (k, (p, t)) in cams.iter().enumerate() {
        if let Some(o) = obs[k][j] {
            ata += p.transpose() * p;
            atb += p.transpose() * (o - t);
        }
    }
    ata.try_inverse().map(|inv| inv * atb)
}

fn residual(
    obs: &[Vec<Option<Vector2<f64>>>],
    cams: &[(Matrix2x3<f64>, Vector2<f64>)],
    shape: &[Vector3<f64>],
) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for (k, (p, t)) in cams.iter().enumerate() {
        for (j, x) in shape.iter().enumerate() {
            if let Some(o) = obs[k][j] {
                sum += (p * x + t - o).norm_squared();
                count += 1;
            }
        }
    }
    (sum / count.max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, Scaling, align3, procrustes::rms_distance3};
    use rand::{Rng, SeedableRng, rngs::StdRng};
    use rand_distr::{Distribution, Normal};

    /// A small non-planar face-like cloud (nose tip at 2).
    fn face() -> Vec<Vector3<f64>> {
        crate::test_faces::face(9)
    }

    fn views(shape: &[Vector3<f64>], yaws: &[f64], rng: &mut StdRng) -> Vec<Shape2> {
        yaws.iter()
            .map(|&y| {
                let r =
                    EulerAngles::new(y, rng.random_range(-8.0..8.0), rng.random_range(-8.0..8.0))
                        .unwrap()
                        .to_rotation();
                let cam = WeakPerspective::new(
                    r,
                    rng.random_range(1.5..3.0),
                    Vector2::new(220.0, -240.0),
                )
                .unwrap();
                Shape2::full(shape.iter().map(|x| cam.project(x)).collect()).unwrap()
            })
            .collect()
    }

    fn aligned_rms(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        let sim = align3(a, b, Scaling::Similarity).unwrap();
        let moved: Vec<_> = a.iter().map(|p| sim.apply(p)).collect();
        rms_distance3(&moved, b)
    }

    #[test]
    fn exact_views_give_the_shape_and_cameras_back() {
        let mut rng = StdRng::seed_from_u64(7);
        let truth = face();
        let v = views(&truth, &[-30.0, -12.0, 0.0, 15.0, 28.0], &mut rng);
        let rec = reconstruct(&v, SfmOptions::with_nose_tip(2)).unwrap();
        assert!(
            aligned_rms(&rec.shape, &truth) < 1e-8,
            "{}",
            aligned_rms(&rec.shape, &truth)
        );
        assert!(rec.rms_residual < 1e-8);
        assert!(rec.shape[2].z > 0.0);
        for (cam, view) in rec.cameras.iter().zip(&v) {
            for (x, p) in rec.shape.iter().zip(view.points()) {
                assert!((cam.project(x) - p).norm() < 1e-7);
            }
        }
    }

    #[test]
    fn missing_points_are_imputed() {
        let mut rng = StdRng::seed_from_u64(3);
        let truth = face();
        let v = views(&truth, &[-30.0, -15.0, 0.0, 15.0, 30.0], &mut rng);
        let v: Vec<Shape2> = v
            .iter()
            .enumerate()
            .map(|(k, s)| s.with_missing([k, (k + 4) % 9]))
            .collect();
        let rec = reconstruct(&v, SfmOptions::with_nose_tip(2)).unwrap();
        assert_eq!(rec.missing_entries, 10);
        assert!(
            aligned_rms(&rec.shape, &truth) < 1e-6,
            "{}",
            aligned_rms(&rec.shape, &truth)
        );
    }

    #[test]
    fn noise_stays_small() {
        let mut rng = StdRng::seed_from_u64(11);
        let truth = face();
        let mut v = views(&truth, &[-30.0, -15.0, 0.0, 15.0, 30.0], &mut rng);
        let noise = Normal::new(0.0, 0.3).unwrap();
        for s in v.iter_mut() {
            let pts = s
                .points()
                .iter()
                .map(|p| p + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)))
                .collect();
            *s = Shape2::full(pts).unwrap();
        }
        let rec = reconstruct(&v, SfmOptions::with_nose_tip(2)).unwrap();
        assert!(aligned_rms(&rec.shape, &truth) < 1.5);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let mut rng = StdRng::seed_from_u64(1);
        let v = views(&face(), &[-20.0, 0.0, 20.0], &mut rng);
        assert!(reconstruct(&v[..2], SfmOptions::with_nose_tip(2)).is_err());
        assert!(reconstruct(&v, SfmOptions::with_nose_tip(99)).is_err());
        // One point seen in one view only.
        let w: Vec<Shape2> = v
            .iter()
            .enumerate()
            .map(|(k, s)| {
                if k > 0 {
                    s.with_missing([0])
                } else {
                    s.clone()
                }
            })
            .collect();
        assert!(matches!(
            reconstruct(&w, SfmOptions::with_nose_tip(2)),
            Err(Error::TooFewPoints { .. })
        ));
        // The same view three times: no depth.
        let same = vec![v[0].clone(), v[0].clone(), v[0].clone()];
        assert!(reconstruct(&same, SfmOptions::with_nose_tip(2)).is_err());
        // A flat shape seen from three angles.
        let flat: Vec<_> = face().iter().map(|p| Vector3::new(p.x, p.y, 0.0)).collect();
        let fv = views(&flat, &[-20.0, 0.0, 20.0], &mut rng);
        assert!(reconstruct(&fv, SfmOptions::with_nose_tip(2)).is_err());
    }
}
