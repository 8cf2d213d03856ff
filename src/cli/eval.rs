//! `facepose eval`: accuracy reports. `--protocol paper` runs the paper's synthetic protocol
//! (§5, Table 1) with robustness curves and error maps; `--protocol real` evaluates a model on
//! real faces (AFLW2000-3D form); `all` does both. The report goes to standard output and, with
//! `--out DIR`, to `DIR/report.md` with its PNG plots and `DIR/report.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, ValueEnum};
use facepose_core::pose::Method;
use facepose_core::shape::Scheme;
use facepose_eval::aflw::{self, Source, aflw_markdown, error_by_yaw};
use facepose_eval::mesh::{MeshOptions, mesh_markdown, mesh_protocol};
use facepose_eval::paper::{
    PaperOptions, default_entries, paper_markdown, paper_protocol, robustness_markdown,
    train_paper_model,
};
use facepose_eval::paper::{PaperReport, Perturbation};
use facepose_eval::plot::{
    LandmarkPanel, Panel, Series, heat_maps_png, landmarks_png, line_chart_png,
};
use facepose_eval::tracking::{TrackingOptions, tracking_markdown, tracking_protocol};
use facepose_eval::uncertainty;
use facepose_files::data::{AflwFace, load_aflw, load_population};

use super::progress::{QuietArg, Reporter};
use super::{CliError, DataArg};

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Protocol {
    /// The paper's synthetic protocol on a 3D population (Table 1, robustness, error maps).
    Paper,
    /// Real faces with ground-truth pose.
    Real,
    /// MediaPipe input: the model's face mesh at known poses with landmark noise.
    Mediapipe,
    /// Streams: smoothing filters on synthetic head trajectories (noise, wild and occluded
    /// frames), with and without each estimate's uncertainty.
    Tracking,
    /// Detector landmarks (MediaPipe, dlib) on renders of textured heads at known poses
    /// (tests/fixtures/rendered/, issue 37): accuracy, gain, coverage, trajectories, peers.
    Rendered,
    /// All of them.
    All,
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Split {
    /// Training identities (what item 3's corrections are fitted on).
    Train,
    /// Test identities (the headline figures).
    Test,
    /// Every identity.
    All,
}

impl Split {
    fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
            Split::All => "all",
        }
    }
}

#[derive(Args)]
pub struct EvalArgs {
    /// Which evaluation to run.
    #[arg(long, value_enum, default_value_t = Protocol::Real)]
    protocol: Protocol,
    /// Faces with ground truth, JSON Lines in the AFLW2000-3D form (default: the dev split).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Model bundle directory for the real faces (default: the embedded default model). The
    /// paper's protocol trains its own model from the population's first shapes.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Methods to evaluate.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "auto,fit-shape,fit,regression,geometry,detector"
    )]
    methods: Vec<String>,
    /// Folder for report.md, report.json and the PNG plots; created if needed.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Paper protocol: the 3D population (default: the shared data's bfm68/population_249.json).
    #[arg(long)]
    population: Option<PathBuf>,
    /// Paper protocol: the first N shapes make the mean shape (and basis); the rest are tested.
    #[arg(long, default_value_t = 100)]
    train_shapes: usize,
    /// Paper protocol: principal components of the shape basis for fit-shape (0: none).
    #[arg(long, default_value_t = 40)]
    components: usize,
    /// Paper protocol: each test shape is seen at about 1/stride of the poses (seeded; 1: all).
    #[arg(long, default_value_t = 8)]
    stride: usize,
    /// Paper protocol: (shape, pose) draws per robustness condition.
    #[arg(long, default_value_t = 300)]
    samples: usize,
    /// Paper protocol: seed of the view scales, noise and missing points.
    #[arg(long, default_value_t = 2011)]
    seed: u64,
    /// Rendered protocol: the fixtures' folder (default: the repository's
    /// tests/fixtures/rendered).
    #[arg(long)]
    rendered: Option<PathBuf>,
    /// Rendered protocol: the identities of the headline tables (the other split is shown too).
    #[arg(long, value_enum, default_value_t = Split::Test)]
    split: Split,
    /// Rendered protocol: the trajectories' Kalman filter's acceleration noise, degrees/s²
    /// (default: the stream's, 150).
    #[arg(long, value_name = "DEG_PER_S2")]
    kalman_acceleration: Option<f64>,
    /// Rendered protocol: how much more the trajectories' Kalman filter trusts the `detector`
    /// regression's answers than their calibrated covariance (default: the method's, 4).
    #[arg(long, value_name = "FACTOR")]
    detector_filter_trust: Option<f64>,
    #[command(flatten)]
    data: DataArg,
    #[command(flatten)]
    quiet: QuietArg,
}

