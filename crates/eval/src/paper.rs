//! The paper's synthetic protocol (§5, Table 1), with robustness curves and error maps.
//!
//! - **Model.** A mean shape from the first shapes of a 3D population (the paper: the first 100
//!   of its 249), trained with the project's own [`train_from_population`] on the paper's grid
//!   ([`RegressionParams::paper`]: yaw and pitch within ±40° at 2°) for `ibug68`, `inner51` (the
//!   paper's "50 points") and `five` ([`train_paper_model`]).
//! - **Views.** Each test shape (model frame, mm, frontal, centred here) is rotated to every pose
//!   of the same grid, projected at a scale that gives an inter-ocular distance (eye centres) of
//!   60-100 px and a translation near the centre of a 450 px image (both drawn from a seeded
//!   generator per shape and pose), and the paper's HPR on that shape's own triangulation marks
//!   hidden points, which are sent as missing (the paper zeroes them). The five points are the
//!   anchor means (eye centres, nose tip, mouth corners) of all 68 projected points, missing
//!   only when all their source points are hidden.
//! - **Stages.** "Training" runs the methods on the mean shape's own projections over the whole
//!   grid; "testing" on the other shapes, subsampled deterministically: shape `k` at pose `j`
//!   is used when a hash of `(seed, k, j)` is divisible by `stride` ([`keeps`]), so every pose
//!   is seen by about `shapes / stride` shapes, every shape at about `poses / stride` poses,
//!   and no shape follows a lattice of poses (which would paint stripes on the error maps).
//! - **Measures.** The paper's mean squared error (degrees²) and the mean absolute error, yaw
//!   and pitch separately, and the mean geodesic error (which also counts roll). An estimate
//!   that fails is counted and left out of the means.
//! - **Robustness.** The same seeded draws of (test shape, pose) for every condition and method:
//!   Gaussian landmark noise with σ a fraction of the inter-ocular distance in pixels, or `k`
//!   random present points sent as missing (at most one for five-point entries).
//! - **Error maps.** Per method, the mean of the yaw and pitch absolute errors at each pose of the
//!   grid over the test shapes.
//!
//! Everything is pure: shapes and the model come in as arguments, rows and grids go out.

use nalgebra::{Vector2, Vector3};
use rand::seq::index::sample;
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::progress::{Observer, Phase, PhaseReport};
use facepose_core::error::{Error, Result};
use facepose_core::geometry::convention::wrap_deg;
use facepose_core::geometry::procrustes::centre3;
use facepose_core::geometry::{EulerAngles, geodesic_deg};
use facepose_core::hpr::PaperHpr;
use facepose_core::model::{
    BasisSource, PoseModel, RegressionParams, Subset, TrainOptions, train_from_population,
};
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::{Scheme, Shape2};
use facepose_core::synth::{PoseGrid, SyntheticView, ViewSynthesizer};

/// One method on one scheme: a row of Table 1.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct PaperEntry {
    /// The method.
    pub method: Method,
    /// The scheme the landmarks are sent in (`ibug68`, `inner51`, `five`).
    pub scheme: String,
}

impl PaperEntry {
    /// The entry of `method` on `scheme`.
    pub fn new(method: Method, scheme: &str) -> Self {
        PaperEntry {
            method,
            scheme: scheme.into(),
        }
    }

    /// A short label, e.g. `regression, 51 points`.
    pub fn label(&self, model: &PoseModel) -> String {
        let n = model
            .subset(&self.scheme)
            .map(|s| s.scheme.len())
            .unwrap_or(0);
        format!("{}, {n} points", self.method)
    }
}

/// The entries for `methods`, in the paper's order: geometry (five points), regression on five,
/// 51 and 68 points, then the fits (68 and five points; the shape fit only when the model has
/// a basis). Entries whose scheme the model does not serve are left out.
pub fn default_entries(model: &PoseModel, methods: &[Method]) -> Vec<PaperEntry> {
    let all = [
        (Method::Geometry, "five"),
        (Method::Regression, "five"),
        (Method::Regression, "inner51"),
        (Method::Regression, "ibug68"),
        (Method::Fit, "five"),
        (Method::Fit, "ibug68"),
        (Method::FitShape, "ibug68"),
        (Method::Auto, "ibug68"),
    ];
    all.iter()
        .filter(|(m, s)| {
            methods.contains(m)
                && model.subset(s).is_ok()
                && (*m != Method::FitShape || model.morph.is_some())
        })
        .map(|&(m, s)| PaperEntry::new(m, s))
        .collect()
}

