//! The uncertainty's calibration on real faces (AFLW2000-3D): fitting it
//! ([`calibrate_on_faces`], what `facepose train --calibrate` stores in a bundle) and measuring
//! it by cross-validation ([`cross_validate`]): the coverage of the 90% intervals, the rank
//! correlation between the predicted standard deviation and the actual error, and the
//! reliability by decile of the prediction.
//!
//! Cross-validation: the faces are split into [`FOLDS`] folds by their position among the
//! `within_99` faces (face `i` in fold `i mod FOLDS`); each fold's estimates, from every landmark
//! set of its faces, are predicted by a calibration fitted on the other folds' faces only, so
//! no face is ever predicted by a calibration that saw any landmark set of it.

use serde::Serialize;

use super::aflw::{Source, landmarks};
use super::plot::{Panel, Series};
use facepose_core::data::AflwFace;
use facepose_core::error::Result;
use facepose_core::model::PoseModel;
use facepose_core::pose::{Method, estimate};
use facepose_core::uncertainty::calibration::{Sample, calibrate};
use facepose_core::uncertainty::{Calibration, PointClass, Uncertainty};

/// Folds of the cross-validation.
pub const FOLDS: usize = 10;

/// The methods a calibration is fitted for (`auto` is one of them on each input).
pub const CALIBRATED_METHODS: [Method; 4] = [
    Method::Fit,
    Method::FitShape,
    Method::Regression,
    Method::Geometry,
];

/// One estimate of a face, with where it came from.
#[derive(Debug, Clone, Copy)]
pub struct Labeled {
    /// The face's position among the `within_99` faces.
    pub face: usize,
    /// The landmark set sent.
    pub source: Source,
    /// The method asked for (`auto` included).
    pub asked: Method,
    /// The estimate's calibration figures.
    pub sample: Sample,
}

/// The estimates of `methods` on `sources` over the `within_99` faces that give a raw spread.
pub fn samples(
    model: &PoseModel,
    faces: &[AflwFace],
    methods: &[Method],
    sources: &[Source],
) -> Vec<Labeled> {
    let mut out = Vec::new();
    for (face, f) in faces.iter().filter(|f| f.within_99).enumerate() {
        for &source in sources {
            let Ok((scheme, lm)) = landmarks(f, source) else {
                continue;
            };
            let points = model.subset(scheme).map_or(PointClass::Dense, |s| {
                PointClass::of_scheme(&s.scheme.name, s.scheme.len())
            });
            for &asked in methods {
                let Ok(e) = estimate(model, scheme, &lm, asked) else {
                    continue;
                };
                let Some(raw) = e.spread else { continue };
                out.push(Labeled {
                    face,
                    source,
                    asked,
                    sample: Sample {
                        method: e.method,
                        points,
                        raw,
                        estimate: [e.angles.pitch, e.angles.yaw, e.angles.roll],
                        truth: [f.pitch, f.yaw, f.roll],
                    },
                });
            }
        }
    }
    out
}

/// The landmark sets a calibration is fitted on: the human re-annotation (dense) and the two
/// five-point sets taken from it, which stand for what detectors give. The fitted set
/// (projections of the very 3DMM fit that defines the ground truth) is left out: its landmarks
/// look the same to every predictor (residual, misfit, spread) while its errors are a third as
/// large, so no one calibration serves both, and pooled they would leave intervals too narrow
/// for detector landmarks (docs/RESULTS.md). On fitted landmarks the intervals are then
/// conservative.
pub const CALIBRATION_SOURCES: [Source; 3] = [Source::Reannotated, Source::Five, Source::Dlib5];

/// The calibration of `model` on `faces`: [`CALIBRATED_METHODS`] on [`CALIBRATION_SOURCES`].
pub fn calibrate_on_faces(
    model: &PoseModel,
    faces: &[AflwFace],
    name: &str,
) -> Result<Calibration> {
    let s = samples(model, faces, &CALIBRATED_METHODS, &CALIBRATION_SOURCES);
    let n = faces.iter().filter(|f| f.within_99).count();
    calibrate(
        &fitting(&s),
        &format!(
            "{name}: {n} faces with every |angle| <= 99°, landmark sets reannotated (dense), \
             five and dlib5 from it"
        ),
    )
}

/// The samples a calibration is fitted on: those of [`CALIBRATION_SOURCES`]; `auto`'s are the
/// same estimates as the method it resolves to, so they are left out rather than counted twice.
fn fitting(labeled: &[Labeled]) -> Vec<Sample> {
    labeled
        .iter()
        .filter(|l| l.asked != Method::Auto && CALIBRATION_SOURCES.contains(&l.source))
        .map(|l| l.sample)
        .collect()
}