const HEATMAP_PNG: &str = "paper-heatmap.png";
const ROBUSTNESS_PNG: &str = "paper-robustness.png";
const REAL_PNG: &str = "real-error-by-yaw.png";
const STYLE_PNG: &str = "real-landmarks-large-yaw.png";
const RELIABILITY_PNG: &str = "real-uncertainty-reliability.png";

pub fn run(a: EvalArgs) -> Result<(), CliError> {
    let progress = Reporter::new(&a.quiet);
    let methods = a
        .methods
        .iter()
        .map(|m| m.parse::<Method>())
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(out) = &a.out {
        std::fs::create_dir_all(out)
            .map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    }
    let mut report = String::new();
    let mut json = serde_json::Map::new();
    let mut pngs: Vec<(&str, Vec<u8>)> = Vec::new();
    if matches!(a.protocol, Protocol::Paper | Protocol::All) {
        let (text, paper) = run_paper(&a, &methods, &progress)?;
        report.push_str(&text);
        progress.stage("paper protocol: drawing the error maps and robustness curves");
        pngs.push((
            HEATMAP_PNG,
            heat_maps_png(
                "Error over the pose grid (test shapes): mean of |yaw error| and |pitch error| (scale per panel, to its 95th percentile)",
                &paper.heat_maps,
                "error (°)",
            )?,
        ));
        pngs.push((ROBUSTNESS_PNG, robustness_png(&paper)?));
        json.insert("paper".into(), serde_json::to_value(&paper)?);
    }
    if matches!(a.protocol, Protocol::Real | Protocol::All) {
        if !report.is_empty() {
            report.push('\n');
        }
        let path = a
            .data
            .or_file(a.dataset.as_deref(), "aflw2000/aflw2000_dev.jsonl")?;
        progress.stage(format_args!("real faces: reading {}", path.display()));
        let faces = load_aflw(&path)?;
        let (text, rows) = run_real(&a, &path, &faces, &methods, &progress)?;
        report.push_str(&text);
        let (text, png, figures) = run_uncertainty(&a, &faces, &methods, &progress)?;
        report.push_str(&text);
        pngs.push((RELIABILITY_PNG, png));
        json.insert("uncertainty".into(), figures);
        progress.stage("real faces: drawing the plots");
        pngs.push((
            REAL_PNG,
            line_chart_png("Real faces: error against |yaw|", &error_by_yaw(&rows))?,
        ));
        pngs.push((STYLE_PNG, large_yaw_landmarks_png(&faces)?));
        json.insert("real".into(), serde_json::to_value(&rows)?);
    }
    if matches!(a.protocol, Protocol::Mediapipe | Protocol::All) {
        if !report.is_empty() {
            report.push('\n');
        }
        let (_, model) = super::load_model(a.model.as_deref())?;
        progress.stage("mediapipe: the face mesh at known poses");
        let opts = MeshOptions {
            seed: a.seed,
            ..MeshOptions::default()
        };
        let rows = mesh_protocol(&model, &methods, &opts)?;
        report.push_str("## MediaPipe landmarks, synthetic\n\n");
        report.push_str(&mesh_markdown(&rows, &opts));
        json.insert("mediapipe".into(), serde_json::to_value(&rows)?);
    }
    if matches!(a.protocol, Protocol::Tracking | Protocol::All) {
        if !report.is_empty() {
            report.push('\n');
        }
        let (_, model) = super::load_model(a.model.as_deref())?;
        progress.stage("tracking: filters on synthetic head trajectories");
        let opts = TrackingOptions {
            seed: a.seed,
            ..TrackingOptions::default()
        };
        let (rows, failed) = tracking_protocol(&model, &opts)?;
        report.push_str(&format!(
            "## Tracking: smoothing with and without the uncertainty\n\n\
             {} synthetic head trajectories of {} s at {} frames per second ({} frames), seed {}: a face drawn \
             from the model's shape basis turning smoothly (|yaw| up to 65°, up to about 100°/s), landmark noise \
             {}% of the inter-ocular distance (80 px), {}% wild frames (every point off by 12% of the IOD) and \
             {}% occluded ones (the half of the face left of the nose missing); every frame estimated with `auto` \
             ({failed} frames had no estimate and hold the last output). Errors are geodesic, in degrees; jitter \
             is the RMS angle between the output's frame-to-frame turn and the truth's. `kalman, fixed` is the \
             Kalman filter with the same 3° covariance for every frame; `kalman, uncertainty` weighs each frame \
             by its calibrated turn covariance. crates/eval/src/tracking.rs has the details.\n\n{}\n",
            opts.trajectories,
            opts.seconds,
            opts.fps,
            rows.first().map_or(0, |r| r.frames),
            opts.seed,
            opts.noise * 100.0,
            opts.wild * 100.0,
            opts.occluded * 100.0,
            tracking_markdown(&rows)
        ));
        json.insert("tracking".into(), serde_json::to_value(&rows)?);
    }
    if matches!(a.protocol, Protocol::Rendered | Protocol::All) {
        if !report.is_empty() {
            report.push('\n');
        }
        let (text, figures) = run_rendered(&a, &methods, &progress)?;
        report.push_str(&text);
        json.insert("rendered".into(), figures);
    }
    print!("{report}");
    if let Some(out) = &a.out {
        progress.stage(format_args!(
            "writing report.md, report.json and the plots to {}",
            out.display()
        ));
        write(&out.join("report.md"), report.as_bytes())?;
        write(
            &out.join("report.json"),
            serde_json::to_string_pretty(&json)?.as_bytes(),
        )?;
        for (name, bytes) in &pngs {
            write(&out.join(name), bytes)?;
        }
    }
    progress.stage("done");
    Ok(())
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), CliError> {
    std::fs::write(path, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()).into())
}

