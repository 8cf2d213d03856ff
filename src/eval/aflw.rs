//! Evaluation on real faces with ground-truth pose (AFLW2000-3D JSON Lines): for each method and
//! landmark source, the mean absolute error of pitch, yaw and roll (and their mean, the figure
//! papers report), the mean geodesic error, and the mean error per |yaw| bin, over the faces with
//! every |angle| <= 99° (`within_99`).

use serde::Serialize;

use crate::data::AflwFace;
use crate::estimate::{Method, estimate};
use crate::geometry::{EulerAngles, geodesic_deg, rotation_from_rows};
use crate::model::PoseModel;
use crate::shape::{Shape2, ibug68};

/// Where the landmarks come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// `landmarks_fitted`: projections of a 3DMM fit (jaw points are fixed 3D vertices).
    Fitted,
    /// `landmarks_reannotated`: human re-annotation (the jaw follows the visible contour).
    Reannotated,
    /// Five points (eye centres, nose tip, mouth corners) derived from the re-annotated ones.
    Five,
}

impl Source {
    pub const ALL: [Source; 3] = [Source::Fitted, Source::Reannotated, Source::Five];

    pub fn name(self) -> &'static str {
        match self {
            Source::Fitted => "fitted",
            Source::Reannotated => "reannotated",
            Source::Five => "five (from reannotated)",
        }
    }
}

/// Upper edges of the |yaw| bins.
pub const YAW_BINS: [(f64, f64); 3] = [(0.0, 30.0), (30.0, 60.0), (60.0, 99.0)];

/// One row: a method on a source.
#[derive(Debug, Clone, Serialize)]
pub struct AflwRow {
    pub method: Method,
    pub source: Source,
    pub faces: usize,
    pub failures: usize,
    pub mae_pitch: f64,
    pub mae_yaw: f64,
    pub mae_roll: f64,
    pub mae_mean: f64,
    pub geodesic: f64,
    /// Mean of the three absolute errors per |yaw| bin (faces per bin alongside).
    pub mae_by_yaw: [f64; 3],
    pub faces_by_yaw: [usize; 3],
    /// (|true yaw|, mean absolute error) per face, for plots.
    #[serde(skip)]
    pub per_face: Vec<(f64, f64)>,
}

fn wrap(d: f64) -> f64 {
    (d + 180.0).rem_euclid(360.0) - 180.0
}

/// The landmarks of a face from a source, in the scheme the source is given in.
pub fn landmarks(face: &AflwFace, source: Source) -> crate::Result<(&'static str, Shape2)> {
    let to_shape =
        |pts: &[[f64; 2]]| Shape2::from_options(&pts.iter().map(|p| Some(*p)).collect::<Vec<_>>());
    match source {
        Source::Fitted => Ok(("ibug68", to_shape(&face.landmarks_fitted)?)),
        Source::Reannotated => Ok(("ibug68", to_shape(&face.landmarks_reannotated)?)),
        Source::Five => Ok((
            "five",
            to_shape(&face.landmarks_reannotated)?.to_five(&ibug68())?,
        )),
    }
}

/// Evaluates `method` on `source` over the `within_99` faces. A face the method cannot answer
/// counts as a failure (and is left out of the means).
pub fn evaluate(model: &PoseModel, faces: &[AflwFace], method: Method, source: Source) -> AflwRow {
    let mut row = AflwRow {
        method,
        source,
        faces: 0,
        failures: 0,
        mae_pitch: 0.0,
        mae_yaw: 0.0,
        mae_roll: 0.0,
        mae_mean: 0.0,
        geodesic: 0.0,
        mae_by_yaw: [0.0; 3],
        faces_by_yaw: [0; 3],
        per_face: Vec::new(),
    };
    for face in faces.iter().filter(|f| f.within_99) {
        let result =
            landmarks(face, source).and_then(|(scheme, lm)| estimate(model, scheme, &lm, method));
        let Ok(est) = result else {
            row.failures += 1;
            continue;
        };
        let a: EulerAngles = est.angles;
        let e = [
            wrap(a.pitch - face.pitch).abs(),
            wrap(a.yaw - face.yaw).abs(),
            wrap(a.roll - face.roll).abs(),
        ];
        let mean = (e[0] + e[1] + e[2]) / 3.0;
        row.faces += 1;
        row.mae_pitch += e[0];
        row.mae_yaw += e[1];
        row.mae_roll += e[2];
        if let Ok(truth) = rotation_from_rows(face.rotation, 1e-4) {
            row.geodesic += geodesic_deg(&est.rotation, &truth);
        }
        let b = YAW_BINS
            .iter()
            .position(|&(lo, hi)| face.yaw.abs() >= lo && face.yaw.abs() < hi)
            .unwrap_or(2);
        row.mae_by_yaw[b] += mean;
        row.faces_by_yaw[b] += 1;
        row.per_face.push((face.yaw.abs(), mean));
    }
    let n = row.faces.max(1) as f64;
    row.mae_pitch /= n;
    row.mae_yaw /= n;
    row.mae_roll /= n;
    row.mae_mean = (row.mae_pitch + row.mae_yaw + row.mae_roll) / 3.0;
    row.geodesic /= n;
    for b in 0..3 {
        row.mae_by_yaw[b] /= row.faces_by_yaw[b].max(1) as f64;
    }
    row
}

/// The rows as a Markdown table.
pub fn aflw_markdown(rows: &[AflwRow]) -> String {
    let mut s = String::from(
        "| method | landmarks | faces | failed | pitch | yaw | roll | **MAE** | geodesic | \\|yaw\\| 0-30 | 30-60 | 60-99 |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | **{:.2}** | {:.2} | {:.2} ({}) | {:.2} ({}) | {:.2} ({}) |\n",
            r.method,
            r.source.name(),
            r.faces,
            r.failures,
            r.mae_pitch,
            r.mae_yaw,
            r.mae_roll,
            r.mae_mean,
            r.geodesic,
            r.mae_by_yaw[0],
            r.faces_by_yaw[0],
            r.mae_by_yaw[1],
            r.faces_by_yaw[1],
            r.mae_by_yaw[2],
            r.faces_by_yaw[2]
        ));
    }
    s
}
