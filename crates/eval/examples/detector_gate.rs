//! How `auto` tells MediaPipe Face Mesh's output from the mesh's own projection: the misfit of
//! the mesh's rigid fit ([`facepose_core::pose::Estimate::misfit`]) on each source, against
//! the cut [`DETECTOR_MISFIT`], with the geodesic error of `fit` and `detector` on each.
//!
//! `cargo run --release -p facepose-eval --example detector_gate` (from the repository's root:
//! it reads tests/fixtures/rendered and tests/fixtures/detectors). Sources:
//! - `rendered, bfm|mediapipe`: MediaPipe's 478 points on every render of the rendered benchmark
//!   (both splits; `detector` was trained on the `train` identities, so its error there is
//!   in-sample);
//! - `photos`: MediaPipe's points on the real photographs (no true pose: no error);
//! - `mesh, noise σ`: the served mesh projected at 600 poses drawn as `eval --protocol
//!   mediapipe` draws them (|yaw| ≤ 90°, |pitch| ≤ 60°, |roll| ≤ 45°, seeded), with Gaussian
//!   noise of σ times the eyes' distance.

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use std::collections::BTreeMap;

use facepose_core::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
use facepose_core::model::default_model;
use facepose_core::model::mesh::MEDIAPIPE478;
use facepose_core::pose::{DETECTOR_MISFIT, Method, estimate};
use facepose_core::shape::Shape2;
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_eval::rendered::{Detector, landmarks, truth_rotation};
use facepose_files::rendered::load_rendered;
use nalgebra::{Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};

/// Per source: (misfit, error of `fit`, error of `detector`), errors NaN without a truth.
type Seen = BTreeMap<String, Vec<(f64, f64, f64)>>;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (_, model) = default_model()?;
    let mut seen = Seen::new();
    let mut note = |source: String, lm: &Shape2, truth: Option<nalgebra::Rotation3<f64>>| {
        let (Ok(f), Ok(d)) = (
            estimate(&model, MEDIAPIPE478, lm, Method::Fit),
            estimate(&model, MEDIAPIPE478, lm, Method::Detector),
        ) else {
            return;
        };
        let err = |r| truth.map_or(f64::NAN, |t| geodesic_deg(r, &t));
        seen.entry(source)
            .or_default()
            .push((f.misfit, err(&f.rotation), err(&d.rotation)));
    };
    for rec in load_rendered(std::path::Path::new("tests/fixtures/rendered"), None)? {
        if let Some((_, lm, _)) = landmarks(&rec, Detector::Mediapipe478) {
            note(
                format!("rendered, {}", rec.geometry),
                &lm,
                rec.truth_absolute.then(|| truth_rotation(&rec)),
            );
        }
    }
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(
        "tests/fixtures/detectors/mediapipe.json",
    )?)?;
    for face in doc["faces"].as_array().ok_or("faces")? {
        let num = |v: &serde_json::Value| v.as_f64().ok_or("a number");
        let pts = face["landmarks"]
            .as_array()
            .ok_or("landmarks")?
            .iter()
            .map(|p| Ok(Some([num(&p[0])?, num(&p[1])?])))
            .collect::<Result<Vec<_>, &str>>()?;
        let size = ImageSize {
            width: num(&face["image_size"][0])?,
            height: num(&face["image_size"][1])?,
        };
        note("photos".into(), &pixel_shape(&pts, Some(size))?, None);
    }
    let (_, ms) = model.mesh_scheme(MEDIAPIPE478).ok_or("no mesh")?;
    let points = &ms.points;
    let a = &ms.scheme.anchors;
    let eye =
        |idx: &[usize]| idx.iter().map(|&i| points[i]).sum::<Vector3<f64>>() / idx.len() as f64;
    let iod_mm = (eye(&a.eye_right) - eye(&a.eye_left)).norm();
    let mut rng = StdRng::seed_from_u64(7);
    let unit = Normal::new(0.0, 1.0)?;
    for noise in [0.0, 0.005, 0.01, 0.02] {
        for _ in 0..600 {
            let angles = EulerAngles::new(
                rng.random_range(-90.0..=90.0),
                rng.random_range(-60.0..=60.0),
                rng.random_range(-45.0..=45.0),
            )?;
            let scale = rng.random_range(60.0..=100.0) / iod_mm;
            let t = Vector2::new(
                rng.random_range(200.0..=250.0),
                -rng.random_range(200.0..=250.0),
            );
            let cam = WeakPerspective::new(angles.to_rotation(), scale, t)?;
            let sigma = noise * scale * iod_mm;
            let pts = points
                .iter()
                .map(|x| {
                    let d = Vector2::new(unit.sample(&mut rng), unit.sample(&mut rng));
                    cam.project(x) + d * sigma
                })
                .collect();
            note(
                format!("mesh, noise {noise}"),
                &Shape2::full(pts)?,
                Some(angles.to_rotation()),
            );
        }
    }
    println!("Cut: misfit {DETECTOR_MISFIT} (`auto` answers with `detector` at or above it).\n");
    println!(
        "| source | faces | misfit min | 10% | median | 90% | max | at or above the cut | \
         error fit | error detector |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (source, v) in &seen {
        let mut m: Vec<f64> = v.iter().map(|x| x.0).collect();
        m.sort_by(f64::total_cmp);
        let q = |p: f64| m[((m.len() - 1) as f64 * p).round() as usize];
        let above = m.iter().filter(|&&x| x >= DETECTOR_MISFIT).count();
        let mean = |k: usize| {
            let e: Vec<f64> = v
                .iter()
                .map(|x| [x.1, x.2][k])
                .filter(|e| !e.is_nan())
                .collect();
            if e.is_empty() {
                "-".to_string()
            } else {
                format!("{:.2}°", e.iter().sum::<f64>() / e.len() as f64)
            }
        };
        println!(
            "| {source} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {above} | {} | {} |",
            v.len(),
            q(0.0),
            q(0.1),
            q(0.5),
            q(0.9),
            q(1.0),
            mean(0),
            mean(1)
        );
    }
    Ok(())
}