/// Parameters of the protocol.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PaperOptions {
    /// Test poses (the paper: its training grid).
    pub grid: PoseGrid,
    /// Testing-stage subsampling (1: every shape at every pose).
    pub stride: usize,
    /// Range of the inter-ocular distance of the views, pixels.
    pub iod_px: (f64, f64),
    /// Landmark noise levels, σ as a fraction of the inter-ocular distance.
    pub noise: Vec<f64>,
    /// Numbers of random missing points.
    pub missing: Vec<usize>,
    /// Draws of (test shape, pose) per robustness condition.
    pub robustness_samples: usize,
    /// Seed of the random draws.
    pub seed: u64,
}

impl Default for PaperOptions {
    fn default() -> Self {
        PaperOptions {
            grid: PoseGrid::paper(),
            stride: 8,
            iod_px: (60.0, 100.0),
            noise: vec![0.0, 0.01, 0.02, 0.05],
            missing: vec![0, 5, 10, 20],
            robustness_samples: 300,
            seed: 2011,
        }
    }
}

/// Most points sent as missing in a five-point query (one of five still leaves an answer for
/// the fit and, when both eyes remain, the regression).
pub const MAX_MISSING_FIVE: usize = 1;

/// How many points a `Missing(k)` condition drops from a scheme of `n` points: `k`, but at most
/// [`MAX_MISSING_FIVE`] of five.
pub fn missing_points(n: usize, k: usize) -> usize {
    if n <= 5 { k.min(MAX_MISSING_FIVE) } else { k }
}

/// Trains the protocol's model from the training shapes (model frame, mm): mean by generalized
/// Procrustes analysis, the paper's grid, subsets `inner51` and `five`, and a shape basis of up
/// to `components` principal components of the same shapes (0: none, no `fit-shape`).
pub fn train_paper_model(
    scheme: &Scheme,
    shapes: &[Vec<Vector3<f64>>],
    components: usize,
    seed: u64,
) -> Result<PoseModel> {
    let opts = TrainOptions {
        regression: RegressionParams::paper(),
        subsets: vec!["inner51".into(), "five".into()],
        seed,
    };
    train_from_population(scheme, shapes, BasisSource::Pca(components), &opts)
}

/// Which stage a row measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// The mean shape's own projections.
    Training,
    /// The other shapes' projections.
    Testing,
}

impl Stage {
    /// The stage's name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Training => "training",
            Stage::Testing => "testing",
        }
    }
}

/// Errors of one entry at one stage, degrees (MSE in degrees²).
#[derive(Debug, Clone, Serialize)]
pub struct PaperRow {
    /// The entry's label (e.g. `regression, 51 points`).
    pub label: String,
    /// The entry.
    pub entry: PaperEntry,
    /// The stage measured.
    pub stage: Stage,
    /// Estimates made.
    pub estimates: usize,
    /// Estimates that failed.
    pub failures: usize,
    /// Mean squared yaw error, degrees².
    pub mse_yaw: f64,
    /// Mean squared pitch error, degrees².
    pub mse_pitch: f64,
    /// Mean absolute yaw error, degrees.
    pub mae_yaw: f64,
    /// Mean absolute pitch error, degrees.
    pub mae_pitch: f64,
    /// Mean geodesic error, degrees.
    pub geodesic: f64,
}

/// A perturbation of the landmarks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Perturbation {
    /// Gaussian noise, σ as a fraction of the inter-ocular distance.
    Noise(f64),
    /// This many random present points sent as missing (capped for five points).
    Missing(usize),
}

