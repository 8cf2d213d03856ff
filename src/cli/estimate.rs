//! `facepose estimate`: landmarks in (JSON Lines or CSV, a file or standard input), one pose per
//! face out (JSON Lines on standard output). A bad line gives `{"id": ..., "error": ...}` and the
//! run goes on; the exit status says whether every face, some or none were estimated
//! ([`EXIT_STATUS_HELP`]). The formats: docs/FORMATS.md, "Landmarks for `facepose estimate`".

use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};
use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::convention::ConventionRequest;
use facepose_core::model::PoseModel;
use facepose_core::pose::{
    ConventionOptions, EstimateOptions, LandmarkStyle, METHODS, Method, conventions_of,
    estimate_with,
};
use facepose_core::shape::Shape2;
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_records::{ConventionsRecord, Landmarks, PoseRecord};
use serde::Deserialize;
use serde_json::{Value, json};

use super::names::Names;
use super::{CliError, Finished};

/// What the exit status of `facepose estimate` means (its `--help` shows this).
pub const EXIT_STATUS_HELP: &str = "Exit status: 0 every face was estimated; 1 some faces \
were not (their lines carry \"error\"); 3 nothing was estimated (no face in the input, or \
every one failed); 2 the arguments or the input file are unusable.";

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    /// CSV for a .csv file or a first line with commas that is not a JSON object; else JSON Lines.
    Auto,
    /// One JSON object per line: {"landmarks": [[x, y] | null, ...], "id": ..., ...}.
    Jsonl,
    /// One face per row: [id,]x0,y0,x1,y1,...; empty cells for a missing point.
    Csv,
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Header {
    /// A header when no cell of the first row but its first is a number: a data row always
    /// has numbers, so no face is taken for a header.
    Auto,
    /// The first row is a header.
    Yes,
    /// Every row is a face.
    No,
}

#[derive(Args)]
#[command(after_help = EXIT_STATUS_HELP)]
pub struct EstimateArgs {
    /// Input file, or - for standard input.
    #[arg(long)]
    input: PathBuf,
    /// Landmark scheme of the input (ibug68, inner51, five, dlib5, mediapipe468, mediapipe478, or
    /// a trained model's own). Default: chosen per face by its number of points where only one
    /// scheme has that many (68: ibug68, 51: inner51, 468: mediapipe468, 478: mediapipe478); 5
    /// points must be named (five or dlib5). A JSON line's own
    /// `"scheme"` takes precedence.
    #[arg(long)]
    scheme: Option<String>,
    /// Conventions to answer in besides facepose's own, comma-separated, each
    /// `name[:param=value...]`: quaternion, euler (e.g. `euler:preset=openface`,
    /// `euler:order=zyx:units=radians`), opencv (`opencv:object_frame=model`), mediapipe
    /// (docs/API.md, "Answers in your convention"). Each pose gains a `conventions` object.
    #[arg(long, value_parser = parse_conventions)]
    conventions: Option<Conventions>,
    /// Estimator (auto picks the most accurate for the input; README "Methods").
    #[arg(long, default_value = "auto", value_parser = Names::<Method>::new(METHODS.iter().map(|m| (m.name, m.summary))))]
    method: Method,
    /// Model bundle directory (default: the embedded default model).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Input format (docs/FORMATS.md).
    #[arg(long, value_enum, default_value_t = Format::Auto)]
    format: Format,
    /// Whether a CSV input's first row is a header.
    #[arg(long, value_enum, default_value_t = Header::Auto)]
    header: Header,
    /// Camera intrinsics `fx,fy,cx,cy` (pixels) for every face: the fit methods then refine
    /// the pose under perspective and report the face's position. A JSON line's own
    /// `"camera": {"fx": .., "fy": .., "cx": .., "cy": ..}` takes precedence.
    #[arg(long, value_parser = parse_camera)]
    camera: Option<Intrinsics>,
    /// How the landmarks were made: `projected` (3D-style: hidden points are where they would
    /// project) or `contour` (2D-style: hidden jaw points on the visible outline). A JSON
    /// line's own `"landmark_style"` takes precedence.
    #[arg(
        long,
        default_value = "projected",
        value_parser = Names::<LandmarkStyle>::new(
            LandmarkStyle::ALL.iter().zip(LandmarkStyle::NAMES).map(|(s, n)| (n, s.summary()))
        )
    )]
    landmark_style: LandmarkStyle,
    /// The image's size `width,height` in pixels for every face: the landmarks are then
    /// normalized coordinates, fractions of the width and height (MediaPipe's x, y). A JSON
    /// line's own `"image_size": [w, h]` takes precedence.
    #[arg(long, value_name = "W,H", value_parser = parse_image_size)]
    image_size: Option<ImageSize>,
}

fn parse_image_size(s: &str) -> Result<ImageSize, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("image size: {e} (expected width,height)"))?;
    let [width, height] = v[..] else {
        return Err(format!(
            "image size: {} numbers, expected width,height",
            v.len()
        ));
    };
    let size = ImageSize { width, height };
    size.validate().map_err(|e| e.to_string())?;
    Ok(size)
}

