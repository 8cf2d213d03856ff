//! Evaluation on real faces with ground-truth pose (AFLW2000-3D JSON Lines): for each method and
//! landmark source, the mean absolute error of pitch, yaw and roll (and their mean, the figure
//! papers report), the mean geodesic error, and the mean error per |yaw| bin, over the faces with
//! every |angle| <= 99° (`within_99`).

use serde::Serialize;

use facepose_core::data::AflwFace;
use facepose_core::geometry::convention::wrap_deg;
use facepose_core::geometry::{EulerAngles, geodesic_deg, rotation_from_rows};
use facepose_core::model::PoseModel;
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::{DLIB5_IN_IBUG68, Shape2, ibug68};

/// Where the landmarks come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// `landmarks_fitted`: projections of a 3DMM fit (jaw points are fixed 3D vertices).
    Fitted,
    /// `landmarks_reannotated`: human re-annotation. In 3D style, although the data's README
    /// says otherwise: hidden points, the far half of the jaw included, are placed where they
    /// would project, not on the visible outline (docs/RESULTS.md shows both sets at large yaw).
    Reannotated,
    /// Five points (eye centres, nose tip, mouth corners) derived from the re-annotated ones.
    Five,
    /// dlib's five points (eye corners, nose base: scheme `dlib5`), the re-annotated ones'
    /// points 45, 42, 36, 39 and 33.
    Dlib5,
    /// Diagnostic: the re-annotated landmarks with the 17 jaw points of the fitted set, which
    /// are consistent with the ground truth's own 3DMM fit. Shows how much of the error on
    /// re-annotated landmarks comes from the jaw annotation disagreeing with that fit.
    ReannotatedFittedJaw,
}

impl Source {
    /// The sources of the benchmark tables (the diagnostic one left out).
    pub const ALL: [Source; 4] = [
        Source::Fitted,
        Source::Reannotated,
        Source::Five,
        Source::Dlib5,
    ];

    /// The source's name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Source::Fitted => "fitted",
            Source::Reannotated => "reannotated",
            Source::Five => "five (from reannotated)",
            Source::Dlib5 => "dlib5 (from reannotated)",
            Source::ReannotatedFittedJaw => "reannotated, jaw from fitted (diagnostic)",
        }
    }
}

/// Upper edges of the |yaw| bins.
pub const YAW_BINS: [(f64, f64); 3] = [(0.0, 30.0), (30.0, 60.0), (60.0, 99.0)];

/// One row: a method on a source.
#[derive(Debug, Clone, Serialize)]
pub struct AflwRow {
    /// The method.
    pub method: Method,
    /// The landmark set sent.
    pub source: Source,
    /// Faces evaluated.
    pub faces: usize,
    /// Faces the method failed on (excluded from the errors).
    pub failures: usize,
    /// Mean absolute pitch error, degrees.
    pub mae_pitch: f64,
    /// Mean absolute yaw error, degrees.
    pub mae_yaw: f64,
    /// Mean absolute roll error, degrees.
    pub mae_roll: f64,
    /// Mean of the three mean absolute errors, degrees.
    pub mae_mean: f64,
    /// Mean geodesic error (angle of `R_estimateᵀ R_true`), degrees.
    pub geodesic: f64,
    /// Mean of the three absolute errors per |yaw| bin (faces per bin alongside).
    pub mae_by_yaw: [f64; 3],
    /// Faces per |yaw| bin.
    pub faces_by_yaw: [usize; 3],
    /// (|true yaw|, mean absolute error) per face, for plots.
    #[serde(skip)]
    pub per_face: Vec<(f64, f64)>,
    /// (estimated, true) pitch, yaw and roll per face, degrees.
    #[serde(skip)]
    pub angles: Vec<([f64; 3], [f64; 3])>,
}

static IBUG68: std::sync::LazyLock<facepose_core::shape::Scheme> = std::sync::LazyLock::new(ibug68);