/// Errors of one entry under one perturbation.
#[derive(Debug, Clone, Serialize)]
pub struct RobustnessRow {
    /// The entry's label.
    pub label: String,
    /// The entry.
    pub entry: PaperEntry,
    /// The perturbation applied.
    pub perturbation: Perturbation,
    /// Points actually dropped per view under `Missing` (see [`missing_points`]), else 0.
    pub dropped: usize,
    /// Estimates made.
    pub estimates: usize,
    /// Estimates that failed.
    pub failures: usize,
    /// Mean absolute yaw error, degrees.
    pub mae_yaw: f64,
    /// Mean absolute pitch error, degrees.
    pub mae_pitch: f64,
    /// Mean of the two.
    pub mae: f64,
    /// The share of the estimates whose 90% interval holds the true yaw and pitch (NaN when
    /// the model has no calibration).
    pub coverage_yaw: f64,
    /// As `coverage_yaw`, for pitch.
    pub coverage_pitch: f64,
}

/// Mean absolute error (mean of yaw and pitch) at each pose of the grid, for one entry.
#[derive(Debug, Clone, Serialize)]
pub struct HeatMap {
    /// The entry's label.
    pub label: String,
    /// Grid yaw values (columns) and pitch values (rows), degrees.
    pub yaw: Vec<f64>,
    /// Grid pitch values (rows), degrees.
    pub pitch: Vec<f64>,
    /// `values[p * yaw.len() + y]`; `None` where no estimate fell.
    pub values: Vec<Option<f64>>,
}

/// Everything the protocol measured.
#[derive(Debug, Clone, Serialize)]
pub struct PaperReport {
    /// The protocol's parameters.
    pub options: PaperOptions,
    /// Test shapes.
    pub test_shapes: usize,
    /// Poses of the grid.
    pub poses: usize,
    /// Test views per entry at the testing stage.
    pub test_views: usize,
    /// Table 1's rows.
    pub rows: Vec<PaperRow>,
    /// The robustness rows.
    pub robustness: Vec<RobustnessRow>,
    /// One heat map per entry.
    pub heat_maps: Vec<HeatMap>,
}

/// A test shape ready for synthesis: centred points and their HPR operator.
struct TestShape {
    points: Vec<Vector3<f64>>,
    hpr: PaperHpr,
    /// Inter-ocular distance (eye centres), mm.
    iod: f64,
}

impl TestShape {
    fn new(model: &PoseModel, shape: &[Vector3<f64>]) -> Result<Self> {
        if shape.len() != model.scheme.len() {
            return Err(Error::PointCount {
                what: "test shape".into(),
                expected: model.scheme.len(),
                got: shape.len(),
            });
        }
        let points = centre3(shape);
        let hpr = PaperHpr::from_frontal(&points)?;
        let a = &model.scheme.anchors;
        let eye =
            |idx: &[usize]| idx.iter().map(|&i| points[i]).sum::<Vector3<f64>>() / idx.len() as f64;
        let iod = (eye(&a.eye_right) - eye(&a.eye_left)).norm();
        if !(iod.is_finite() && iod > 0.0) {
            return Err(Error::Degenerate(
                "test shape: the eye centres coincide".into(),
            ));
        }
        Ok(TestShape { points, hpr, iod })
    }
}

/// One view in image pixels: every point's position (hidden ones too) and its visibility.
struct ImageView {
    angles: EulerAngles,
    points: Vec<Vector2<f64>>,
    visible: Vec<bool>,
    iod_px: f64,
}

fn mix(seed: u64, shape: usize, pose: usize, stream: u64) -> u64 {
    let mut h = seed ^ 0x9e37_79b9_7f4a_7c15;
    for v in [shape as u64, pose as u64, stream] {
        h = (h ^ v).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h ^= h >> 31;
        h = h.wrapping_mul(0x94d0_49bb_1331_11eb);
        h ^= h >> 29;
    }
    h
}

/// A seeded generator for one (shape, pose) pair, independent of the order of the loops.
fn rng_for(seed: u64, shape: usize, pose: usize, stream: u64) -> StdRng {
    StdRng::seed_from_u64(mix(seed, shape, pose, stream))
}

/// Whether the testing stage uses test shape `k` at pose `j` (grid order).
pub fn keeps(opts: &PaperOptions, k: usize, j: usize) -> bool {
    opts.stride <= 1 || mix(opts.seed, k, j, 2).is_multiple_of(opts.stride as u64)
}

