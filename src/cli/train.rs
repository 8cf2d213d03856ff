//! `facepose train`: builds a model bundle from 3D shape sets (or multi-view 2D sets, rebuilt by
//! structure from motion first) and writes it atomically.

use std::path::PathBuf;
use std::time::Instant;

use clap::{Args, ValueEnum};
use facepose_core::model::bundle::{Bundle, Provenance, SourceFile, sha256_hex};
use facepose_core::model::{
    BasisSource, MeshSource, RegressionParams, TrainOptions, train_from_population,
};
use facepose_core::sfm::{SfmOptions, reconstruct};
use facepose_core::shape::{Scheme, Shape2};
use facepose_eval::detector_training::train_detectors;
use facepose_eval::uncertainty::calibrate_on_faces;
use facepose_files::data::{
    load_aflw, load_canonical_mesh, load_morphable_model, load_multi_view, load_population,
};
use facepose_files::rendered::{load_rendered, rendered_files};
use facepose_files::store::write_bundle_dir;
use nalgebra::Vector3;

use super::CliError;
use super::progress::{QuietArg, Reporter};

#[derive(Clone, Copy, ValueEnum)]
pub enum Grid {
    /// The paper's: yaw and pitch within ±40° at 2°, one model.
    Paper,
    /// Coarse ±90° yaw / ±60° pitch model and five yaw bins at 2°.
    Wide,
}

#[derive(Args)]
pub struct TrainArgs {
    /// 3D shape sets (population JSON); repeat to combine files.
    #[arg(long, required_unless_present = "views", conflicts_with = "views")]
    shapes: Vec<PathBuf>,
    /// A multi-view 2D set (docs/FORMATS.md), rebuilt by structure from motion.
    #[arg(long)]
    views: Option<PathBuf>,
    /// The bundle directory to create (must not exist).
    #[arg(long)]
    out: PathBuf,
    /// Train on this many shapes only: shapes [skip, skip + N) of the combined --shapes files
    /// in the order given (with --views: of the reconstructed subjects). Default: all shapes
    /// after --skip. Recorded in the bundle's provenance.
    #[arg(long, value_name = "N")]
    first: Option<usize>,
    /// Leave out the first N shapes of the combined sets (e.g. to hold them out for testing,
    /// as `eval --protocol paper` does with --train-shapes); see --first.
    #[arg(long, value_name = "N", default_value_t = 0)]
    skip: usize,
    /// The regression's pose grids.
    #[arg(long, value_enum, default_value_t = Grid::Wide)]
    grid: Grid,
    /// Sub-schemes to serve besides the model's own. Default: every built-in subset of the
    /// shapes' scheme (ibug68: inner51, five, dlib5; another scheme with the five anchors:
    /// five).
    #[arg(long, value_delimiter = ',')]
    subsets: Option<Vec<String>>,
    /// Principal components of the shape basis for `fit-shape` (0: none); ignored with
    /// --morphable.
    #[arg(long, default_value_t = 40)]
    components: usize,
    /// A morphable model over the scheme's points (JSON like
    /// ../shared/data/bfm68/morphable_model.json) whose identity and expression bases become
    /// the shape basis for `fit-shape`, instead of principal components of the shapes.
    #[arg(long)]
    morphable: Option<PathBuf>,
    /// Widen the morphable model's expression prior by this factor.
    #[arg(long, default_value_t = 1.0, requires = "morphable")]
    expression_spread: f64,
    /// MediaPipe's canonical face mesh (../shared/data/mediapipe/canonical_face_468.json): the
    /// model then serves `mediapipe468` and `mediapipe478`, the mesh aligned to its mean by the
    /// file's ibug68 correspondence (an ibug68 model only).
    #[arg(long, value_name = "FILE")]
    mesh: Option<PathBuf>,
    /// Faces with ground-truth pose (AFLW2000-3D JSON Lines, e.g.
    /// ../shared/data/aflw2000/aflw2000_dev.jsonl): the bundle then stores the uncertainty's
    /// calibration fitted on them, and answers carry a standard deviation and a 90% interval per
    /// angle (an ibug68 model only: the faces' landmarks are ibug68).
    #[arg(long, value_name = "FILE")]
    calibrate: Option<PathBuf>,
    /// The rendered benchmark's directory (tests/fixtures/rendered): the bundle then stores the
    /// detector regressions of MediaPipe's 478 points and of dlib's 68 (method `detector`, which
    /// `auto` answers a detector's complete `mediapipe478` face and a complete `ibug68` face
    /// sent with `landmark_style: contour` with), trained on its `train` identities only, with
    /// their uncertainty calibrated on the answers of their leave-one-identity-out folds. Needs
    /// --mesh and --calibrate.
    #[arg(long, value_name = "DIR", requires_all = ["mesh", "calibrate"])]
    detector_renders: Option<PathBuf>,
    /// Model name (default: the --out directory's name).
    #[arg(long)]
    name: Option<String>,
    /// The version recorded in the bundle (its `version` field, any text). `serve` shows it for
    /// a bundle deployed as `<models>/<name>/model.json`; under `<models>/<name>/versions/<N>/`
    /// it must be N (and --name the folder's name) or the server refuses the bundle.
    #[arg(long, value_name = "VERSION", default_value = "1")]
    model_version: String,
    /// Creation time to record (RFC 3339; default: now). Fix it to rebuild byte for byte.
    #[arg(long)]
    created: Option<String>,
    #[command(flatten)]
    quiet: QuietArg,
}

