//! Validation of a shape set before training (the retraining endpoint's uploads): which shapes
//! are kept, which are dropped and why.
//!
//! Each shape is checked on its own first (cheap, O(points)):
//! - **point count**: exactly the scheme's number of points;
//! - **finite**: every coordinate a finite number, and within ±[`MAX_COORDINATE`];
//! - **degenerate**: not all at one place, not on one line, not flat (a face has depth: the
//!   smallest principal axis of its points is at least [`MIN_DEPTH_RATIO`] of the largest), the
//!   eye centres apart and the mouth off the eye line;
//! - **mirrored**: in the shape's own anchor frame (x along the eye line from the image-left eye
//!   to the image-right eye, y from the mouth up to the eyes, z = x × y) the nose tip must stand
//!   in front of the centroid. A reflected shape (one coordinate negated, or left and right
//!   points swapped) has its nose behind: that test does not depend on the shape's orientation.
//!
//! Then, over the shapes left, **outliers by Procrustes distance**: the distance of each shape
//! to the generalized Procrustes mean after similarity alignment, relative to the mean's RMS
//! radius (so unitless and scale-free). A shape is an outlier when its distance exceeds both
//! `median + k · 1.4826 · MAD` (a robust "k standard deviations") and a floor
//! ([`ValidationOptions::min_outlier_distance`]) that keeps a tight synthetic set from losing
//! shapes over tiny differences. The mean is computed twice: over all remaining shapes, then
//! over the inliers of that first pass, so that gross outliers do not pull it.
//!
//! The kept shapes come back aligned to that mean, turned into its anchor frame (frontal: eye
//! line along +x, nose towards +z), so training does not depend on how the uploaded shapes were
//! oriented. 3D shapes keep their size (rigid alignment, mm); reconstructions from 2D views,
//! which have no common scale, are scaled to the mean ([`ValidationOptions::scale_free`]).
//!
//! Multi-view subjects ([`subject_views`], [`reconstruct_subject`]) are checked and rebuilt by
//! structure from motion one by one; a subject that cannot be rebuilt is dropped with the
//! reason, the same way as a 3D shape.
//!
//! Pure: no I/O; the caller decides what to do when too few shapes remain.

use nalgebra::{Matrix3, Rotation3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::geometry::procrustes::{GpaOptions, centre3, centroid_size3};
use crate::geometry::{Scaling, align3, generalized_procrustes};
use crate::sfm::{SfmOptions, reconstruct};
use crate::shape::{Scheme, Shape2, Shape3};

/// A face is not flat: the smallest principal axis of its points (square root of the smallest
/// eigenvalue of their scatter) must be at least this fraction of the largest. The bfm68 faces
/// are about 0.35; points drawn on a plane are 0.
pub const MIN_DEPTH_RATIO: f64 = 0.02;

/// The largest coordinate accepted (3D: millimetres or the views' pixels; 2D: pixels). A face
/// is a few hundred units across; far beyond that a value is a unit or encoding mistake, and
/// squares of such values would overflow the alignment's sums.
pub const MAX_COORDINATE: f64 = 1e9;

/// Why a shape was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DropReason {
    /// Not the scheme's number of points.
    PointCount,
    /// A coordinate is NaN or infinite.
    NonFinite,
    /// A coordinate is beyond ±[`MAX_COORDINATE`].
    OutOfRange,
    /// All points at one place, on a line or on a plane; eyes together; mouth on the eye line.
    Degenerate,
    /// A reflection of a face, not a face.
    Mirrored,
    /// Far from the other shapes after Procrustes alignment.
    Outlier,
    /// Structure from motion could not rebuild the subject from its views.
    Reconstruction,
}

impl DropReason {
    /// The snake_case name used in reports.
    pub fn name(self) -> &'static str {
        match self {
            DropReason::PointCount => "point_count",
            DropReason::NonFinite => "non_finite",
            DropReason::OutOfRange => "out_of_range",
            DropReason::Degenerate => "degenerate",
            DropReason::Mirrored => "mirrored",
            DropReason::Outlier => "outlier",
            DropReason::Reconstruction => "reconstruction",
        }
    }
}

