//! Weak-perspective fit of a linear morphable shape model: the rigid camera and the identity /
//! expression coefficients under a Gaussian prior.
//!
//! Shape: `X(c) = mean + Σ_k c_k B_k` with `c ~ N(prior_mean, I)` (coefficients in standard
//! deviations, bases in mm per standard deviation). [`fit_morphable`] takes Gauss-Newton steps
//! on the joint maximum a posteriori problem (pose and coefficients together) from the robust
//! rigid fit of the prior shape. Fitting pose and shape in turn converges slowly along the
//! directions where they trade off (nose depth against pitch), which is where the accuracy is;
//! the joint step moves along them at once.
//!
//! Speed: the coefficient block of the normal equations,
//! `s² Σᵢ wᵢ Bᵢᵀ Rᵀ P ᵀP R Bᵢ = s² Σᵢ wᵢ Bᵢᵀ (I - r₃ r₃ᵀ) Bᵢ` (`Bᵢ` the 3 x K basis rows of
//! point `i`, `r₃` the viewing direction in the model frame), is a combination of six
//! precomputed second-moment matrices of the basis, so a step costs `O(K²)` for it instead of
//! `O(n K²)`; points with weights other than one are corrected for one by one.

use nalgebra::{DMatrix, DVector, Rotation3, Vector2, Vector3};

use super::fit::{FitOptions, Hidden, RigidFit, fit_rigid, model_size, tukey_reweight};
use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::geometry::image_to_plane;
use crate::shape::Shape2;

/// A linear shape model over a scheme's points, with what the fit precomputes from it.
#[derive(Debug, Clone)]
pub struct MorphableBasis {
    mean: Vec<Vector3<f64>>,
    components: Vec<Vec<Vector3<f64>>>,
    prior_mean: Vec<f64>,
    prior_shape: Vec<Vector3<f64>>,
    /// The basis by axis: `axes[a][(i, k)]` is coordinate `a` of component `k` at point `i`.
    axes: [DMatrix<f64>; 3],
    /// `Σᵢ Bᵢ[a]ᵀ Bᵢ[a]` for a = x, y, z.
    moments_aa: [DMatrix<f64>; 3],
    /// `Σᵢ (Bᵢ[a]ᵀ Bᵢ[b] + Bᵢ[b]ᵀ Bᵢ[a])` for (a, b) = (x, y), (x, z), (y, z).
    moments_ab: [DMatrix<f64>; 3],
}

impl PartialEq for MorphableBasis {
    fn eq(&self, other: &Self) -> bool {
        self.mean == other.mean
            && self.components == other.components
            && self.prior_mean == other.prior_mean
    }
}

const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

impl MorphableBasis {
    /// Validates sizes and finiteness and precomputes the fit's moments.
    pub fn new(
        mean: Vec<Vector3<f64>>,
        components: Vec<Vec<Vector3<f64>>>,
        prior_mean: Vec<f64>,
    ) -> Result<Self> {
        if components.len() != prior_mean.len() {
            return Err(Error::param(
                "prior_mean",
                format!(
                    "{} values for {} basis shapes",
                    prior_mean.len(),
                    components.len()
                ),
            ));
        }
        if let Some(k) = components.iter().position(|b| b.len() != mean.len()) {
            return Err(Error::PointCount {
                what: format!("basis shape {k}"),
                expected: mean.len(),
                got: components[k].len(),
            });
        }
        let finite = mean
            .iter()
            .chain(components.iter().flatten())
            .all(|p| p.iter().all(|v| v.is_finite()))
            && prior_mean.iter().all(|v| v.is_finite());
        if !finite {
            return Err(Error::non_finite("morphable model"));
        }
        let (n, k) = (mean.len(), components.len());
        let axes: [DMatrix<f64>; 3] =
            std::array::from_fn(|a| DMatrix::from_fn(n, k, |i, c| components[c][i][a]));
        let moments_aa = std::array::from_fn(|a| axes[a].tr_mul(&axes[a]));
        let moments_ab = PAIRS.map(|(a, b)| {
            let m = axes[a].tr_mul(&axes[b]);
            &m + m.transpose()
        });
        let mut basis = MorphableBasis {
            mean,
            components,
            prior_mean,
            prior_shape: Vec::new(),
            axes,
            moments_aa,
            moments_ab,
        };
        basis.prior_shape = basis.shape(&basis.prior_mean);
        Ok(basis)
    }

