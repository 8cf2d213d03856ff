//! Weak-perspective fit of a linear morphable shape model: the rigid camera and the identity /
//! expression coefficients under a Gaussian prior.
//!
//! Shape: `X(c) = mean + Σ_k c_k B_k` with `c ~ N(prior_mean, I)` (coefficients in standard
//! deviations, bases in mm per standard deviation). [`fit_morphable`] takes Gauss-Newton steps
//! on the joint maximum a posteriori problem (pose and coefficients together) from the rigid
//! fit of the prior shape. Fitting pose and shape in turn converges slowly along the
//! directions where they trade off (nose depth against pitch), which is where the accuracy is;
//! the joint step moves along them at once.
//!
//! The fit works on the basis' principal components: since the prior is isotropic, any
//! rotation of the coefficients leaves the problem as it is, and the one that diagonalizes
//! `Σᵢ Bᵢᵀ Bᵢ` (`Bᵢ` the 3 x K basis rows of point `i`) orders the components by their energy
//! over the points, which bounds how far the landmarks can move them against the prior. A fit
//! may leave those of least energy at their prior mean
//! ([`MorphableBasis::with_fit_components`]).
//!
//! Speed (docs/PERFORMANCE.md): a step's normal equations have `6 + K` unknowns. Every weight
//! is one on a full set of projected-style landmarks, and the first step starts from the prior
//! shape, so most of the system comes from moments computed once ([`MorphableBasis::new`]):
//! - the coefficient block `s² Σᵢ wᵢ Pᵢᵀ (I - r₃ r₃ᵀ) Pᵢ` (`Pᵢ` the principal components at
//!   point `i`, 3 x K; `r₃` the viewing direction in the model frame) combines six
//!   second-moment matrices of the basis: `O(K²)` instead of `O(n K²)`;
//! - the cross block (pose against coefficients) depends on the points only through
//!   `Σᵢ Pᵢ[a]ᵀ X̄ᵢ[b]` and `Σᵢ Pᵢ[a]` at the prior shape `X̄`, and the pose block through the
//!   prior shape's first and second moments: `O(K)` and `O(1)` instead of `O(n K)` and `O(n)`;
//! - points with a weight other than one are corrected for one by one.
//!
//! What is left per face is one pass over the points (residuals, the pose gradient), the
//! coefficient gradient (the weighted residuals, lifted into the model frame, against the
//! basis: `3 n K`), the factorization (`(6 + K)³ / 6`) and the new shape (`3 n K`), all in
//! [`super::dense`]'s vectorized kernels. The step after robust reweighting, where no weight is
//! one and the shape has moved, forms the system point by point (`n K²`), over fewer
//! components ([`MorphableBasis::robust_components`]).
//!
//! Shapes are flat inside: coordinate `a` of point `i` at `a np + i` (`np` the point count
//! padded to whole tiles), so that the per-point passes run four points at a time.

use std::cell::RefCell;

use nalgebra::{DMatrix, Matrix3, Rotation3, SymmetricEigen, Vector2, Vector3};

use super::dense::{self, TILE, madd};
use super::fit::{FitOptions, Hidden, RigidFit, fit_rigid, tukey_weights};
use super::visibility_map::VisibilityMap;
use crate::error::{Error, Result};
use crate::geometry::image_to_plane;
use crate::shape::Shape2;

/// How many principal components the fit moves by default in its first step, and in its robust
/// step (at most the basis' count). On the default model (50 components) the components past
/// these, the least energetic, bought little accuracy on AFLW2000-3D for their cost: the
/// accuracy-speed frontier is in docs/PERFORMANCE.md (`cargo run --release --example
/// shape_fit_frontier`). Costs move by steps: the coefficient gradient goes through the basis
/// by 16 components at a time (32 fill two groups), a system by tiles of 4 unknowns (6 + 14
/// fill five).
pub const DEFAULT_FIT_COMPONENTS: usize = 32;
/// Principal components the robust step moves by default (see above).
pub const DEFAULT_ROBUST_COMPONENTS: usize = 14;

/// A linear shape model over a scheme's points, with what the fit precomputes from it.
#[derive(Debug, Clone)]
pub struct MorphableBasis {
    mean: Vec<Vector3<f64>>,
    components: Vec<Vec<Vector3<f64>>>,
    prior_mean: Vec<f64>,
    prior_shape: Vec<Vector3<f64>>,
    /// The prior shape, flat ([`Flat`]).
    prior_flat: Vec<f64>,
    /// The prior shape's first and second moments, `Σᵢ X̄ᵢ` and `Σᵢ X̄ᵢ X̄ᵢᵀ`.
    prior_sum: Vector3<f64>,
    prior_moment: Matrix3<f64>,
    /// The principal directions in coefficient space, each padded to whole tiles: principal
    /// coefficients `e` are the coefficients `prior_mean + Σ_j e_j directions[j]`.
    directions: Vec<f64>,
    /// The energy of each principal component over the points (`Σᵢ |Pᵢ[:, j]|²`, mm² per
    /// standard deviation), descending.
    energies: Vec<f64>,
    /// Principal components the fit moves, the first step and the robust one.
    fit_components: usize,
    robust_components: usize,
    /// The components the fit moves by point and axis: `rows[(3i + a) stride + j]` is
    /// coordinate `a` of component `j` at point `i` (`stride` = [`row_stride`] of their count,
    /// zeros in the padding).
    rows: Vec<f64>,
    /// The same as the Jacobian rows hold them, for the fit's components and for the robust
    /// step's ([`JacobianBasis`]).
    jacobian: [JacobianBasis; 2],
    /// The principal components one by one, each a flat shape: `cols[j 3np..(j + 1) 3np]`.
    cols: Vec<f64>,
    /// The second moments of the components the fit moves, where the fit's systems hold their
    /// coefficient block (rows and columns from 6, in [`dense`] tiles, zeros elsewhere):
    /// `Σᵢ Pᵢ[a]ᵀ Pᵢ[a]` for a = x, y, z, then `Σᵢ (Pᵢ[a]ᵀ Pᵢ[b] + Pᵢ[b]ᵀ Pᵢ[a])` for
    /// (a, b) = (x, y), (x, z), (y, z).
    moments: [Vec<dense::Tile>; 6],
    /// Over every point at the prior shape `X̄`: `Σᵢ Pᵢ[a, j] X̄ᵢ[b]` in column `3a + b`, then
    /// `Σᵢ Pᵢ[a, j]` in column `9 + a`, each column as the fit's systems hold component `j`
    /// (rows from 6, in tiles: `prior_cross[column nt + tile]`).
    prior_cross: Vec<[f64; TILE]>,
    /// The same for every component, `cross[column K + j]`.
    cross: Vec<f64>,
}

impl PartialEq for MorphableBasis {
    fn eq(&self, other: &Self) -> bool {
        self.mean == other.mean
            && self.components == other.components
            && self.prior_mean == other.prior_mean
            && self.fit_components == other.fit_components
            && self.robust_components == other.robust_components
    }
}

const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

/// The first `kk` principal components at each point and axis as a Jacobian row holds them
/// from its second tile on: component `j` in column `6 + j` of the row, so here at position
/// `2 + j` of `chunks` tiles, tile by tile and in a tile point by point
/// (`blocks[3 (c n + i) + a]`, `n` points), zeros elsewhere. A point's coefficient rows are
/// then three multiply-adds per tile, and a pass over the points for one tile of their rows
/// reads the basis in order.
#[derive(Debug, Clone, Default)]
struct JacobianBasis {
    kk: usize,
    chunks: usize,
    blocks: Vec<[f64; TILE]>,
}

/// The length of the rows of [`MorphableBasis`]'s `rows`, for [`dense::rows_times`]: `k`
/// rounded up to a multiple of four tiles.
fn row_stride(k: usize) -> usize {
    dense::tiles(k).div_ceil(4) * 4 * TILE
}

/// The layout of a flat shape of `n` points: coordinate `a` of point `i` at `a np + i`, `np`
/// the point count padded to whole tiles (zeros in the padding).
#[derive(Debug, Clone, Copy)]
struct Flat {
    n: usize,
    np: usize,
}

impl Flat {
    fn new(n: usize) -> Flat {
        Flat {
            n,
            np: dense::tiles(n) * TILE,
        }
    }

    fn len(self) -> usize {
        3 * self.np
    }

    fn point(self, x: &[f64], i: usize) -> Vector3<f64> {
        Vector3::new(x[i], x[self.np + i], x[2 * self.np + i])
    }

    fn set(self, x: &mut [f64], i: usize, p: &Vector3<f64>) {
        for a in 0..3 {
            x[a * self.np + i] = p[a];
        }
    }