fn image_view(
    view: SyntheticView,
    iod_mm: f64,
    opts: &PaperOptions,
    rng: &mut StdRng,
) -> ImageView {
    let (lo, hi) = opts.iod_px;
    let iod_px = if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    };
    let s = iod_px / iod_mm;
    let c = Vector2::new(
        225.0 + rng.random_range(-20.0..20.0),
        225.0 + rng.random_range(-20.0..20.0),
    );
    ImageView {
        angles: view.angles,
        points: view.projected.iter().map(|p| s * p + c).collect(),
        visible: view.visible,
        iod_px,
    }
}

/// The landmarks of a view in a subset's scheme: hidden points missing.
fn subset_landmarks(model: &PoseModel, subset: &Subset, v: &ImageView) -> Result<Shape2> {
    let pts3: Vec<Vector3<f64>> = v
        .points
        .iter()
        .map(|p| Vector3::new(p.x, p.y, 0.0))
        .collect();
    let pts = subset.map.map_points(&model.scheme, &pts3);
    let vis = subset.map.map_visibility(&model.scheme, &v.visible);
    Shape2::new(pts.iter().map(|p| p.xy()).collect(), vis)
}

/// Running sums of one entry.
#[derive(Default, Clone)]
struct Acc {
    n: usize,
    failures: usize,
    se_yaw: f64,
    se_pitch: f64,
    ae_yaw: f64,
    ae_pitch: f64,
    geodesic: f64,
    /// Estimates with an uncertainty, and those whose 90% interval holds the true yaw and
    /// pitch.
    with_interval: usize,
    covered_yaw: usize,
    covered_pitch: usize,
}

impl Acc {
    /// Adds one estimate; returns the mean of its yaw and pitch absolute errors.
    fn add(
        &mut self,
        result: Result<facepose_core::pose::Estimate>,
        truth: &EulerAngles,
    ) -> Option<f64> {
        let Ok(e) = result else {
            self.failures += 1;
            return None;
        };
        let dy = wrap_deg(e.angles.yaw - truth.yaw);
        let dp = wrap_deg(e.angles.pitch - truth.pitch);
        self.n += 1;
        self.se_yaw += dy * dy;
        self.se_pitch += dp * dp;
        self.ae_yaw += dy.abs();
        self.ae_pitch += dp.abs();
        self.geodesic += geodesic_deg(&e.rotation, &truth.to_rotation());
        if let Some(u) = &e.uncertainty {
            self.with_interval += 1;
            self.covered_pitch += usize::from(dp.abs() <= u.half_width(0));
            self.covered_yaw += usize::from(dy.abs() <= u.half_width(1));
        }
        Some(0.5 * (dy.abs() + dp.abs()))
    }

    /// The share of the estimates with an uncertainty whose interval holds the truth (NaN
    /// without any).
    fn coverage(&self, covered: usize) -> f64 {
        if self.with_interval == 0 {
            f64::NAN
        } else {
            covered as f64 / self.with_interval as f64
        }
    }

    fn mean(&self, v: f64) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            v / self.n as f64
        }
    }
}

/// Per entry, per pose of the grid: the summed error (mean of yaw and pitch) and the count.
type Cells = Vec<Vec<(f64, usize)>>;

/// Runs every entry on `shapes` over the grid; `keep(k, j)` selects shape `k` at pose `j`.
/// Returns the sums and, per entry, the summed error and count per pose. Reports `phase`, one
/// step per pose.
fn run_grid(
    model: &PoseModel,
    shapes: &[TestShape],
    entries: &[PaperEntry],
    opts: &PaperOptions,
    keep: &dyn Fn(usize, usize) -> bool,
    progress: &dyn Observer,
    phase: Phase,
) -> Result<(Vec<Acc>, Cells)> {
    let subsets = entries
        .iter()
        .map(|e| model.subset(&e.scheme))
        .collect::<Result<Vec<_>>>()?;
    let mut acc = vec![Acc::default(); entries.len()];
    let poses: Vec<EulerAngles> = opts.grid.poses().collect();
    let mut cells = vec![vec![(0.0, 0usize); poses.len()]; entries.len()];
    let mut synths = shapes
        .iter()
        .map(|s| ViewSynthesizer::new(&s.points, &s.hpr))
        .collect::<Result<Vec<_>>>()?;
    let mut report = PhaseReport::start(progress, phase, poses.len());
    // Pose-major, so that the regression's per-pattern solutions are reused while warm.
    for (j, &angles) in poses.iter().enumerate() {
        for (k, shape) in shapes.iter().enumerate() {
            if !keep(k, j) {
                continue;
            }
            let view = synths[k].view(angles)?;
            let v = image_view(view, shape.iod, opts, &mut rng_for(opts.seed, k, j, 0));
            for (i, (entry, subset)) in entries.iter().zip(&subsets).enumerate() {
                let lm = subset_landmarks(model, subset, &v)?;
                let r = estimate(model, &entry.scheme, &lm, entry.method);
                if let Some(e) = acc[i].add(r, &v.angles) {
                    cells[i][j].0 += e;
                    cells[i][j].1 += 1;
                }
            }
        }
        report.step();
    }
    report.finish();
    Ok((acc, cells))
}

