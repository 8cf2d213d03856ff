//! Training the detector regression of the default model ([`facepose_core::estimate::detector`])
//! on the rendered benchmark's `train` identities (`tests/fixtures/rendered/`), and the
//! calibration of its uncertainty on the answers of its leave-one-identity-out folds, so that
//! no interval is fitted on the answers it is scored on. The `test` identities are never read
//! here: `facepose eval --protocol rendered` scores the result on them.
//!
//! Only MediaPipe's 478 points are trained: on dlib's 68 points (`landmark_style: contour`) a
//! regression trained the same way would also answer AFLW2000-3D's re-annotated landmarks,
//! which arrive with the same scheme and style and which it was not trained for, and on five
//! points it measured worse than the rigid fit (docs/RESULTS.md).

use std::collections::BTreeSet;

use facepose_core::data::RenderedRecord;
use facepose_core::error::Result;
use facepose_core::estimate::detector::{DetectorRegression, DetectorSample, fit};
use facepose_core::model::PoseModel;
use facepose_core::model::mesh::MEDIAPIPE478;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::uncertainty::PointClass;
use facepose_core::uncertainty::calibration::{CalibrationGroup, Sample, fit_group};

use crate::rendered::{Detector, landmarks, truth_angles, truth_rotation};

/// The split whose identities the regression is trained on.
pub const TRAIN_SPLIT: &str = "train";

/// The detector the regression reads, for people.
pub const MEDIAPIPE_DETECTOR: &str = "MediaPipe 0.10.14 Face Mesh (refine_landmarks, 478 points), \
                                      image_size given";

/// The regression of MediaPipe's 478 points trained on `records`' `train` identities, and the
/// calibration group of method `detector` fitted on its folds' answers. `data` names the
/// records for people. `model` answers with each fold's regression in turn and is given back
/// with the detector regressions it had.
pub fn train_mediapipe(
    model: &mut PoseModel,
    records: &[RenderedRecord],
    data: &str,
) -> Result<(DetectorRegression, CalibrationGroup)> {
    let train: Vec<&RenderedRecord> = records.iter().filter(|r| r.split == TRAIN_SPLIT).collect();
    let identities: Vec<String> = train
        .iter()
        .map(|r| r.identity.clone())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let mut samples = Vec::new();
    let mut used = Vec::new();
    let rigid = EstimateOptions {
        method: Method::Fit,
        camera: None,
        style: LandmarkStyle::Projected,
    };
    for r in &train {
        if let Some((_, lm, _)) = landmarks(r, Detector::Mediapipe478) {
            let group = identities.binary_search(&r.identity).unwrap_or(0);
            // The reference the regression de-rolls by: the served rigid fit's rotation.
            let reference = estimate_with(model, MEDIAPIPE478, &lm, &rigid)?.rotation;
            samples.push(DetectorSample {
                landmarks: lm,
                reference,
                rotation: truth_rotation(r),
                group,
            });
            used.push(*r);
        }
    }
    let data = format!(
        "{data}: split {TRAIN_SPLIT}, {} renders where MediaPipe found the face (every set, both \
         geometries)",
        samples.len()
    );
    let fitted = fit(
        MEDIAPIPE478,
        MEDIAPIPE_DETECTOR,
        &data,
        &identities,
        &samples,
    )?;
    // Each sample answered by the fold that did not see its identity, through the estimator
    // itself, so that the raw spread and misfit are the served ones; the model gets back the
    // regressions it had whatever happens.
    let had = std::mem::take(&mut model.detectors);
    let cal = fold_samples(model, &fitted.folds, &samples, &used);
    model.detectors = had;
    let group = fit_group(&cal?, Method::Detector, PointClass::Dense)?;
    Ok((fitted.regression, group))
}

/// The calibration samples of method `detector`: each of `samples` answered by its group's
/// fold regression (installed in `model` in turn).
fn fold_samples(
    model: &mut PoseModel,
    folds: &[DetectorRegression],
    samples: &[DetectorSample],
    records: &[&RenderedRecord],
) -> Result<Vec<Sample>> {
    let opts = EstimateOptions {
        method: Method::Detector,
        camera: None,
        style: LandmarkStyle::Projected,
    };
    let mut cal = Vec::with_capacity(samples.len());
    for (g, fold) in folds.iter().enumerate() {
        model.detectors = vec![fold.clone()];
        for (s, r) in samples.iter().zip(records).filter(|(s, _)| s.group == g) {
            let e = estimate_with(model, MEDIAPIPE478, &s.landmarks, &opts)?;
            if let Some(raw) = e.spread {
                cal.push(Sample {
                    method: Method::Detector,
                    points: PointClass::Dense,
                    raw,
                    estimate: [e.angles.pitch, e.angles.yaw, e.angles.roll],
                    truth: truth_angles(r),
                });
            }
        }
    }
    Ok(cal)
}