/// One dropped shape (or subject): its index in the input, the reason, and the details.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dropped {
    /// Index in the input.
    pub index: usize,
    /// Why it was dropped.
    pub reason: DropReason,
    /// Details, for people.
    pub detail: String,
}

/// A shape's rejection before the set-level checks.
pub type Rejection = (DropReason, String);

/// Options of [`validate_shapes`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValidationOptions {
    /// `k` of the outlier threshold `median + k · 1.4826 · MAD`.
    pub outlier_k: f64,
    /// No shape closer than this to the mean (relative Procrustes distance) is an outlier.
    pub min_outlier_distance: f64,
    /// Align kept shapes with scale (for reconstructions from views, which have no common
    /// scale); otherwise rigidly, keeping each shape's size.
    pub scale_free: bool,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        ValidationOptions {
            outlier_k: 6.0,
            min_outlier_distance: 0.1,
            scale_free: false,
        }
    }
}

impl ValidationOptions {
    fn check(&self) -> Result<()> {
        if !(self.outlier_k.is_finite() && self.outlier_k > 0.0) {
            return Err(Error::param(
                "outlier_k",
                format!("must be positive, got {}", self.outlier_k),
            ));
        }
        if !(self.min_outlier_distance.is_finite() && self.min_outlier_distance >= 0.0) {
            return Err(Error::param(
                "min_outlier_distance",
                format!("must be 0 or more, got {}", self.min_outlier_distance),
            ));
        }
        Ok(())
    }
}

/// What [`validate_shapes`] found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationReport {
    /// Shapes given.
    pub total: usize,
    /// Shapes kept.
    pub kept: usize,
    /// Every dropped shape, by index.
    pub dropped: Vec<Dropped>,
    /// Median relative Procrustes distance to the mean (when at least three shapes were
    /// compared).
    pub median_distance: Option<f64>,
    /// The distance above which a shape was an outlier.
    pub outlier_threshold: Option<f64>,
}

impl ValidationReport {
    /// `"12 shapes: 9 kept, 3 dropped (2 mirrored, 1 outlier)"`.
    pub fn summary(&self) -> String {
        let mut counts: Vec<(DropReason, usize)> = Vec::new();
        for d in &self.dropped {
            match counts.iter_mut().find(|(r, _)| *r == d.reason) {
                Some((_, n)) => *n += 1,
                None => counts.push((d.reason, 1)),
            }
        }
        let mut s = format!(
            "{} shapes: {} kept, {} dropped",
            self.total,
            self.kept,
            self.dropped.len()
        );
        if !counts.is_empty() {
            let parts: Vec<String> = counts
                .iter()
                .map(|(r, n)| format!("{n} {}", r.name()))
                .collect();
            s.push_str(&format!(" ({})", parts.join(", ")));
        }
        s
    }
}

/// The kept shapes and the report.
#[derive(Debug, Clone)]
pub struct ValidatedShapes {
    /// Kept shapes, aligned to the mean in its anchor frame (see the module docs), in input
    /// order.
    pub shapes: Vec<Vec<Vector3<f64>>>,
    /// Input index of each kept shape.
    pub indices: Vec<usize>,
    /// What was dropped and why.
    pub report: ValidationReport,
}