fn run_paper(
    a: &EvalArgs,
    methods: &[Method],
    progress: &Reporter,
) -> Result<(String, PaperReport), CliError> {
    let path = a
        .data
        .or_file(a.population.as_deref(), "bfm68/population_249.json")?;
    progress.stage(format_args!("paper protocol: reading {}", path.display()));
    let pop = load_population(&path)?;
    let scheme = Scheme::builtin(&pop.scheme).ok_or_else(|| {
        format!(
            "{}: scheme {:?} is not a built-in scheme",
            path.display(),
            pop.scheme
        )
    })?;
    if a.train_shapes < 2 || a.train_shapes >= pop.shapes.len() {
        return Err(format!(
            "--train-shapes {} must be at least 2 and leave test shapes ({} in {})",
            a.train_shapes,
            pop.shapes.len(),
            path.display()
        )
        .into());
    }
    let (train, test) = pop.shapes.split_at(a.train_shapes);
    progress.stage(format_args!(
        "paper protocol: training the model on the first {} shapes",
        a.train_shapes
    ));
    let t = Instant::now();
    let mut model = train_paper_model(&scheme, train, a.components, a.seed)?;
    // The uncertainty's calibration is of the estimators on real faces: the served model's.
    let (_, served) = super::load_model(a.model.as_deref())?;
    model.calibration = served.calibration.clone();
    let train_time = t.elapsed().as_secs_f64();
    let entries = default_entries(&model, methods);
    let opts = PaperOptions {
        stride: a.stride,
        robustness_samples: a.samples,
        seed: a.seed,
        ..PaperOptions::default()
    };
    let t = Instant::now();
    let paper = paper_protocol(&model, test, &entries, &opts, progress)?;
    let run_time = t.elapsed().as_secs_f64();
    let eps: Vec<String> = model
        .subsets
        .iter()
        .map(|s| format!("{} {:e}", s.scheme.name, s.regression.epsilon()))
        .collect();
    let g = &opts.grid;
    let basis = match &model.morph {
        Some(_) => format!(
            "`fit-shape` fits the mean plus a shape basis of up to {} principal components of the same {} training shapes (none of the test shapes); \
             the population is itself drawn from a 3D morphable model, so such a basis spans test faces better than it would real ones",
            a.components, a.train_shapes
        ),
        None => "no shape basis (`--components 0`), so no `fit-shape`".into(),
    };
    let text = format!(
        "## The paper's protocol (§5, Table 1)\n\n\
         Population {pop_path} ({n} shapes, scheme {scheme}): the mean shape (generalized Procrustes) of the first {nt} trains the model \
         with the paper's grid (yaw and pitch {y0}..{y1}° and {p0}..{p1}° at {ys}°, one regression per scheme; ε chosen on the training shapes: {eps}); \
         {basis}. The other {ntest} shapes are tested, each rotated to the same {poses} poses, projected with an inter-ocular distance of \
         {i0}-{i1} px (seeded per shape and pose), and with the points that the paper's HPR hides on that shape sent as missing (the five points \
         are anchor means of all 68 projections). \"Training\" = the mean shape's own {poses} views; \"testing\" = each test shape at a seeded \
         1/{stride} of the poses, i.e. {views} views per method (about {per_pose:.0} shapes per pose). \
         The geometric method's ratios from this mean shape: L_f = {lf:.3} (the paper: 0.45), l_n = {ln:.3} (the paper: 0.50); \
         the face axis leans {tilt:.1}° in depth. \
         Errors in degrees; MSE (the paper's measure) in degrees²; geodesic = mean angle of R_estimateᵀ R_true, which also counts roll \
         (true roll 0). Failed estimates are counted and left out of the means (the geometric method needs all five points, so it fails where HPR hides a mouth corner, near the corners of the grid). Training {train_time:.1} s, evaluation {run_time:.1} s (one core).\n\n\
         {table}\n\
         ### Robustness\n\n\
         {samples} seeded draws of (test shape, pose) from the same grid, the same for every method and condition; MAE = mean of the yaw and \
         pitch mean absolute errors, degrees. Noise: Gaussian, σ a percentage of the view's inter-ocular distance in pixels, added to each sent \
         point. Missing: that many random points (of those not hidden) sent as null; five-point entries drop at most {cap} (the geometric method \
         needs all five; the regression needs both eyes), marked [1 dropped]; their curves show that one point.\n\n\
         {robust}\
         ![Robustness curves]({ROBUSTNESS_PNG})\n\n\
         ### The uncertainty under the paper's protocol\n\n\
         The share of the robustness draws whose 90% interval (the served model's calibration, fitted on real faces) holds the true yaw / \
         pitch, percent. The truth is exact here, and the test shapes differ from the mean in ways real faces do not (the population is drawn \
         from a morphable model), so this measures how the calibration learned on real faces carries to another kind of error.\n\n\
         {coverage}\n\
         ### Error over the pose grid\n\n\
         Mean of the yaw and pitch absolute errors at each pose over the test shapes that see it (testing stage); one colour scale per panel, from 0 to about its 95th percentile (larger errors take the top colour; grey: no estimate).\n\n\
         ![Error over the yaw x pitch grid]({HEATMAP_PNG})\n",
        pop_path = path.display(),
        lf = model.geometry.lf,
        ln = model.geometry.ln,
        tilt = model.geometry.axis_tilt.to_degrees(),
        n = pop.shapes.len(),
        scheme = pop.scheme,
        nt = a.train_shapes,
        y0 = g.yaw.min,
        y1 = g.yaw.max,
        p0 = g.pitch.min,
        p1 = g.pitch.max,
        ys = g.yaw.step,
        eps = eps.join(", "),
        ntest = test.len(),
        poses = g.len(),
        i0 = opts.iod_px.0,
        i1 = opts.iod_px.1,
        stride = opts.stride,
        views = paper.test_views,
        per_pose = test.len() as f64 / opts.stride as f64,
        table = paper_markdown(&paper),
        samples = opts.robustness_samples,
        cap = facepose_eval::paper::MAX_MISSING_FIVE,
        robust = robustness_markdown(&paper),
        coverage = facepose_eval::paper::coverage_markdown(&paper),
    );
    Ok((text, paper))
}

