//! Between the protobuf messages and the application's types: a face's landmarks in either
//! form, poses, per-face errors, models, versions, jobs.

use facepose_app::error::ServiceError;
use facepose_app::estimate::{FaceInput, FaceOutcome};
use facepose_app::jobs::Job;
use facepose_app::pose::{FacePose, FaceSpec};
use facepose_app::tracking::Smoothed;
use facepose_app::views::{ModelView, VersionView};
use facepose_core::estimate::Intrinsics;
use facepose_core::model::validate::ValidationReport;
use facepose_core::shape::pixels::ImageSize;
use facepose_records::AngleUncertainty;

use super::error;
use crate::proto;

/// `points` (image pixels, all present) as `Landmark` messages, for Rust clients.
pub fn landmark_messages(points: &[[f64; 2]]) -> Vec<proto::Landmark> {
    points
        .iter()
        .map(|p| proto::Landmark {
            x: p[0],
            y: p[1],
            missing: false,
        })
        .collect()
}

/// A face's landmarks (`landmarks` or packed `xy` with `missing`) as optional points, into
/// `out` (reused between faces); INVALID_ARGUMENT when the two forms are mixed or `xy` and
/// `missing` do not fit together.
pub fn landmarks_into(
    face: &proto::Face,
    out: &mut Vec<Option<[f64; 2]>>,
) -> Result<(), ServiceError> {
    out.clear();
    if face.xy.is_empty() {
        if !face.missing.is_empty() {
            return Err(ServiceError::invalid(
                "Face.missing goes with Face.xy; with Face.landmarks, set Landmark.missing",
            ));
        }
        out.extend(
            face.landmarks
                .iter()
                .map(|l| (!l.missing).then_some([l.x, l.y])),
        );
        return Ok(());
    }
    if !face.landmarks.is_empty() {
        return Err(ServiceError::invalid(format!(
            "the face has both Face.landmarks ({}) and Face.xy ({} numbers): set one of them",
            face.landmarks.len(),
            face.xy.len()
        )));
    }
    if !face.xy.len().is_multiple_of(2) {
        return Err(ServiceError::invalid(format!(
            "Face.xy has {} numbers: it needs an x and a y per landmark (x0, y0, x1, y1, ...)",
            face.xy.len()
        )));
    }
    let n = face.xy.len() / 2;
    out.extend(face.xy.chunks_exact(2).map(|p| Some([p[0], p[1]])));
    for &i in &face.missing {
        let slot = out.get_mut(i as usize).ok_or_else(|| {
            ServiceError::invalid(format!(
                "Face.missing has index {i}, but Face.xy has {n} landmarks (indices 0 to {})",
                n - 1
            ))
        })?;
        *slot = None;
    }
    Ok(())
}

impl FaceInput for proto::Face {
    /// Its landmarks, in either form, converted into `points`.
    fn spec<'a>(
        &'a self,
        points: &'a mut Vec<Option<[f64; 2]>>,
    ) -> Result<FaceSpec<'a>, ServiceError> {
        landmarks_into(self, points)?;
        Ok(face_spec(self, points))
    }

    fn track_id(&self) -> &str {
        &self.id
    }
}

/// A face's result message from its outcome and what smoothing did to it.
pub fn face_result(
    face: proto::Face,
    outcome: FaceOutcome,
    smoothed: Smoothed,
) -> proto::FaceResult {
    let result = match outcome {
        Ok(p) => proto::face_result::Result::Pose(pose_message(&p, smoothed)),
        Err(e) => proto::face_result::Result::Error(face_error(&e)),
    };
    proto::FaceResult {
        id: face.id,
        result: Some(result),
    }
}