pub fn run(a: TrainArgs) -> Result<(), CliError> {
    let start = Instant::now();
    let progress = Reporter::new(&a.quiet);
    let mut sources = Vec::new();
    let mut shapes: Vec<Vec<Vector3<f64>>> = Vec::new();
    let scheme_name;
    if let Some(views) = &a.views {
        progress.stage(format_args!("reading {}", views.display()));
        let bytes =
            std::fs::read(views).map_err(|e| format!("cannot read {}: {e}", views.display()))?;
        let set = load_multi_view(views)?;
        let scheme = Scheme::builtin(&set.scheme)
            .ok_or_else(|| format!("{}: unknown scheme {:?}", views.display(), set.scheme))?;
        let nose = scheme.anchors.nose_tip[0];
        let subjects = set.subjects.len();
        progress.count("structure from motion", 0, subjects, "subjects");
        for (k, subject) in set.subjects.iter().enumerate() {
            let vs = subject
                .views
                .iter()
                .map(|v| {
                    if v.len() == scheme.len() {
                        Shape2::from_options(v).map_err(|e| e.to_string())
                    } else {
                        Err(format!("{} points, expected {}", v.len(), scheme.len()))
                    }
                })
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| format!("{}: subject {k}: {e}", views.display()))?;
            let rec = reconstruct(&vs, SfmOptions::with_nose_tip(nose))
                .map_err(|e| format!("{}: subject {k}: {e}", views.display()))?;
            shapes.push(rec.shape);
            progress.count("structure from motion", k + 1, subjects, "subjects");
        }
        sources.push(SourceFile {
            path: views.display().to_string(),
            sha256: sha256_hex(&bytes),
            shapes: shapes.len(),
        });
        scheme_name = set.scheme;
    } else {
        let mut name = None;
        for path in &a.shapes {
            progress.stage(format_args!("reading {}", path.display()));
            let bytes =
                std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
            let pop = load_population(path)?;
            if name.as_ref().is_some_and(|n| n != &pop.scheme) {
                return Err(format!(
                    "{}: scheme {:?} differs from the other files'",
                    path.display(),
                    pop.scheme
                )
                .into());
            }
            name = Some(pop.scheme.clone());
            sources.push(SourceFile {
                path: path.display().to_string(),
                sha256: sha256_hex(&bytes),
                shapes: pop.shapes.len(),
            });
            shapes.extend(pop.shapes);
        }
        scheme_name = name.ok_or("no --shapes given")?;
    }
    let scheme = Scheme::builtin(&scheme_name).ok_or_else(|| {
        format!(
            "unknown scheme {scheme_name:?} (known: {})",
            Scheme::builtin_names().join(", ")
        )
    })?;
    let total = shapes.len();
    let end = a.first.map(|f| a.skip + f).unwrap_or(total);
    if a.skip >= total || end > total {
        return Err(format!(
            "--skip {} --first {:?} is outside the {total} shapes",
            a.skip, a.first
        )
        .into());
    }
    let shapes = &shapes[a.skip..end];
    if let Some((k, s)) = shapes
        .iter()
        .enumerate()
        .find(|(_, s)| s.len() != scheme.len())
    {
        return Err(format!(
            "shape {} has {} points, scheme {} has {}",
            a.skip + k,
            s.len(),
            scheme.name,
            scheme.len()
        )
        .into());
    }
    let subsets = a
        .subsets
        .clone()
        .unwrap_or_else(|| facepose_core::shape::builtin::default_subsets(&scheme.name));
    progress.stage(format_args!(
        "training on {} shapes ({} grid, subsets {})",
        shapes.len(),
        match a.grid {
            Grid::Paper => "paper",
            Grid::Wide => "wide",
        },
        subsets.join(",")
    ));
    let opts = TrainOptions {
        regression: match a.grid {
            Grid::Paper => RegressionParams::paper(),
            Grid::Wide => RegressionParams::wide(),
        },
        subsets,
        ..TrainOptions::default()
    };
    let morphable = match &a.morphable {
        Some(path) => {
            sources.push(source_file(path)?);
            Some(load_morphable_model(path)?)
        }
        None => None,
    };
    let basis = match &morphable {
        Some(model) => BasisSource::Morphable {
            model,
            expression_spread: a.expression_spread,
        },
        None => BasisSource::Pca(a.components),
    };
    let mut model = train_from_population(&scheme, shapes, basis, &opts)?;
    progress.stage("trained");
    if let Some(path) = &a.mesh {
        if scheme.name != "ibug68" {
            return Err(format!(
                "--mesh needs an ibug68 model (the mesh's correspondence is to ibug68), this one is {}",
                scheme.name
            )
            .into());
        }
        sources.push(source_file(path)?);
        let mesh = load_canonical_mesh(path)?;
        model.attach_mesh(&MeshSource {
            vertices: mesh.vertices,
            triangles: mesh.triangles,
            to_model: mesh.ibug68,
        })?;
        progress.stage("aligned the face mesh and computed its visibility");
    }
    if let Some(path) = &a.calibrate {
        if scheme.name != "ibug68" {
            return Err(format!(
                "--calibrate needs an ibug68 model (the faces' landmarks are ibug68), this one is {}",
                scheme.name
            )
            .into());
        }
        progress.stage(format_args!(
            "calibrating the uncertainty on {}",
            path.display()
        ));
        sources.push(source_file(path)?);
        let faces = load_aflw(path)?;
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        model.calibration = Some(calibrate_on_faces(&model, &faces, &name)?);
        progress.stage("calibrated the uncertainty");
    }
    if let Some(dir) = &a.detector_renders {
        progress.stage(format_args!(
            "training the detector regressions (MediaPipe's 478 points, dlib's 68) on {}",
            dir.display()
        ));
        for f in rendered_files(dir)? {
            sources.push(source_file(&dir.join(f))?);
        }
        let records = load_rendered(dir, None)?;
        let (regressions, group) =
            train_detectors(&mut model, &records, &dir.display().to_string())?;
        if let Some(c) = model.calibration.as_mut() {
            c.data
                .push_str("; method detector: its folds' answers on the rendered train identities");
            c.groups.push(group);
        }
        model.detectors = regressions;
        progress.stage("trained the detector regressions");
    }
    let created = match a.created {
        Some(c) => c,
        None => time::OffsetDateTime::now_utc()
            .format(&time::format_description::well_known::Rfc3339)?,
    };
    let name = a.name.clone().unwrap_or_else(|| {
        a.out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "model".into())
    });
    let provenance = Provenance {
        sources,
        // The command without --out, so that a rebuild elsewhere gives the same bytes.
        command: command_without_out(),
        notes: format!(
            "shapes {}..{} of the shape sets; mean by generalized Procrustes analysis; shape basis: {}",
            a.skip,
            end,
            match &a.morphable {
                Some(_) => format!(
                    "the morphable model of the last source (expression prior x{})",
                    a.expression_spread
                ),
                None => format!("up to {} principal components of the shapes", a.components),
            }
        ) + if a.mesh.is_some() {
            "; face mesh: MediaPipe's canonical face mesh (Apache-2.0), aligned to the mean by \
             its ibug68 correspondence (MIT, PeizhiYan/Mediapipe_2_Dlib_Landmarks)"
        } else {
            ""
        } + if a.calibrate.is_some() {
            "; uncertainty calibrated on the last source's faces (AFLW2000-3D; research use)"
        } else {
            ""
        } + if a.detector_renders.is_some() {
            "; detector regressions: MediaPipe's and dlib's points on the rendered benchmark's \
             train identities (renders of photos shipped in scikit-image and the insightface wheel)"
        } else {
            ""
        },
    };
    let bundle = Bundle::from_model(&model, &opts, &name, &a.model_version, &created, provenance)?;
    write_bundle_dir(&a.out, &bundle)?;
    progress.stage(format_args!(
        "wrote {} ({:.2?} in all)",
        a.out.display(),
        start.elapsed()
    ));
    Ok(())
}

/// A source of no shapes (a morphable model, a mesh) for the provenance: its path and SHA-256.
fn source_file(path: &std::path::Path) -> Result<SourceFile, CliError> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    Ok(SourceFile {
        path: path.display().to_string(),
        sha256: sha256_hex(&bytes),
        shapes: 0,
    })
}

/// The command line as the bundle records it: without --out (a rebuild elsewhere gives the
/// same bytes) and without --quiet (which changes nothing in the bundle).
fn command_without_out() -> String {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut out = Vec::new();
    let mut skip = false;
    for a in &args {
        if skip {
            skip = false;
        } else if a == "--out" {
            skip = true;
        } else if !(a.starts_with("--out=") || a == "--quiet" || a == "-q") {
            out.push(a.clone());
        }
    }
    format!("facepose {}", out.join(" "))
}