/// The robustness curves: MAE against noise and against missing points, one line per entry.
fn robustness_png(paper: &PaperReport) -> Result<Vec<u8>, CliError> {
    let mut labels: Vec<&str> = Vec::new();
    for r in &paper.robustness {
        if !labels.contains(&r.label.as_str()) {
            labels.push(&r.label);
        }
    }
    let series = |noise: bool| -> Vec<Series> {
        labels
            .iter()
            .map(|l| Series {
                name: (*l).into(),
                points: paper
                    .robustness
                    .iter()
                    .filter(|r| r.label == *l && r.estimates > 0)
                    .filter_map(|r| match (r.perturbation, noise) {
                        (Perturbation::Noise(f), true) => Some((100.0 * f, r.mae)),
                        // Five-point entries: at the number of points actually dropped, once.
                        (Perturbation::Missing(_), false) => Some((r.dropped as f64, r.mae)),
                        _ => None,
                    })
                    .fold(Vec::new(), |mut v: Vec<(f64, f64)>, p| {
                        if !v.iter().any(|q| q.0 == p.0) {
                            v.push(p);
                        }
                        v
                    }),
            })
            .collect()
    };
    let panels = [
        Panel {
            title: "Landmark noise".into(),
            x_label: "σ (% of inter-ocular distance)".into(),
            y_label: "MAE of yaw and pitch (°)".into(),
            series: series(true),
        },
        Panel {
            title: "Missing landmarks (five points: at most 1)".into(),
            x_label: "points sent as null".into(),
            y_label: "MAE of yaw and pitch (°)".into(),
            series: series(false),
        },
    ];
    Ok(line_chart_png(
        "Robustness on the paper's protocol (test shapes)",
        &panels,
    )?)
}

