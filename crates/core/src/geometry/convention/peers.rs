//! The answers of two peers, in their own conventions: OpenCV's `rvec`/`tvec` (what
//! `cv2.solvePnP` returns) and MediaPipe Face Landmarker's facial transformation matrix.
//!
//! **OpenCV.** Camera frame x right, y down, z forward (`RDF`), millimetres; a model point `X`
//! is seen at `K (R_cv X + t)` (`cv2.projectPoints(X, rvec, tvec, K, None)`), `rvec` the
//! Rodrigues vector of `R_cv` (axis times angle, radians, angle in [0, π]). With `F =
//! diag(1, -1, -1)` (facepose's camera axes to OpenCV's) and the face at `(R, T)` in that camera:
//! - object points in OpenCV's axes (`object_frame = "opencv"`, the default: the model's points
//!   `F X`, so that a face looking at the camera is `rvec = 0`, as OpenFace reports it):
//!   `R_cv = F R F`;
//! - object points in facepose's model frame (`object_frame = "model"`, the frame the tutorials'
//!   generic 3D faces are written in, y up): `R_cv = F R` (a face looking at the camera is then a
//!   half turn about x, `rvec ≈ (π, 0, 0)`);
//! - `tvec = F T` either way (the model origin does not move).
//!
//! **MediaPipe.** `facial_transformation_matrixes[i]` maps MediaPipe's canonical face
//! (`canonical_face_model.obj`: x right, y up, z towards the viewer, centimetres) into the
//! metric space of its virtual camera: a perspective camera at the origin looking down -z
//! (`RUB`), vertical field of view 63°, principal point at the image centre, so its focal length
//! is `H / (2 tan 31.5°)` pixels for an image H pixels high; the face is assumed to be the
//! canonical face's size. The upper 3x3 is the rotation (MediaPipe's Procrustes leaves a scale
//! within a few per cent of 1 there; facepose's is exactly a rotation), the last column the
//! canonical origin's position in cm, the last row `(0, 0, 0, 1)`. Memory layout: Python's
//! `FaceLandmarkerResult` gives a row-major 4x4 numpy array; the web's (`@mediapipe/tasks-vision`)
//! gives `{rows: 4, columns: 4, data}` with `data` the 16 values **column-major** (Eigen's layout,
//! the one three.js's `Matrix4.fromArray` reads), so the translation is `data[12..15]`. The
//! answer carries both.
//!
//! facepose's served mesh is the canonical mesh moved into the model frame by a similarity
//! `v_model = σ Q v_mm + c` ([`MeshFrame`]), so a canonical vertex `v` (cm) is at
//! `R (σ Q 10 v + c) + T` (mm) in the camera. MediaPipe fixes the face's size, not its depth;
//! dividing the whole scene by `10 σ` keeps every pixel and gives
//! `M = [R Q | (R c + T) / (10 σ)]`, with `(R, T)` the pose in MediaPipe's virtual camera.

use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};

use super::camera::CameraPose;
use super::request::ConventionError;
use crate::estimate::Intrinsics;
use crate::geometry::procrustes::{Scaling, Similarity3, align3};

/// `F = diag(1, -1, -1)`: facepose's camera axes (x right, y up, z back) to OpenCV's.
pub fn opencv_flip() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// The frame of the 3D object points that `rvec` refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ObjectFrame {
    /// The model's points in OpenCV's axes (`F X`: x right, y down, z away from the viewer for
    /// a face looking at the camera): a frontal face is `rvec = 0`.
    #[default]
    OpenCv,
    /// The model's points as facepose serves them (x right, y up, z towards the viewer).
    Model,
}

impl ObjectFrame {
    /// The names, as requests write them.
    pub const NAMES: [&'static str; 2] = ["opencv", "model"];

    /// The name, as requests write it.
    pub fn name(self) -> &'static str {
        match self {
            ObjectFrame::OpenCv => "opencv",
            ObjectFrame::Model => "model",
        }
    }

    /// The model's points (mm, model frame) in this frame: what to pass to `cv2.solvePnP` or
    /// `cv2.projectPoints` with the answer's `rvec` and `tvec`.
    pub fn object_points(self, model: &[Vector3<f64>]) -> Vec<[f64; 3]> {
        let f = match self {
            ObjectFrame::OpenCv => opencv_flip(),
            ObjectFrame::Model => Matrix3::identity(),
        };
        model.iter().map(|x| (f * x).into()).collect()
    }
}

/// What `cv2.solvePnP` returns, and what it was given.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenCvAnswer {
    /// Rodrigues vector of `rotation`, radians (angle in [0, π]).
    pub rvec: [f64; 3],
    /// The model origin in OpenCV's camera frame, mm.
    pub tvec: [f64; 3],
    /// `R_cv`, row-major (what `cv2.Rodrigues(rvec)` returns).
    pub rotation: [[f64; 3]; 3],
    /// `K`, row-major: the request's intrinsics or the assumed ones.
    pub camera_matrix: [[f64; 3]; 3],
    /// Whether `camera_matrix` was assumed (no intrinsics in the request).
    pub camera_assumed: bool,
    /// The frame of the object points `rvec` refers to.
    pub object_frame: ObjectFrame,
}

impl OpenCvAnswer {
    /// The answer for a pose in the camera `k` (facepose's camera axes).
    pub fn new(p: &CameraPose, k: &Intrinsics, assumed: bool, frame: ObjectFrame) -> Self {
        let f = opencv_flip();
        let r_cv = match frame {
            ObjectFrame::OpenCv => f * p.rotation.matrix() * f,
            ObjectFrame::Model => f * p.rotation.matrix(),
        };
        let rot = Rotation3::from_matrix_unchecked(r_cv);
        let rvec = rodrigues(&rot);
        OpenCvAnswer {
            rvec: rvec.into(),
            tvec: (f * p.translation).into(),
            rotation: rows3(&r_cv),
            camera_matrix: [[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]],
            camera_assumed: assumed,
            object_frame: frame,
        }
    }
}

