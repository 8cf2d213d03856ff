//! `facepose hpr`: the HPR accuracy table on MediaPipe's canonical mesh.

use std::path::PathBuf;

use clap::Args;
use facepose_core::hpr::KatzHpr;
use facepose_core::synth::AngleRange;
use facepose_eval::hpr_table::{hpr_markdown, hpr_table};
use facepose_files::data::load_canonical_mesh;

use super::progress::{QuietArg, Reporter};
use super::{CliError, DataArg};

#[derive(Args)]
pub struct HprArgs {
    /// The mesh file (default: the shared data's canonical_face_468.json).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Grid step in degrees.
    #[arg(long, default_value_t = 5.0)]
    step: f64,
    /// Largest |yaw| in degrees.
    #[arg(long, default_value_t = 90.0)]
    max_yaw: f64,
    /// Largest |pitch| in degrees.
    #[arg(long, default_value_t = 60.0)]
    max_pitch: f64,
    /// Print JSON rows instead of Markdown.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    data: DataArg,
    #[command(flatten)]
    quiet: QuietArg,
}

pub fn run(a: HprArgs) -> Result<(), CliError> {
    let progress = Reporter::new(&a.quiet);
    let path = a
        .data
        .or_file(a.mesh.as_deref(), "mediapipe/canonical_face_468.json")?;
    progress.stage(format_args!("reading {}", path.display()));
    let mesh = load_canonical_mesh(&path)?;
    let yaw = AngleRange::new(-a.max_yaw, a.max_yaw, a.step)?;
    let pitch = AngleRange::new(-a.max_pitch, a.max_pitch, a.step)?;
    let katz: Vec<KatzHpr> = [(2.0, 1.0), (10.0, 2.0)]
        .iter()
        .map(|&(camera_distance, gamma)| KatzHpr {
            camera_distance,
            gamma,
        })
        .collect();
    let rows = hpr_table(
        &mesh.vertices,
        &mesh.triangles,
        &mesh.ibug68,
        yaw,
        pitch,
        &katz,
        &progress,
    )?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!(
            "HPR on {} over yaw ±{}°, pitch ±{}° in {}° steps (truth: ray casting on the mesh's {} triangles)\n",
            path.display(),
            a.max_yaw,
            a.max_pitch,
            a.step,
            mesh.triangles.len()
        );
        print!("{}", hpr_markdown(&rows));
    }
    progress.stage("done");
    Ok(())
}