fn rows_of(model: &PoseModel, entries: &[PaperEntry], acc: &[Acc], stage: Stage) -> Vec<PaperRow> {
    entries
        .iter()
        .zip(acc)
        .map(|(e, a)| PaperRow {
            label: e.label(model),
            entry: e.clone(),
            stage,
            estimates: a.n,
            failures: a.failures,
            mse_yaw: a.mean(a.se_yaw),
            mse_pitch: a.mean(a.se_pitch),
            mae_yaw: a.mean(a.ae_yaw),
            mae_pitch: a.mean(a.ae_pitch),
            geodesic: a.mean(a.geodesic),
        })
        .collect()
}

/// Applies a perturbation to landmarks (`iod_px`: the view's inter-ocular distance, pixels).
fn perturb(lm: &Shape2, p: Perturbation, iod_px: f64, rng: &mut StdRng) -> Result<Shape2> {
    match p {
        Perturbation::Noise(f) => {
            if f == 0.0 {
                return Ok(lm.clone());
            }
            let n =
                Normal::new(0.0, f * iod_px).map_err(|e| Error::param("noise", e.to_string()))?;
            let pts = lm
                .points()
                .iter()
                .map(|q| q + Vector2::new(n.sample(rng), n.sample(rng)))
                .collect();
            Shape2::new(pts, lm.present().to_vec())
        }
        Perturbation::Missing(k) => {
            let cap = missing_points(lm.len(), k);
            let present: Vec<usize> = lm.iter_present().map(|(i, _)| i).collect();
            let k = cap.min(present.len());
            let drop: Vec<usize> = sample(rng, present.len(), k)
                .into_iter()
                .map(|i| present[i])
                .collect();
            Ok(lm.with_missing(drop))
        }
    }
}