/// The landmarks of a face from a source, in the scheme the source is given in.
pub fn landmarks(face: &AflwFace, source: Source) -> facepose_core::Result<(&'static str, Shape2)> {
    let to_shape =
        |pts: &[[f64; 2]]| Shape2::from_options(&pts.iter().map(|p| Some(*p)).collect::<Vec<_>>());
    match source {
        Source::Fitted => Ok(("ibug68", to_shape(&face.landmarks_fitted)?)),
        Source::Reannotated => Ok(("ibug68", to_shape(&face.landmarks_reannotated)?)),
        Source::ReannotatedFittedJaw => {
            let mut pts = face.landmarks_reannotated.clone();
            if pts.len() == 68 && face.landmarks_fitted.len() == 68 {
                pts[..17].copy_from_slice(&face.landmarks_fitted[..17]);
            }
            Ok(("ibug68", to_shape(&pts)?))
        }
        Source::Five => Ok((
            "five",
            to_shape(&face.landmarks_reannotated)?.to_five(&IBUG68)?,
        )),
        Source::Dlib5 => {
            let pts = &face.landmarks_reannotated;
            if pts.len() != IBUG68.len() {
                return Err(facepose_core::Error::PointCount {
                    what: "re-annotated landmarks".into(),
                    expected: IBUG68.len(),
                    got: pts.len(),
                });
            }
            Ok(("dlib5", to_shape(&DLIB5_IN_IBUG68.map(|i| pts[i]))?))
        }
    }
}

/// Evaluates `method` on `source` over the `within_99` faces. A face the method cannot answer
/// counts as a failure (and is left out of the means).
pub fn evaluate(model: &PoseModel, faces: &[AflwFace], method: Method, source: Source) -> AflwRow {
    let mut geodesic_faces = 0usize;
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
        angles: Vec::new(),
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
            wrap_deg(a.pitch - face.pitch).abs(),
            wrap_deg(a.yaw - face.yaw).abs(),
            wrap_deg(a.roll - face.roll).abs(),
        ];
        let mean = (e[0] + e[1] + e[2]) / 3.0;
        row.faces += 1;
        row.mae_pitch += e[0];
        row.mae_yaw += e[1];
        row.mae_roll += e[2];
        if let Ok(truth) = rotation_from_rows(face.rotation, 1e-4) {
            row.geodesic += geodesic_deg(&est.rotation, &truth);
            geodesic_faces += 1;
        }
        let b = YAW_BINS
            .iter()
            .position(|&(lo, hi)| face.yaw.abs() >= lo && face.yaw.abs() < hi)
            .unwrap_or(2);
        row.mae_by_yaw[b] += mean;
        row.faces_by_yaw[b] += 1;
        row.per_face.push((face.yaw.abs(), mean));
        row.angles
            .push(([a.pitch, a.yaw, a.roll], [face.pitch, face.yaw, face.roll]));
    }
    let n = row.faces.max(1) as f64;
    row.mae_pitch /= n;
    row.mae_yaw /= n;
    row.mae_roll /= n;
    row.mae_mean = (row.mae_pitch + row.mae_yaw + row.mae_roll) / 3.0;
    row.geodesic /= geodesic_faces.max(1) as f64;
    for b in 0..3 {
        row.mae_by_yaw[b] /= row.faces_by_yaw[b].max(1) as f64;
    }
    row
}

/// How an estimate relates to the truth, per axis (pitch, yaw, roll), by least squares over the
/// faces of a row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Slope of the estimate regressed on the truth: below 1, the estimates are compressed.
    pub estimate_on_truth: f64,
    /// Slope of the truth regressed on the estimate: 1 when the errors are uncorrelated with the
    /// estimate, so that no rescaling of the estimate lowers them.
    pub truth_on_estimate: f64,
    /// Correlation of estimate and truth.
    pub correlation: f64,
    /// Mean absolute error after the affine correction of the estimate (`a + b · estimate`)
    /// with the least mean absolute error on these same faces (least absolute deviations): the
    /// floor of any affine recalibration, fitted in-sample, so optimistic.
    pub mae_recalibrated: f64,
}