fn run_real(
    a: &EvalArgs,
    path: &Path,
    faces: &[AflwFace],
    methods: &[Method],
    progress: &Reporter,
) -> Result<(String, Vec<aflw::AflwRow>), CliError> {
    let (bundle, model) = super::load_model(a.model.as_deref())?;
    let mut rows = Vec::new();
    let mut timing = Vec::new();
    // The shape fit does not take anchor means (five), the geometric method needs the nose tip
    // and mouth corners (not in dlib5), the detector regression a regression for the scheme
    // (the default model has one for MediaPipe's points only; its figures are the rendered
    // protocol's).
    let scheme = |s: Source| match s {
        Source::Five => "five",
        Source::Dlib5 => "dlib5",
        Source::Fitted | Source::Reannotated | Source::ReannotatedFittedJaw => "ibug68",
    };
    let pairs: Vec<(Method, Source)> = methods
        .iter()
        .flat_map(|&m| Source::ALL.into_iter().map(move |s| (m, s)))
        .filter(|&(m, s)| {
            !((m == Method::FitShape && s == Source::Five)
                || (m == Method::Geometry && s == Source::Dlib5)
                || (m == Method::Detector && model.detector(scheme(s)).is_none()))
        })
        .collect();
    let label = format!("real faces: {} faces", faces.len());
    let unit = "(method, landmark set) pairs";
    progress.count(&label, 0, pairs.len(), unit);
    for (k, &(m, s)) in pairs.iter().enumerate() {
        let t = Instant::now();
        let row = aflw::evaluate(&model, faces, m, s);
        timing.push(format!(
            "{m} on {}: {:.1} µs per face",
            s.name(),
            t.elapsed().as_secs_f64() * 1e6 / row.faces.max(1) as f64
        ));
        rows.push(row);
        progress.count(&label, k + 1, pairs.len(), unit);
    }
    // Calibration: whether the error of `auto` is a distortion of the estimate (which a
    // recalibration could remove) or scatter around it.
    let calibrated: Vec<&aflw::AflwRow> = rows
        .iter()
        .filter(|r| {
            r.method == Method::Auto && matches!(r.source, Source::Fitted | Source::Reannotated)
        })
        .collect();
    let calibration = format!(
        "### Diagnostic: calibration of `auto`\n\n\
         Least-squares lines between the estimated and the true angles over the same faces. On re-annotated landmarks the \
         estimated pitch is compressed (slope of estimate on truth below 1) while the slope of truth on estimate stays near 1: \
         the pitch error is scatter that is not correlated with the estimate, not a distortion of it. The last column is the \
         lowest MAE that any correction `a + b · estimate` reaches on these very faces (least absolute deviations, fitted \
         in-sample, so an optimistic floor for an affine recalibration).\n\n{}\n",
        aflw::calibration_markdown(&calibrated)
    );
    // Near |yaw| 90° Euler angles amplify rotation errors: how much of the MAE that is.
    let gimbal = format!(
        "### Diagnostic: Euler angles near |yaw| 90°\n\n\
         The error of `auto` per |true yaw| bin, as the mean absolute angle error (MAE, the figure above) and as the geodesic \
         error of the rotation. Near 90° of yaw only pitch - roll (or pitch + roll) is determined, so a rotation a few degrees \
         off can put pitch and roll tens of degrees off: a handful of faces there carry a large part of the MAE. The last \
         column is the bin's summed face errors over all the row's faces.\n\n{}\n",
        aflw::gimbal_markdown(&calibrated)
    );
    // The diagnostic row: where the error on re-annotated landmarks comes from.
    let diagnostic = rows
        .iter()
        .find(|r| r.method == Method::Auto && r.source == Source::Reannotated)
        .map(|auto| {
            aflw::aflw_markdown(&[
                auto.clone(),
                aflw::evaluate(&model, faces, Method::Auto, Source::ReannotatedFittedJaw),
            ])
        });
    let diagnostic = match diagnostic {
        Some(table) => format!(
            "### Diagnostic: the jaw of the re-annotated landmarks\n\n\
             The same faces with the 17 re-annotated jaw points replaced by the fitted ones, which are consistent with the 3DMM fit \
             that defines the ground truth (a diagnostic, not an estimate anyone could make). The gap is the part of the error \
             that comes from the human jaw annotation disagreeing with that fit, face by face.\n\n{table}\n"
        ),
        None => String::new(),
    };
    let misfit = format!(
        "### Does it look like a face?\n\n\
         The misfit of every face (all {} of them): the share of the landmarks' spread that the best fit of the face leaves \
         unexplained (for the paper's methods, the rigid fit's). An answer above {} carries a warning, above {} it is refused as \
         not a face in its scheme; MediaPipe's first 68 points sent as ibug68 give 0.93 (tests/integration/mediapipe.rs).\n\n{}\n",
        faces.len(),
        facepose_core::pose::MISFIT_WARN,
        facepose_core::pose::MISFIT_REFUSE,
        aflw::misfit_markdown(&aflw::misfits(
            &model,
            faces,
            &Source::ALL,
            &[
                Method::Auto,
                Method::Fit,
                Method::Regression,
                Method::Geometry
            ],
        ))
    );
    let text = format!(
        "## Real faces: {}\n\nModel `{}` version {} ({}; geometric ratios L_f = {:.3}, l_n = {:.3}, the paper's 0.45 and 0.50). \
         Faces with every |angle| <= 99° (`within_99`); errors in degrees; \
         MAE = mean of the pitch, yaw and roll mean absolute errors; geodesic = mean angle of R_estimateᵀ R_true; \
         the last columns give the MAE per |yaw| bin (faces in parentheses).\n\n{}\nTime per face (one core, including parsing): {}.\n\n\
         The plot gives the MAE per 10° bin of |true yaw| (bins of at least 3 faces).\n\n![Error against yaw]({REAL_PNG})\n\n\
         The first faces with |yaw| > 60°, both landmark sets, the jaw joined: in both the far half of the jaw folds back inside \
         the face, where the hidden 3D jaw projects (3D style), rather than following the visible outline.\n\n\
         ![Landmarks at large yaw]({STYLE_PNG})\n\n{}",
        path.display(),
        bundle.name,
        bundle.version,
        bundle.created,
        model.geometry.lf,
        model.geometry.ln,
        aflw_markdown(&rows),
        timing.join("; "),
        diagnostic + &calibration + &gimbal + &misfit
    );
    Ok((text, rows))
}