fn parse_camera(s: &str) -> Result<Intrinsics, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("camera: {e} (expected fx,fy,cx,cy)"))?;
    let [fx, fy, cx, cy] = v[..] else {
        return Err(format!("camera: {} numbers, expected fx,fy,cx,cy", v.len()));
    };
    let k = Intrinsics { fx, fy, cx, cy };
    k.validate().map_err(|e| e.to_string())?;
    Ok(k)
}

/// The parsed `--conventions` list.
#[derive(Clone, Debug)]
struct Conventions(Vec<ConventionRequest>);

fn parse_conventions(s: &str) -> Result<Conventions, String> {
    ConventionRequest::parse_list(s)
        .map(Conventions)
        .map_err(|e| e.to_string())
}

/// What a line may override.
#[derive(Default)]
struct LineOptions {
    camera: Option<Intrinsics>,
    style: Option<LandmarkStyle>,
    scheme: Option<String>,
}

pub fn run(a: EstimateArgs) -> Result<(), CliError> {
    let method = a.method;
    let style = a.landmark_style;
    let (_, model) = super::load_model(a.model.as_deref())?;
    if let Some(s) = &a.scheme {
        model.scheme(s)?;
    }
    let reader: Box<dyn Read> = if a.input.as_os_str() == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        Box::new(
            std::fs::File::open(&a.input)
                .map_err(|e| format!("cannot read {}: {e}", a.input.display()))?,
        )
    };
    let mut lines = BufReader::new(reader).lines().peekable();
    let format = match a.format {
        Format::Auto
            if a.input
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("csv")) =>
        {
            Format::Csv
        }
        Format::Auto => match lines.peek() {
            Some(Ok(l)) if !l.trim_start().starts_with('{') && l.contains(',') => Format::Csv,
            _ => Format::Jsonl,
        },
        f => f,
    };
    let out = std::io::stdout();
    let mut out = BufWriter::new(out.lock());
    let start = Instant::now();
    let mut last_report = Instant::now();
    let (mut done, mut failed) = (0usize, 0usize);
    let mut first_row = true;
    for (k, line) in lines.enumerate() {
        let line = line.map_err(|e| format!("{}: line {}: {e}", a.input.display(), k + 1))?;
        if line.trim().is_empty() {
            continue;
        }
        let (id, parsed) = match format {
            Format::Csv => {
                let first = std::mem::replace(&mut first_row, false);
                if first && is_csv_header(&line, a.header) {
                    continue;
                }
                let (id, shape) = parse_csv(&line, a.image_size);
                (id, shape.map(|s| (s, LineOptions::default())))
            }
            _ => parse_jsonl(&line, a.image_size),
        };
        let result = parsed.and_then(|(shape, line_opts)| {
            let opts = EstimateOptions {
                method,
                camera: line_opts.camera.or(a.camera),
                style: line_opts.style.unwrap_or(style),
            };
            let scheme = scheme_of(&model, line_opts.scheme.or(a.scheme.clone()), &shape)?;
            let e = estimate_with(&model, &scheme, &shape, &opts).map_err(|e| e.to_string())?;
            let conventions = match &a.conventions {
                Some(c) => Some(
                    conventions_of(
                        &model,
                        &scheme,
                        &shape,
                        &opts,
                        &e,
                        &ConventionOptions {
                            requests: &c.0,
                            orientation: None,
                            image_size: a.image_size,
                        },
                    )
                    .map_err(|e| e.to_string())?,
                ),
                None => None,
            };
            Ok((e, scheme, conventions))
        });
        let value = match result {
            Ok((e, scheme, conventions)) => {
                let mut record = PoseRecord::from(&e);
                if let Some(c) = &conventions {
                    record
                        .warnings
                        .extend(c.warnings.iter().map(ToString::to_string));
                    record.conventions = Some(Box::new(ConventionsRecord::from(c)));
                }
                let mut v = serde_json::to_value(record)?;
                if let Some(o) = v.as_object_mut() {
                    o.insert("scheme".into(), scheme.into());
                    if let Some(id) = id {
                        o.insert("id".into(), id);
                    }
                }
                v
            }
            Err(msg) => {
                failed += 1;
                json!({"id": id.unwrap_or(Value::Null), "line": k + 1, "error": msg})
            }
        };
        writeln!(out, "{value}")?;
        done += 1;
        if last_report.elapsed() > Duration::from_secs(2) {
            last_report = Instant::now();
            eprintln!(
                "{done} faces ({failed} with errors), {:.0}/s",
                done as f64 / start.elapsed().as_secs_f64()
            );
        }
    }
    out.flush()?;
    let summary = format!(
        "{} of {done} faces estimated, {failed} with errors, in {:.2?}",
        done - failed,
        start.elapsed()
    );
    match (done, failed) {
        (0, _) => Err(Finished::new(3, "nothing estimated: the input has no face").into()),
        (d, f) if f == d => Err(Finished::new(
            3,
            format!(
                "nothing estimated: every face failed ({summary}); each line's \"error\" says why"
            ),
        )
        .into()),
        (_, f) if f > 0 => Err(Finished::new(1, summary).into()),
        _ => {
            if start.elapsed() > Duration::from_secs(2) {
                eprintln!("done: {summary}");
            }
            Ok(())
        }
    }
}

