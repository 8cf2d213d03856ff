//! Draws docs/convention.png: the default model's mean face head-on and at yaw +30°, pitch +30°
//! and roll +30° in the `Pose_Para` convention, as the image shows them (x right, y down), so
//! the signs can be read off a picture. `cargo run --release --example convention [OUT]`.

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
        .unwrap_or_else(|| "docs/convention.png".into());
    let (_, model) = default_model()?;
    let cases = [
        ("head-on: yaw 0, pitch 0, roll 0", 0.0, 0.0, 0.0),
        ("yaw +30: the nose turns to image-left", 30.0, 0.0, 0.0),
        ("pitch +30: chin up", 0.0, 30.0, 0.0),
        ("roll +30: clockwise on screen", 0.0, 0.0, 30.0),
    ];
    let mut panels = Vec::new();
    for (title, yaw, pitch, roll) in cases {
        let a = EulerAngles::new(yaw, pitch, roll)?;
        let cam = WeakPerspective::new(a.to_rotation(), 2.0, Vector2::new(200.0, -200.0))?;
        let pts: Vec<[f64; 2]> = model
            .mean
            .iter()
            .map(|x| {
                let p = cam.project(x);
                [p.x, p.y]
            })
            .collect();
        // The nose (bridge to tip, points 27-30) as its own set; each set's first 17 points
        // are joined: the jaw, and the whole nose line.
        let nose: Vec<[f64; 2]> = pts[27..31].to_vec();
        panels.push(LandmarkPanel {
            title: title.into(),
            outline: 17,
            numbered: vec![],
            sets: vec![
                ("ibug68 landmarks".into(), pts),
                ("nose bridge".into(), nose),
            ],
        });
    }
    let png = landmarks_png(
        "Pose_Para angles: R = Rx(pitch) Ry(yaw) Rz(roll) applied to the mean face (image x right, y down)",
        &panels,
    )?;
    std::fs::write(&out, png)?;
    eprintln!("wrote {out}");
    Ok(())
}