    fn of(self, points: &[Vector3<f64>]) -> Vec<f64> {
        let mut x = vec![0.0; self.len()];
        for (i, p) in points.iter().enumerate() {
            self.set(&mut x, i, p);
        }
        x
    }
}

impl MorphableBasis {
    /// Validates sizes and finiteness and precomputes the principal components and their
    /// moments.
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
        let flat = Flat::new(n);
        // Principal directions: eigenvectors of the components' Gram matrix, by energy.
        let gram = DMatrix::from_fn(k, k, |p, q| {
            components[p]
                .iter()
                .zip(&components[q])
                .map(|(x, y)| x.dot(y))
                .sum::<f64>()
        });
        let kp = dense::tiles(k) * TILE;
        let mut directions = vec![0.0; k * kp];
        if k > 0 {
            let eig = SymmetricEigen::new(gram);
            let mut order: Vec<usize> = (0..k).collect();
            order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
            for (j, &o) in order.iter().enumerate() {
                let v = eig.eigenvectors.column(o);
                directions[j * kp..j * kp + k].copy_from_slice(v.as_slice());
            }
        }
        let principal: Vec<Vec<Vector3<f64>>> = (0..k)
            .map(|j| {
                let v = &directions[j * kp..j * kp + k];
                (0..n)
                    .map(|i| components.iter().zip(v).map(|(b, &vl)| b[i] * vl).sum())
                    .collect()
            })
            .collect();
        let energies: Vec<f64> = principal
            .iter()
            .map(|p| p.iter().map(|x| x.norm_squared()).sum())
            .collect();
        let mut cols = vec![0.0; flat.len() * k];
        for (j, p) in principal.iter().enumerate() {
            cols[j * flat.len()..(j + 1) * flat.len()].copy_from_slice(&flat.of(p));
        }
        let fit_components = k.min(DEFAULT_FIT_COMPONENTS);
        let robust_components = k.min(DEFAULT_ROBUST_COMPONENTS);
        let mut basis = MorphableBasis {
            mean,
            components,
            prior_mean,
            prior_shape: Vec::new(),
            prior_flat: Vec::new(),
            prior_sum: Vector3::zeros(),
            prior_moment: Matrix3::zeros(),
            directions,
            energies,
            fit_components,
            robust_components,
            rows: Vec::new(),
            jacobian: Default::default(),
            cols,
            moments: Default::default(),
            prior_cross: Vec::new(),
            cross: Vec::new(),
        };
        basis.prior_shape = basis.shape(&basis.prior_mean);
        basis.prior_flat = flat.of(&basis.prior_shape);
        basis.prior_sum = basis.prior_shape.iter().sum();
        basis.prior_moment = basis.prior_shape.iter().map(|x| x * x.transpose()).sum();
        basis.cross = vec![0.0; 12 * k];
        for (j, p) in principal.iter().enumerate() {
            for (d, x) in p.iter().zip(&basis.prior_shape) {
                for a in 0..3 {
                    for b in 0..3 {
                        basis.cross[(3 * a + b) * k + j] += d[a] * x[b];
                    }
                    basis.cross[(9 + a) * k + j] += d[a];
                }
            }
        }
        (basis.moments, basis.prior_cross) = basis.moments_of(fit_components);
        basis.rows = basis.rows_of(fit_components);
        basis.jacobian =
            [fit_components, basis.robust_components()].map(|kk| basis.jacobian_of(kk));
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

    /// The energy of each principal component over the points (mm² per standard deviation of
    /// its coefficient), descending.
    pub fn energies(&self) -> &[f64] {
        &self.energies
    }

    /// How many principal components the fit moves (the others stay at their prior mean): by
    /// default [`DEFAULT_FIT_COMPONENTS`] (all, for a basis of fewer).
    pub fn fit_components(&self) -> usize {
        self.fit_components
    }

    /// How many principal components the step after robust reweighting moves, at most
    /// [`Self::fit_components`]: by default [`DEFAULT_ROBUST_COMPONENTS`] (all, for a basis of
    /// fewer).
    pub fn robust_components(&self) -> usize {
        self.robust_components.min(self.fit_components)
    }

    /// The same basis with the fit moving its first `fit` principal components and the robust
    /// step its first `robust` (each at least one and at most `K`, and `robust` at most `fit`):
    /// for the accuracy-speed frontier, and for a fit on every component.
    pub fn with_fit_components(mut self, fit: usize, robust: usize) -> Self {
        let k = self.components.len();
        self.fit_components = fit.max(1).min(k);
        self.robust_components = robust.max(1).min(self.fit_components);
        (self.moments, self.prior_cross) = self.moments_of(self.fit_components);
        self.rows = self.rows_of(self.fit_components);
        self.jacobian =
            [self.fit_components, self.robust_components()].map(|kk| self.jacobian_of(kk));
        self
    }

    /// The second moments and the cross moments of the first `kk` principal components (see
    /// `moments` and `prior_cross`).
    fn moments_of(&self, kk: usize) -> ([Vec<dense::Tile>; 6], Vec<[f64; TILE]>) {
        let flat = Flat::new(self.n_points());
        let nt = dense::tiles(6 + kk);
        let k = self.n_components();
        let mut cross = vec![[0.0; TILE]; 12 * nt];
        for t in 0..12 {
            for j in 0..kk {
                cross[t * nt + (6 + j) / TILE][(6 + j) % TILE] = self.cross[t * k + j];
            }
        }
        let col = |j: usize| &self.cols[j * flat.len()..(j + 1) * flat.len()];
        let mut out: [Vec<dense::Tile>; 6] =
            std::array::from_fn(|_| vec![[[0.0; TILE]; TILE]; nt * nt]);
        for q in 0..kk {
            for p in q..kk {
                let (t, c, r) = dense::at(nt, 6 + p, 6 + q);
                for i in 0..flat.n {
                    let (x, y) = (flat.point(col(p), i), flat.point(col(q), i));
                    for a in 0..3 {
                        out[a][t][c][r] += x[a] * y[a];
                    }
                    for (m, (a, b)) in out[3..].iter_mut().zip(PAIRS) {
                        m[t][c][r] += x[a] * y[b] + x[b] * y[a];
                    }
                }
            }
        }
        (out, cross)
    }

    /// The first `kk` principal components by point and axis (see `rows`).
    fn rows_of(&self, kk: usize) -> Vec<f64> {
        let flat = Flat::new(self.n_points());
        let stride = row_stride(kk);
        let mut rows = vec![0.0; 3 * flat.n * stride];
        for j in 0..kk {
            let col = &self.cols[j * flat.len()..(j + 1) * flat.len()];
            for i in 0..flat.n {
                for a in 0..3 {
                    rows[(3 * i + a) * stride + j] = col[a * flat.np + i];
                }
            }
        }
        rows
    }

    /// The first `kk` principal components laid out as the Jacobian rows hold them.
    fn jacobian_of(&self, kk: usize) -> JacobianBasis {
        let flat = Flat::new(self.n_points());
        let chunks = dense::tiles(6 + kk) - 1;
        let mut blocks = vec![[0.0; TILE]; 3 * flat.n * chunks];
        for j in 0..kk {
            let col = &self.cols[j * flat.len()..(j + 1) * flat.len()];
            let (c, l) = ((2 + j) / TILE, (2 + j) % TILE);
            for i in 0..flat.n {
                for a in 0..3 {
                    blocks[3 * (c * flat.n + i) + a][l] = col[a * flat.np + i];
                }
            }
        }
        JacobianBasis { kk, chunks, blocks }
    }

    /// The Jacobian layout of the first `kk` components (the fit's or the robust step's).
    fn jacobian(&self, kk: usize) -> &JacobianBasis {
        let j = self.jacobian.iter().find(|j| j.kk == kk);
        j.expect("a step moves the fit's or the robust step's components")
    }

    fn n_points(&self) -> usize {
        self.mean.len()
    }

    fn n_components(&self) -> usize {
        self.components.len()
    }

    /// The coefficients of principal coefficients `e` (the missing ones zero).
    fn coefficients(&self, e: &[f64]) -> Vec<f64> {
        let k = self.n_components();
        let mut c = self.prior_mean.clone();
        c.resize(dense::tiles(k) * TILE, 0.0);
        dense::add_columns(&mut c, &self.directions, e);
        c.truncate(k);
        c
    }
}

/// Options of [`fit_morphable`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MorphOptions {
    /// The rigid fit that starts it, as to hidden points (`hidden`) and how much contour points
    /// weigh (`contour_weight`) and its iterations: the start itself takes no Tukey rounds, and
    /// the joint fit keeps none of its weights. Whether the joint fit
    /// reweighs robustly (`robust`). With no components or no iterations, the fit is this rigid
    /// fit of the prior shape, as it is.
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