/// The uncertainty's calibration measured by cross-validation on the real faces: the section's
/// text, the reliability plot and the figures for report.json.
fn run_uncertainty(
    a: &EvalArgs,
    faces: &[AflwFace],
    methods: &[Method],
    progress: &Reporter,
) -> Result<(String, Vec<u8>, serde_json::Value), CliError> {
    let (_, model) = super::load_model(a.model.as_deref())?;
    progress.stage("real faces: the uncertainty, cross-validated");
    let labeled = uncertainty::samples(&model, faces, &Method::ALL, &Source::ALL);
    let predicted = uncertainty::cross_validate(&labeled)?;
    let rows = uncertainty::coverage_rows(&labeled, &predicted, methods, &Source::ALL);
    let curves: Vec<(String, Vec<uncertainty::ReliabilityBin>)> =
        [Source::Fitted, Source::Reannotated, Source::Five]
            .into_iter()
            .map(|s| {
                (
                    format!("auto, {}", s.name()),
                    uncertainty::reliability(&labeled, &predicted, Method::Auto, s),
                )
            })
            .collect();
    let shipped = match &model.calibration {
        Some(c) => format!(
            "The model's own calibration (in its bundle, from `facepose train --calibrate`): {}.",
            c.data
        ),
        None => {
            "This model has no calibration in its bundle: its answers carry no uncertainty.".into()
        }
    };
    let text = format!(
        "### How far to trust an answer: the uncertainty, cross-validated\n\n\
         Every answer carries a standard deviation and a 90% interval per angle (docs/API.md, \
         \"Uncertainty\"): the covariance of a weak-perspective fit at the answer's pose (the \
         landmarks' residual and layout), mapped to degrees that hold on real faces by a calibration \
         per method and landmark kind (`ln σ` linear in the log raw standard deviation, |yaw|, \
         |yaw|² and the log misfit, by maximum likelihood; the interval's half-width from the 90% \
         quantile of |error| / σ). The calibration is fitted on the re-annotated landmarks and the \
         five-point sets taken from them (what detectors give); the fitted landmarks, projections \
         of the very 3DMM fit that defines the ground truth, look the same to every predictor but \
         err a third as much, so their intervals come out conservative. Here each face is \
         predicted by a calibration fitted on the other folds only: {} folds by face, every \
         landmark set of a face in the same fold, {} estimates. Coverage is the share of faces \
         whose true angle is inside the 90% interval (target 88-92%); ρ is Spearman's rank \
         correlation between the predicted standard deviation and the actual error. {shipped}\n\n{}\n\
         Reliability of `auto`: the (face, angle) pairs in ten bins by predicted standard \
         deviation; a calibrated prediction has an observed RMS error equal to it.\n\n{}\n\
         ![Reliability]({RELIABILITY_PNG})\n\n",
        uncertainty::FOLDS,
        labeled.len(),
        uncertainty::coverage_markdown(&rows),
        uncertainty::reliability_markdown(&curves),
    );
    let png = line_chart_png(
        "Uncertainty of auto on real faces: observed RMS error against predicted sd, by decile (cross-validated)",
        &uncertainty::reliability_panels(&curves),
    )?;
    let json = serde_json::json!({ "coverage": rows, "reliability": curves });
    Ok((text, png, json))
}

