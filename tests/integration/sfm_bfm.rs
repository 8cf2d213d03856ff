//! Structure from motion on shapes of the bfm68 population, seen in five views within ±30° yaw.

use crate::common;

use facepose_core::geometry::procrustes::rms_distance3;
use facepose_core::geometry::{EulerAngles, Scaling, WeakPerspective, align3};
use facepose_core::sfm::{SfmOptions, reconstruct};
use facepose_core::shape::Shape2;
use facepose_files::data::load_population;
use nalgebra::{Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};

fn population() -> Vec<Vec<Vector3<f64>>> {
    load_population(&common::data_file("bfm68/population_249.json"))
        .unwrap()
        .shapes
}

/// Outer eye corners (ibug68 36 and 45).
fn iod(s: &[Vector3<f64>]) -> f64 {
    (s[36] - s[45]).norm()
}

/// Five views within ±30° yaw (small pitch and roll), random scale and position; pixels.
fn five_views(
    shape: &[Vector3<f64>],
    rng: &mut StdRng,
    noise_px_per_mm: f64,
) -> (Vec<Shape2>, f64) {
    let yaws = [-30.0, -15.0, 0.0, 15.0, 30.0]
        .map(|y: f64| (y + rng.random_range(-3.0..3.0)).clamp(-30.0, 30.0));
    let mut scales = Vec::new();
    let views = yaws
        .iter()
        .map(|&yaw| {
            let r = EulerAngles::new(
                yaw,
                rng.random_range(-10.0..10.0),
                rng.random_range(-10.0..10.0),
            )
            .unwrap()
            .to_rotation();
            let s = rng.random_range(1.5..3.5);
            scales.push(s);
            let cam = WeakPerspective::new(
                r,
                s,
                Vector2::new(
                    rng.random_range(150.0..300.0),
                    -rng.random_range(150.0..300.0),
                ),
            )
            .unwrap();
            let noise = Normal::new(0.0, noise_px_per_mm * s).unwrap();
            let pts = shape
                .iter()
                .map(|x| cam.project(x) + Vector2::new(noise.sample(rng), noise.sample(rng)))
                .collect();
            Shape2::full(pts).unwrap()
        })
        .collect();
    (views, scales.iter().sum::<f64>() / 5.0)
}

fn aligned_rms(rec: &[Vector3<f64>], truth: &[Vector3<f64>]) -> f64 {
    let sim = align3(rec, truth, Scaling::Similarity).unwrap();
    let moved: Vec<_> = rec.iter().map(|p| sim.apply(p)).collect();
    rms_distance3(&moved, truth)
}

#[test]
fn exact_views_reconstruct_to_1e6_relative() {
    let mut rng = StdRng::seed_from_u64(2011);
    for shape in population().iter().take(20) {
        let (views, _) = five_views(shape, &mut rng, 0.0);
        let rec = reconstruct(&views, SfmOptions::with_nose_tip(30)).unwrap();
        let size =
            (shape.iter().map(|p| p.norm_squared()).sum::<f64>() / shape.len() as f64).sqrt();
        let rel = aligned_rms(&rec.shape, shape) / size;
        assert!(rel < 1e-6, "relative RMS {rel}");
        // The nose points to the camera: no mirror image.
        let c = rec.shape.iter().sum::<Vector3<f64>>() / 68.0;
        assert!(rec.shape[30].z > c.z);
    }
}

#[test]
fn noise_of_half_a_percent_iod_stays_under_two_percent() {
    let mut rng = StdRng::seed_from_u64(7);
    let mut worst: f64 = 0.0;
    for shape in population().iter().skip(100).take(30) {
        let sigma_mm = 0.005 * iod(shape);
        let (views, _) = five_views(shape, &mut rng, sigma_mm);
        let rec = reconstruct(&views, SfmOptions::with_nose_tip(30)).unwrap();
        worst = worst.max(aligned_rms(&rec.shape, shape) / iod(shape));
    }
    assert!(
        worst <= 0.02,
        "worst RMS error {:.3}% of the inter-ocular distance",
        100.0 * worst
    );
}

#[test]
fn views_with_missing_points_still_reconstruct() {
    let mut rng = StdRng::seed_from_u64(99);
    let shape = &population()[5];
    let (views, _) = five_views(shape, &mut rng, 0.0);
    // Each view loses six random points (at most 30 % of entries, each point still in >= 2 views).
    let views: Vec<Shape2> = views
        .iter()
        .enumerate()
        .map(|(k, v)| v.with_missing((0..6).map(|i| (k * 13 + i * 11) % 68)))
        .collect();
    let rec = reconstruct(&views, SfmOptions::with_nose_tip(30)).unwrap();
    assert_eq!(rec.missing_entries, 30);
    let rel = aligned_rms(&rec.shape, shape) / iod(shape);
    assert!(rel < 1e-6, "relative RMS {rel}");
}