    /// The mean shape (coefficients zero), model frame, mm.
    pub fn mean(&self) -> &[Vector3<f64>] {
        &self.mean
    }

    /// The basis shapes, mm per standard deviation of their coefficient.
    pub fn components(&self) -> &[Vec<Vector3<f64>>] {
        &self.components
    }

    /// The prior mean of each coefficient, in standard deviations.
    pub fn prior_mean(&self) -> &[f64] {
        &self.prior_mean
    }

    /// The shape for coefficients `c` (missing trailing coefficients count as zero).
    pub fn shape(&self, c: &[f64]) -> Vec<Vector3<f64>> {
        let mut out = self.mean.clone();
        for (b, &ck) in self.components.iter().zip(c) {
            for (o, v) in out.iter_mut().zip(b) {
                *o += ck * v;
            }
        }
        out
    }

    /// The shape at the prior mean: the population's mean face.
    pub fn prior_shape(&self) -> &[Vector3<f64>] {
        &self.prior_shape
    }

    /// `Σᵢ wᵢ Bᵢᵀ (I - r₃ r₃ᵀ) Bᵢ` from the moments, corrected for weights other than one.
    fn coefficient_block(&self, r3: &Vector3<f64>, w: &[f64]) -> DMatrix<f64> {
        let k = self.components.len();
        let mut out = DMatrix::<f64>::zeros(k, k);
        for a in 0..3 {
            add_scaled(&mut out, 1.0 - r3[a] * r3[a], &self.moments_aa[a]);
        }
        for (m, (a, b)) in self.moments_ab.iter().zip(PAIRS) {
            add_scaled(&mut out, -r3[a] * r3[b], m);
        }
        // Bᵢᵀ (I - r₃r₃ᵀ) Bᵢ = Σ_a Bᵢ[a]ᵀ Bᵢ[a] - uᵢ uᵢᵀ with uᵢ = Bᵢᵀ r₃.
        let proj = DMatrix::from_fn(3, 3, |a, b| f64::from(u8::from(a == b)) - r3[a] * r3[b]);
        let mut rows = DMatrix::<f64>::zeros(3, k);
        let mut projected = DMatrix::<f64>::zeros(3, k);
        for (i, &wi) in w.iter().enumerate() {
            if wi == 1.0 {
                continue;
            }
            for a in 0..3 {
                rows.row_mut(a).copy_from(&self.axes[a].row(i));
            }
            projected.gemm(1.0, &proj, &rows, 0.0);
            // out -= (1 - wᵢ) rowsᵀ (I - r₃r₃ᵀ) rows
            out.gemm_tr(-(1.0 - wi), &rows, &projected, 1.0);
        }
        out
    }
}

/// Options of [`fit_morphable`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MorphOptions {
    /// The rigid fit that starts it (its final weights carry over: missing, hidden and
    /// rejected points stay out).
    pub rigid: FitOptions,
    /// Gauss-Newton steps of the joint problem. One step from the rigid fit is the default:
    /// on AFLW2000-3D it is more accurate than iterating to convergence, which fits the
    /// coefficients to the landmarks' noise (docs/RESULTS.md).
    pub iterations: usize,
    /// Assumed landmark noise in model units (mm): the maximum a posteriori balance of
    /// landmark residuals against coefficients' deviations from their prior means (in standard
    /// deviations). Smaller trusts the landmarks more.
    pub noise_mm: f64,
}