/// The robustness rows; reports [`Phase::PaperRobustness`], one step per (condition, entry).
fn robustness(
    model: &PoseModel,
    shapes: &[TestShape],
    entries: &[PaperEntry],
    opts: &PaperOptions,
    progress: &dyn Observer,
) -> Result<Vec<RobustnessRow>> {
    let subsets = entries
        .iter()
        .map(|e| model.subset(&e.scheme))
        .collect::<Result<Vec<_>>>()?;
    let poses: Vec<EulerAngles> = opts.grid.poses().collect();
    let mut draw = StdRng::seed_from_u64(opts.seed ^ 0x5eed);
    let draws: Vec<(usize, usize)> = (0..opts.robustness_samples)
        .map(|_| {
            (
                draw.random_range(0..shapes.len()),
                draw.random_range(0..poses.len()),
            )
        })
        .collect();
    let mut synths = shapes
        .iter()
        .map(|s| ViewSynthesizer::new(&s.points, &s.hpr))
        .collect::<Result<Vec<_>>>()?;
    let views = draws
        .iter()
        .map(|&(k, j)| {
            let view = synths[k].view(poses[j])?;
            Ok(image_view(
                view,
                shapes[k].iod,
                opts,
                &mut rng_for(opts.seed, k, j, 0),
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    let conditions: Vec<Perturbation> = opts
        .noise
        .iter()
        .map(|&f| Perturbation::Noise(f))
        .chain(opts.missing.iter().map(|&k| Perturbation::Missing(k)))
        .collect();
    let mut rows = Vec::new();
    let mut report = PhaseReport::start(
        progress,
        Phase::PaperRobustness,
        conditions.len() * entries.len(),
    );
    for (ci, &p) in conditions.iter().enumerate() {
        for (entry, subset) in entries.iter().zip(&subsets) {
            let mut acc = Acc::default();
            for (s, v) in views.iter().enumerate() {
                // The same perturbation of a view for every entry of the same scheme.
                let mut rng = rng_for(opts.seed, s, ci, 1);
                let lm = perturb(&subset_landmarks(model, subset, v)?, p, v.iod_px, &mut rng)?;
                acc.add(estimate(model, &entry.scheme, &lm, entry.method), &v.angles);
            }
            let (y, pi) = (acc.mean(acc.ae_yaw), acc.mean(acc.ae_pitch));
            rows.push(RobustnessRow {
                label: entry.label(model),
                entry: entry.clone(),
                perturbation: p,
                dropped: match p {
                    Perturbation::Missing(k) => missing_points(subset.scheme.len(), k),
                    Perturbation::Noise(_) => 0,
                },
                estimates: acc.n,
                failures: acc.failures,
                mae_yaw: y,
                mae_pitch: pi,
                mae: 0.5 * (y + pi),
                coverage_yaw: acc.coverage(acc.covered_yaw),
                coverage_pitch: acc.coverage(acc.covered_pitch),
            });
            report.step();
        }
    }
    report.finish();
    Ok(rows)
}

/// Runs the protocol: `model` (from [`train_paper_model`]) on its own mean shape (training
/// stage) and on `test_shapes` (model frame, mm, frontal, all points; testing stage).
/// `progress` sees [`Phase::PaperTraining`] and [`Phase::PaperTesting`] (poses of the grid),
/// then [`Phase::PaperRobustness`]; [`crate::progress::Silent`] for none.
pub fn paper_protocol(
    model: &PoseModel,
    test_shapes: &[Vec<Vector3<f64>>],
    entries: &[PaperEntry],
    opts: &PaperOptions,
    progress: &dyn Observer,
) -> Result<PaperReport> {
    if test_shapes.is_empty() {
        return Err(Error::too_few("test shapes", 1, 0));
    }
    if opts.stride == 0 {
        return Err(Error::param("stride", "must be at least 1"));
    }
    let (lo, hi) = opts.iod_px;
    if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi >= lo) {
        return Err(Error::param(
            "iod_px",
            format!("needs 0 < min <= max, got {lo}..{hi}"),
        ));
    }
    if opts.noise.iter().any(|f| !(f.is_finite() && *f >= 0.0)) {
        return Err(Error::param("noise", "levels must be finite and >= 0"));
    }
    let mean = [TestShape::new(model, &model.mean)?];
    let tests = test_shapes
        .iter()
        .map(|s| TestShape::new(model, s))
        .collect::<Result<Vec<_>>>()?;

    let (train_acc, _) = run_grid(
        model,
        &mean,
        entries,
        opts,
        &|_, _| true,
        progress,
        Phase::PaperTraining,
    )?;
    let (test_acc, cells) = run_grid(
        model,
        &tests,
        entries,
        opts,
        &|k, j| keeps(opts, k, j),
        progress,
        Phase::PaperTesting,
    )?;
    let mut rows = Vec::new();
    for (t, s) in rows_of(model, entries, &train_acc, Stage::Training)
        .into_iter()
        .zip(rows_of(model, entries, &test_acc, Stage::Testing))
    {
        rows.push(t);
        rows.push(s);
    }
    let yaw: Vec<f64> = opts.grid.yaw.values().collect();
    let pitch: Vec<f64> = opts.grid.pitch.values().collect();
    let heat_maps = entries
        .iter()
        .zip(&cells)
        .map(|(e, c)| {
            // Grid order is yaw outermost: pose j = y * (pitch * roll) + p * roll + r.
            let per_yaw = pitch.len() * opts.grid.roll.len();
            let mut values = vec![None; yaw.len() * pitch.len()];
            for yi in 0..yaw.len() {
                for pi in 0..pitch.len() {
                    let (mut sum, mut n) = (0.0, 0);
                    for r in 0..opts.grid.roll.len() {
                        let (s, k) = c[yi * per_yaw + pi * opts.grid.roll.len() + r];
                        sum += s;
                        n += k;
                    }
                    values[pi * yaw.len() + yi] = (n > 0).then(|| sum / n as f64);
                }
            }
            HeatMap {
                label: e.label(model),
                yaw: yaw.clone(),
                pitch: pitch.clone(),
                values,
            }
        })
        .collect();
    let robustness = robustness(model, &tests, entries, opts, progress)?;
    Ok(PaperReport {
        options: opts.clone(),
        test_shapes: tests.len(),
        poses: opts.grid.len(),
        test_views: test_acc.first().map_or(0, |a| a.n + a.failures),
        rows,
        robustness,
        heat_maps,
    })
}

fn f2(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2}")
    } else {
        "—".into()
    }
}

/// Table 1: one line per entry and stage.
pub fn paper_markdown(report: &PaperReport) -> String {
    let mut s = String::from(
        "| method | stage | estimates | failed | MSE yaw | MSE pitch | MAE yaw | MAE pitch | geodesic |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in &report.rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.label,
            r.stage.name(),
            r.estimates,
            r.failures,
            f2(r.mse_yaw),
            f2(r.mse_pitch),
            f2(r.mae_yaw),
            f2(r.mae_pitch),
            f2(r.geodesic)
        ));
    }
    s
}

