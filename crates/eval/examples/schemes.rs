//! Draws docs/schemes.png: the two five-point layouts on the default model's mean face, numbered
//! in their order: `five` (eye centres, nose tip, mouth corners: RetinaFace, MTCNN, InsightFace)
//! and `dlib5` (dlib's `shape_predictor_5_face_landmarks`: eye corners and the base of the
//! nose), both from the model's own subsets. `cargo run --release --example schemes [OUT]`.

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::default_model;
use facepose_eval::plot::{LandmarkPanel, landmarks_png};
use nalgebra::Vector2;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "docs/schemes.png".into());
    let (_, model) = default_model()?;
    let cam = WeakPerspective::new(
        EulerAngles::new(0.0, 0.0, 0.0)?.to_rotation(),
        2.0,
        Vector2::new(200.0, -200.0),
    )?;
    let project = |pts: &[nalgebra::Vector3<f64>]| -> Vec<[f64; 2]> {
        pts.iter()
            .map(|x| {
                let p = cam.project(x);
                [p.x, p.y]
            })
            .collect()
    };
    let all = project(&model.mean);
    let mut panels = Vec::new();
    for (name, title) in [
        ("five", "five: RetinaFace, MTCNN, InsightFace"),
        ("dlib5", "dlib5: dlib's 5-point predictor"),
    ] {
        let subset = model.subset(name)?;
        panels.push(LandmarkPanel {
            title: title.into(),
            outline: 17,
            numbered: vec![1],
            sets: vec![
                ("ibug68 (for reference)".into(), all.clone()),
                (format!("{name} points, in order"), project(&subset.mean)),
            ],
        });
    }
    let png = landmarks_png(
        "The two five-point schemes on the mean face (image-left = the subject's right)",
        &panels,
    )?;
    std::fs::write(&out, png)?;
    eprintln!("wrote {out}");
    Ok(())
}