/// [`Calibration`] of each axis of `row` (None for fewer than 3 faces or no spread).
pub fn calibration(row: &AflwRow) -> Option<[Calibration; 3]> {
    let axis = |k: usize| {
        let pairs: Vec<(f64, f64)> = row.angles.iter().map(|(e, t)| (e[k], t[k])).collect();
        if pairs.len() < 3 {
            return None;
        }
        let n = pairs.len() as f64;
        let me = pairs.iter().map(|p| p.0).sum::<f64>() / n;
        let mt = pairs.iter().map(|p| p.1).sum::<f64>() / n;
        let (mut see, mut stt, mut set) = (0.0, 0.0, 0.0);
        for (e, t) in &pairs {
            let (de, dt) = (e - me, t - mt);
            see += de * de;
            stt += dt * dt;
            set += de * dt;
        }
        if see <= 0.0 || stt <= 0.0 {
            return None;
        }
        let mae_recalibrated = least_absolute_deviations(&pairs);
        Some(Calibration {
            estimate_on_truth: set / stt,
            truth_on_estimate: set / see,
            correlation: set / (see * stt).sqrt(),
            mae_recalibrated,
        })
    };
    Some([axis(0)?, axis(1)?, axis(2)?])
}

/// The least mean absolute error of `a + b · estimate` against the truth over `(estimate,
/// truth)` pairs (wrapped angle differences): iteratively reweighted least squares from the
/// least-squares line, weights `1 / max(|residual|, 1e-6)`, keeping the best line seen.
fn least_absolute_deviations(pairs: &[(f64, f64)]) -> f64 {
    let mae = |a: f64, b: f64| {
        pairs
            .iter()
            .map(|&(e, t)| wrap_deg(a + b * e - t).abs())
            .sum::<f64>()
            / pairs.len() as f64
    };
    let mut w = vec![1.0; pairs.len()];
    let mut best = f64::INFINITY;
    for _ in 0..100 {
        let sw: f64 = w.iter().sum();
        let me = pairs.iter().zip(&w).map(|(p, w)| w * p.0).sum::<f64>() / sw;
        let mt = pairs.iter().zip(&w).map(|(p, w)| w * p.1).sum::<f64>() / sw;
        let (mut see, mut set) = (0.0, 0.0);
        for ((e, t), wi) in pairs.iter().zip(&w) {
            see += wi * (e - me) * (e - me);
            set += wi * (e - me) * (t - mt);
        }
        if see <= 0.0 {
            break;
        }
        let b = set / see;
        let a = mt - b * me;
        best = best.min(mae(a, b));
        for ((e, t), wi) in pairs.iter().zip(w.iter_mut()) {
            *wi = 1.0 / (a + b * e - t).abs().max(1e-6);
        }
    }
    best.min(mae(0.0, 1.0))
}

/// The calibration of `rows` as a Markdown table, one line per row and axis.
pub fn calibration_markdown(rows: &[&AflwRow]) -> String {
    let mut s = String::from(
        "| method | landmarks | axis | MAE | slope of estimate on truth | slope of truth on estimate | correlation | MAE after the best affine correction (in-sample) |\n|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let Some(cal) = calibration(r) else { continue };
        let mae = [r.mae_pitch, r.mae_yaw, r.mae_roll];
        for (k, axis) in ["pitch", "yaw", "roll"].iter().enumerate() {
            let c = cal[k];
            s.push_str(&format!(
                "| {} | {} | {axis} | {:.2} | {:.3} | {:.3} | {:.3} | {:.2} |\n",
                r.method,
                r.source.name(),
                mae[k],
                c.estimate_on_truth,
                c.truth_on_estimate,
                c.correlation,
                c.mae_recalibrated
            ));
        }
    }
    s
}

/// |true yaw| bins of [`gimbal_markdown`], degrees: the last ones close to 90°, where pitch
/// and roll stop being separable.
pub const GIMBAL_BINS: [(f64, f64); 4] = [(0.0, 30.0), (30.0, 60.0), (60.0, 80.0), (80.0, 99.0)];

/// One |true yaw| bin of a row: how the Euler-angle error compares with the geodesic one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GimbalBin {
    /// Faces in the bin.
    pub faces: usize,
    /// Mean over the faces of the mean of the three absolute angle errors, degrees.
    pub mae: f64,
    /// Mean angle of `R_estimateᵀ R_true`, degrees.
    pub geodesic: f64,
    /// This bin's part of the row's MAE: its summed face errors over all faces, degrees.
    pub share: f64,
}