/// The fitted camera and shape.
#[derive(Debug, Clone)]
pub struct MorphFit {
    /// The fitted camera.
    pub camera: RigidFit,
    /// The coefficients of the principal components the fit moved, in standard deviations
    /// from the prior ([`MorphFit::coefficients`] gives the basis shapes' coefficients).
    pub principal: Vec<f64>,
    /// The fitted shape, model frame, mm.
    pub shape: Vec<Vector3<f64>>,
}

impl MorphFit {
    /// The coefficient of each of `model`'s basis shapes (`model` the basis fitted): the shape
    /// is `model`'s [`MorphableBasis::shape`] of them. Left to the caller who wants them, as
    /// the pose does not.
    pub fn coefficients(&self, model: &MorphableBasis) -> Vec<f64> {
        model.coefficients(&self.principal)
    }
}

thread_local! {
    /// One fit's buffers, kept per thread: a fit allocates only its inputs and its result.
    static WORK: RefCell<Work> = RefCell::new(Work::default());
}

/// Fits the morphable model to `landmarks` (image pixels): Gauss-Newton steps (damped when a
/// step would raise the cost) on
/// `Σ wᵢ ‖s P R Xᵢ(c) + t - yᵢ‖² + (s₀ σ)² Σ_k (c_k - μ_k)²`
/// jointly over rotation, scale, translation and `c` (its first
/// [`MorphableBasis::fit_components`] principal components), from the robust rigid fit of the
/// prior shape (`σ` = [`MorphOptions::noise_mm`], `s₀` the rigid fit's scale, so the balance does
/// not depend on the image size); then, when a residual stands out, Tukey's weights on the
/// joint residuals and a step over the first [`MorphableBasis::robust_components`].
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
    if model.n_components() == 0 || opts.iterations == 0 {
        let camera = fit_rigid(
            model.prior_shape(),
            landmarks,
            contour,
            visibility,
            opts.rigid,
        )?;
        return Ok(MorphFit {
            camera,
            principal: Vec::new(),
            shape: model.prior_shape.clone(),
        });
    }
    // The start: the rigid fit without its Tukey rounds. The joint fit drops the start's
    // weights and reweighs on its own residuals; on the AFLW2000-3D dev faces the MAE of `auto`
    // moves by 0.001° without them, for a tenth of the fit's cost (docs/PERFORMANCE.md).
    let start_opts = FitOptions {
        robust: false,
        ..opts.rigid
    };
    let start = fit_rigid(
        model.prior_shape(),
        landmarks,
        contour,
        visibility,
        start_opts,
    )?;
    let flat = Flat::new(model.n_points());
    // The joint fit weighs points by presence (and visibility at the rigid pose when asked):
    // a shape the prior shape does not match looks like outliers to a rigid model. Robustness
    // comes after, on the joint residuals.
    let mut w: Vec<f64> = landmarks
        .present()
        .iter()
        .map(|&p| f64::from(u8::from(p)))
        .collect();
    if opts.rigid.contour_weight != 1.0 {
        for &i in contour {
            if w.get(i) == Some(&1.0) {
                w[i] = opts.rigid.contour_weight;
            }
        }
    }
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
    // The landmarks in the y-up plane, flat like the shapes (x then y; zeros for missing
    // points and in the padding, where the weights are zero).
    let mut y = vec![0.0; 2 * flat.np];
    for (i, p) in landmarks.iter_present() {
        let p = image_to_plane(p);
        (y[i], y[flat.np + i]) = (p.x, p.y);
    }
    let prior_w = (start.scale * opts.noise_mm).powi(2);
    let (mut st, cost) = WORK.with_borrow_mut(|work| {
        work.fit(model);
        work.w.clear();
        work.w.extend_from_slice(&w);
        work.w.resize(flat.np, 0.0);
        let st = Joint {
            r: start.rotation,
            s: start.scale,
            t: start.translation,
            e: vec![0.0; model.fit_components],
            x: model.prior_flat.clone(),
            at_prior: true,
        };
        let kk = model.fit_components;
        let (mut st, mut cost) = joint_steps(model, kk, &y, st, prior_w, opts.iterations, work);
        if opts.rigid.robust {
            // Tukey's weights on the joint residuals (in `work.res2`), when one stands out.
            let before = w.clone();
            let floor = 0.01 * st.s * spread(flat, &st.x, &w);
            if tukey_weights(&work.res2[..flat.n], &mut w, floor, &mut work.scratch) {
                if w.iter().filter(|&&v| v > 0.0).count() >= 4 {
                    work.w[..flat.n].copy_from_slice(&w);
                    let kr = model.robust_components();
                    (st, cost) = joint_steps(model, kr, &y, st, prior_w, opts.iterations, work);
                } else {
                    w = before;
                }
            }
        }
        (st, cost)
    });
    st.r.renormalize();
    let sw: f64 = w.iter().sum();
    let rms_px = ((cost - prior_term(&st.e, prior_w)).max(0.0) / sw).sqrt();
    if !(rms_px.is_finite() && st.s.is_finite()) {
        return Err(Error::Numerical("the shape fit diverged".into()));
    }
    Ok(MorphFit {
        camera: RigidFit {
            rotation: st.r,
            scale: st.s,
            translation: st.t,
            weights: w,
            rms_px,
        },
        principal: st.e,
        shape: (0..flat.n).map(|i| flat.point(&st.x, i)).collect(),
    })
}

/// Root of the weighted mean squared distance of the points of the flat shape `x` to their
/// weighted centroid.
fn spread(flat: Flat, x: &[f64], w: &[f64]) -> f64 {
    let np = flat.np;
    // Each sum on its own (no chain of additions through the points' three axes).
    let (mut sw, mut sum, mut sq) = (0.0, [0.0; 3], [0.0; 3]);
    for (i, &wi) in w.iter().enumerate() {
        sw += wi;
        for a in 0..3 {
            let v = x[a * np + i];
            sum[a] += wi * v;
            sq[a] += wi * v * v;
        }
    }
    let c2: f64 = sum.iter().map(|s| (s / sw) * (s / sw)).sum();
    ((sq[0] + sq[1] + sq[2]) / sw - c2).max(0.0).sqrt()
}

/// The state of the joint problem.
#[derive(Debug, Clone, Default)]
struct Joint {
    r: Rotation3<f64>,
    s: f64,
    t: Vector2<f64>,
    /// Principal coefficients (the first [`MorphableBasis::fit_components`]).
    e: Vec<f64>,
    /// `X(e)`, flat, kept in step with `e`.
    x: Vec<f64>,
    /// Whether `e` is zero and `x` the prior shape, where moments give the system.
    at_prior: bool,
}

/// The buffers of a fit, sized for the largest system (`6 + K` unknowns, padded to whole
/// [`dense`] tiles); a step over fewer components uses their beginning.
#[derive(Default)]
struct Work {
    /// The weights, padded with zeros like the flat shapes.
    w: Vec<f64>,
    /// `JᵀWJ` in tiles, lower triangle (then factored in place).
    jtj: Vec<dense::Tile>,
    /// `JᵀWr`.
    jtr: Vec<f64>,
    /// The step, the inverses of the factor's diagonal, and the diagonal of `JᵀWJ` before
    /// damping.
    step: Vec<f64>,
    inv: Vec<f64>,
    diagonal: Vec<f64>,
    /// Jacobian rows of points (two each, padded), the same rows times their weight
    /// corrections (at the prior shape), and the square roots of the weights and the
    /// residuals times them (`√wᵢ`, `√wᵢ rₓ`, `√wᵢ r_y`, each `np` long, flat).
    rows: dense::Rows,
    scaled: dense::Rows,
    scales: Vec<f64>,
    /// Weighted residuals lifted into the model frame (`s wᵢ Rᵀ Pᵀ rᵢ`), point by point.
    lifted: Vec<f64>,
    /// Squared residuals at the state, at the candidate, and scratch for the robust weights.
    res2: Vec<f64>,
    cand_res2: Vec<f64>,
    scratch: Vec<f64>,
    /// A candidate state.
    cand: Joint,
}

impl Work {
    /// Sizes the buffers for `model`.
    fn fit(&mut self, model: &MorphableBasis) {
        let (flat, k) = (Flat::new(model.n_points()), model.n_components());
        let nt = dense::tiles(6 + k);
        if self.jtj.len() != nt * nt {
            self.jtj = vec![[[0.0; TILE]; TILE]; nt * nt];
        }
        let size = |v: &mut Vec<f64>, len: usize| {
            if v.len() != len {
                *v = vec![0.0; len];
            }
        };
        size(&mut self.jtr, TILE * nt);
        size(&mut self.step, TILE * nt);
        size(&mut self.inv, TILE * nt);
        size(&mut self.lifted, flat.len());
        size(&mut self.cand.x, flat.len());
        size(&mut self.res2, flat.np);
        size(&mut self.cand_res2, flat.np);
        self.w.reserve(flat.np);
        self.diagonal.reserve(TILE * nt);
        self.scales.reserve(3 * flat.np);
        self.scratch.reserve(flat.n);
    }
}

