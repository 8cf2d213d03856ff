//! The structure-from-motion protocol: shapes of a population are seen in five seeded views
//! within ±30° yaw (pitch and roll within ±10°, random scale and position), optionally with
//! Gaussian landmark noise (a fraction of the inter-ocular distance) and missing points, then
//! reconstructed; the error is the RMS point distance after similarity alignment to the true
//! shape, as a fraction of the inter-ocular distance (outer eye corners).

use nalgebra::{Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::progress::{Observer, Phase, PhaseReport};
use facepose_core::error::Result;
use facepose_core::geometry::procrustes::rms_distance3;
use facepose_core::geometry::{EulerAngles, Scaling, WeakPerspective, align3};
use facepose_core::sfm::{SfmOptions, reconstruct};
use facepose_core::shape::{Scheme, Shape2};

/// One condition of the protocol.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SfmCondition {
    /// Landmark noise, standard deviation as a fraction of the inter-ocular distance.
    pub noise_iod: f64,
    /// Points dropped per view.
    pub missing_per_view: usize,
}

/// The outcome of one condition.
#[derive(Debug, Clone, Serialize)]
pub struct SfmResult {
    /// The condition.
    pub condition: SfmCondition,
    /// Shapes reconstructed.
    pub shapes: usize,
    /// Mean and worst RMS error, fractions of the inter-ocular distance.
    pub mean_error_iod: f64,
    /// Worst RMS error, fraction of the inter-ocular distance.
    pub max_error_iod: f64,
}

/// Five views of `shape` (model frame, mm) in image pixels.
pub fn synthetic_views(
    shape: &[Vector3<f64>],
    rng: &mut StdRng,
    noise_mm: f64,
    missing: usize,
) -> Result<Vec<Shape2>> {
    let n = shape.len();
    [-30.0, -15.0, 0.0, 15.0, 30.0]
        .iter()
        .enumerate()
        .map(|(k, y): (usize, &f64)| {
            let yaw = (y + rng.random_range(-3.0..3.0)).clamp(-30.0, 30.0);
            let r = EulerAngles::new(
                yaw,
                rng.random_range(-10.0..10.0),
                rng.random_range(-10.0..10.0),
            )?
            .to_rotation();
            let s = rng.random_range(1.5..3.5);
            let cam = WeakPerspective::new(
                r,
                s,
                Vector2::new(
                    rng.random_range(150.0..300.0),
                    -rng.random_range(150.0..300.0),
                ),
            )?;
            let noise = Normal::new(0.0, noise_mm * s)
                .map_err(|e| facepose_core::Error::param("noise", e.to_string()))?;
            let pts = shape
                .iter()
                .map(|x| cam.project(x) + Vector2::new(noise.sample(rng), noise.sample(rng)))
                .collect();
            // Consecutive blocks, disjoint while 5·missing <= n: every point stays in four views.
            Ok(Shape2::full(pts)?.with_missing((0..missing).map(|i| (k * missing + i) % n)))
        })
        .collect()
}

/// The distance between the outer eye corners: of each eye's points, the one farthest from the
/// other eye's centre (the eye point itself for a one-point eye).
fn outer_eye_distance(shape: &[Vector3<f64>], left: &[usize], right: &[usize]) -> f64 {
    let centre = |eye: &[usize]| {
        eye.iter().map(|&i| shape[i]).sum::<Vector3<f64>>() / eye.len().max(1) as f64
    };
    let outer = |eye: &[usize], other: Vector3<f64>| {
        eye.iter()
            .map(|&i| shape[i])
            .max_by(|a, b| (a - other).norm().total_cmp(&(b - other).norm()))
            .unwrap_or(other)
    };
    (outer(left, centre(right)) - outer(right, centre(left))).norm()
}