/// The first four faces of the dataset with |yaw| > 60°, fitted and re-annotated landmarks over
/// each other.
fn large_yaw_landmarks_png(faces: &[AflwFace]) -> Result<Vec<u8>, CliError> {
    let panels: Vec<LandmarkPanel> = faces
        .iter()
        .filter(|f| f.within_99 && f.yaw.abs() > 60.0)
        .take(4)
        .map(|f| LandmarkPanel {
            title: format!("{}: yaw {:.0}°, pitch {:.0}°", f.image, f.yaw, f.pitch),
            outline: 17,
            numbered: vec![],
            sets: vec![
                ("fitted".into(), f.landmarks_fitted.clone()),
                ("reannotated".into(), f.landmarks_reannotated.clone()),
            ],
        })
        .collect();
    Ok(landmarks_png(
        "Real faces at |yaw| > 60°: fitted and re-annotated landmarks (jaw joined)",
        &panels,
    )?)
}

/// The rendered benchmark's folder: `--rendered`, else the repository's fixtures (relative to
/// the working directory, else to the source tree this binary was built from).
fn rendered_dir(a: &EvalArgs) -> PathBuf {
    use facepose_files::rendered::RENDERED_DIR;
    if let Some(d) = &a.rendered {
        return d.clone();
    }
    let here = PathBuf::from(RENDERED_DIR);
    if here.join("identities.json").exists() {
        here
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(RENDERED_DIR)
    }
}