/// A table of the robustness rows: one line per entry (in the report's order), one column per
/// condition of `conds`, each cell `cell(row)` (empty where there is no row).
fn conditions_table(
    report: &PaperReport,
    conds: &[Perturbation],
    cell: impl Fn(&RobustnessRow) -> String,
) -> String {
    let head: Vec<String> = conds
        .iter()
        .map(|c| match c {
            Perturbation::Noise(f) => format!("σ {}%", f * 100.0),
            Perturbation::Missing(k) => format!("{k} missing"),
        })
        .collect();
    let mut out = format!(
        "| method | {} |\n|---|{}\n",
        head.join(" | "),
        "---|".repeat(head.len())
    );
    let mut labels: Vec<&str> = Vec::new();
    for r in &report.robustness {
        if !labels.contains(&r.label.as_str()) {
            labels.push(&r.label);
        }
    }
    for l in labels {
        let cells: Vec<String> = conds
            .iter()
            .map(|c| {
                report
                    .robustness
                    .iter()
                    .find(|r| r.label == l && r.perturbation == *c)
                    .map_or(String::new(), &cell)
            })
            .collect();
        out.push_str(&format!("| {l} | {} |\n", cells.join(" | ")));
    }
    out
}

fn noise_conditions(report: &PaperReport) -> Vec<Perturbation> {
    report
        .options
        .noise
        .iter()
        .map(|&f| Perturbation::Noise(f))
        .collect()
}

fn missing_conditions(report: &PaperReport) -> Vec<Perturbation> {
    report
        .options
        .missing
        .iter()
        .map(|&k| Perturbation::Missing(k))
        .collect()
}

/// The robustness tables: MAE (mean of yaw and pitch) per entry and condition, noise levels in
/// one table and missing points in the other; failed estimates in parentheses.
pub fn robustness_markdown(report: &PaperReport) -> String {
    let mut out = String::new();
    for conds in [noise_conditions(report), missing_conditions(report)] {
        out.push_str(&conditions_table(report, &conds, |r| {
            let mut cell = f2(r.mae);
            if let Perturbation::Missing(k) = r.perturbation
                && r.dropped != k
            {
                cell.push_str(&format!(" [{} dropped]", r.dropped));
            }
            if r.failures > 0 {
                cell.push_str(&format!(" ({} failed)", r.failures));
            }
            cell
        }));
        out.push('\n');
    }
    out
}

/// The coverage of the uncertainty's 90% intervals per entry and robustness condition: yaw /
/// pitch, percent.
pub fn coverage_markdown(report: &PaperReport) -> String {
    let mut conds = noise_conditions(report);
    conds.extend(missing_conditions(report));
    conditions_table(report, &conds, |r| {
        if r.coverage_yaw.is_nan() {
            "-".into()
        } else {
            format!(
                "{:.0} / {:.0}",
                100.0 * r.coverage_yaw,
                100.0 * r.coverage_pitch
            )
        }
    })
}