/// The cheap checks of one 3D shape (count, finite, degenerate, mirrored).
pub fn check_shape(scheme: &Scheme, shape: &[Vector3<f64>]) -> std::result::Result<(), Rejection> {
    let n = scheme.len();
    if shape.len() != n {
        return Err((
            DropReason::PointCount,
            format!("{} points; scheme {} has {n}", shape.len(), scheme.name),
        ));
    }
    if let Some((i, p)) = shape
        .iter()
        .enumerate()
        .find(|(_, p)| !p.iter().all(|v| v.is_finite()))
    {
        let axis = ["x", "y", "z"][p.iter().position(|v| !v.is_finite()).unwrap_or(0)];
        return Err((
            DropReason::NonFinite,
            format!("point {i} {axis} is not a finite number"),
        ));
    }
    if let Some((i, p)) = shape
        .iter()
        .enumerate()
        .find(|(_, p)| p.amax() > MAX_COORDINATE)
    {
        return Err((
            DropReason::OutOfRange,
            format!(
                "point {i} = [{:e}, {:e}, {:e}] is beyond ±{MAX_COORDINATE:e}: check the units",
                p.x, p.y, p.z
            ),
        ));
    }
    let frame = anchor_frame(scheme, shape)?;
    if frame.nose_depth <= 0.0 {
        return Err((
            DropReason::Mirrored,
            format!(
                "the nose tip is {:.3} behind the centroid in the shape's own frame (eye line x, \
                 up y, z = x × y): a reflection of a face (a coordinate negated or left and right \
                 swapped)",
                -frame.nose_depth
            ),
        ));
    }
    Ok(())
}

/// A shape's own frame from its anchors.
struct AnchorFrame {
    /// Rows: x (eye line), y (up), z (out of the face).
    rotation: Rotation3<f64>,
    /// Nose tip minus centroid along z, in the shape's unit.
    nose_depth: f64,
}

/// Builds the anchor frame, rejecting degenerate shapes on the way.
fn anchor_frame(
    scheme: &Scheme,
    shape: &[Vector3<f64>],
) -> std::result::Result<AnchorFrame, Rejection> {
    let degenerate = |why: String| (DropReason::Degenerate, why);
    let centred = centre3(shape);
    let size = centroid_size3(&centred);
    let scale = shape.iter().map(|p| p.amax()).fold(0.0, f64::max);
    if size.is_nan() || size <= 1e-9 * (1.0 + scale) {
        return Err(degenerate("all points are at one place".into()));
    }
    let scatter: Matrix3<f64> = centred.iter().map(|p| p * p.transpose()).sum();
    let mut ev: Vec<f64> = SymmetricEigen::new(scatter)
        .eigenvalues
        .iter()
        .map(|v| v.max(0.0).sqrt())
        .collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    if ev[1] < 1e-6 * ev[0] {
        return Err(degenerate("the points lie on one line".into()));
    }
    if ev[2] < MIN_DEPTH_RATIO * ev[0] {
        return Err(degenerate(format!(
            "the points lie on a plane (depth {:.4} of the width; a face needs at least \
             {MIN_DEPTH_RATIO}): send 3D shapes, or 2D views as subjects",
            ev[2] / ev[0]
        )));
    }
    let mean_of =
        |idx: &[usize]| idx.iter().map(|&i| centred[i]).sum::<Vector3<f64>>() / idx.len() as f64;
    let a = &scheme.anchors;
    let (el, er) = (mean_of(&a.eye_left), mean_of(&a.eye_right));
    let nose = mean_of(&a.nose_tip);
    let mouth = (mean_of(&a.mouth_left) + mean_of(&a.mouth_right)) / 2.0;
    let eye = er - el;
    let tiny = 1e-6 * size;
    if eye.norm() <= tiny {
        return Err(degenerate("the two eye centres coincide".into()));
    }
    let x = eye.normalize();
    let up = (el + er) / 2.0 - mouth;
    let y = up - up.dot(&x) * x;
    if y.norm() <= 1e-3 * up.norm().max(eye.norm()) {
        return Err(degenerate("the mouth is on the eye line".into()));
    }
    let y = y.normalize();
    let z = x.cross(&y);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        x.transpose(),
        y.transpose(),
        z.transpose(),
    ]));
    Ok(AnchorFrame {
        rotation,
        nose_depth: nose.dot(&z),
    })
}