/// The row's errors per [`GIMBAL_BINS`] bin, from its per-face angles. Near |yaw| 90° a
/// rotation error of a few degrees moves pitch and roll by tens (only pitch - roll, or
/// pitch + roll, is determined there), so the MAE grows much faster than the geodesic error.
pub fn gimbal_bins(row: &AflwRow) -> [GimbalBin; 4] {
    let mut bins = [GimbalBin {
        faces: 0,
        mae: 0.0,
        geodesic: 0.0,
        share: 0.0,
    }; 4];
    let rotation = |a: [f64; 3]| {
        EulerAngles {
            pitch: a[0],
            yaw: a[1],
            roll: a[2],
        }
        .to_rotation()
    };
    for &(est, truth) in &row.angles {
        let mean = (0..3)
            .map(|k| wrap_deg(est[k] - truth[k]).abs())
            .sum::<f64>()
            / 3.0;
        let b = GIMBAL_BINS
            .iter()
            .position(|&(lo, hi)| truth[1].abs() >= lo && truth[1].abs() < hi)
            .unwrap_or(GIMBAL_BINS.len() - 1);
        bins[b].faces += 1;
        bins[b].mae += mean;
        bins[b].geodesic += geodesic_deg(&rotation(est), &rotation(truth));
    }
    let total = row.angles.len().max(1) as f64;
    for b in &mut bins {
        b.share = b.mae / total;
        let n = b.faces.max(1) as f64;
        b.mae /= n;
        b.geodesic /= n;
    }
    bins
}

/// [`gimbal_bins`] of `rows` as a Markdown table, one line per row and bin.
pub fn gimbal_markdown(rows: &[&AflwRow]) -> String {
    let mut s = String::from(
        "| method | landmarks | \\|true yaw\\| | faces | MAE | geodesic | MAE / geodesic | part of the row's MAE |\n|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        for (b, &(lo, hi)) in gimbal_bins(r).iter().zip(&GIMBAL_BINS) {
            if b.faces == 0 {
                continue;
            }
            s.push_str(&format!(
                "| {} | {} | {lo:.0}-{hi:.0} | {} | {:.2} | {:.2} | {:.1} | {:.2} of {:.2} |\n",
                r.method,
                r.source.name(),
                b.faces,
                b.mae,
                b.geodesic,
                b.mae / b.geodesic.max(1e-9),
                b.share,
                r.mae_mean
            ));
        }
    }
    s
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

/// Width of the |yaw| bins of [`error_by_yaw`], degrees.
pub const CURVE_BIN: f64 = 10.0;