/// Each estimate's uncertainty from a calibration fitted on the other folds (see the module
/// docs); `None` where that calibration has no group for it.
pub fn cross_validate(labeled: &[Labeled]) -> Result<Vec<Option<Uncertainty>>> {
    let mut out = vec![None; labeled.len()];
    for fold in 0..FOLDS {
        let train: Vec<Labeled> = labeled
            .iter()
            .filter(|l| l.face % FOLDS != fold)
            .copied()
            .collect();
        let cal = calibrate(&fitting(&train), "fold")?;
        for (i, l) in labeled.iter().enumerate() {
            if l.face % FOLDS == fold {
                let s = &l.sample;
                out[i] = cal.uncertainty(s.method, s.points, &s.raw, s.estimate);
            }
        }
    }
    Ok(out)
}

/// Calibration figures of one method on one landmark set, per angle (pitch, yaw, roll).
#[derive(Debug, Clone, Serialize)]
pub struct CoverageRow {
    /// The method.
    pub method: Method,
    /// The landmark set.
    pub source: Source,
    /// Estimates with an uncertainty.
    pub estimates: usize,
    /// Share of the estimates whose true angle is inside the 90% interval.
    pub coverage: [f64; 3],
    /// Mean predicted standard deviation, degrees.
    pub mean_sd: [f64; 3],
    /// Mean absolute error, degrees.
    pub mae: [f64; 3],
    /// Spearman's rank correlation between the predicted standard deviation and the absolute
    /// error.
    pub spearman: [f64; 3],
}

/// Whether the true angle `k` of `s` is inside `u`'s interval (wrapped to ±180°).
fn covered(s: &Sample, u: &Uncertainty, k: usize) -> bool {
    s.error(k) <= u.half_width(k)
}

/// The rows of [`CoverageRow`], one per (asked method, source) that has predictions, in the
/// order of `methods` and `sources`.
pub fn coverage_rows(
    labeled: &[Labeled],
    predicted: &[Option<Uncertainty>],
    methods: &[Method],
    sources: &[Source],
) -> Vec<CoverageRow> {
    let mut rows = Vec::new();
    for &method in methods {
        for &source in sources {
            let pairs: Vec<(&Sample, &Uncertainty)> = labeled
                .iter()
                .zip(predicted)
                .filter(|(l, _)| l.asked == method && l.source == source)
                .filter_map(|(l, u)| u.as_ref().map(|u| (&l.sample, u)))
                .collect();
            if pairs.is_empty() {
                continue;
            }
            let n = pairs.len() as f64;
            let per = |f: &dyn Fn(&Sample, &Uncertainty, usize) -> f64| {
                [0, 1, 2].map(|k| pairs.iter().map(|(s, u)| f(s, u, k)).sum::<f64>() / n)
            };
            rows.push(CoverageRow {
                method,
                source,
                estimates: pairs.len(),
                coverage: per(&|s, u, k| f64::from(u8::from(covered(s, u, k)))),
                mean_sd: per(&|_, u, k| u.sd[k]),
                mae: per(&|s, _, k| s.error(k)),
                spearman: [0, 1, 2].map(|k| {
                    let (a, b): (Vec<f64>, Vec<f64>) =
                        pairs.iter().map(|(s, u)| (u.sd[k], s.error(k))).unzip();
                    spearman(&a, &b)
                }),
            });
        }
    }
    rows
}

/// Ranks (1-based, ties averaged).
fn ranks(v: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut r = vec![0.0; v.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && v[idx[j + 1]] == v[idx[i]] {
            j += 1;
        }
        let rank = 0.5 * (i + j) as f64 + 1.0;
        for &k in &idx[i..=j] {
            r[k] = rank;
        }
        i = j + 1;
    }
    r
}

/// Spearman's rank correlation (NaN for fewer than two values or no spread).
pub fn spearman(a: &[f64], b: &[f64]) -> f64 {
    let (ra, rb) = (ranks(a), ranks(b));
    let n = ra.len() as f64;
    if ra.len() < 2 {
        return f64::NAN;
    }
    let (ma, mb) = (ra.iter().sum::<f64>() / n, rb.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in ra.iter().zip(&rb) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}

/// One decile of the predicted standard deviation.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ReliabilityBin {
    /// (estimate, angle) pairs in the bin.
    pub estimates: usize,
    /// Mean predicted standard deviation, degrees.
    pub predicted_sd: f64,
    /// Root mean square of the actual errors, degrees: a calibrated prediction equals it.
    pub observed_rms: f64,
    /// Share inside the 90% interval.
    pub coverage: f64,
}