/// Validates a 3D shape set (see the module docs). Fails only on invalid options or scheme;
/// bad shapes are dropped and reported, and the caller decides whether enough remain.
pub fn validate_shapes(
    scheme: &Scheme,
    shapes: &[Vec<Vector3<f64>>],
    opts: &ValidationOptions,
) -> Result<ValidatedShapes> {
    opts.check()?;
    scheme.validate()?;
    let mut dropped = Vec::new();
    let mut idx = Vec::new();
    for (k, s) in shapes.iter().enumerate() {
        match check_shape(scheme, s) {
            Ok(()) => idx.push(k),
            Err((reason, detail)) => dropped.push(Dropped {
                index: k,
                reason,
                detail,
            }),
        }
    }
    let (mut median_distance, mut outlier_threshold) = (None, None);
    let mut mean = None;
    if idx.len() >= 3 {
        let subset = |ix: &[usize]| ix.iter().map(|&k| shapes[k].clone()).collect::<Vec<_>>();
        // Pass 1 over every remaining shape, pass 2 over the first pass's inliers.
        let mut inliers = idx.clone();
        let mut result = None;
        for _ in 0..2 {
            let m = generalized_procrustes(&subset(&inliers), GpaOptions::default())?;
            let d = distances(&m, idx.iter().map(|&k| &shapes[k][..]))?;
            let (med, threshold) = robust_threshold(&d, opts);
            inliers = idx
                .iter()
                .zip(&d)
                .filter(|(_, dk)| **dk <= threshold)
                .map(|(&k, _)| k)
                .collect();
            result = Some((m, d, med, threshold));
            if inliers.len() < 3 {
                break;
            }
        }
        if let Some((m, d, med, threshold)) = result {
            let mut keep = Vec::with_capacity(idx.len());
            for (&k, &dk) in idx.iter().zip(&d) {
                if dk > threshold {
                    dropped.push(Dropped {
                        index: k,
                        reason: DropReason::Outlier,
                        detail: format!(
                            "Procrustes distance to the mean {dk:.4} (relative to its RMS \
                             radius) is over the threshold {threshold:.4} (median {med:.4})"
                        ),
                    });
                } else {
                    keep.push(k);
                }
            }
            idx = keep;
            median_distance = Some(med);
            outlier_threshold = Some(threshold);
            mean = Some(m);
        }
    } else if let Some(&first) = idx.first() {
        mean = Some(centre3(&shapes[first]));
    }
    dropped.sort_by_key(|d| d.index);
    let aligned = match &mean {
        Some(m) if !idx.is_empty() => {
            // The mean in its own anchor frame; every kept shape aligned onto it.
            let frame = anchor_frame(scheme, m)
                .map_err(|(_, why)| Error::Degenerate(format!("the mean shape: {why}")))?;
            let m: Vec<Vector3<f64>> = centre3(m).iter().map(|p| frame.rotation * p).collect();
            let scaling = if opts.scale_free {
                Scaling::Similarity
            } else {
                Scaling::Rigid
            };
            idx.iter()
                .map(|&k| {
                    let t = align3(&shapes[k], &m, scaling)?;
                    Ok(shapes[k].iter().map(|p| t.apply(p)).collect())
                })
                .collect::<Result<Vec<_>>>()?
        }
        _ => vec![],
    };
    Ok(ValidatedShapes {
        report: ValidationReport {
            total: shapes.len(),
            kept: idx.len(),
            dropped,
            median_distance,
            outlier_threshold,
        },
        shapes: aligned,
        indices: idx,
    })
}

/// Relative Procrustes distance of each shape to `mean`: RMS distance after similarity
/// alignment over the mean's RMS radius.
fn distances<'a>(
    mean: &[Vector3<f64>],
    shapes: impl Iterator<Item = &'a [Vector3<f64>]>,
) -> Result<Vec<f64>> {
    let c = centre3(mean);
    let radius = centroid_size3(&c) / (c.len() as f64).sqrt();
    shapes
        .map(|s| {
            let t = align3(s, &c, Scaling::Similarity)?;
            let aligned: Vec<_> = s.iter().map(|p| t.apply(p)).collect();
            Ok(crate::geometry::procrustes::rms_distance3(&aligned, &c) / radius)
        })
        .collect()
}

