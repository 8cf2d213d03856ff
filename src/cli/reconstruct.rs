//! `facepose reconstruct`: structure from motion on a multi-view JSON file, writing the 3D
//! shapes in the population format that `train --shapes` reads.

use std::io::Write;
use std::path::PathBuf;

use clap::Args;
use facepose_core::geometry::EulerAngles;
use facepose_core::sfm::{SfmOptions, reconstruct};
use facepose_core::shape::{Scheme, Shape2, Shape3};
use facepose_files::data::load_multi_view;
use serde_json::json;

use super::CliError;

#[derive(Args)]
pub struct ReconstructArgs {
    /// The multi-view JSON file (format in docs/FORMATS.md).
    #[arg(long)]
    views: PathBuf,
    /// Where to write the shapes (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Keep the frame of view 0 instead of putting the eye line along x.
    #[arg(long)]
    no_frontalize: bool,
}

pub fn run(a: ReconstructArgs) -> Result<(), CliError> {
    let set = load_multi_view(&a.views)?;
    let scheme = Scheme::builtin(&set.scheme).ok_or_else(|| {
        format!(
            "unknown scheme {:?} (known: {})",
            set.scheme,
            Scheme::builtin_names().join(", ")
        )
    })?;
    let nose = *scheme
        .anchors
        .nose_tip
        .first()
        .ok_or("the scheme has no nose tip")?;
    let mut shapes = Vec::new();
    let mut subjects = Vec::new();
    for (k, subject) in set.subjects.iter().enumerate() {
        let label = subject.id.clone().unwrap_or_else(|| json!(k));
        let views = subject
            .views
            .iter()
            .enumerate()
            .map(|(v, pts)| {
                if pts.len() != scheme.len() {
                    return Err(format!(
                        "subject {label}, view {v}: {} points, scheme {} has {}",
                        pts.len(),
                        scheme.name,
                        scheme.len()
                    ));
                }
                Shape2::from_options(pts).map_err(|e| format!("subject {label}, view {v}: {e}"))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let rec = reconstruct(&views, SfmOptions::with_nose_tip(nose))
            .map_err(|e| format!("subject {label}: {e}"))?;
        let mut shape = Shape3::full(rec.shape.clone())?;
        if !a.no_frontalize {
            shape = shape
                .frontalized(&scheme)
                .map_err(|e| format!("subject {label}: {e}"))?;
        }
        shapes.push(
            shape
                .points()
                .iter()
                .map(|p| [p.x, p.y, p.z])
                .collect::<Vec<_>>(),
        );
        let cameras: Vec<_> = rec
            .cameras
            .iter()
            .map(|c| {
                let ang = EulerAngles::from_rotation(&c.rotation);
                json!({"yaw": ang.yaw, "pitch": ang.pitch, "roll": ang.roll, "scale": c.scale, "translation": [c.translation.x, c.translation.y]})
            })
            .collect();
        subjects.push(json!({"id": label, "rms_residual_px": rec.rms_residual, "missing_entries": rec.missing_entries, "cameras": cameras}));
    }
    let out = json!({
        "scheme": scheme.name,
        "units": "pixels of the views at their mean camera scale",
        "frame": if a.no_frontalize { "camera frame of view 0: x right, y up, z towards the camera; centred" } else { "x towards the subject's left (eye line), y up, z towards the camera; centred" },
        "shapes": shapes,
        "subjects": subjects,
    });
    let text = serde_json::to_string_pretty(&out)?;
    match a.out {
        Some(path) => std::fs::write(&path, text + "\n")
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?,
        None => writeln!(std::io::stdout().lock(), "{text}")?,
    }
    Ok(())
}