/// The transport-neutral face of a proto face whose landmarks are `points`.
pub fn face_spec<'a>(face: &'a proto::Face, points: &'a [Option<[f64; 2]>]) -> FaceSpec<'a> {
    FaceSpec {
        landmarks: points,
        scheme: Some(face.scheme.as_str()),
        method: Some(face.method.as_str()),
        camera: face.camera.map(|c| Intrinsics {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
        }),
        style: Some(face.landmark_style.as_str()),
        image_size: face.image_size.map(|s| ImageSize {
            width: s.width,
            height: s.height,
        }),
        // The proto has no conventions yet (issue 39's gRPC part).
        conventions: &[],
        orientation: None,
    }
}

/// A face's pose as a gRPC `Pose`, with the stream's smoothing outcome.
pub fn pose_message(p: &FacePose, smoothing: Smoothed) -> proto::Pose {
    let r = &p.record;
    proto::Pose {
        yaw: r.yaw,
        pitch: r.pitch,
        roll: r.roll,
        rotation: r.rotation.iter().flatten().copied().collect(),
        visible: r.visible.clone(),
        residual: r.residual,
        method: r.method.to_string(),
        scheme: p.scheme.clone(),
        translation: r
            .translation
            .map(|[x, y, z]| proto::Translation { x, y, z }),
        smoothed: smoothing.smoothed,
        warnings: r.warnings.clone(),
        uncertainty: r.uncertainty.as_ref().map(|u| {
            let angle = |a: &AngleUncertainty| proto::AngleUncertainty {
                sd: a.sd,
                interval90: a.interval90.to_vec(),
            };
            proto::Uncertainty {
                yaw: Some(angle(&u.yaw)),
                pitch: Some(angle(&u.pitch)),
                roll: Some(angle(&u.roll)),
            }
        }),
        gated: smoothing.gated,
    }
}

/// A face's error as a gRPC `FaceError`.
pub fn face_error(e: &ServiceError) -> proto::FaceError {
    proto::FaceError {
        code: error::code_name(error::code(e.kind())).to_string(),
        message: error::message(e),
    }
}

/// A served model as a gRPC `ModelInfo`.
pub fn model_info(m: ModelView) -> proto::ModelInfo {
    proto::ModelInfo {
        versions: m.versions.into_iter().map(version_message).collect(),
        name: m.name,
        version: m.version,
        created: m.created,
        scheme: m.scheme,
        schemes: m
            .schemes
            .into_iter()
            .map(|s| proto::SchemeInfo {
                name: s.name,
                points: s.points as u32,
            })
            .collect(),
        methods: m.methods.iter().map(|x| x.to_string()).collect(),
        checksum: m.checksum,
        source: m.source,
        is_default: m.default,
    }
}

/// A model version as a gRPC `VersionInfo`.
pub fn version_message(v: VersionView) -> proto::VersionInfo {
    proto::VersionInfo {
        version: v.version,
        created: v.created,
        checksum: v.checksum,
        scheme: v.scheme,
        source: v.source,
        active: v.active,
        served: v.served,
        fixed: v.fixed,
    }
}

fn report_message(r: &ValidationReport) -> proto::ValidationReport {
    proto::ValidationReport {
        total: r.total as u32,
        kept: r.kept as u32,
        dropped: r
            .dropped
            .iter()
            .map(|d| proto::DroppedShape {
                index: d.index as u32,
                reason: d.reason.name().to_string(),
                detail: d.detail.clone(),
            })
            .collect(),
        median_distance: r.median_distance,
        outlier_threshold: r.outlier_threshold,
    }
}

/// A job as its gRPC message.
pub fn job_message(j: &Job) -> proto::Job {
    proto::Job {
        id: j.id.clone(),
        model: j.model.clone(),
        state: j.state.name().to_string(),
        stage: j.stage.map_or("", |s| s.name()).to_string(),
        progress: j.progress,
        kind: j.kind.clone(),
        uploaded: j.uploaded as u32,
        activate: j.activate,
        created: j.created.clone(),
        updated: j.updated.clone(),
        validation: j.validation.as_ref().map(report_message),
        version: j.version.clone().unwrap_or_default(),
        error: j.error.clone().unwrap_or_default(),
        replica: j.replica.clone(),
    }
}