/// `(median, threshold)` of distances.
fn robust_threshold(d: &[f64], opts: &ValidationOptions) -> (f64, f64) {
    let med = median(d.to_vec());
    let mad = median(d.iter().map(|v| (v - med).abs()).collect());
    let threshold = (med + opts.outlier_k * 1.4826 * mad).max(opts.min_outlier_distance);
    (med, threshold)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// One subject's views as shapes, with the cheap checks: at least three views, each with the
/// scheme's number of points, finite coordinates and at least four points present, and every
/// point seen in at least two views.
pub fn subject_views(
    scheme: &Scheme,
    views: &[Vec<Option<[f64; 2]>>],
) -> std::result::Result<Vec<Shape2>, Rejection> {
    let n = scheme.len();
    if views.len() < 3 {
        return Err((
            DropReason::Reconstruction,
            format!(
                "{} views; structure from motion needs at least 3",
                views.len()
            ),
        ));
    }
    let mut out = Vec::with_capacity(views.len());
    for (v, view) in views.iter().enumerate() {
        if view.len() != n {
            return Err((
                DropReason::PointCount,
                format!(
                    "view {v} has {} points; scheme {} has {n}",
                    view.len(),
                    scheme.name
                ),
            ));
        }
        if let Some(i) = view
            .iter()
            .position(|p| p.is_some_and(|q| !q.iter().all(|c| c.is_finite())))
        {
            return Err((
                DropReason::NonFinite,
                format!("view {v} point {i} is not a finite number"),
            ));
        }
        if let Some(i) = view
            .iter()
            .position(|p| p.is_some_and(|q| q.iter().any(|c| c.abs() > MAX_COORDINATE)))
        {
            return Err((
                DropReason::OutOfRange,
                format!("view {v} point {i} is beyond ±{MAX_COORDINATE:e} pixels"),
            ));
        }
        let shape = Shape2::from_options(view)
            .map_err(|e| (DropReason::NonFinite, format!("view {v}: {e}")))?;
        if shape.n_present() < 4 {
            return Err((
                DropReason::Reconstruction,
                format!(
                    "view {v} has {} points present; at least 4 are needed",
                    shape.n_present()
                ),
            ));
        }
        out.push(shape);
    }
    if let Some(j) = (0..n).find(|&j| out.iter().filter(|s| s.present()[j]).count() < 2) {
        return Err((
            DropReason::Reconstruction,
            format!("point {j} is seen in fewer than 2 views"),
        ));
    }
    Ok(out)
}

/// Rebuilds one subject by structure from motion (views from [`subject_views`]), its nose
/// towards +z. The shape is in the views' pixels at their mean camera scale.
pub fn reconstruct_subject(
    scheme: &Scheme,
    views: &[Shape2],
) -> std::result::Result<Vec<Vector3<f64>>, Rejection> {
    let nose = scheme.anchors.nose_tip.first().copied().unwrap_or(0);
    let rec = reconstruct(views, SfmOptions::with_nose_tip(nose))
        .map_err(|e| (DropReason::Reconstruction, e.to_string()))?;
    // A reconstruction must be a shape like any other.
    Shape3::full(rec.shape.clone()).map_err(|e| (DropReason::Reconstruction, e.to_string()))?;
    Ok(rec.shape)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{EulerAngles, WeakPerspective};
    use crate::shape::{five, ibug68};
    use nalgebra::Vector2;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    /// A face-like 68-point shape: the default model's mean with seeded per-point jitter and a
    /// size factor.
    fn faces(count: usize, seed: u64) -> Vec<Vec<Vector3<f64>>> {
        let (_, model) = crate::model::default_model().unwrap();
        let mut rng = StdRng::seed_from_u64(seed);
        (0..count)
            .map(|_| {
                let s = rng.random_range(0.9..1.1);
                model
                    .mean
                    .iter()
                    .map(|p| {
                        s * p
                            + Vector3::new(
                                rng.random_range(-1.5..1.5),
                                rng.random_range(-1.5..1.5),
                                rng.random_range(-1.5..1.5),
                            )
                    })
                    .collect()
            })
            .collect()
    }

    fn reasons(v: &ValidatedShapes) -> Vec<(usize, DropReason)> {
        v.report
            .dropped
            .iter()
            .map(|d| (d.index, d.reason))
            .collect()
    }

    #[test]
    fn a_clean_set_keeps_every_shape() {
        let shapes = faces(40, 1);
        let v = validate_shapes(&ibug68(), &shapes, &ValidationOptions::default()).unwrap();
        assert_eq!(v.report.kept, 40, "{:?}", v.report);
        assert!(v.report.dropped.is_empty());
        assert_eq!(v.shapes.len(), 40);
        assert_eq!(v.indices, (0..40).collect::<Vec<_>>());
        let med = v.report.median_distance.unwrap();
        assert!(med > 0.0 && med < 0.1, "{med}");
    }

    #[test]
    fn each_bad_shape_is_dropped_with_its_reason() {
        let mut shapes = faces(30, 2);
        shapes[3].pop();
        shapes[5][10].y = f64::NAN;
        shapes[7] = vec![Vector3::new(1.0, 2.0, 3.0); 68];
        shapes[9] = (0..68)
            .map(|i| Vector3::new(i as f64, 2.0 * i as f64, 0.5 * i as f64))
            .collect();
        shapes[11] = shapes[0]
            .iter()
            .map(|p| Vector3::new(p.x, p.y, 0.0))
            .collect();
        // Mirrored two ways: x negated, and left/right points swapped by the scheme's mirror.
        shapes[13] = shapes[1]
            .iter()
            .map(|p| Vector3::new(-p.x, p.y, p.z))
            .collect();
        let mirror = ibug68().mirror.unwrap();
        shapes[15] = (0..68).map(|i| shapes[2][mirror[i]]).collect();
        // An outlier: the mouth and jaw 30 mm lower than the rest of the face.
        for i in (0..17).chain(48..68) {
            shapes[17][i].y -= 30.0;
        }
        // Metres read as nanometres, say.
        shapes[19][4].z = 2e9;
        let v = validate_shapes(&ibug68(), &shapes, &ValidationOptions::default()).unwrap();
        assert_eq!(
            reasons(&v),
            [
                (3, DropReason::PointCount),
                (5, DropReason::NonFinite),
                (7, DropReason::Degenerate),
                (9, DropReason::Degenerate),
                (11, DropReason::Degenerate),
                (13, DropReason::Mirrored),
                (15, DropReason::Mirrored),
                (17, DropReason::Outlier),
                (19, DropReason::OutOfRange),
            ],
            "{:#?}",
            v.report
        );
        let d = &v.report.dropped;
        assert!(
            d[0].detail.contains("67 points; scheme ibug68 has 68"),
            "{}",
            d[0].detail
        );
        assert!(d[1].detail.contains("point 10 y"), "{}", d[1].detail);
        assert!(d[2].detail.contains("one place"), "{}", d[2].detail);
        assert!(d[3].detail.contains("one line"), "{}", d[3].detail);
        assert!(d[4].detail.contains("plane"), "{}", d[4].detail);
        assert!(
            d[8].detail.contains("point 4 = [") && d[8].detail.contains("2e9]"),
            "{}",
            d[8].detail
        );
        assert_eq!(v.report.kept, 21);
        assert_eq!(
            v.report.summary(),
            "30 shapes: 21 kept, 9 dropped (1 point_count, 1 non_finite, 3 degenerate, 2 mirrored, 1 outlier, 1 out_of_range)"
        );
    }

    #[test]
    fn orientation_and_position_do_not_matter_and_come_out_frontal() {
        let shapes = faces(20, 3);
        let mut rng = StdRng::seed_from_u64(4);
        let turned: Vec<Vec<Vector3<f64>>> = shapes
            .iter()
            .map(|s| {
                let r = EulerAngles::new(
                    rng.random_range(-180.0..180.0),
                    rng.random_range(-89.0..89.0),
                    rng.random_range(-180.0..180.0),
                )
                .unwrap()
                .to_rotation();
                let t = Vector3::new(100.0, -40.0, 7.0);
                s.iter().map(|p| r * p + t).collect()
            })
            .collect();
        let v = validate_shapes(&ibug68(), &turned, &ValidationOptions::default()).unwrap();
        assert_eq!(v.report.kept, 20, "{:?}", v.report);
        // Frontal: eye line along +x, nose tip in front; sizes kept (rigid alignment).
        let sch = ibug68();
        for (k, s) in v.shapes.iter().enumerate() {
            let f = Shape3::full(s.clone()).unwrap();
            let el = f.anchor(&sch.anchors.eye_left).unwrap();
            let er = f.anchor(&sch.anchors.eye_right).unwrap();
            let nose = f.anchor(&sch.anchors.nose_tip).unwrap();
            let c = f.centroid().unwrap();
            let e = (er - el).normalize();
            assert!(e.x > 0.99, "{e}");
            assert!(nose.z - c.z > 10.0, "{nose} {c}");
            let size = |p: &[Vector3<f64>]| centroid_size3(&centre3(p));
            assert!((size(s) - size(&shapes[k])).abs() < 1e-9);
        }
    }

    #[test]
    fn subjects_rebuild_from_views_or_say_why_not() {
        let sch = ibug68();
        let shape = &faces(1, 5)[0];
        let view = |yaw: f64, pitch: f64| -> Vec<Option<[f64; 2]>> {
            let cam = WeakPerspective::new(
                EulerAngles::new(yaw, pitch, 0.0).unwrap().to_rotation(),
                2.0,
                Vector2::new(300.0, -300.0),
            )
            .unwrap();
            shape
                .iter()
                .map(|p| {
                    let q = cam.project(p);
                    Some([q.x, q.y])
                })
                .collect()
        };
        let views = vec![
            view(0.0, 0.0),
            view(30.0, 5.0),
            view(-25.0, -10.0),
            view(10.0, 20.0),
        ];
        let shapes = subject_views(&sch, &views).unwrap();
        let rec = reconstruct_subject(&sch, &shapes).unwrap();
        check_shape(&sch, &rec).unwrap();
        // Same shape up to a similarity.
        let t = align3(&rec, shape, Scaling::Similarity).unwrap();
        let back: Vec<_> = rec.iter().map(|p| t.apply(p)).collect();
        assert!(crate::geometry::procrustes::rms_distance3(&back, shape) < 1e-3);

        let e = subject_views(&sch, &views[..2]).unwrap_err();
        assert_eq!(e.0, DropReason::Reconstruction);
        assert!(e.1.contains("at least 3"), "{}", e.1);
        let mut short = views.clone();
        short[1].pop();
        assert_eq!(
            subject_views(&sch, &short).unwrap_err().0,
            DropReason::PointCount
        );
        let mut nan = views.clone();
        nan[2][4] = Some([f64::INFINITY, 1.0]);
        let e = subject_views(&sch, &nan).unwrap_err();
        assert_eq!(e.0, DropReason::NonFinite);
        assert!(e.1.contains("view 2 point 4"), "{}", e.1);
        let mut unseen = views.clone();
        for v in unseen.iter_mut().skip(1) {
            v[7] = None;
        }
        let e = subject_views(&sch, &unseen).unwrap_err();
        assert!(e.1.contains("point 7"), "{}", e.1);
    }

    #[test]
    fn small_schemes_and_bad_options() {
        // The five-point scheme: eyes, nose, mouth corners have depth and a chirality.
        let (_, model) = crate::model::default_model().unwrap();
        let f5 = crate::model::SubsetMap::Anchors.map_points(&model.scheme, &model.mean);
        check_shape(&five(), &f5).unwrap();
        let mirrored: Vec<_> = f5.iter().map(|p| Vector3::new(p.x, p.y, -p.z)).collect();
        assert_eq!(
            check_shape(&five(), &mirrored).unwrap_err().0,
            DropReason::Mirrored
        );
        let bad = ValidationOptions {
            outlier_k: f64::NAN,
            ..Default::default()
        };
        assert!(validate_shapes(&five(), &[f5], &bad).is_err());
        // Fewer than three shapes: no outlier statistics, but the checks and the alignment.
        let v = validate_shapes(&ibug68(), &faces(2, 6), &ValidationOptions::default()).unwrap();
        assert_eq!(v.report.kept, 2);
        assert_eq!(v.report.median_distance, None);
        assert_eq!(v.shapes.len(), 2);
    }
}