/// The Rodrigues vector (axis times angle in [0, π]) of a rotation, as `cv2.Rodrigues`: at a
/// half turn the axis' sign is chosen so that its first non-zero component is positive.
pub fn rodrigues(r: &Rotation3<f64>) -> Vector3<f64> {
    let v = r.scaled_axis();
    let angle = v.norm();
    if std::f64::consts::PI - angle < 1e-9 {
        let sign = v
            .iter()
            .find(|c| c.abs() > 1e-9)
            .map_or(1.0, |c| c.signum());
        return v * sign;
    }
    v
}

/// A 3x3 matrix as row-major arrays.
pub fn rows3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]])
}

/// MediaPipe's virtual camera (FaceLandmarker's default environment).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VirtualCamera {
    /// Vertical field of view, degrees.
    pub vertical_fov_deg: f64,
    /// cm; the near and far planes take no part in the matrix.
    pub near: f64,
    /// Far plane, cm; takes no part in the matrix.
    pub far: f64,
}

/// FaceLandmarker's default environment.
pub const MEDIAPIPE_CAMERA: VirtualCamera = VirtualCamera {
    vertical_fov_deg: 63.0,
    near: 1.0,
    far: 10000.0,
};

impl VirtualCamera {
    /// The pinhole intrinsics (pixels) of this camera on an image of `width` x `height`.
    pub fn intrinsics(&self, width: f64, height: f64) -> Intrinsics {
        let f = height / (2.0 * (self.vertical_fov_deg.to_radians() / 2.0).tan());
        Intrinsics {
            fx: f,
            fy: f,
            cx: width / 2.0,
            cy: height / 2.0,
        }
    }
}

/// How MediaPipe's canonical face (mm) sits in the model frame: `v_model = σ Q v + c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshFrame(pub Similarity3);

/// Vertices of MediaPipe's canonical face model (`canonical_face_model.obj`, Apache-2.0, as in
/// the shared data's `canonical_face_468.json`), mm: enough to find the similarity that moved
/// it into a model's frame from the served mesh.
pub const CANONICAL_REFERENCE: [(usize, [f64; 3]); 7] = [
    (1, [0.0, -11.2687, 74.756]),
    (10, [0.0, 82.6178, 44.8154]),
    (33, [-44.4586, 26.6399, 31.7342]),
    (61, [-24.5621, -43.4262, 42.8388]),
    (152, [0.0, -94.0338, 42.6449]),
    (263, [44.4586, 26.6399, 31.7342]),
    (291, [24.5621, -43.4262, 42.8388]),
];

impl MeshFrame {
    /// The frame of a served mesh (the model's `mediapipe468` points, 468 vertices in the model
    /// frame), found from [`CANONICAL_REFERENCE`]. Fails unless the served vertices are a
    /// similarity of the canonical ones (to 0.01 mm).
    pub fn of_served_mesh(vertices: &[Vector3<f64>]) -> Result<MeshFrame, ConventionError> {
        if vertices.len() != 468 {
            return Err(ConventionError::NoMesh(format!(
                "the served mesh has {} vertices, MediaPipe's has 468",
                vertices.len()
            )));
        }
        let src: Vec<Vector3<f64>> = CANONICAL_REFERENCE
            .iter()
            .map(|(_, v)| Vector3::from(*v))
            .collect();
        let dst: Vec<Vector3<f64>> = CANONICAL_REFERENCE
            .iter()
            .map(|(i, _)| vertices[*i])
            .collect();
        let sim = align3(&src, &dst, Scaling::Similarity)
            .map_err(|e| ConventionError::NoMesh(e.to_string()))?;
        let worst = src
            .iter()
            .zip(&dst)
            .map(|(a, b)| (sim.apply(a) - b).norm())
            .fold(0.0, f64::max);
        if worst > 1e-2 {
            return Err(ConventionError::NoMesh(format!(
                "the served mesh is not MediaPipe's canonical face moved rigidly \
                 ({worst:.3} mm off)"
            )));
        }
        Ok(MeshFrame(sim))
    }
}

/// MediaPipe's facial transformation matrix, in its two layouts.
#[derive(Debug, Clone, PartialEq)]
pub struct MediaPipeAnswer {
    /// Row-major 4x4 (Python's `facial_transformation_matrixes[i]`).
    pub matrix: [[f64; 4]; 4],
    /// The 16 values column-major (the web's `Matrix.data`, three.js `Matrix4.fromArray`).
    pub data: [f64; 16],
    /// Rows of `matrix` (4).
    pub rows: usize,
    /// Columns of `matrix` (4).
    pub columns: usize,
    /// The virtual camera it refers to.
    pub camera: VirtualCamera,
}

impl MediaPipeAnswer {
    /// The matrix of a pose `p` in MediaPipe's virtual camera (facepose's axes, mm).
    pub fn new(p: &CameraPose, frame: &MeshFrame) -> Self {
        let sim = &frame.0;
        let r = p.rotation.matrix() * sim.rotation.matrix();
        let t = (p.rotation * sim.translation + p.translation) / (10.0 * sim.scale);
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        let matrix = [0, 1, 2, 3].map(|i| [0, 1, 2, 3].map(|j| m[(i, j)]));
        let mut data = [0.0; 16];
        data.copy_from_slice(m.as_slice()); // nalgebra stores column-major
        MediaPipeAnswer {
            matrix,
            data,
            rows: 4,
            columns: 4,
            camera: MEDIAPIPE_CAMERA,
        }
    }
}