impl Default for MorphOptions {
    fn default() -> Self {
        MorphOptions {
            rigid: FitOptions::default(),
            iterations: 1,
            noise_mm: 1.0,
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

/// Fits the morphable model to `landmarks` (image pixels): Gauss-Newton steps (damped when a
/// step would raise the cost) on
/// `Σ wᵢ ‖s P R Xᵢ(c) + t - yᵢ‖² + (s₀ σ)² Σ_k (c_k - μ_k)²`
/// jointly over rotation, scale, translation and `c`, from the robust rigid fit of the prior
/// shape, whose weights it keeps (`σ` = [`MorphOptions::noise_mm`], `s₀` the rigid fit's scale,
/// so the balance does not depend on the image size).
pub fn fit_morphable(
    model: &MorphableBasis,
    landmarks: &Shape2,
    contour: &[usize],
    visibility: Option<&VisibilityMap>,
    opts: MorphOptions,
) -> Result<MorphFit> {
    if !(opts.noise_mm.is_finite() && opts.noise_mm > 0.0) {
        return Err(Error::param(
            "noise_mm",
            format!("must be positive, got {}", opts.noise_mm),
        ));
    }
    let k = model.components.len();
    let start = fit_rigid(
        model.prior_shape(),
        landmarks,
        contour,
        visibility,
        opts.rigid,
    )?;
    if k == 0 || opts.iterations == 0 {
        return Ok(MorphFit {
            camera: start,
            coefficients: model.prior_mean.clone(),
            shape: model.prior_shape.clone(),
        });
    }
    let y: Vec<Vector2<f64>> = landmarks.points().iter().map(image_to_plane).collect();
    // The joint fit weighs points by presence (and visibility at the rigid pose when asked),
    // not by the rigid fit's robust weights: a shape the prior shape does not match looks like
    // outliers to a rigid model. Robustness comes after, on the joint residuals.
    let mut w: Vec<f64> = (0..landmarks.len())
        .map(|i| match landmarks.present()[i] {
            false => 0.0,
            true if contour.contains(&i) => opts.rigid.contour_weight,
            true => 1.0,
        })
        .collect();
    let droppable = |i: usize| opts.rigid.hidden == Hidden::DropAll || contour.contains(&i);
    if let Some(map) =
        visibility.filter(|m| opts.rigid.hidden != Hidden::Keep && m.n_points() == w.len())
    {
        let visible = map.lookup(&start.rotation);
        let kept = (0..w.len())
            .filter(|&i| w[i] > 0.0 && (visible[i] || !droppable(i)))
            .count();
        if kept >= 4 {
            for (i, wi) in w.iter_mut().enumerate() {
                if !visible[i] && droppable(i) {
                    *wi = 0.0;
                }
            }
        }
    }
    let prior_w = (start.scale * opts.noise_mm).powi(2);
    let mut st = Joint {
        r: start.rotation,
        s: start.scale,
        t: start.translation,
        c: DVector::from_column_slice(&model.prior_mean),
        shape: model.prior_shape.clone(),
    };
    st = joint_steps(model, &y, &w, st, prior_w, opts.iterations);
    if opts.rigid.robust {
        let before = w.clone();
        let floor = 0.01 * st.s * model_size(&st.shape, &w);
        if tukey_reweight(&st.shape, &y, &mut w, &st.r, st.s, &st.t, floor) {
            if w.iter().filter(|&&v| v > 0.0).count() >= 4 {
                st = joint_steps(model, &y, &w, st, prior_w, opts.iterations);
            } else {
                w = before;
            }
        }
    }
    let cost = joint_cost(model, &y, &w, &st, prior_w);
    let sw: f64 = w.iter().sum();
    let rms_px = ((cost - prior_term(model, &st.c, prior_w)).max(0.0) / sw).sqrt();
    if !(rms_px.is_finite() && st.s.is_finite()) {
        return Err(Error::Numerical("the shape fit diverged".into()));
    }
    Ok(MorphFit {
        camera: RigidFit {
            rotation: Rotation3::from_matrix(st.r.matrix()),
            scale: st.s,
            translation: st.t,
            weights: w,
            rms_px,
        },
        coefficients: st.c.iter().copied().collect(),
        shape: st.shape,
    })
}

/// Up to `iterations` Gauss-Newton steps from `st`, each damped (Levenberg-Marquardt) until it
/// lowers the cost; stops early when no step does.
fn joint_steps(
    model: &MorphableBasis,
    y: &[Vector2<f64>],
    w: &[f64],
    mut st: Joint,
    prior_w: f64,
    iterations: usize,
) -> Joint {
    let k = model.components.len();
    let mut cost = joint_cost(model, y, w, &st, prior_w);
    let mut lambda = 0.0;
    for _ in 0..iterations {
        let (jtj, jtr) = normal_equations(model, y, w, &st, prior_w);
        // Marquardt's scaling, floored so that directions the data barely sees are damped too.
        let floor = 1e-6 * jtj.diagonal().max();
        let mut accepted = false;
        for _ in 0..8 {
            let mut a = jtj.clone();
            for i in 0..a.nrows() {
                a[(i, i)] += lambda * jtj[(i, i)].max(floor);
            }
            let Some(chol) = a.cholesky() else {
                lambda = (lambda * 10.0f64).max(1e-4);
                continue;
            };
            let delta = chol.solve(&(-&jtr));
            let c = &st.c + delta.rows(6, k);
            let cand = Joint {
                r: Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])) * st.r,
                s: st.s + delta[3],
                t: st.t + Vector2::new(delta[4], delta[5]),
                shape: model.shape(c.as_slice()),
                c,
            };
            let c2 = joint_cost(model, y, w, &cand, prior_w);
            if cand.s > 0.0 && c2 <= cost {
                (st, cost) = (cand, c2);
                lambda *= 0.1;
                accepted = true;
                break;
            }
            lambda = (lambda * 10.0f64).max(1e-4);
        }
        if !accepted {
            break;
        }
    }
    st
}