/// Up to `iterations` (at least one) Gauss-Newton steps from `st` moving the pose and the
/// first `kk` principal coefficients, each damped (Levenberg-Marquardt) until it lowers the
/// cost; stops early when no step does. Returns the state and its cost, and leaves its
/// squared residuals in `work.res2`.
fn joint_steps(
    model: &MorphableBasis,
    kk: usize,
    y: &[f64],
    mut st: Joint,
    prior_w: f64,
    iterations: usize,
    work: &mut Work,
) -> (Joint, f64) {
    let (d, nt) = (6 + kk, dense::tiles(6 + kk));
    let diag = |i: usize| dense::at(nt, i, i);
    let mut cost = f64::NAN;
    let mut lambda = 0.0;
    // Whether `work.res2` holds the squared residuals at `st`.
    let mut fresh = false;
    for _ in 0..iterations {
        let mut accepted = false;
        for attempt in 0..8 {
            // The system is factored in place: a damped retry (rare) forms it again.
            let here = normal_equations(model, kk, y, &st, prior_w, work);
            let jtj = &mut work.jtj[..nt * nt];
            if attempt == 0 {
                cost = here;
                work.diagonal.clear();
                work.diagonal.extend((0..d).map(|i| {
                    let (t, c, r) = diag(i);
                    jtj[t][c][r]
                }));
            }
            if lambda > 0.0 {
                // Marquardt's scaling, floored so that directions the data barely sees are
                // damped too.
                let floor = 1e-6 * work.diagonal.iter().fold(f64::MIN, |a, &b| a.max(b));
                for (i, &di) in work.diagonal.iter().enumerate() {
                    let (t, c, r) = diag(i);
                    jtj[t][c][r] += lambda * di.max(floor);
                }
            }
            if !dense::factor(jtj, nt, &mut work.inv) {
                lambda = (lambda * 10.0f64).max(1e-4);
                continue;
            }
            let step = &mut work.step[..TILE * nt];
            for (dl, g) in step.iter_mut().zip(&work.jtr) {
                *dl = -g;
            }
            dense::solve(jtj, nt, &work.inv, step);
            let step = &step[..d];
            let cand = &mut work.cand;
            cand.r = Rotation3::new(Vector3::new(step[0], step[1], step[2])) * st.r;
            cand.s = st.s + step[3];
            cand.t = st.t + Vector2::new(step[4], step[5]);
            cand.e.clone_from(&st.e);
            for (e, dj) in cand.e.iter_mut().zip(&step[6..]) {
                *e += dj;
            }
            cand.x.copy_from_slice(&st.x);
            dense::add_columns(&mut cand.x, &model.cols, &step[6..]);
            cand.at_prior = false;
            let c2 = joint_cost(y, &work.w, cand, prior_w, &mut work.cand_res2);
            if cand.s > 0.0 && c2 <= cost {
                std::mem::swap(&mut st, cand);
                std::mem::swap(&mut work.res2, &mut work.cand_res2);
                fresh = true;
                cost = c2;
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
    if !fresh {
        joint_cost(y, &work.w, &st, prior_w, &mut work.res2);
    }
    (st, cost)
}

fn prior_term(e: &[f64], prior_w: f64) -> f64 {
    prior_w * e.iter().map(|v| v * v).sum::<f64>()
}

/// The camera of a pass over the points: `s R`'s first two rows, the third row of `R`, `s`
/// and the translation.
#[derive(Debug, Clone, Copy)]
struct Camera {
    sr: [[f64; 3]; 2],
    r3: [f64; 3],
    s: f64,
    t: [f64; 2],
}

impl Camera {
    fn of(st: &Joint) -> Camera {
        let m = st.r.matrix();
        Camera {
            sr: [0, 1].map(|p| [0, 1, 2].map(|a| st.s * m[(p, a)])),
            r3: [0, 1, 2].map(|a| m[(2, a)]),
            s: st.s,
            t: [st.t.x, st.t.y],
        }
    }
}

/// The cost at `st` (with the padded weights `w`), and every point's squared residual into
/// `res2`.
fn joint_cost(y: &[f64], w: &[f64], st: &Joint, prior_w: f64, res2: &mut [f64]) -> f64 {
    residuals(&st.x, y, w, Camera::of(st), res2) + prior_term(&st.e, prior_w)
}

dense::kernel! {
    /// Squared residuals `|s (R xᵢ)ₓᵧ + t - yᵢ|²` of the flat shape `x` against the flat
    /// landmarks `y` into `res2`, four points at a time; returns their sum weighted by `w`.
    fn residuals / residuals_generic(x: &[f64], y: &[f64], w: &[f64], cam: Camera, res2: &mut [f64]) -> f64 {
        let np = w.len();
        let (xs, ys, zs) = (&x[..np], &x[np..2 * np], &x[2 * np..3 * np]);
        let (ux, uy) = (&y[..np], &y[np..2 * np]);
        let [r1, r2] = cam.sr;
        let mut acc = [0.0; TILE];
        for (i, (((((x4, y4), z4), ux4), uy4), w4)) in xs.as_chunks::<TILE>().0.iter()
            .zip(ys.as_chunks::<TILE>().0)
            .zip(zs.as_chunks::<TILE>().0)
            .zip(ux.as_chunks::<TILE>().0)
            .zip(uy.as_chunks::<TILE>().0)
            .zip(w.as_chunks::<TILE>().0)
            .enumerate()
        {
            let mut e = [0.0; TILE];
            for l in 0..TILE {
                let px = madd::<FMA>(r1[2], z4[l], madd::<FMA>(r1[1], y4[l], r1[0] * x4[l]));
                let py = madd::<FMA>(r2[2], z4[l], madd::<FMA>(r2[1], y4[l], r2[0] * x4[l]));
                let (rx, ry) = (px + cam.t[0] - ux4[l], py + cam.t[1] - uy4[l]);
                e[l] = madd::<FMA>(rx, rx, ry * ry);
                acc[l] = madd::<FMA>(w4[l], e[l], acc[l]);
            }
            res2[TILE * i..TILE * (i + 1)].copy_from_slice(&e);
        }
        (acc[0] + acc[2]) + (acc[1] + acc[3])
    }
}

dense::kernel! {
    /// One pass over the points of the flat shape `x` (weights `w`, landmarks `y`): returns the
    /// weighted squared residuals' sum and the pose gradient (`Σ wᵢ Jᵢᵀ rᵢ` over the rotation
    /// increment, scale and translation), and writes the weighted residuals lifted into the
    /// model frame, `s wᵢ Rᵀ Pᵀ rᵢ`, into `lifted` (point by point: `3i + a`).
    fn gradient_pass / gradient_pass_generic(x: &[f64], y: &[f64], w: &[f64], cam: Camera, lifted: &mut [f64]) -> [f64; 7] {
        let np = w.len();
        let (xs, ys, zs) = (&x[..np], &x[np..2 * np], &x[2 * np..3 * np]);
        let (ux, uy) = (&y[..np], &y[np..2 * np]);
        let [r1, r2] = cam.sr;
        let r3 = cam.r3;
        // Lanes of: the cost, then the gradient by unknown (the scale's times s).
        let mut acc = [[0.0; TILE]; 7];
        for ((((((x4, y4), z4), ux4), uy4), w4), l12) in xs.as_chunks::<TILE>().0.iter()
            .zip(ys.as_chunks::<TILE>().0)
            .zip(zs.as_chunks::<TILE>().0)
            .zip(ux.as_chunks::<TILE>().0)
            .zip(uy.as_chunks::<TILE>().0)
            .zip(w.as_chunks::<TILE>().0)
            .zip(lifted.as_chunks_mut::<{ 3 * TILE }>().0)
        {
            for l in 0..TILE {
                let (px, py, pz) = (x4[l], y4[l], z4[l]);
                // c = s qₓ, b = s q_y, a = s q_z.
                let c = madd::<FMA>(r1[2], pz, madd::<FMA>(r1[1], py, r1[0] * px));
                let b = madd::<FMA>(r2[2], pz, madd::<FMA>(r2[1], py, r2[0] * px));
                let a = cam.s * madd::<FMA>(r3[2], pz, madd::<FMA>(r3[1], py, r3[0] * px));
                let (rx, ry) = (c + cam.t[0] - ux4[l], b + cam.t[1] - uy4[l]);
                let (wrx, wry) = (w4[l] * rx, w4[l] * ry);
                acc[0][l] = madd::<FMA>(wrx, rx, madd::<FMA>(wry, ry, acc[0][l]));
                acc[1][l] = madd::<FMA>(-a, wry, acc[1][l]);
                acc[2][l] = madd::<FMA>(a, wrx, acc[2][l]);
                acc[3][l] = madd::<FMA>(c, wry, madd::<FMA>(-b, wrx, acc[3][l]));
                acc[4][l] = madd::<FMA>(c, wrx, madd::<FMA>(b, wry, acc[4][l]));
                acc[5][l] += wrx;
                acc[6][l] += wry;
                for k in 0..3 {
                    l12[3 * l + k] = madd::<FMA>(wrx, r1[k], wry * r2[k]);
                }
            }
        }
        let mut out = acc.map(|a| (a[0] + a[2]) + (a[1] + a[3]));
        out[4] /= cam.s;
        out
    }
}

/// A point's pose Jacobian rows, as the rigid fit's: `(0, a, -b, q_x, 1, 0)` and
/// `(-a, 0, c, q_y, 0, 1)` with `q = R Xᵢ`, `(a, b, c) = s (q_z, q_y, q_x)`.
fn pose_rows(q: &Vector3<f64>, s: f64) -> [[f64; 6]; 2] {
    let (a, b, c) = (s * q.z, s * q.y, s * q.x);
    [[0.0, a, -b, q.x, 1.0, 0.0], [-a, 0.0, c, q.y, 0.0, 1.0]]
}

/// `JᵀWJ` (lower triangle, in tiles) and `JᵀWr` of the joint problem at `st` into `work`, for
/// the pose (rotation increment ω, scale, translation) and the first `kk` principal
/// coefficients, padded with unknowns of their own to whole tiles; returns the cost at `st`.
///
/// A point's coefficient Jacobian rows are `uᵢ = s (R Pᵢ)ₓ` and `vᵢ = s (R Pᵢ)ᵧ`. At the prior
/// shape the system comes from moments ([`blocks_from_moments`]), one pass over the points
/// for the residuals and the pose gradient ([`gradient_pass`]) and the coefficient gradient
/// `Σᵢ wᵢ (uᵢ rₓ + vᵢ r_y) = Σᵢ Pᵢᵀ (s wᵢ Rᵀ Pᵀ rᵢ)` from one pass over the basis; the points
/// whose weight is not one are then corrected for, through their Jacobian rows
/// ([`dense::gram`]). Elsewhere, the system is the Gram matrix of every point's Jacobian rows
/// times the square root of its weight ([`normal_equations_by_points`], [`dense::gram_of`]).
fn normal_equations(
    model: &MorphableBasis,
    kk: usize,
    y: &[f64],
    st: &Joint,
    prior_w: f64,
    work: &mut Work,
) -> f64 {
    let w = &work.w;
    let in_use = w.iter().filter(|&&wi| wi > 0.0).count();
    let off = w[..model.n_points()]
        .iter()
        .filter(|&&wi| wi != 1.0)
        .count();
    if !(st.at_prior && kk == model.fit_components && off + 2 < in_use) {
        return normal_equations_by_points(model, kk, y, st, prior_w, work);
    }
    let (d, nt) = (6 + kk, dense::tiles(6 + kk));
    let cam = Camera::of(st);
    let [cost, g0, g1, g2, g3, g4, g5] = gradient_pass(&st.x, y, w, cam, &mut work.lifted);
    let jtr = &mut work.jtr[..TILE * nt];
    jtr[..6].copy_from_slice(&[g0, g1, g2, g3, g4, g5]);
    jtr[d..].fill(0.0);
    // Coefficient gradient: each principal component against the lifted residuals, then the
    // prior.
    let g = &mut jtr[6..d];
    dense::rows_times(&model.rows, row_stride(kk), &work.lifted, g);
    dense::axpy(prior_w, &st.e[..kk], g);

    let m = st.r.matrix();
    let jtj = &mut work.jtj[..nt * nt];
    blocks_from_moments(model, m, st.s, jtj);
    for r in 6..TILE * nt {
        let (t, tc, tr) = dense::at(nt, r, r);
        jtj[t][tc][tr] = if r < d { jtj[t][tc][tr] + prior_w } else { 1.0 };
    }
    // Points whose weight is not one: their rows with weight w - 1.
    if off > 0 {
        work.rows.reset(2 * off, nt);
        work.scaled.reset(2 * off, nt);
        let x = Flat::new(model.n_points());
        let mut r = 0;
        for i in 0..model.n_points() {
            let wi = work.w[i];
            if wi != 1.0 {
                push_rows::<false>(
                    model,
                    kk,
                    m,
                    st.s,
                    (i, x.point(&st.x, i)),
                    (r, wi - 1.0),
                    work,
                );
                r += 2;
            }
        }
        dense::gram(&work.rows, &work.scaled, &mut work.jtj[..nt * nt]);
    }
    cost + prior_term(&st.e, prior_w)
}

dense::kernel! {
    /// [`normal_equations`] away from the prior shape or with few weights of one: the Gram
    /// matrix of every point's Jacobian rows, each row scaled by the square root of the
    /// point's weight (`JᵀWJ = Σᵢ (√wᵢ Jᵢ)ᵀ (√wᵢ Jᵢ)`, the weights being positive, or zero
    /// for zero rows), and the gradient `Σᵢ (√wᵢ Jᵢ)ᵀ (√wᵢ rᵢ)` summed as the rows are made:
    /// one pass over the points, four at a time, for the pose's tile of the rows (with
    /// `q = R xᵢ` and `(a, b, c) = s (q_z, q_y, q_x)`, `√wᵢ (0, a, -b, qₓ)` and
    /// `√wᵢ (-a, 0, c, q_y)`), then one per further tile for the coefficients'
    /// `uᵢ = √wᵢ s R₀ Pᵢ` and `vᵢ = √wᵢ s R₁ Pᵢ` (the first of them led by the translation's
    /// `√wᵢ (1, 0)` and `√wᵢ (0, 1)`), the camera's factors held throughout.
    fn normal_equations_by_points / by_points_generic(
        model: &MorphableBasis,
        kk: usize,
        y: &[f64],
        st: &Joint,
        prior_w: f64,
        work: &mut Work
    ) -> f64 {
        let (d, nt) = (6 + kk, dense::tiles(6 + kk));
        let flat = Flat::new(model.n_points());
        let (n, np) = (flat.n, flat.np);
        let m = st.r.matrix();
        let s = st.s;
        let jb = model.jacobian(kk);
        let chunks = jb.chunks;
        debug_assert_eq!(chunks + 1, nt);
        // Rows for every point, the padding's included: zeros where the weight is zero.
        let rows = &mut work.rows;
        rows.reset(2 * np, nt);
        let (first, coef) = rows.blocks[..nt * 2 * np].split_at_mut(2 * np);
        let (g, _) = work.jtr[..TILE * nt].as_chunks_mut::<TILE>();
        let scales = &mut work.scales;
        // Every value is written before it is read: no need to clear.
        if scales.len() < 3 * np {
            scales.resize(3 * np, 0.0);
        }
        let (sws, rest) = scales.split_at_mut(np);
        let (exs, eys) = rest.split_at_mut(np);
        // The pose's tile, four points at a time.
        let mut cost = [0.0; TILE];
        let mut g0 = [[0.0; TILE]; TILE];
        let (x4s, y4s, z4s) = (&st.x[..np], &st.x[np..2 * np], &st.x[2 * np..3 * np]);
        let (u4s, v4s) = (&y[..np], &y[np..2 * np]);
        for (((((((((x4, y4), z4), u4), v4), w4), out), sw4), ex4), ey4) in x4s.as_chunks::<TILE>().0.iter()
            .zip(y4s.as_chunks::<TILE>().0)
            .zip(z4s.as_chunks::<TILE>().0)
            .zip(u4s.as_chunks::<TILE>().0)
            .zip(v4s.as_chunks::<TILE>().0)
            .zip(work.w[..np].as_chunks::<TILE>().0)
            .zip(first.as_chunks_mut::<{ 2 * TILE }>().0)
            .zip(sws.as_chunks_mut::<TILE>().0)
            .zip(exs.as_chunks_mut::<TILE>().0)
            .zip(eys.as_chunks_mut::<TILE>().0)
        {
            // Lane by lane, four points at once.
            let q: [[f64; TILE]; 3] = std::array::from_fn(|k| {
                std::array::from_fn(|l| {
                    madd::<FMA>(m[(k, 2)], z4[l], madd::<FMA>(m[(k, 1)], y4[l], m[(k, 0)] * x4[l]))
                })
            });
            let rx: [f64; TILE] = std::array::from_fn(|l| madd::<FMA>(s, q[0][l], st.t.x) - u4[l]);
            let ry: [f64; TILE] = std::array::from_fn(|l| madd::<FMA>(s, q[1][l], st.t.y) - v4[l]);
            let wl = w4.map(|v| v.max(0.0));
            let sw = wl.map(f64::sqrt);
            let ex: [f64; TILE] = std::array::from_fn(|l| sw[l] * rx[l]);
            let ey: [f64; TILE] = std::array::from_fn(|l| sw[l] * ry[l]);
            let ss = sw.map(|v| v * s);
            let sa: [f64; TILE] = std::array::from_fn(|l| ss[l] * q[2][l]);
            let sb: [f64; TILE] = std::array::from_fn(|l| ss[l] * q[1][l]);
            let sc: [f64; TILE] = std::array::from_fn(|l| ss[l] * q[0][l]);
            let sqx: [f64; TILE] = std::array::from_fn(|l| sw[l] * q[0][l]);
            let sqy: [f64; TILE] = std::array::from_fn(|l| sw[l] * q[1][l]);
            for l in 0..TILE {
                cost[l] = madd::<FMA>(wl[l], madd::<FMA>(rx[l], rx[l], ry[l] * ry[l]), cost[l]);
                g0[0][l] = madd::<FMA>(-sa[l], ey[l], g0[0][l]);
                g0[1][l] = madd::<FMA>(sa[l], ex[l], g0[1][l]);
                g0[2][l] = madd::<FMA>(sc[l], ey[l], madd::<FMA>(-sb[l], ex[l], g0[2][l]));
                g0[3][l] = madd::<FMA>(sqy[l], ey[l], madd::<FMA>(sqx[l], ex[l], g0[3][l]));
            }
            (*sw4, *ex4, *ey4) = (sw, ex, ey);
            for l in 0..TILE {
                out[2 * l] = [0.0, sa[l], -sb[l], sqx[l]];
                out[2 * l + 1] = [-sa[l], 0.0, sc[l], sqy[l]];
            }
        }
        g[0] = g0.map(|a| (a[0] + a[2]) + (a[1] + a[3]));
        // The coefficients' tiles.
        let cx = [s * m[(0, 0)], s * m[(0, 1)], s * m[(0, 2)]];
        let cy = [s * m[(1, 0)], s * m[(1, 1)], s * m[(1, 2)]];
        let (basis, _) = jb.blocks[..3 * n * chunks].as_chunks::<3>();
        let scales = (&sws[..n], &exs[..n], &eys[..n]);
        for (t, ((out, gt), basis)) in coef
            .chunks_exact_mut(2 * np)
            .zip(&mut g[1..])
            .zip(basis.chunks_exact(n.max(1)))
            .enumerate()
        {
            let (out, _) = out.as_chunks_mut::<2>();
            *gt = if t == 0 {
                coefficient_tile::<FMA, true>(basis, scales, cx, cy, &mut out[..n])
            } else {
                coefficient_tile::<FMA, false>(basis, scales, cx, cy, &mut out[..n])
            };
            out[n..].fill([[0.0; TILE]; 2]);
        }
        let jtj = &mut work.jtj[..nt * nt];
        dense::gram_of(&work.rows, jtj);
        dense::axpy(prior_w, &st.e[..kk], &mut work.jtr[6..d]);
        for r in 6..TILE * nt {
            let (t, tc, tr) = dense::at(nt, r, r);
            jtj[t][tc][tr] += if r < d { prior_w } else { 1.0 };
        }
        (cost[0] + cost[2]) + (cost[1] + cost[3]) + prior_term(&st.e, prior_w)
    }
}

/// A further tile of the rows of every point into `out` (a pair of rows per point), from that
/// tile of the basis in Jacobian layout (`basis`, by point its three axes), the points' `√wᵢ`,
/// `√wᵢ rₓ` and `√wᵢ r_y` (`scales`) and `s R₀`, `s R₁` (`cx`, `cy`); returns the tile's
/// gradient. `FIRST`: the tile also holds the translation's columns (zeros in the basis).
#[inline(always)]
fn coefficient_tile<const FMA: bool, const FIRST: bool>(
    basis: &[[[f64; TILE]; 3]],
    (sws, exs, eys): (&[f64], &[f64], &[f64]),
    cx: [f64; 3],
    cy: [f64; 3],
    out: &mut [[[f64; TILE]; 2]],
) -> [f64; TILE] {
    let lead =
        |k: usize| -> [f64; TILE] { std::array::from_fn(|l| f64::from(u8::from(FIRST && l == k))) };
    let (ex0, ey1) = (lead(0), lead(1));
    let mut gt = [0.0; TILE];
    let points = basis.iter().zip(out).zip(sws.iter().zip(exs).zip(eys));
    for (([x4, y4, z4], o), ((&sw, &ex), &ey)) in points {
        let u: [f64; TILE] = std::array::from_fn(|l| {
            let e = madd::<FMA>(cx[2], z4[l], madd::<FMA>(cx[1], y4[l], cx[0] * x4[l]));
            sw * if FIRST { e + ex0[l] } else { e }
        });
        let v: [f64; TILE] = std::array::from_fn(|l| {
            let e = madd::<FMA>(cy[2], z4[l], madd::<FMA>(cy[1], y4[l], cy[0] * x4[l]));
            sw * if FIRST { e + ey1[l] } else { e }
        });
        *o = [u, v];
        for l in 0..TILE {
            gt[l] = madd::<FMA>(ey, v[l], madd::<FMA>(ex, u[l], gt[l]));
        }
    }
    gt
}

/// Writes the two Jacobian rows of point `i` (at shape point `x`) as rows `r` and `r + 1` of
/// `work.rows`, and the same times `f` into `work.scaled`.
#[inline(always)]
fn push_rows<const FMA: bool>(
    model: &MorphableBasis,
    kk: usize,
    m: &Matrix3<f64>,
    s: f64,
    (i, x): (usize, Vector3<f64>),
    (r, f): (usize, f64),
    work: &mut Work,
) {
    let q = m * x;
    let jb = model.jacobian(kk);
    let n = model.n_points();
    let (rows, scaled) = (&mut work.rows, &mut work.scaled);
    let mm = rows.m;
    for (k, pose) in pose_rows(&q, s).into_iter().enumerate() {
        let (fx, fy, fz) = (s * m[(k, 0)], s * m[(k, 1)], s * m[(k, 2)]);
        let first = [pose[0], pose[1], pose[2], pose[3]];
        rows.blocks[r + k] = first;
        scaled.blocks[r + k] = first.map(|v| f * v);
        for c in 0..jb.chunks {
            let [x4, y4, z4] = jb.blocks[3 * (c * n + i)..][..3] else {
                unreachable!("three axes")
            };
            let mut b: [f64; TILE] =
                std::array::from_fn(|l| madd::<FMA>(fz, z4[l], madd::<FMA>(fy, y4[l], fx * x4[l])));
            if c == 0 {
                (b[0], b[1]) = (pose[4], pose[5]);
            }
            rows.blocks[(c + 1) * mm + r + k] = b;
            scaled.blocks[(c + 1) * mm + r + k] = b.map(|v| f * v);
        }
    }
}

/// The system at the prior shape with every weight one (tiles of `jtj`, the fit's
/// components), from moments: the pose, cross and coefficient blocks; zeros elsewhere in the
/// lower triangle.
///
/// With `q = R X̄ᵢ` and `(a, b, c) = s (q_z, q_y, q_x)`, the pose block's sums are entries of
/// `Σ q qᵀ = R (Σ X̄ᵢ X̄ᵢᵀ) Rᵀ` and `Σ q = R Σ X̄ᵢ`. With `Q = R Nⱼ Rᵀ`, `Nⱼ = Σᵢ Pᵢ[:, j] X̄ᵢᵀ`
/// and `σ = R Σᵢ Pᵢ[:, j]`, the cross block's are, per component `j`: `Σ u a = s² Q₀₂`,
/// `Σ v a = s² Q₁₂`, `Σ (v c - u b) = s² (Q₁₀ - Q₀₁)`, `Σ (u qₓ + v q_y) = s (Q₀₀ + Q₁₁)`,
/// `Σ u = s σ₀`, `Σ v = s σ₁`: linear in `Nⱼ` and `σ`, so each column of the block combines
/// the twelve rows of `prior_cross`. The coefficient block is
/// `s² (Σ_a (1 - r₃ₐ²) M_aa - Σ_{a<b} r₃ₐ r₃_b (M_ab + M_ba))`.
fn blocks_from_moments(model: &MorphableBasis, m: &Matrix3<f64>, s: f64, jtj: &mut [dense::Tile]) {
    let kk = model.fit_components;
    let nt = dense::tiles(6 + kk);
    let s2 = s * s;
    let r3 = m.row(2);
    let f = [
        s2 * (1.0 - r3[0] * r3[0]),
        s2 * (1.0 - r3[1] * r3[1]),
        s2 * (1.0 - r3[2] * r3[2]),
        -s2 * r3[0] * r3[1],
        -s2 * r3[0] * r3[2],
        -s2 * r3[1] * r3[2],
    ];
    let mo = &model.moments;
    // The moments are zero in the first tile column (the pose's); the cross and pose blocks
    // below fill it.
    dense::combine6(jtj, nt, 1, f, std::array::from_fn(|a| &mo[a][..]));

    let q2 = m * model.prior_moment * m.transpose();
    let q1 = m * model.prior_sum;
    let n = model.n_points() as f64;
    let (xx, yy, zz) = (q2[(0, 0)], q2[(1, 1)], q2[(2, 2)]);
    let (xz, yz) = (q2[(0, 2)], q2[(1, 2)]);
    // `Σ (c q_y - b qₓ)` is zero: `c q_y = b qₓ = s qₓ q_y`.
    #[rustfmt::skip]
    let pose = [
        [s2 * zz,  0.0,      -s2 * xz,          -s * yz,   0.0,      -s * q1.z],
        [0.0,      s2 * zz,  -s2 * yz,          s * xz,    s * q1.z, 0.0],
        [-s2 * xz, -s2 * yz, s2 * (xx + yy),    0.0,       -s * q1.y, s * q1.x],
        [-s * yz,  s * xz,   0.0,               xx + yy,   q1.x,     q1.y],
        [0.0,      s * q1.z, -s * q1.y,         q1.x,      n,        0.0],
        [-s * q1.z, 0.0,     s * q1.x,          q1.y,      0.0,      n],
    ];
    // Each cross column: its coefficients on the columns of `prior_cross` (`3a + b`, then
    // `9 + a`).
    let mut coef = [[0.0; 12]; 6];
    for a in 0..3 {
        for b in 0..3 {
            let ab = 3 * a + b;
            coef[0][ab] = -s2 * m[(1, a)] * m[(2, b)];
            coef[1][ab] = s2 * m[(0, a)] * m[(2, b)];
            coef[2][ab] = s2 * (m[(1, a)] * m[(0, b)] - m[(0, a)] * m[(1, b)]);
            coef[3][ab] = s * (m[(0, a)] * m[(0, b)] + m[(1, a)] * m[(1, b)]);
        }
        coef[4][9 + a] = s * m[(0, a)];
        coef[5][9 + a] = s * m[(1, a)];
    }
    dense::combine_columns(jtj, nt, coef, &model.prior_cross);
    // The pose block, over the rows of the cross block's first tile that are the pose's.
    let mut set = |r: usize, c: usize, v: f64| {
        let (t, tc, tr) = dense::at(nt, r, c);
        jtj[t][tc][tr] = v;
    };
    for (r, row) in pose.iter().enumerate() {
        for (c, &v) in row.iter().enumerate().take(r + 1) {
            set(r, c, v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
    use nalgebra::{DMatrix, DVector};
    use proptest::prelude::*;

    /// A small face and two deformations: a deeper nose and a wider mouth.
    fn basis() -> MorphableBasis {
        let mean = crate::test_faces::face(10);
        let mut nose = vec![Vector3::zeros(); 10];
        nose[2] = Vector3::new(0.0, 0.0, 4.0);
        nose[8] = Vector3::new(0.0, 0.0, 2.0);
        let mut mouth = vec![Vector3::zeros(); 10];
        mouth[3] = Vector3::new(-3.0, 0.0, 0.0);
        mouth[4] = Vector3::new(3.0, 0.0, 0.0);
        MorphableBasis::new(mean, vec![nose, mouth], vec![0.5, 0.0]).unwrap()
    }

    /// `n` points and `k` components of pseudo-random shape (seeded), none of them special.
    fn random_basis(n: usize, k: usize, seed: u64) -> MorphableBasis {
        let mut state = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mean = (0..n)
            .map(|_| Vector3::new(60.0 * next(), 70.0 * next(), 30.0 * next()))
            .collect();
        let components = (0..k)
            .map(|c| {
                let size = 6.0 / (1.0 + c as f64);
                (0..n)
                    .map(|_| Vector3::new(next(), next(), next()) * size)
                    .collect()
            })
            .collect();
        let prior = (0..k).map(|_| 0.3 * next()).collect();
        MorphableBasis::new(mean, components, prior).unwrap()
    }

    fn view(b: &MorphableBasis, c: &[f64], a: EulerAngles) -> Shape2 {
        let cam = WeakPerspective::new(a.to_rotation(), 2.0, Vector2::new(300.0, -250.0)).unwrap();
        Shape2::full(b.shape(c).iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    /// Principal component `j` from the basis and its direction, point by point.
    fn principal(b: &MorphableBasis, j: usize) -> Vec<Vector3<f64>> {
        let kp = dense::tiles(b.n_components()) * TILE;
        let v = &b.directions[j * kp..j * kp + b.n_components()];
        (0..b.n_points())
            .map(|i| b.components.iter().zip(v).map(|(c, &vl)| c[i] * vl).sum())
            .collect()
    }

    /// The normal equations from explicit Jacobian rows, one point at a time (the pose's as the
    /// rigid fit's, the coefficients' from the principal components): the reference.
    fn explicit_system(
        b: &MorphableBasis,
        kk: usize,
        y: &[Vector2<f64>],
        w: &[f64],
        st: &Joint,
        prior_w: f64,
    ) -> (DMatrix<f64>, DVector<f64>, f64) {
        let d = 6 + kk;
        let flat = Flat::new(b.n_points());
        let m = st.r.matrix();
        let comps: Vec<Vec<Vector3<f64>>> = (0..kk).map(|j| principal(b, j)).collect();
        let (mut h, mut g, mut cost) = (DMatrix::zeros(d, d), DVector::zeros(d), 0.0);
        for i in 0..flat.n {
            let q = m * flat.point(&st.x, i);
            let (a, bb, c) = (st.s * q.z, st.s * q.y, st.s * q.x);
            let res = st.s * q.xy() + st.t - y[i];
            let mut rx = DVector::from_column_slice(&[0.0, a, -bb, q.x, 1.0, 0.0]);
            let mut ry = DVector::from_column_slice(&[-a, 0.0, c, q.y, 0.0, 1.0]);
            rx = rx.resize_vertically(d, 0.0);
            ry = ry.resize_vertically(d, 0.0);
            for (j, p) in comps.iter().enumerate() {
                let rp = m * p[i];
                rx[6 + j] = st.s * rp.x;
                ry[6 + j] = st.s * rp.y;
            }
            h += w[i] * (&rx * rx.transpose() + &ry * ry.transpose());
            g += w[i] * (&rx * res.x + &ry * res.y);
            cost += w[i] * res.norm_squared();
        }
        for j in 0..kk {
            h[(6 + j, 6 + j)] += prior_w;
            g[6 + j] += prior_w * st.e[j];
        }
        (h, g, cost + prior_term(&st.e, prior_w))
    }

    /// `normal_equations` as a dense symmetric matrix and vector of the first `6 + kk`.
    fn tiled_system(
        b: &MorphableBasis,
        kk: usize,
        y: &[Vector2<f64>],
        w: &[f64],
        st: &Joint,
        prior_w: f64,
    ) -> (DMatrix<f64>, DVector<f64>, f64) {
        tiled_system_of(normal_equations, b, kk, y, w, st, prior_w)
    }

    type System = fn(&MorphableBasis, usize, &[f64], &Joint, f64, &mut Work) -> f64;

    /// `tiled_system` of one way to form the system (`normal_equations`, or the build of the
    /// system point by point as built for the target).
    fn tiled_system_of(
        system: System,
        b: &MorphableBasis,
        kk: usize,
        y: &[Vector2<f64>],
        w: &[f64],
        st: &Joint,
        prior_w: f64,
    ) -> (DMatrix<f64>, DVector<f64>, f64) {
        let flat = Flat::new(b.n_points());
        let mut work = Work::default();
        work.fit(b);
        work.w = w.to_vec();
        work.w.resize(flat.np, 0.0);
        let mut yf = vec![0.0; 2 * flat.np];
        for (i, p) in y.iter().enumerate() {
            (yf[i], yf[flat.np + i]) = (p.x, p.y);
        }
        let cost = system(b, kk, &yf, st, prior_w, &mut work);
        let (d, nt) = (6 + kk, dense::tiles(6 + kk));
        let h = DMatrix::from_fn(d, d, |r, c| {
            let (t, tc, tr) = dense::at(nt, r.max(c), r.min(c));
            work.jtj[t][tc][tr]
        });
        (h, DVector::from_column_slice(&work.jtr[..d]), cost)
    }

    fn state(b: &MorphableBasis, kk: usize, e: &[f64], a: EulerAngles) -> Joint {
        let flat = Flat::new(b.n_points());
        let mut x = b.prior_flat.clone();
        let cols: Vec<f64> = b.cols[..kk * flat.len()].to_vec();
        dense::add_columns(&mut x, &cols, &e[..kk]);
        Joint {
            r: a.to_rotation(),
            s: 1.3,
            t: Vector2::new(5.0, -8.0),
            e: e.to_vec(),
            x,
            at_prior: e.iter().all(|&v| v == 0.0),
        }
    }

    fn assert_close(
        got: &(DMatrix<f64>, DVector<f64>, f64),
        want: &(DMatrix<f64>, DVector<f64>, f64),
    ) {
        assert!(
            (&got.0 - &want.0).norm() <= 1e-9 * want.0.norm(),
            "{} vs {}",
            got.0,
            want.0
        );
        assert!(
            (&got.1 - &want.1).norm() <= 1e-9 * want.1.norm(),
            "{} vs {}",
            got.1,
            want.1
        );
        assert!(
            (got.2 - want.2).abs() <= 1e-9 * want.2,
            "{} vs {}",
            got.2,
            want.2
        );
    }

    /// The system from the moments (with corrections for weights other than one) and from the
    /// points agree with the explicit Jacobian, at the prior shape and away from it, for the
    /// fit's components and the robust step's.
    #[test]
    fn normal_equations_match_the_explicit_jacobian() {
        let b = random_basis(23, 9, 7).with_fit_components(7, 5);
        let a = EulerAngles::new(-35.0, 12.0, 7.0).unwrap();
        let y: Vec<Vector2<f64>> = (0..23)
            .map(|i| Vector2::new(3.0 * i as f64, -2.0 * (i % 4) as f64))
            .collect();
        let ones = vec![1.0; 23];
        let mut some = ones.clone();
        (some[2], some[8], some[15]) = (0.0, 0.5, 0.25);
        let other: Vec<f64> = (0..23).map(|i| 0.2 + 0.03 * i as f64).collect();
        let zero = vec![0.0; 7];
        let moved: Vec<f64> = (0..7).map(|j| 0.3 - 0.1 * j as f64).collect();
        for w in [&ones, &some, &other] {
            for (e, kk) in [(&zero, 7), (&moved, 7), (&moved, 5)] {
                let st = state(&b, 7, e, a);
                let got = tiled_system(&b, kk, &y, w, &st, 0.8);
                let want = explicit_system(&b, kk, &y, w, &st, 0.8);
                assert_close(&got, &want);
                // The build point by point that the dispatch may not take.
                let generic = by_points_generic::<false>;
                let got = tiled_system_of(generic, &b, kk, &y, w, &st, 0.8);
                assert_close(&got, &want);
            }
        }
    }

    /// The principal components span the basis: the shape from the fitted coefficients is the
    /// fitted shape, and the principal directions are orthonormal, by energy.
    #[test]
    fn coefficients_and_shape_agree() {
        let b = random_basis(30, 8, 3);
        let k = b.n_components();
        let kp = dense::tiles(k) * TILE;
        for p in 0..k {
            for q in 0..k {
                let dot: f64 = (0..k)
                    .map(|l| b.directions[p * kp + l] * b.directions[q * kp + l])
                    .sum();
                assert!((dot - f64::from(u8::from(p == q))).abs() < 1e-12);
            }
            let energy: f64 = principal(&b, p).iter().map(|x| x.norm_squared()).sum();
            assert!((energy - b.energies()[p]).abs() < 1e-9 * energy.max(1.0));
        }
        assert!(b.energies().windows(2).all(|e| e[0] >= e[1]));
        let c: Vec<f64> = (0..k).map(|j| 0.5 - 0.2 * j as f64).collect();
        let a = EulerAngles::new(20.0, -10.0, 5.0).unwrap();
        let lm = view(&b, &c, a);
        let f = fit_morphable(&b, &lm, &[], None, MorphOptions::default()).unwrap();
        for (x, want) in f.shape.iter().zip(b.shape(&f.coefficients(&b))) {
            assert!((x - want).norm() < 1e-9, "{x} vs {want}");
        }
    }

    /// The default counts, capped by the basis; a fit over fewer takes at least one and at most
    /// them all.
    #[test]
    fn component_counts() {
        let b = random_basis(40, 30, 11);
        assert_eq!(
            (b.fit_components(), b.robust_components()),
            (30, DEFAULT_ROBUST_COMPONENTS.min(30))
        );
        let few = random_basis(40, 5, 11);
        assert_eq!((few.fit_components(), few.robust_components()), (5, 5));
        let c = b.clone().with_fit_components(100, 100);
        assert_eq!((c.fit_components(), c.robust_components()), (30, 30));
        let c = b.with_fit_components(0, 9);
        assert_eq!((c.fit_components(), c.robust_components()), (1, 1));
        // No components: the rigid fit of the mean.
        let none = MorphableBasis::new(crate::test_faces::face(10), vec![], vec![]).unwrap();
        assert_eq!((none.fit_components(), none.robust_components()), (0, 0));
        let a = EulerAngles::new(20.0, 10.0, 0.0).unwrap();
        let f = fit_morphable(
            &none,
            &view(&none, &[], a),
            &[],
            None,
            MorphOptions::default(),
        );
        assert!(geodesic_deg(&f.unwrap().camera.rotation, &a.to_rotation()) < 1e-6);
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
            let coefficients = f.coefficients(&b);
            let e = EulerAngles::from_rotation(&f.camera.rotation);
            assert!(
                (e.yaw - yaw).abs() < 0.05 && (e.pitch - pitch).abs() < 0.05,
                "{a:?} -> {e:?}"
            );
            assert!((e.roll - roll).abs() < 0.05);
            // The nose's depth is invisible head-on; the mouth's width is not.
            assert!(
                (coefficients[1] - truth[1]).abs() < 0.05,
                "{coefficients:?}"
            );
            if yaw != 0.0 {
                assert!(
                    (coefficients[0] - truth[0]).abs() < 0.05,
                    "{coefficients:?}"
                );
            }
        }
    }

    proptest! {
        /// A face of the basis projected at a known pose is recovered by the converged fit on
        /// every component, from the rigid fit of the prior shape.
        #[test]
        fn recovers_a_known_pose(
            yaw in -60.0f64..60.0,
            pitch in -35.0f64..35.0,
            roll in -40.0f64..40.0,
            c in prop::collection::vec(-1.5f64..1.5, 6),
        ) {
            let b = random_basis(40, 6, 5);
            let b = b.clone().with_fit_components(6, 6);
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let opts = MorphOptions { iterations: 40, noise_mm: 1e-4, ..MorphOptions::default() };
            let f = fit_morphable(&b, &view(&b, &c, a), &[], None, opts).unwrap();
            prop_assert!(geodesic_deg(&f.camera.rotation, &a.to_rotation()) < 0.01);
            prop_assert!(f.camera.rms_px < 1e-3);
        }
    }

    /// The default model: one of its faces at a known pose. The defaults' one step (on the fit's
    /// components) lands nearer than the rigid fit of the prior shape, and the converged fit on
    /// every component within hundredths of a degree.
    #[test]
    fn default_model_faces_are_recovered() {
        let (_, model) = crate::model::default_model().unwrap();
        let b = model.morph.as_ref().unwrap();
        let c: Vec<f64> = (0..b.n_components())
            .map(|j| b.prior_mean()[j] + 0.8 * ((j as f64) * 1.3).sin())
            .collect();
        let all = b.clone().with_fit_components(usize::MAX, usize::MAX);
        for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (35.0, -15.0, 8.0), (-60.0, 20.0, -10.0)] {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let err = |r: &Rotation3<f64>| geodesic_deg(r, &a.to_rotation());
            let lm = view(b, &c, a);
            let rigid = fit_rigid(b.prior_shape(), &lm, &[], None, FitOptions::default()).unwrap();
            let one = fit_morphable(b, &lm, &[], None, MorphOptions::default()).unwrap();
            assert!(
                err(&one.camera.rotation) < err(&rigid.rotation),
                "{a:?}: rigid {} one step {}",
                err(&rigid.rotation),
                err(&one.camera.rotation)
            );
            let opts = MorphOptions {
                iterations: 30,
                noise_mm: 1e-3,
                ..MorphOptions::default()
            };
            let many = fit_morphable(&all, &lm, &[], None, opts).unwrap();
            assert!(
                err(&many.camera.rotation) < 0.02,
                "{a:?}: {}",
                err(&many.camera.rotation)
            );
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
        let err = |r: &Rotation3<f64>| geodesic_deg(r, &a.to_rotation());
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
