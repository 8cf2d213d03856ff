//! Faces projected from the default model's mean shape at known poses (the independent
//! expectation: the service must give those poses back), and rotation helpers.

use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::{SubsetMap, default_model};
use facepose_service::proto;
use nalgebra::{Rotation3, Vector2};

/// The default model, loaded once per test process.
pub fn model() -> &'static facepose_core::model::PoseModel {
    static MODEL: std::sync::OnceLock<facepose_core::model::PoseModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

/// The 68 landmarks (image pixels) of the default model's mean shape seen at a known pose by a
/// weak-perspective camera.
pub fn face68(yaw: f64, pitch: f64, roll: f64) -> Vec<[f64; 2]> {
    let model = model();
    let cam = camera(yaw, pitch, roll);
    model
        .mean
        .iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x, p.y]
        })
        .collect()
}

/// The five points (eye centres, nose tip, mouth corners) of the same face.
pub fn face5(yaw: f64, pitch: f64, roll: f64) -> Vec<[f64; 2]> {
    let model = model();
    let cam = camera(yaw, pitch, roll);
    SubsetMap::Anchors
        .map_points(&model.scheme, &model.mean)
        .iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x, p.y]
        })
        .collect()
}

/// MediaPipe Face Landmarker's 478 points of the default model's face mesh at a known pose,
/// normalized as MediaPipe gives them: pixels of a `width` x `height` image divided by its
/// size.
pub fn face478_normalized(yaw: f64, pitch: f64, roll: f64, size: [f64; 2]) -> Vec<[f64; 2]> {
    let (_, ms) = model().mesh_scheme("mediapipe478").unwrap();
    let cam = camera(yaw, pitch, roll);
    ms.points
        .iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x / size[0], p.y / size[1]]
        })
        .collect()
}

fn camera(yaw: f64, pitch: f64, roll: f64) -> WeakPerspective {
    WeakPerspective::new(
        EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation(),
        2.1,
        Vector2::new(320.0, -240.0),
    )
    .unwrap()
}

/// The rotation of Euler angles (yaw, pitch, roll), degrees, Pose_Para.
pub fn rotation(yaw: f64, pitch: f64, roll: f64) -> Rotation3<f64> {
    EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation()
}

/// Row-major 3x3 from JSON, checked to be a rotation.
pub fn rotation_json(v: &serde_json::Value) -> Rotation3<f64> {
    let rows: [[f64; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| v[i][j].as_f64().expect("rotation entries are numbers"))
    });
    facepose_core::geometry::rotation_from_rows(rows, 1e-6).unwrap()
}

/// Row-major 9 doubles from gRPC, checked to be a rotation.
pub fn rotation_flat(v: &[f64]) -> Rotation3<f64> {
    assert_eq!(v.len(), 9);
    let rows: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| v[3 * i + j]));
    facepose_core::geometry::rotation_from_rows(rows, 1e-6).unwrap()
}

/// A gRPC `Face` of these landmarks (image pixels), scheme, method and id.
pub fn proto_face(points: &[[f64; 2]], scheme: &str, method: &str, id: &str) -> proto::Face {
    proto::Face {
        landmarks: facepose_service::grpc::landmark_messages(points),
        scheme: scheme.into(),
        method: method.into(),
        camera: None,
        id: id.into(),
        landmark_style: String::new(),
        xy: vec![],
        missing: vec![],
        image_size: None,
        conventions: Vec::new(),
        camera_orientation: None,
    }
}
