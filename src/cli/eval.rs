//! `facepose eval`: accuracy reports. `--protocol real` evaluates a model on real faces
//! (AFLW2000-3D form); `--protocol paper` runs the paper's synthetic protocol (Table 1). The
//! report (Markdown, plus PNG plots where available) goes to `--out DIR` and standard output.

use std::path::PathBuf;
use std::time::Instant;

use clap::{Args, ValueEnum};
use facepose::data::{data_dir, load_aflw};
use facepose::estimate::Method;
use facepose::eval::aflw::{Source, aflw_markdown, evaluate};

use super::CliError;

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Protocol {
    /// Real faces with ground-truth pose.
    Real,
}

#[derive(Args)]
pub struct EvalArgs {
    #[arg(long, value_enum, default_value_t = Protocol::Real)]
    protocol: Protocol,
    /// Faces with ground truth, JSON Lines in the AFLW2000-3D form (default: the dev split).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Model bundle directory (default: the embedded default model).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Methods to evaluate.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "auto,fit-shape,fit,regression,geometry"
    )]
    methods: Vec<String>,
    /// Folder for the report (report.md); created if needed.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(a: EvalArgs) -> Result<(), CliError> {
    let methods = a
        .methods
        .iter()
        .map(|m| m.parse::<Method>())
        .collect::<Result<Vec<_>, _>>()?;
    let (bundle, model) = super::load_model(a.model.as_deref())?;
    let path = a
        .dataset
        .unwrap_or_else(|| data_dir().join("aflw2000/aflw2000_dev.jsonl"));
    let faces = load_aflw(&path)?;
    let mut rows = Vec::new();
    let mut timing = Vec::new();
    for &m in &methods {
        for s in Source::ALL {
            if m == Method::FitShape && s == Source::Five {
                continue;
            }
            let t = Instant::now();
            let row = evaluate(&model, &faces, m, s);
            timing.push(format!(
                "{m} on {}: {:.1} µs per face",
                s.name(),
                t.elapsed().as_secs_f64() * 1e6 / row.faces.max(1) as f64
            ));
            rows.push(row);
        }
    }
    let report = format!(
        "## Real faces: {}\n\nModel `{}` version {} ({}). Faces with every |angle| <= 99° (`within_99`); errors in degrees; \
         MAE = mean of the pitch, yaw and roll mean absolute errors; geodesic = mean angle of R_estimateᵀ R_true; \
         the last columns give the MAE per |yaw| bin (faces in parentheses).\n\n{}\nTime per face (one core, including parsing): {}.\n",
        path.display(),
        bundle.name,
        bundle.version,
        bundle.created,
        aflw_markdown(&rows),
        timing.join("; ")
    );
    print!("{report}");
    if let Some(out) = a.out {
        std::fs::create_dir_all(&out)
            .map_err(|e| format!("cannot create {}: {e}", out.display()))?;
        let file = out.join("report.md");
        std::fs::write(&file, &report)
            .map_err(|e| format!("cannot write {}: {e}", file.display()))?;
    }
    Ok(())
}