/// The reliability of `method` on `source`: its (estimate, angle) pairs in ten bins by predicted
/// standard deviation, the three angles pooled.
pub fn reliability(
    labeled: &[Labeled],
    predicted: &[Option<Uncertainty>],
    method: Method,
    source: Source,
) -> Vec<ReliabilityBin> {
    let mut pts: Vec<(f64, f64, bool)> = labeled
        .iter()
        .zip(predicted)
        .filter(|(l, _)| l.asked == method && l.source == source)
        .filter_map(|(l, u)| u.as_ref().map(|u| (&l.sample, u)))
        .flat_map(|(s, u)| (0..3).map(move |k| (u.sd[k], s.error(k), covered(s, u, k))))
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = pts.len();
    (0..10)
        .filter_map(|d| {
            let bin = &pts[d * n / 10..(d + 1) * n / 10];
            (!bin.is_empty()).then(|| {
                let m = bin.len() as f64;
                ReliabilityBin {
                    estimates: bin.len(),
                    predicted_sd: bin.iter().map(|p| p.0).sum::<f64>() / m,
                    observed_rms: (bin.iter().map(|p| p.1 * p.1).sum::<f64>() / m).sqrt(),
                    coverage: bin.iter().filter(|p| p.2).count() as f64 / m,
                }
            })
        })
        .collect()
}

fn pct(v: f64) -> String {
    format!("{:.1}%", 100.0 * v)
}

/// The coverage table.
pub fn coverage_markdown(rows: &[CoverageRow]) -> String {
    let mut out = String::from(
        "| method | landmarks | estimates | coverage pitch | yaw | roll | mean sd pitch / yaw / roll | MAE pitch / yaw / roll | Spearman ρ(sd, \\|error\\|) pitch / yaw / roll |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let three = |v: [f64; 3], d: usize| v.map(|x| format!("{x:.d$}")).join(" / ");
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.method,
            r.source.name(),
            r.estimates,
            pct(r.coverage[0]),
            pct(r.coverage[1]),
            pct(r.coverage[2]),
            three(r.mean_sd, 2),
            three(r.mae, 2),
            three(r.spearman, 2),
        ));
    }
    out
}

/// The reliability table of several (label, bins).
pub fn reliability_markdown(curves: &[(String, Vec<ReliabilityBin>)]) -> String {
    let mut out = String::from(
        "| method, landmarks | decile | estimates × angles | predicted sd | observed RMS error | coverage |\n\
         |---|---|---|---|---|---|\n",
    );
    for (label, bins) in curves {
        for (d, b) in bins.iter().enumerate() {
            out.push_str(&format!(
                "| {label} | {} | {} | {:.2} | {:.2} | {} |\n",
                d + 1,
                b.estimates,
                b.predicted_sd,
                b.observed_rms,
                pct(b.coverage)
            ));
        }
    }
    out
}

/// A reliability plot: observed RMS error against predicted standard deviation per decile, one
/// panel per curve, with the diagonal a calibrated prediction follows.
pub fn reliability_panels(curves: &[(String, Vec<ReliabilityBin>)]) -> Vec<Panel> {
    curves
        .iter()
        .map(|(label, bins)| {
            let top = bins
                .iter()
                .map(|b| b.predicted_sd.max(b.observed_rms))
                .fold(0.0, f64::max);
            Panel {
                title: label.clone(),
                x_label: "predicted sd (°)".into(),
                y_label: "observed RMS error (°)".into(),
                series: vec![
                    Series {
                        name: "deciles of the prediction".into(),
                        points: bins
                            .iter()
                            .map(|b| (b.predicted_sd, b.observed_rms))
                            .collect(),
                    },
                    Series {
                        name: "calibrated (y = x)".into(),
                        points: vec![(0.0, 0.0), (top, top)],
                    },
                ],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spearman_of_monotone_and_reversed() {
        let a = [1.0, 2.0, 3.0, 4.0, 5.0];
        let b = [10.0, 20.0, 25.0, 100.0, 1000.0];
        assert!((spearman(&a, &b) - 1.0).abs() < 1e-12);
        let c: Vec<f64> = b.iter().rev().copied().collect();
        assert!((spearman(&a, &c) + 1.0).abs() < 1e-12);
        // Ties share their mean rank.
        assert_eq!(ranks(&[3.0, 1.0, 3.0]), vec![2.5, 1.0, 2.5]);
    }
}
