//! Training the detector regressions of the default model
//! ([`facepose_core::estimate::detector`]) on the rendered benchmark's `train` identities
//! (`tests/fixtures/rendered/`), and the calibration of their uncertainty on the answers of
//! their leave-one-identity-out folds, so that no interval is fitted on the answers it is scored
//! on. The `test` identities are never read here: `facepose eval --protocol rendered` scores
//! the result on them.
//!
//! Two detectors are trained: MediaPipe's 478 points (`mediapipe478`) and dlib's 68
//! (`ibug68`, sent with `landmark_style: contour` as docs/API.md advises, which is how `auto`
//! tells them from 3D-style landmarks). On five points a regression measured worse than the
//! rigid fit (docs/RESULTS.md). Both regressions' fold answers calibrate one group (method
//! `detector` on dense points: the calibration has one group per method and point class).

use std::collections::BTreeSet;

use facepose_core::data::RenderedRecord;
use facepose_core::error::Result;
use facepose_core::estimate::detector::{DetectorRegression, DetectorSample, fit};
use facepose_core::model::PoseModel;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::uncertainty::PointClass;
use facepose_core::uncertainty::calibration::{CalibrationGroup, Sample, fit_group};

use crate::rendered::{Detector, landmarks, truth_angles, truth_rotation};

/// The split whose identities the regressions are trained on.
pub const TRAIN_SPLIT: &str = "train";

/// The detectors the default model has a regression for, and how each is described.
pub const TRAINED: [(Detector, &str); 2] = [
    (
        Detector::Mediapipe478,
        "MediaPipe 0.10.14 Face Mesh (refine_landmarks, 478 points), image_size given",
    ),
    (
        Detector::Dlib68,
        "dlib 20.0.1's 68-point shape predictor (face-recognition-models), landmark_style contour",
    ),
];

/// One detector's training faces: each sample with its record and the style it is sent in.
struct Faces<'a> {
    scheme: &'static str,
    style: LandmarkStyle,
    samples: Vec<DetectorSample>,
    records: Vec<&'a RenderedRecord>,
}

/// The regressions of [`TRAINED`]'s detectors on `records`' `train` identities, and the
/// calibration group of method `detector` fitted on their folds' answers. `data` names the
/// records for people. `model` answers with each fold's regression in turn and is given back
/// with the detector regressions it had.
pub fn train_detectors(
    model: &mut PoseModel,
    records: &[RenderedRecord],
    data: &str,
) -> Result<(Vec<DetectorRegression>, CalibrationGroup)> {
    let train: Vec<&RenderedRecord> = records.iter().filter(|r| r.split == TRAIN_SPLIT).collect();
    let identities: Vec<String> = train
        .iter()
        .map(|r| r.identity.clone())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let mut regressions = Vec::new();
    let mut cal = Vec::new();
    for (det, description) in TRAINED {
        let faces = faces_of(model, &train, &identities, det)?;
        let data = format!(
            "{data}: split {TRAIN_SPLIT}, {} renders where {} found the face (every set, both \
             geometries)",
            faces.samples.len(),
            det.name()
        );
        let fitted = fit(
            faces.scheme,
            description,
            &data,
            &identities,
            &faces.samples,
        )?;
        // Each sample answered by the fold that did not see its identity, through the
        // estimator itself, so that the raw spread and misfit are the served ones; the model
        // gets back the regressions it had whatever happens.
        let had = std::mem::take(&mut model.detectors);
        let answers = fold_samples(model, &fitted.folds, &faces);
        model.detectors = had;
        cal.extend(answers?);
        regressions.push(fitted.regression);
    }
    let group = fit_group(&cal, Method::Detector, PointClass::Dense)?;
    Ok((regressions, group))
}

/// `det`'s faces among `train`, each with the reference its regression de-rolls by: the served
/// rigid fit's rotation in the style the points are sent in.
fn faces_of<'a>(
    model: &PoseModel,
    train: &[&'a RenderedRecord],
    identities: &[String],
    det: Detector,
) -> Result<Faces<'a>> {
    let mut faces = Faces {
        scheme: "",
        style: LandmarkStyle::Projected,
        samples: Vec::new(),
        records: Vec::new(),
    };
    for r in train {
        let Some((scheme, lm, style)) = landmarks(r, det) else {
            continue;
        };
        let rigid = EstimateOptions {
            method: Method::Fit,
            camera: None,
            style,
        };
        let group = identities.binary_search(&r.identity).unwrap_or(0);
        let reference = estimate_with(model, scheme, &lm, &rigid)?.rotation;
        faces.scheme = scheme;
        faces.style = style;
        faces.samples.push(DetectorSample {
            landmarks: lm,
            reference,
            rotation: truth_rotation(r),
            group,
        });
        faces.records.push(r);
    }
    Ok(faces)
}

/// The calibration samples of method `detector`: each of `faces` answered by its group's
/// fold regression (installed in `model` in turn).
fn fold_samples(
    model: &mut PoseModel,
    folds: &[DetectorRegression],
    faces: &Faces,
) -> Result<Vec<Sample>> {
    let opts = EstimateOptions {
        method: Method::Detector,
        camera: None,
        style: faces.style,
    };
    let mut cal = Vec::with_capacity(faces.samples.len());
    for (g, fold) in folds.iter().enumerate() {
        model.detectors = vec![fold.clone()];
        for (s, r) in faces
            .samples
            .iter()
            .zip(&faces.records)
            .filter(|(s, _)| s.group == g)
        {
            let e = estimate_with(model, faces.scheme, &s.landmarks, &opts)?;
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