/// The plot of error against yaw: one panel per landmark source, one line per method, the
/// mean of the three absolute errors per 10° bin of |true yaw| (at the bin centre; bins with
/// fewer than 3 faces left out).
pub fn error_by_yaw(rows: &[AflwRow]) -> Vec<super::plot::Panel> {
    let mut sources: Vec<Source> = Vec::new();
    for r in rows {
        if !sources.contains(&r.source) {
            sources.push(r.source);
        }
    }
    sources
        .into_iter()
        .map(|s| super::plot::Panel {
            title: format!("landmarks: {}", s.name()),
            x_label: "|true yaw| (°)".into(),
            y_label: "MAE of pitch, yaw, roll (°)".into(),
            series: rows
                .iter()
                .filter(|r| r.source == s)
                .map(|r| {
                    let nb = (99.0 / CURVE_BIN).ceil() as usize;
                    let mut sum = vec![(0.0, 0usize); nb];
                    for &(y, e) in &r.per_face {
                        let b = ((y / CURVE_BIN) as usize).min(nb - 1);
                        sum[b].0 += e;
                        sum[b].1 += 1;
                    }
                    super::plot::Series {
                        name: r.method.to_string(),
                        points: sum
                            .iter()
                            .enumerate()
                            .filter(|(_, (_, n))| *n >= 3)
                            .map(|(b, (e, n))| ((b as f64 + 0.5) * CURVE_BIN, e / *n as f64))
                            .collect(),
                    }
                })
                .collect(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use facepose_core::geometry::{WeakPerspective, rotation_rows};
    use facepose_core::model::default_model;
    use nalgebra::Vector2;

    /// A row over no faces, for tests that set its per-face angles.
    fn empty_row() -> AflwRow {
        evaluate(
            &default_model().unwrap().1,
            &[],
            Method::Fit,
            Source::Fitted,
        )
    }

    #[test]
    fn calibration_of_known_lines() {
        let mut row = empty_row();
        // Pitch estimates half the truth plus 1; yaw exact; roll the truth plus scatter that
        // is independent of it (alternating ±2 over a symmetric design).
        let truth = [-20.0, -10.0, 10.0, 20.0];
        let scatter = [2.0, -2.0, -2.0, 2.0];
        row.angles = truth
            .iter()
            .zip(scatter)
            .map(|(&t, d)| ([0.5 * t + 1.0, t, t + d], [t, t, t]))
            .collect();
        let c = calibration(&row).unwrap();
        assert!((c[0].estimate_on_truth - 0.5).abs() < 1e-12);
        assert!((c[0].truth_on_estimate - 2.0).abs() < 1e-12);
        assert!((c[0].correlation - 1.0).abs() < 1e-12);
        assert!(c[0].mae_recalibrated < 1e-12);
        assert!((c[1].truth_on_estimate - 1.0).abs() < 1e-12);
        // Scatter uncorrelated with the truth: the estimate on truth slope stays 1 and the
        // correction cannot remove it all.
        assert!((c[2].estimate_on_truth - 1.0).abs() < 1e-12);
        assert!(c[2].mae_recalibrated > 1.0);
        // One outlier: least squares would tilt the line (and raise the MAE to 2.4); the least
        // absolute deviations keep the identity, MAE 2.
        row.angles = [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0), (3.0, 3.0), (4.0, 14.0)]
            .map(|(e, t)| ([e, e, e], [t, t, t]))
            .to_vec();
        let c = calibration(&row).unwrap();
        assert!((c[0].mae_recalibrated - 2.0).abs() < 1e-3, "{:?}", c[0]);
        row.angles.truncate(2);
        assert!(calibration(&row).is_none());
    }

    #[test]
    fn near_90_degrees_of_yaw_the_euler_error_outgrows_the_geodesic_one() {
        let mut row = empty_row();
        // Frontal: 3° of pitch only, so MAE 1 and geodesic 3. At yaw 85°: pitch and roll
        // both 20° off in opposite directions, which is nearly the same rotation.
        let near = EulerAngles::new(85.0, 20.0, 20.0).unwrap().to_rotation();
        let far = EulerAngles::new(85.0, 0.0, 0.0).unwrap().to_rotation();
        let g = geodesic_deg(&near, &far);
        assert!(g < 4.0, "{g}");
        row.angles = vec![
            ([3.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            ([20.0, 85.0, 20.0], [0.0, 85.0, 0.0]),
        ];
        let bins = gimbal_bins(&row);
        assert_eq!(bins.map(|b| b.faces), [1, 0, 0, 1]);
        assert!((bins[0].mae - 1.0).abs() < 1e-12 && (bins[0].geodesic - 3.0).abs() < 1e-9);
        assert!((bins[3].mae - 40.0 / 3.0).abs() < 1e-12);
        assert!((bins[3].geodesic - g).abs() < 1e-9);
        // The shares add up to the mean of the face errors.
        let total: f64 = bins.iter().map(|b| b.share).sum();
        assert!((total - (1.0 + 40.0 / 3.0) / 2.0).abs() < 1e-12);
        let table = gimbal_markdown(&[&row]);
        assert_eq!(table.lines().count(), 4, "{table}");
        assert!(table.contains("| 80-99 | 1 | 13.33 |"), "{table}");
    }

    /// A face whose landmarks are the default model's mean seen at a known pose.
    fn face(model: &PoseModel, yaw: f64, pitch: f64, roll: f64) -> AflwFace {
        let a = EulerAngles::new(yaw, pitch, roll).unwrap();
        let cam = WeakPerspective::new(a.to_rotation(), 1.6, Vector2::new(225.0, -226.0)).unwrap();
        let pts: Vec<[f64; 2]> = model
            .mean
            .iter()
            .map(|x| {
                let p = cam.project(x);
                [p.x, p.y]
            })
            .collect();
        AflwFace {
            image: format!("synthetic_{yaw}_{pitch}_{roll}"),
            pitch,
            yaw,
            roll,
            rotation: rotation_rows(&a.to_rotation()),
            within_99: true,
            landmarks_fitted: pts.clone(),
            landmarks_reannotated: pts,
        }
    }

    #[test]
    fn faces_made_from_a_known_pose_give_no_error() {
        let (_, model) = default_model().unwrap();
        let mut faces = vec![
            face(&model, 10.0, -5.0, 3.0),
            face(&model, -40.0, 15.0, -8.0),
            face(&model, 70.0, 5.0, 0.0),
        ];
        faces.push(AflwFace {
            within_99: false,
            ..face(&model, 120.0, 0.0, 0.0)
        });
        for source in [Source::Fitted, Source::Reannotated] {
            let row = evaluate(&model, &faces, Method::Fit, source);
            assert_eq!(
                (row.faces, row.failures),
                (3, 0),
                "the 4th face is not within_99"
            );
            assert!(row.mae_mean < 1e-6 && row.geodesic < 1e-6, "{row:?}");
            assert_eq!(row.faces_by_yaw, [1, 1, 1]);
            assert_eq!(row.per_face.len(), 3);
        }
        let panels = error_by_yaw(&[evaluate(&model, &faces, Method::Fit, Source::Fitted)]);
        assert_eq!(panels.len(), 1);
        // Bins need 3 faces: one face per bin here, so no points.
        assert!(panels[0].series[0].points.is_empty());
    }

    #[test]
    fn the_yaw_curve_averages_per_bin() {
        let row = AflwRow {
            method: Method::Fit,
            source: Source::Five,
            faces: 7,
            failures: 0,
            mae_pitch: 0.0,
            mae_yaw: 0.0,
            mae_roll: 0.0,
            mae_mean: 0.0,
            geodesic: 0.0,
            mae_by_yaw: [0.0; 3],
            faces_by_yaw: [0; 3],
            angles: Vec::new(),
            per_face: vec![
                (1.0, 1.0),
                (5.0, 2.0),
                (9.9, 3.0),
                (42.0, 4.0),
                (45.0, 6.0),
                (48.0, 8.0),
                (98.0, 1.0),
            ],
        };
        let p = &error_by_yaw(&[row])[0];
        assert_eq!(p.series[0].points, vec![(5.0, 2.0), (45.0, 6.0)]);
    }
}

/// The misfit ([`facepose_core::pose::Estimate::misfit`]) of real faces, per source and method: the
/// figures behind the "does it look like a face" thresholds.
#[derive(Debug, Clone, Serialize)]
pub struct MisfitRow {
    /// The landmark set sent.
    pub source: Source,
    /// The method.
    pub method: Method,
    /// Faces evaluated.
    pub faces: usize,
    /// Median misfit.
    pub p50: f64,
    /// 99th percentile of the misfit.
    pub p99: f64,
    /// Largest misfit.
    pub max: f64,
    /// Faces whose answer carries a warning, or that were refused as not a face.
    pub flagged: usize,
}

/// [`MisfitRow`]s over every face (not only `within_99`): each of `sources` with each of
/// `methods`.
pub fn misfits(
    model: &PoseModel,
    faces: &[AflwFace],
    sources: &[Source],
    methods: &[Method],
) -> Vec<MisfitRow> {
    let mut rows = Vec::new();
    for &source in sources {
        for &method in methods {
            let (mut m, mut flagged) = (Vec::new(), 0);
            for face in faces {
                let Ok((scheme, lm)) = landmarks(face, source) else {
                    continue;
                };
                match estimate(model, scheme, &lm, method) {
                    Ok(e) => {
                        flagged += usize::from(!e.warnings.is_empty());
                        m.push(e.misfit);
                    }
                    Err(facepose_core::Error::NotAFace { misfit, .. }) => {
                        flagged += 1;
                        m.push(misfit);
                    }
                    Err(_) => {}
                }
            }
            if m.is_empty() {
                continue; // a method the scheme does not serve (geometry on dlib5)
            }
            m.sort_by(f64::total_cmp);
            let q = |p: f64| {
                m.get(((m.len().max(1) - 1) as f64 * p).round() as usize)
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            rows.push(MisfitRow {
                source,
                method,
                faces: m.len(),
                p50: q(0.5),
                p99: q(0.99),
                max: q(1.0),
                flagged,
            });
        }
    }
    rows
}

/// The misfit rows as a Markdown table.
pub fn misfit_markdown(rows: &[MisfitRow]) -> String {
    let mut s = String::from(
        "| landmarks | method | faces | misfit p50 | p99 | max | warned or refused |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {} |\n",
            r.source.name(),
            r.method,
            r.faces,
            r.p50,
            r.p99,
            r.max,
            r.flagged
        ));
    }
    s
}
