//! Between the protobuf messages and the application's types: a face's landmarks in either
//! form, the conventions a face asks for, poses, per-face errors, models, versions, jobs.

use facepose_app::error::ServiceError;
use facepose_app::estimate::{FaceInput, FaceOutcome, FaceScratch};
use facepose_app::jobs::Job;
use facepose_app::pose::{FacePose, FaceSpec};
use facepose_app::tracking::Smoothed;
use facepose_app::views::{ModelView, VersionView};
use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::convention::request::check_unique;
use facepose_core::geometry::convention::{
    Axes, CameraOrientation, ConventionError, ConventionRequest, EulerSpec,
};
use facepose_core::model::validate::ValidationReport;
use facepose_core::shape::pixels::ImageSize;
use facepose_records::{
    AngleUncertainty, ConventionsRecord, EulerRecord, MediaPipeRecord, OpenCvRecord,
    QuaternionRecord,
};

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

/// The most conventions a face may ask for: one of each.
pub const MAX_CONVENTIONS: usize = ConventionRequest::NAMES.len();

/// The most parameters of one convention or of a camera orientation's Euler angles (the Euler
/// convention has six).
pub const MAX_PARAMS: usize = 8;

/// A convention error as the client's: INVALID_ARGUMENT, the core's words after the field's.
fn bad_convention(field: &str, e: ConventionError) -> ServiceError {
    ServiceError::invalid(format!("{field}: {e}"))
}

/// `(name, value)` pairs of a message's parameters, at most [`MAX_PARAMS`].
fn param_pairs<'p>(
    field: &str,
    params: &'p std::collections::BTreeMap<String, String>,
) -> Result<Vec<(&'p str, &'p str)>, ServiceError> {
    if params.len() > MAX_PARAMS {
        return Err(ServiceError::invalid(format!(
            "{field} has {} parameters; a convention has at most {MAX_PARAMS}",
            params.len()
        )));
    }
    Ok(params
        .iter()
        .map(|(k, v)| (k.as_str(), v.as_str()))
        .collect())
}

/// The conventions a face asks for (`Face.conventions`), parsed into `out` (reused between
/// faces); INVALID_ARGUMENT with what to fix for an unknown name, parameter or value, or a
/// name asked twice. A face that asks for none costs a length check.
pub fn conventions_into(
    face: &proto::Face,
    out: &mut Vec<ConventionRequest>,
) -> Result<(), ServiceError> {
    out.clear();
    if face.conventions.is_empty() {
        return Ok(());
    }
    if face.conventions.len() > MAX_CONVENTIONS {
        return Err(ServiceError::invalid(format!(
            "Face.conventions has {} items; name each convention at most once (there are \
             {MAX_CONVENTIONS}: {})",
            face.conventions.len(),
            ConventionRequest::NAMES.join(", ")
        )));
    }
    for (i, c) in face.conventions.iter().enumerate() {
        let field = format!("Face.conventions[{i}]");
        let params = param_pairs(&field, &c.params)?;
        out.push(
            ConventionRequest::parse(&c.name, &params).map_err(|e| bad_convention(&field, e))?,
        );
    }
    check_unique(out).map_err(|e| bad_convention("Face.conventions", e))
}