/// The scheme of one face: the one named (flag or line), else the only served scheme with its
/// number of points.
fn scheme_of(model: &PoseModel, named: Option<String>, shape: &Shape2) -> Result<String, String> {
    match named {
        Some(s) => Ok(s),
        None => model
            .scheme_for_count(shape.len())
            .map(|s| s.name.clone())
            .map_err(|e| format!("{e}, with --scheme or a line's \"scheme\"")),
    }
}

/// Whether the first row of a CSV input is a header: by `--header`, or (auto) when no cell but
/// the first (an id column's name or an id) is a number. A face's row has numbers in its
/// coordinate cells, so a face is never dropped for a header; a header of numbers would be
/// estimated as a face and fail, visibly, as one.
fn is_csv_header(line: &str, header: Header) -> bool {
    match header {
        Header::Yes => true,
        Header::No => false,
        Header::Auto => {
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            cells
                .iter()
                .any(|c| !c.is_empty() && c.parse::<f64>().is_err())
                && cells[1..].iter().all(|c| c.parse::<f64>().is_err())
        }
    }
}

/// One JSON Lines record: `{"landmarks": [[x, y] | null, ...], "id": ...}`.
/// The landmarks are parsed by [`Landmarks`] (shared with the service); their count is checked
/// against the scheme by the estimator.
fn parse_jsonl(
    line: &str,
    image_size: Option<ImageSize>,
) -> (Option<Value>, Result<(Shape2, LineOptions), String>) {
    let v: Value = match serde_json::from_str(line) {
        Ok(v) => v,
        Err(e) => return (None, Err(format!("not valid JSON: {e}"))),
    };
    let id = v.get("id").cloned();
    if let Some(bad) = id.as_ref().filter(|i| !(i.is_string() || i.is_number())) {
        return (
            None,
            Err(format!("\"id\" must be a string or a number, got {bad}")),
        );
    }
    let image_size = match v.get("image_size") {
        None | Some(Value::Null) => Ok(image_size),
        Some(s) => <[f64; 2]>::deserialize(s)
            .map(|[width, height]| Some(ImageSize { width, height }))
            .map_err(|e| format!("\"image_size\": {e} (expected [width, height])")),
    };
    let shape = match (v.get("landmarks"), image_size) {
        (_, Err(e)) => Err(e),
        (None, _) => Err("missing \"landmarks\"".to_string()),
        (Some(lm), Ok(size)) => Landmarks::deserialize(lm)
            .map_err(|e| format!("\"landmarks\": {e}"))
            .and_then(|l| pixel_shape(&l.0, size).map_err(|e| e.to_string())),
    };
    let opts = (|| {
        let camera = match v.get("camera") {
            None | Some(Value::Null) => None,
            Some(c) => Some(Intrinsics::deserialize(c).map_err(|e| {
                format!("\"camera\": {e} (expected {{\"fx\", \"fy\", \"cx\", \"cy\"}})")
            })?),
        };
        let style = match v.get("landmark_style") {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) => Some(s.parse::<LandmarkStyle>().map_err(|e| e.to_string())?),
            Some(other) => {
                return Err(format!("\"landmark_style\" must be a string, got {other}"));
            }
        };
        let scheme = match v.get("scheme") {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) => Some(s.clone()),
            Some(other) => return Err(format!("\"scheme\" must be a string, got {other}")),
        };
        Ok(LineOptions {
            camera,
            style,
            scheme,
        })
    })();
    (id, shape.and_then(|s| opts.map(|o| (s, o))))
}

/// One CSV row: `[id,]x0,y0,...,x{n-1},y{n-1}`, empty cells for a missing point. An odd number
/// of cells means the first is an id (a point has two).
fn parse_csv(line: &str, image_size: Option<ImageSize>) -> (Option<Value>, Result<Shape2, String>) {
    let cells: Vec<&str> = line.split(',').map(str::trim).collect();
    let (id, coords) = if cells.len() % 2 == 1 {
        (Some(json!(cells[0])), &cells[1..])
    } else {
        (None, &cells[..])
    };
    let pts = coords
        .chunks(2)
        .enumerate()
        .map(|(i, c)| match (c[0], c[1]) {
            ("", "") => Ok(None),
            (x, y) => match (x.parse::<f64>(), y.parse::<f64>()) {
                (Ok(x), Ok(y)) => Ok(Some([x, y])),
                _ => Err(format!(
                    "point {i}: {x:?}, {y:?} are not numbers (leave both empty for a missing point)"
                )),
            },
        })
        .collect::<Result<Vec<_>, String>>();
    (
        id,
        pts.and_then(|p| pixel_shape(&p, image_size).map_err(|e| e.to_string())),
    )
}
