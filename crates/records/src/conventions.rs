//! The answer in the caller's conventions as JSON: one object per requested name under a
//! pose's `conventions` key (docs/API.md, "Answers in your convention"). The values come from
//! the core (`facepose_core::geometry::convention`), which knows no JSON.

use facepose_core::geometry::convention::{
    ConventionAnswer, ConventionAnswers, EulerAnswer, MediaPipeAnswer, OpenCvAnswer,
    QuaternionAnswer,
};
use serde::{Deserialize, Serialize};

/// The answers to a request's `conventions`, each under its name.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ConventionsRecord {
    /// The rotation as a unit quaternion (Hamilton, `w ≥ 0`), of the same matrix as `rotation`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quaternion: Option<QuaternionRecord>,
    /// Euler angles in the requested order, kind, units and axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub euler: Option<EulerRecord>,
    /// `rvec` and `tvec` as `cv2.solvePnP` returns them for the model's 3D points.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub opencv: Option<OpenCvRecord>,
    /// MediaPipe Face Landmarker's facial transformation matrix.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mediapipe: Option<MediaPipeRecord>,
}

/// A unit quaternion, Hamilton convention, `w ≥ 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct QuaternionRecord {
    /// Scalar part.
    pub w: f64,
    /// Vector part, x.
    pub x: f64,
    /// Vector part, y.
    pub y: f64,
    /// Vector part, z.
    pub z: f64,
}

/// Euler angles and what they mean.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct EulerRecord {
    /// The three angles, in the order's letters, in `units`.
    pub angles: [f64; 3],
    /// Three letters of xyz: upper case intrinsic, lower case extrinsic.
    pub order: String,
    /// `intrinsic` or `extrinsic`.
    pub kind: String,
    /// `degrees` or `radians`.
    pub units: String,
    /// The axes the angles turn about, three letters of R/L, U/D, B/F (`RUB`: x right, y up,
    /// z towards the viewer).
    pub axes: String,
    /// `standard` (right-hand rule) or `pose-para` (AFLW's matrices).
    pub matrices: String,
    /// The matrix the angles rebuild, in `axes`, row-major.
    pub matrix: [[f64; 3]; 3],
    /// Within 1° of gimbal lock, where the first and third angles are ill-conditioned.
    pub near_gimbal_lock: bool,
}

/// What `cv2.solvePnP` returns, and what it was given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct OpenCvRecord {
    /// Rodrigues vector, radians.
    pub rvec: [f64; 3],
    /// The model origin in OpenCV's camera frame (x right, y down, z forward), mm.
    pub tvec: [f64; 3],
    /// `cv2.Rodrigues(rvec)`, row-major.
    pub rotation: [[f64; 3]; 3],
    /// `K`, row-major: the request's intrinsics, or the assumed ones.
    pub camera_matrix: [[f64; 3]; 3],
    /// Whether `camera_matrix` was assumed (no intrinsics were sent).
    pub camera_assumed: bool,
    /// The frame of the object points (`opencv` or `model`; the scheme route serves both).
    pub object_frame: String,
}

/// MediaPipe's facial transformation matrix in its two layouts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct MediaPipeRecord {
    /// Row-major 4x4, as Python's `facial_transformation_matrixes[i]`.
    pub matrix: [[f64; 4]; 4],
    /// The 16 values column-major, as the web's `Matrix.data`.
    pub data: Vec<f64>,
    /// 4.
    pub rows: usize,
    /// 4.
    pub columns: usize,
    /// The virtual camera's vertical field of view, degrees.
    pub vertical_fov_deg: f64,
}

impl From<&QuaternionAnswer> for QuaternionRecord {
    fn from(q: &QuaternionAnswer) -> Self {
        QuaternionRecord {
            w: q.w,
            x: q.x,
            y: q.y,
            z: q.z,
        }
    }
}

impl From<&EulerAnswer> for EulerRecord {
    fn from(e: &EulerAnswer) -> Self {
        EulerRecord {
            angles: e.angles,
            order: e.order.clone(),
            kind: e.kind.to_string(),
            units: e.units.to_string(),
            axes: e.axes.clone(),
            matrices: e.matrices.to_string(),
            matrix: e.matrix,
            near_gimbal_lock: e.near_gimbal_lock,
        }
    }
}

impl From<&OpenCvAnswer> for OpenCvRecord {
    fn from(o: &OpenCvAnswer) -> Self {
        OpenCvRecord {
            rvec: o.rvec,
            tvec: o.tvec,
            rotation: o.rotation,
            camera_matrix: o.camera_matrix,
            camera_assumed: o.camera_assumed,
            object_frame: o.object_frame.name().to_string(),
        }
    }
}

impl From<&MediaPipeAnswer> for MediaPipeRecord {
    fn from(m: &MediaPipeAnswer) -> Self {
        MediaPipeRecord {
            matrix: m.matrix,
            data: m.data.to_vec(),
            rows: m.rows,
            columns: m.columns,
            vertical_fov_deg: m.camera.vertical_fov_deg,
        }
    }
}

impl From<&ConventionAnswers> for ConventionsRecord {
    fn from(a: &ConventionAnswers) -> Self {
        let mut r = ConventionsRecord::default();
        for answer in &a.answers {
            match answer {
                ConventionAnswer::Quaternion(q) => r.quaternion = Some(q.into()),
                ConventionAnswer::Euler(e) => r.euler = Some(e.into()),
                ConventionAnswer::OpenCv(o) => r.opencv = Some(o.into()),
                ConventionAnswer::MediaPipe(m) => r.mediapipe = Some(m.into()),
            }
        }
        r
    }
}

impl ConventionsRecord {
    /// Every number, for the finiteness check of a pose.
    pub fn numbers(&self) -> impl Iterator<Item = f64> + '_ {
        let q = self.quaternion.iter().flat_map(|q| [q.w, q.x, q.y, q.z]);
        let e = self
            .euler
            .iter()
            .flat_map(|e| e.angles.into_iter().chain(e.matrix.into_iter().flatten()));
        let o = self.opencv.iter().flat_map(|o| {
            o.rvec
                .into_iter()
                .chain(o.tvec)
                .chain(o.rotation.into_iter().flatten())
                .chain(o.camera_matrix.into_iter().flatten())
        });
        let m = self
            .mediapipe
            .iter()
            .flat_map(|m| m.matrix.into_iter().flatten().chain(m.data.iter().copied()));
        q.chain(e).chain(o).chain(m)
    }
}