/// The camera's orientation a face gives (`Face.camera_orientation`), if any; INVALID_ARGUMENT
/// with what to fix when it is not a rotation or its parameters are bad.
pub fn camera_orientation(face: &proto::Face) -> Result<Option<CameraOrientation>, ServiceError> {
    use proto::camera_orientation::Rotation;
    let Some(o) = &face.camera_orientation else {
        return Ok(None);
    };
    let field = "Face.camera_orientation";
    let axes = if o.axes.is_empty() {
        Axes::FACEPOSE
    } else {
        Axes::parse(&o.axes).map_err(|e| bad_convention(&format!("{field}.axes"), e))?
    };
    let orientation = match &o.rotation {
        None => {
            return Err(ServiceError::invalid(format!(
                "{field} has no rotation: set one of matrix, quaternion or euler"
            )));
        }
        Some(Rotation::Matrix(m)) => {
            let v = &m.values;
            if v.len() != 9 {
                return Err(ServiceError::invalid(format!(
                    "{field}.matrix has {} values: it needs 9, the 3x3 matrix row-major",
                    v.len()
                )));
            }
            CameraOrientation::from_rows(
                [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]],
                axes,
            )
        }
        Some(Rotation::Quaternion(q)) => {
            CameraOrientation::from_quaternion(q.w, q.x, q.y, q.z, axes)
        }
        Some(Rotation::Euler(e)) => {
            if !o.axes.is_empty() {
                return Err(ServiceError::invalid(format!(
                    "{field}: with euler, give the axes among its params (\"axes\": {:?}), not in \
                     CameraOrientation.axes",
                    o.axes
                )));
            }
            let &[a, b, c] = e.angles.as_slice() else {
                return Err(ServiceError::invalid(format!(
                    "{field}.euler has {} angles: it needs 3, in the order's letters",
                    e.angles.len()
                )));
            };
            let params = param_pairs(&format!("{field}.euler"), &e.params)?;
            EulerSpec::from_params(&params)
                .and_then(|spec| CameraOrientation::from_euler(&spec, [a, b, c]))
        }
    };
    orientation.map(Some).map_err(|e| bad_convention(field, e))
}

impl FaceInput for proto::Face {
    /// Its landmarks, in either form, converted into the scratch's points, and its conventions
    /// parsed into the scratch's (nothing for a face that asks for none).
    fn spec<'a>(&'a self, scratch: &'a mut FaceScratch) -> Result<FaceSpec<'a>, ServiceError> {
        let FaceScratch {
            points,
            conventions,
        } = scratch;
        landmarks_into(self, points)?;
        conventions_into(self, conventions)?;
        let orientation = camera_orientation(self)?;
        Ok(FaceSpec {
            conventions,
            orientation,
            ..face_spec(self, points)
        })
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

/// The transport-neutral face of a proto face whose landmarks are `points`, without its
/// conventions (see [`FaceInput::spec`]).
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
        // Parsed by `FaceInput::spec`, which holds them.
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
        conventions: r
            .conventions
            .as_deref()
            .map(|c| Box::new(conventions_message(c))),
    }
}

/// The answers in the caller's conventions, one field per name asked for.
pub fn conventions_message(c: &ConventionsRecord) -> proto::Conventions {
    let flat = |m: &[[f64; 3]; 3]| m.iter().flatten().copied().collect::<Vec<_>>();
    proto::Conventions {
        quaternion: c
            .quaternion
            .map(|QuaternionRecord { w, x, y, z }| proto::Quaternion { w, x, y, z }),
        euler: c
            .euler
            .as_ref()
            .map(|e: &EulerRecord| proto::EulerConvention {
                angles: e.angles.to_vec(),
                order: e.order.clone(),
                kind: e.kind.clone(),
                units: e.units.clone(),
                axes: e.axes.clone(),
                matrices: e.matrices.clone(),
                matrix: flat(&e.matrix),
                near_gimbal_lock: e.near_gimbal_lock,
            }),
        opencv: c
            .opencv
            .as_ref()
            .map(|o: &OpenCvRecord| proto::OpenCvConvention {
                rvec: o.rvec.to_vec(),
                tvec: o.tvec.to_vec(),
                rotation: flat(&o.rotation),
                camera_matrix: flat(&o.camera_matrix),
                camera_assumed: o.camera_assumed,
                object_frame: o.object_frame.clone(),
            }),
        mediapipe: c
            .mediapipe
            .as_ref()
            .map(|m: &MediaPipeRecord| proto::MediaPipeConvention {
                matrix: m.matrix.iter().flatten().copied().collect(),
                data: m.data.clone(),
                rows: m.rows as u32,
                columns: m.columns as u32,
                vertical_fov_deg: m.vertical_fov_deg,
            }),
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