/// `out += a · m`, element-wise.
fn add_scaled(out: &mut DMatrix<f64>, a: f64, m: &DMatrix<f64>) {
    out.zip_apply(m, |o, v| *o += a * v);
}

struct Joint {
    r: Rotation3<f64>,
    s: f64,
    t: Vector2<f64>,
    c: DVector<f64>,
    /// `X(c)`, kept in step with `c`.
    shape: Vec<Vector3<f64>>,
}

fn prior_term(model: &MorphableBasis, c: &DVector<f64>, prior_w: f64) -> f64 {
    c.iter()
        .zip(&model.prior_mean)
        .map(|(ck, mk)| prior_w * (ck - mk) * (ck - mk))
        .sum()
}

fn joint_cost(
    model: &MorphableBasis,
    y: &[Vector2<f64>],
    w: &[f64],
    st: &Joint,
    prior_w: f64,
) -> f64 {
    let data: f64 = st
        .shape
        .iter()
        .zip(y)
        .zip(w)
        .filter(|(_, wi)| **wi > 0.0)
        .map(|((x, yi), wi)| wi * (st.s * (st.r * x).xy() + st.t - yi).norm_squared())
        .sum();
    data + prior_term(model, &st.c, prior_w)
}

/// `JᵀWJ` and `JᵀWr` of the joint problem at `st` (unknowns: rotation increment ω, scale,
/// translation, coefficients), in fused passes without per-point matrices.
///
/// A point's pose Jacobian rows are those of the rigid fit, `(0, a, -b, q_x, 1, 0)` and
/// `(-a, 0, c, q_y, 0, 1)` with `q = R Xᵢ`, `(a, b, c) = s (q_z, q_y, q_x)`; its coefficient
/// rows are `uᵢ = s (R Bᵢ)ₓ` and `vᵢ = s (R Bᵢ)ᵧ`. The pose block sums 14 distinct products;
/// the cross block and the coefficient gradient take one pass over the basis, forming `u` and
/// `v` as they go; the coefficient block comes from the basis moments when most weights are one.
fn normal_equations(
    model: &MorphableBasis,
    y: &[Vector2<f64>],
    w: &[f64],
    st: &Joint,
    prior_w: f64,
) -> (DMatrix<f64>, DVector<f64>) {
    let n = y.len();
    let k = model.components.len();
    let m = st.r.matrix();
    let s = st.s;
    // Per point, weighted: a, b, c, q_x, q_y and the residuals.
    let mut pt = vec![[0.0f64; 8]; n];
    let mut pose = [0.0f64; 14];
    let mut gp = [0.0f64; 6];
    for (i, p) in pt.iter_mut().enumerate() {
        let wi = w[i];
        if wi == 0.0 {
            continue;
        }
        let q = m * st.shape[i];
        let (a, b, c) = (s * q.z, s * q.y, s * q.x);
        let rx = s * q.x + st.t.x - y[i].x;
        let ry = s * q.y + st.t.y - y[i].y;
        *p = [
            wi * a,
            wi * b,
            wi * c,
            wi * q.x,
            wi * q.y,
            wi * rx,
            wi * ry,
            wi,
        ];
        let [wa, wb, wc, wqx, wqy, wrx, wry, _] = *p;
        for (acc, v) in pose.iter_mut().zip([
            wa * a,
            wa * c,
            wa * q.y,
            wa,
            wa * b,
            wa * q.x,
            wb * b + wc * c,
            wc * q.y - wb * q.x,
            wb,
            wc,
            wqx * q.x + wqy * q.y,
            wqx,
            wqy,
            wi,
        ]) {
            *acc += v;
        }
        gp[0] -= a * wry;
        gp[1] += a * wrx;
        gp[2] += c * wry - b * wrx;
        gp[3] += q.x * wrx + q.y * wry;
        gp[4] += wrx;
        gp[5] += wry;
    }
    let [
        aa,
        ac,
        aqy,
        sa,
        ab,
        aqx,
        bbcc,
        cross,
        sb,
        sc,
        qq,
        sqx,
        sqy,
        sw,
    ] = pose;
    let d = 6 + k;
    let mut jtj = DMatrix::<f64>::zeros(d, d);
    let mut jtr = DVector::<f64>::zeros(d);
    #[rustfmt::skip]
    let pose_block = [
        [aa,   0.0,  -ac,   -aqy,  0.0, -sa],
        [0.0,  aa,   -ab,   aqx,   sa,  0.0],
        [-ac,  -ab,  bbcc,  cross, -sb, sc],
        [-aqy, aqx,  cross, qq,    sqx, sqy],
        [0.0,  sa,   -sb,   sqx,   sw,  0.0],
        [-sa,  0.0,  sc,    sqy,   0.0, sw],
    ];
    for (r, row) in pose_block.iter().enumerate() {
        for (c, &v) in row.iter().enumerate() {
            jtj[(r, c)] = v;
        }
        jtr[r] = gp[r];
    }
    // Cross block and coefficient gradient, one pass over each basis shape.
    let (sx, sy) = (
        [s * m[(0, 0)], s * m[(0, 1)], s * m[(0, 2)]],
        [s * m[(1, 0)], s * m[(1, 1)], s * m[(1, 2)]],
    );
    let (ax, ay, az) = (
        model.axes[0].as_slice(),
        model.axes[1].as_slice(),
        model.axes[2].as_slice(),
    );
    for kk in 0..k {
        // Column `kk` of each axis matrix (column-major): basis shape `kk` at every point.
        let col = kk * n..(kk + 1) * n;
        let mut acc = [0.0f64; 7];
        // Points of weight zero have all-zero rows in `pt` and add nothing.
        for (((p, &x), &yy), &z) in pt
            .iter()
            .zip(&ax[col.clone()])
            .zip(&ay[col.clone()])
            .zip(&az[col])
        {
            let u = sx[0] * x + sx[1] * yy + sx[2] * z;
            let v = sy[0] * x + sy[1] * yy + sy[2] * z;
            let [wa, wb, wc, wqx, wqy, wrx, wry, wi] = *p;
            acc[0] -= v * wa;
            acc[1] += u * wa;
            acc[2] += v * wc - u * wb;
            acc[3] += u * wqx + v * wqy;
            acc[4] += u * wi;
            acc[5] += v * wi;
            acc[6] += u * wrx + v * wry;
        }
        for j in 0..6 {
            jtj[(6 + kk, j)] = acc[j];
            jtj[(j, 6 + kk)] = acc[j];
        }
        jtr[6 + kk] = acc[6] + prior_w * (st.c[kk] - model.prior_mean[kk]);
    }
    // Coefficient block `s² Σ wᵢ Bᵢᵀ (I - r₃r₃ᵀ) Bᵢ = uᵀWu + vᵀWv`: from the moments when most
    // weights are one (a correction per other point costs about a third of a direct row), else
    // directly (after robust reweighting no weight is one); then the prior.
    let reweighted = w.iter().filter(|&&wi| wi != 1.0).count();
    let mut cc = if 3 * reweighted > 2 * n {
        let rotated = |r: [f64; 3]| {
            let mut out = DMatrix::<f64>::zeros(n, k);
            for (((o, x), yy), z) in out
                .iter_mut()
                .zip(model.axes[0].iter())
                .zip(model.axes[1].iter())
                .zip(model.axes[2].iter())
            {
                *o = r[0] * x + r[1] * yy + r[2] * z;
            }
            out
        };
        let (u, v) = (rotated(sx), rotated(sy));
        let weigh = |mtx: &DMatrix<f64>| {
            let mut out = mtx.clone();
            for (i, &wi) in w.iter().enumerate() {
                out.row_mut(i).scale_mut(wi);
            }
            out
        };
        u.tr_mul(&weigh(&u)) + v.tr_mul(&weigh(&v))
    } else {
        let r3 = Vector3::new(m[(2, 0)], m[(2, 1)], m[(2, 2)]);
        model.coefficient_block(&r3, w) * (s * s)
    };
    for kk in 0..k {
        cc[(kk, kk)] += prior_w;
    }
    jtj.view_mut((6, 6), (k, k)).copy_from(&cc);
    (jtj, jtr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective};
    use nalgebra::Matrix3;

    /// A small face and two deformations: a deeper nose and a wider mouth.
    fn basis() -> MorphableBasis {
        let mean = vec![
            Vector3::new(-32.0, 35.0, 0.0),
            Vector3::new(32.0, 35.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 8.0),
            Vector3::new(25.0, -30.0, 8.0),
            Vector3::new(-60.0, 10.0, -60.0),
            Vector3::new(60.0, 10.0, -60.0),
            Vector3::new(0.0, -70.0, 10.0),
            Vector3::new(0.0, 40.0, 20.0),
            Vector3::new(-15.0, 50.0, 10.0),
        ];
        let mut nose = vec![Vector3::zeros(); 10];
        nose[2] = Vector3::new(0.0, 0.0, 4.0);
        nose[8] = Vector3::new(0.0, 0.0, 2.0);
        let mut mouth = vec![Vector3::zeros(); 10];
        mouth[3] = Vector3::new(-3.0, 0.0, 0.0);
        mouth[4] = Vector3::new(3.0, 0.0, 0.0);
        MorphableBasis::new(mean, vec![nose, mouth], vec![0.5, 0.0]).unwrap()
    }

    fn view(b: &MorphableBasis, c: &[f64], a: EulerAngles) -> Shape2 {
        let cam = WeakPerspective::new(a.to_rotation(), 2.0, Vector2::new(300.0, -250.0)).unwrap();
        Shape2::full(b.shape(c).iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    #[test]
    fn moments_match_the_direct_sum_with_weights() {
        let b = basis();
        let r3 = EulerAngles::new(25.0, -10.0, 5.0)
            .unwrap()
            .to_rotation()
            .matrix()
            .row(2)
            .transpose();
        let w = [1.0, 0.5, 0.0, 1.0, 1.0, 0.25, 1.0, 1.0, 1.0, 0.0];
        let fast = b.coefficient_block(&r3, &w);
        let proj = Matrix3::identity() - r3 * r3.transpose();
        for p in 0..2 {
            for q in 0..2 {
                let direct: f64 = (0..10)
                    .map(|i| w[i] * b.components[p][i].dot(&(proj * b.components[q][i])))
                    .sum();
                assert!((fast[(p, q)] - direct).abs() < 1e-9, "{p} {q}");
            }
        }
    }

    /// The normal equations from the explicit Jacobian (per-point rows as matrices): the
    /// reference the fused passes are checked against.
    fn dense_normal_equations(
        model: &MorphableBasis,
        y: &[Vector2<f64>],
        w: &[f64],
        st: &Joint,
        prior_w: f64,
    ) -> (DMatrix<f64>, DVector<f64>) {
        let n = y.len();
        let k = model.components.len();
        let m = st.r.matrix();
        // Per point: the pose Jacobian rows (as in the rigid fit), plain and weighted, and the
        // weighted residuals.
        let mut px = DMatrix::<f64>::zeros(n, 6);
        let mut py = DMatrix::<f64>::zeros(n, 6);
        let mut rx = DVector::<f64>::zeros(n);
        let mut ry = DVector::<f64>::zeros(n);
        for i in 0..n {
            let wi = w[i];
            if wi == 0.0 {
                continue;
            }
            let q = m * st.shape[i];
            let (a, b, c) = (st.s * q.z, st.s * q.y, st.s * q.x);
            let row_x = [0.0, a, -b, q.x, 1.0, 0.0];
            let row_y = [-a, 0.0, c, q.y, 0.0, 1.0];
            for j in 0..6 {
                px[(i, j)] = row_x[j];
                py[(i, j)] = row_y[j];
            }
            rx[i] = wi * (st.s * q.x + st.t.x - y[i].x);
            ry[i] = wi * (st.s * q.y + st.t.y - y[i].y);
        }
        let weigh = |mtx: &DMatrix<f64>| {
            let mut out = mtx.clone();
            for (i, &wi) in w.iter().enumerate() {
                out.row_mut(i).scale_mut(wi);
            }
            out
        };
        let (jx, jy) = (weigh(&px), weigh(&py));
        // Coefficient Jacobian rows: u = s (R B)ₓ, v = s (R B)ᵧ (n x K each).
        let rotated = |row: usize| {
            let mut out = &model.axes[0] * (st.s * m[(row, 0)]);
            add_scaled(&mut out, st.s * m[(row, 1)], &model.axes[1]);
            add_scaled(&mut out, st.s * m[(row, 2)], &model.axes[2]);
            out
        };
        let (u, v) = (rotated(0), rotated(1));

        let d = 6 + k;
        let mut jtj = DMatrix::<f64>::zeros(d, d);
        let mut jtr = DVector::<f64>::zeros(d);
        // Pose block and gradient.
        let pose = jx.tr_mul(&px) + jy.tr_mul(&py);
        jtj.view_mut((0, 0), (6, 6)).copy_from(&pose);
        let gp = px.tr_mul(&rx) + py.tr_mul(&ry);
        jtr.rows_mut(0, 6).copy_from(&gp);
        // Cross block: Σ wᵢ (uᵢ jxᵢᵀ + vᵢ jyᵢᵀ) = uᵀ (W jx) + vᵀ (W jy).
        let cross = u.tr_mul(&jx) + v.tr_mul(&jy);
        jtj.view_mut((6, 0), (k, 6)).copy_from(&cross);
        jtj.view_mut((0, 6), (6, k)).copy_from(&cross.transpose());
        // Coefficient block `s² Σ wᵢ Bᵢᵀ (I - r₃r₃ᵀ) Bᵢ = uᵀWu + vᵀWv`: from the moments when most
        // weights are one (a correction per other point costs about a third of a direct row), else
        // directly (after robust reweighting no weight is one); then the prior.
        let reweighted = w.iter().filter(|&&wi| wi != 1.0).count();
        let mut cc = if 3 * reweighted > 2 * n {
            u.tr_mul(&weigh(&u)) + v.tr_mul(&weigh(&v))
        } else {
            let r3 = Vector3::new(m[(2, 0)], m[(2, 1)], m[(2, 2)]);
            model.coefficient_block(&r3, w) * (st.s * st.s)
        };
        for kk in 0..k {
            cc[(kk, kk)] += prior_w;
        }
        jtj.view_mut((6, 6), (k, k)).copy_from(&cc);
        let gc = u.tr_mul(&rx) + v.tr_mul(&ry);
        for kk in 0..k {
            jtr[6 + kk] = gc[kk] + prior_w * (st.c[kk] - model.prior_mean[kk]);
        }
        (jtj, jtr)
    }

    /// The fused passes give the normal equations of the explicit Jacobian, with weights one
    /// (the moments path) and other weights (the direct path), away from convergence.
    #[test]
    fn fused_normal_equations_match_the_explicit_jacobian() {
        let b = basis();
        let r = EulerAngles::new(-35.0, 12.0, 7.0).unwrap().to_rotation();
        let c = [0.4, -0.7];
        let st = Joint {
            r,
            s: 1.3,
            t: Vector2::new(5.0, -8.0),
            c: DVector::from_column_slice(&c),
            shape: b.shape(&c),
        };
        let y: Vec<Vector2<f64>> = (0..10)
            .map(|i| Vector2::new(3.0 * i as f64, -2.0 * (i % 4) as f64))
            .collect();
        let ones = [1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.5, 1.0];
        let other = [0.9, 0.5, 0.0, 0.7, 0.8, 0.25, 0.6, 0.95, 0.3, 0.0];
        for w in [ones, other] {
            let (jtj, jtr) = normal_equations(&b, &y, &w, &st, 0.8);
            let (want, want_r) = dense_normal_equations(&b, &y, &w, &st, 0.8);
            assert!(
                (&jtj - &want).norm() < 1e-9 * want.norm(),
                "{jtj} vs {want}"
            );
            assert!(
                (&jtr - &want_r).norm() < 1e-9 * want_r.norm(),
                "{jtr} vs {want_r}"
            );
        }
    }

    #[test]
    fn both_ways_to_the_coefficient_block_agree() {
        let b = basis();
        let r = EulerAngles::new(25.0, -10.0, 5.0).unwrap().to_rotation();
        let st = Joint {
            r,
            s: 1.7,
            t: Vector2::new(3.0, -2.0),
            c: DVector::from_column_slice(&[0.3, -0.2]),
            shape: b.shape(&[0.3, -0.2]),
        };
        let y = vec![Vector2::new(1.0, 2.0); 10];
        let k = 2;
        // Every weight other than one: the direct sum; the same weights through the moments.
        let w = [0.9, 0.5, 0.0, 0.7, 0.8, 0.25, 0.6, 0.95, 0.3, 0.0];
        let (jtj, _) = normal_equations(&b, &y, &w, &st, 0.0);
        let r3 = r.matrix().row(2).transpose();
        let moments = b.coefficient_block(&r3, &w) * (st.s * st.s);
        let direct = jtj.view((6, 6), (k, k));
        assert!((direct - &moments).norm() < 1e-9, "{direct} vs {moments}");
    }

    #[test]
    fn converged_fit_recovers_pose_and_shape_without_noise() {
        let b = basis();
        let truth = [2.0, -1.5];
        for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (30.0, -15.0, 10.0), (-50.0, 20.0, -5.0)] {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let opts = MorphOptions {
                iterations: 30,
                noise_mm: 1e-3,
                ..MorphOptions::default()
            };
            let f = fit_morphable(&b, &view(&b, &truth, a), &[], None, opts).unwrap();
            let e = EulerAngles::from_rotation(&f.camera.rotation);
            assert!(
                (e.yaw - yaw).abs() < 0.05 && (e.pitch - pitch).abs() < 0.05,
                "{a:?} -> {e:?}"
            );
            assert!((e.roll - roll).abs() < 0.05);
            // The nose's depth is invisible head-on; the mouth's width is not.
            assert!(
                (f.coefficients[1] - truth[1]).abs() < 0.05,
                "{:?}",
                f.coefficients
            );
            if yaw != 0.0 {
                assert!(
                    (f.coefficients[0] - truth[0]).abs() < 0.05,
                    "{:?}",
                    f.coefficients
                );
            }
        }
    }

    #[test]
    fn one_step_moves_towards_the_truth_from_the_rigid_fit() {
        // A deep nose read by a rigid fit of the prior shape biases pitch and yaw; one joint step
        // removes most of that bias.
        let b = basis();
        let a = EulerAngles::new(35.0, 20.0, 0.0).unwrap();
        let lm = view(&b, &[3.0, 0.0], a);
        let rigid = fit_rigid(b.prior_shape(), &lm, &[], None, FitOptions::default()).unwrap();
        let one = fit_morphable(&b, &lm, &[], None, MorphOptions::default()).unwrap();
        let err = |r: &Rotation3<f64>| crate::geometry::geodesic_deg(r, &a.to_rotation());
        assert!(
            err(&one.camera.rotation) < 0.5 * err(&rigid.rotation),
            "rigid {} one step {}",
            err(&rigid.rotation),
            err(&one.camera.rotation)
        );
    }

    #[test]
    fn bad_noise_is_an_error() {
        let b = basis();
        let lm = view(&b, &[0.0, 0.0], EulerAngles::new(0.0, 0.0, 0.0).unwrap());
        let opts = MorphOptions {
            noise_mm: 0.0,
            ..MorphOptions::default()
        };
        assert!(fit_morphable(&b, &lm, &[], None, opts).is_err());
    }
}