fn run_rendered(
    a: &EvalArgs,
    methods: &[Method],
    progress: &Reporter,
) -> Result<(String, serde_json::Value), CliError> {
    use facepose_core::geometry::rotation_kalman::KalmanParams;
    use facepose_eval::rendered::{rendered_markdown, rendered_protocol};
    let dir = rendered_dir(a);
    progress.stage(format_args!("rendered: reading {}", dir.display()));
    let records = facepose_files::rendered::load_rendered(&dir, None)?;
    let (bundle, model) = super::load_model(a.model.as_deref())?;
    progress.stage(format_args!(
        "rendered: {} records, every input and method",
        records.len()
    ));
    let kalman = KalmanParams {
        acceleration_deg_s2: a
            .kalman_acceleration
            .unwrap_or(KalmanParams::default().acceleration_deg_s2),
        ..KalmanParams::default()
    };
    let t = Instant::now();
    let report = rendered_protocol(&model, &records, methods, kalman, a.detector_filter_trust)?;
    let secs = t.elapsed().as_secs_f64();
    let text = format!(
        "## Rendered benchmark: detector landmarks (issue 37)\n\n\
         {dir}: {n} records, {st} static renders (sets grid and random; 8 identities, test = \
         insightface/t1#2, t1#4, Tom_Hanks) and {tf} trajectory frames (6 trajectories). Model `{name}` \
         version {version}. Inputs: MediaPipe's 478 points (`mediapipe478`), dlib's 68 (`dlib68`, \
         landmark style contour), dlib's five-point predictor (`dlib5`), the five anchors of dlib's 68 \
         (`five`) and the oracle's visible 68 points (`oracle68`, the exact projection of the rendered \
         mesh: the floor of the renders, weak perspective on perspective renders); the peer \
         `mediapipe-matrix` is MediaPipe's own facial transformation matrix as a rotation of the model \
         frame. No camera intrinsics are given (weak perspective). Geometry `bfm` has absolute truth; \
         \"a constant rotation per identity removed\" scores `Qᵀ R` with Q the orthogonal Procrustes \
         rotation of that identity's answers onto its truths (per input and method), the only way to \
         score geometry `mediapipe` (relative truth). Errors in degrees; gain = least-squares slope of \
         the estimated on the true angle; coverage90 = share of answers whose 90% interval holds the \
         truth. This protocol fits nothing across identities; the model's `detector` regressions \
         (method `detector`, on MediaPipe's 478 points and on dlib's 68, which `auto` answers \
         them with: every render's MediaPipe points misfit MediaPipe's mesh by more than `auto`'s \
         cut, and dlib's come complete with landmark style contour) were fitted on the `train` \
         identities only (`facepose train --detector-renders`), so their `train` rows are \
         in-sample and only their `test` rows measure them. OpenCV SQPnP on the same points is not in \
         this report yet (a follow-up: it needs a script writing a fixture). \
         The trajectories' Kalman filter runs at {acc}°/s² of acceleration noise and trusts the \
         `detector` regressions' answers {trust} times more than their calibrated covariance. \
         crates/eval/src/rendered.rs has the details. Evaluation {secs:.1} s.\n\n{body}",
        acc = kalman.acceleration_deg_s2,
        trust = a
            .detector_filter_trust
            .unwrap_or(facepose_core::pose::DETECTOR_FILTER_TRUST),
        dir = dir.display(),
        n = report.records,
        st = report.static_renders,
        tf = report.trajectory_frames,
        name = bundle.name,
        version = bundle.version,
        body = rendered_markdown(&report, a.split.name()),
    );
    Ok((text, serde_json::to_value(&report)?))
}
