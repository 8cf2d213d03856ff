//! `facepose estimate`: landmarks in (JSON Lines or CSV, a file or standard input), one pose per
//! face out (JSON Lines on standard output). A bad line gives `{"id": ..., "error": ...}` and the
//! run goes on; only unusable arguments or files end it with a non-zero status.

use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};
use facepose_core::estimate::Intrinsics;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::record::{Landmarks, PoseRecord, shape_from_points};
use facepose_core::shape::Shape2;
use serde::Deserialize;
use serde_json::{Value, json};

use super::CliError;

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum Format {
    /// CSV for a .csv file or a first line with commas that is not a JSON object; else JSON Lines.
    Auto,
    Jsonl,
    Csv,
}

#[derive(Args)]
pub struct EstimateArgs {
    /// Input file, or - for standard input.
    #[arg(long)]
    input: PathBuf,
    /// Landmark scheme of the input.
    #[arg(long, default_value = "ibug68")]
    scheme: String,
    /// Estimator (auto picks the most accurate for the input).
    #[arg(long, default_value = "auto")]
    method: String,
    /// Model bundle directory (default: the embedded default model).
    #[arg(long)]
    model: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = Format::Auto)]
    format: Format,
    /// Camera intrinsics `fx,fy,cx,cy` (pixels) for every face: the fit methods then refine
    /// the pose under perspective and report the face's position. A JSON line's own
    /// `"camera": {"fx": .., "fy": .., "cx": .., "cy": ..}` takes precedence.
    #[arg(long, value_parser = parse_camera)]
    camera: Option<Intrinsics>,
    /// How the landmarks were made: `projected` (3D-style: hidden points are where they would
    /// project) or `contour` (2D-style: hidden jaw points on the visible outline). A JSON
    /// line's own `"landmark_style"` takes precedence.
    #[arg(long, default_value = "projected")]
    landmark_style: String,
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

/// What a line may override.
#[derive(Default)]
struct LineOptions {
    camera: Option<Intrinsics>,
    style: Option<LandmarkStyle>,
}

pub fn run(a: EstimateArgs) -> Result<(), CliError> {
    let method: Method = a.method.parse()?;
    let style: LandmarkStyle = a.landmark_style.parse()?;
    let (_, model) = super::load_model(a.model.as_deref())?;
    let subset = model.subset(&a.scheme)?;
    let n = subset.scheme.len();
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
    let mut csv_has_id = None;
    for (k, line) in lines.enumerate() {
        let line = line.map_err(|e| format!("{}: line {}: {e}", a.input.display(), k + 1))?;
        if line.trim().is_empty() {
            continue;
        }
        let (id, parsed) = match format {
            Format::Csv => {
                if k == 0
                    && line
                        .split(',')
                        .next()
                        .is_some_and(|c| c.trim().parse::<f64>().is_err() && !c.trim().is_empty())
                {
                    csv_has_id = Some(line.split(',').count() == 2 * n + 1);
                    continue;
                }
                let (id, shape) = parse_csv(&line, n, csv_has_id);
                (id, shape.map(|s| (s, LineOptions::default())))
            }
            _ => parse_jsonl(&line),
        };
        let result = parsed.and_then(|(shape, line_opts)| {
            let opts = EstimateOptions {
                method,
                camera: line_opts.camera.or(a.camera),
                style: line_opts.style.unwrap_or(style),
            };
            estimate_with(&model, &a.scheme, &shape, &opts).map_err(|e| e.to_string())
        });
        let value = match result {
            Ok(e) => {
                let mut v = serde_json::to_value(PoseRecord::from(&e))?;
                if let Some(id) = id {
                    v.as_object_mut().map(|o| o.insert("id".into(), id));
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
    if start.elapsed() > Duration::from_secs(2) {
        eprintln!(
            "done: {done} faces, {failed} with errors, in {:.2?}",
            start.elapsed()
        );
    }
    Ok(())
}

/// One JSON Lines record: `{"landmarks": [[x, y] | null, ...], "id": ...}`.
/// The landmarks are parsed by [`Landmarks`] (shared with the service); their count is checked
/// against the scheme by the estimator.
fn parse_jsonl(line: &str) -> (Option<Value>, Result<(Shape2, LineOptions), String>) {
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
    let shape = match v.get("landmarks") {
        None => Err("missing \"landmarks\"".to_string()),
        Some(lm) => Landmarks::deserialize(lm)
            .map_err(|e| format!("\"landmarks\": {e}"))
            .and_then(|l| l.to_shape().map_err(|e| e.to_string())),
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
        Ok(LineOptions { camera, style })
    })();
    (id, shape.and_then(|s| opts.map(|o| (s, o))))
}

/// One CSV row: `[id,]x0,y0,...,x{n-1},y{n-1}`, empty cells for a missing point.
fn parse_csv(
    line: &str,
    n: usize,
    has_id: Option<bool>,
) -> (Option<Value>, Result<Shape2, String>) {
    let cells: Vec<&str> = line.split(',').map(str::trim).collect();
    let has_id = has_id.unwrap_or(cells.len() == 2 * n + 1);
    let (id, coords) = if has_id {
        (Some(json!(cells[0])), &cells[1..])
    } else {
        (None, &cells[..])
    };
    if coords.len() != 2 * n {
        return (
            id,
            Err(format!(
                "{} coordinate cells, expected {} (x and y for {n} points)",
                coords.len(),
                2 * n
            )),
        );
    }
    let pts = (0..n)
        .map(|i| match (coords[2 * i], coords[2 * i + 1]) {
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
        pts.and_then(|p| shape_from_points(&p).map_err(|e| e.to_string())),
    )
}