/// Runs the protocol on `shapes` (ibug68, mm) for each condition. `progress` sees one
/// [`Phase::Sfm`] per condition, one step per shape; [`crate::progress::Silent`] for none.
pub fn sfm_check(
    shapes: &[Vec<Vector3<f64>>],
    scheme: &Scheme,
    conditions: &[SfmCondition],
    seed: u64,
    progress: &dyn Observer,
) -> Result<Vec<SfmResult>> {
    let nose = scheme.anchors.nose_tip[0];
    if let Some(short) = shapes.iter().position(|s| s.len() != scheme.len()) {
        return Err(facepose_core::Error::param(
            "shapes",
            format!(
                "shape {short} has {} points, the scheme {} has {}",
                shapes[short].len(),
                scheme.name,
                scheme.len()
            ),
        ));
    }
    if conditions
        .iter()
        .any(|c| 5 * c.missing_per_view > scheme.len())
    {
        return Err(facepose_core::Error::param(
            "missing_per_view",
            format!(
                "at most {} points per view, so that every point stays in four of the five views",
                scheme.len() / 5
            ),
        ));
    }
    let mut out = Vec::new();
    for (index, &condition) in conditions.iter().enumerate() {
        let phase = Phase::Sfm {
            condition: index,
            conditions: conditions.len(),
        };
        let mut report = PhaseReport::start(progress, phase, shapes.len());
        let mut rng = StdRng::seed_from_u64(seed);
        let (mut sum, mut worst) = (0.0, 0.0f64);
        for shape in shapes {
            let iod =
                outer_eye_distance(shape, &scheme.anchors.eye_left, &scheme.anchors.eye_right);
            let views = synthetic_views(
                shape,
                &mut rng,
                condition.noise_iod * iod,
                condition.missing_per_view,
            )?;
            let rec = reconstruct(&views, SfmOptions::with_nose_tip(nose))?;
            let sim = align3(&rec.shape, shape, Scaling::Similarity)?;
            let moved: Vec<_> = rec.shape.iter().map(|p| sim.apply(p)).collect();
            let e = rms_distance3(&moved, shape) / iod;
            sum += e;
            worst = worst.max(e);
            report.step();
        }
        report.finish();
        out.push(SfmResult {
            condition,
            shapes: shapes.len(),
            mean_error_iod: sum / shapes.len().max(1) as f64,
            max_error_iod: worst,
        });
    }
    Ok(out)
}

/// The results as a Markdown table.
pub fn sfm_markdown(rows: &[SfmResult]) -> String {
    let mut s = String::from(
        "| noise (σ, % IOD) | missing points per view | shapes | mean RMS error (% IOD) | worst (% IOD) |\n|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {:.2} | {} | {} | {} | {} |\n",
            100.0 * r.condition.noise_iod,
            r.condition.missing_per_view,
            r.shapes,
            percent(r.mean_error_iod),
            percent(r.max_error_iod)
        ));
    }
    s
}

fn percent(v: f64) -> String {
    let p = 100.0 * v;
    if p < 1e-3 {
        format!("{p:.1e}")
    } else {
        format!("{p:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outer_eye_corners_of_ibug68_are_36_and_45() {
        let mean = &facepose_core::model::default_model().unwrap().1.mean;
        let a = &facepose_core::shape::ibug68().anchors;
        let want = (mean[36] - mean[45]).norm();
        let got = outer_eye_distance(mean, &a.eye_left, &a.eye_right);
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }

    #[test]
    fn progress_counts_every_shape_of_every_condition_in_order() {
        use crate::progress::{Phase, record::Recorder};
        let mean = facepose_core::model::default_model().unwrap().1.mean;
        // Three faces: the mean, wider and taller.
        let shapes: Vec<Vec<Vector3<f64>>> = [(1.0, 1.0), (1.1, 1.0), (1.0, 1.1)]
            .iter()
            .map(|&(sx, sy)| {
                mean.iter()
                    .map(|p| Vector3::new(sx * p.x, sy * p.y, p.z))
                    .collect()
            })
            .collect();
        let conditions = [(0.0, 0), (0.01, 3)].map(|(noise_iod, missing_per_view)| SfmCondition {
            noise_iod,
            missing_per_view,
        });
        let r = Recorder::default();
        let rows = sfm_check(&shapes, &facepose_core::shape::ibug68(), &conditions, 5, &r).unwrap();
        assert_eq!(rows.len(), 2);
        // Monotone within each phase, from 0 to the total, phases not resumed (`phases` checks).
        let phases = r.phases();
        assert_eq!(
            phases,
            [0, 1].map(|condition| Phase::Sfm {
                condition,
                conditions: 2
            })
        );
        let all = r.0.lock().unwrap();
        // Every shape is one step: 0, 1, 2, 3 in each condition.
        assert_eq!(all.len(), 2 * (shapes.len() + 1));
        assert!(all.iter().all(|p| p.total == shapes.len()));
    }

    #[test]
    fn missing_sets_leave_every_point_in_four_views() {
        let mean = facepose_core::model::default_model().unwrap().1.mean;
        let mut rng = StdRng::seed_from_u64(1);
        for m in [1, 5, 10, 13] {
            let views = synthetic_views(&mean, &mut rng, 0.0, m).unwrap();
            for i in 0..mean.len() {
                let seen = views.iter().filter(|v| v.present()[i]).count();
                assert!(seen >= 4, "{m} missing per view: point {i} in {seen} views");
            }
        }
    }
}
