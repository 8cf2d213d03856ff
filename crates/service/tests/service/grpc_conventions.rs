//! Answers in the caller's conventions over gRPC (`Face.conventions`, `Face.camera_orientation`,
//! `Pose.conventions`): faces of the default model's mean shape at known poses, so the expected
//! quaternions and angles come from the pose itself, built here with nalgebra; bad requests are
//! INVALID_ARGUMENT with what to fix; and HTTP and gRPC give a face the same answers.

use facepose_service::proto::{self, camera_orientation::Rotation, face_result};
use facepose_testkit::Endpoint;
use facepose_testkit::faces::*;
use facepose_testkit::server::Server;
use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use serde_json::{Value, json};
use tonic::Code;

fn convention(name: &str, params: &[(&str, &str)]) -> proto::Convention {
    proto::Convention {
        name: name.into(),
        params: params
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect(),
    }
}

fn request(face: proto::Face) -> proto::EstimateRequest {
    proto::EstimateRequest {
        face: Some(face),
        model: String::new(),
    }
}

/// The answer's quaternion against the expected rotation's, up to its sign (`w ≥ 0` is the
/// answer's choice).
fn assert_quaternion(q: &proto::Quaternion, want: &Rotation3<f64>, tol: f64) {
    let w = UnitQuaternion::from_rotation_matrix(want);
    assert!(q.w >= 0.0, "{q:?}");
    let s = if w.w < 0.0 { -1.0 } else { 1.0 };
    let want = [w.w, w.i, w.j, w.k].map(|v| s * v);
    for (g, e) in [q.w, q.x, q.y, q.z].iter().zip(want) {
        assert!((g - e).abs() < tol, "{q:?} vs {want:?}");
    }
}

#[tokio::test]
async fn known_poses_in_the_callers_conventions() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (30.0, -12.0, 8.0), (-45.0, 15.0, -10.0)] {
        let mut face = proto_face(&face68(yaw, pitch, roll), "", "fit", "");
        face.conventions = vec![
            convention("quaternion", &[]),
            convention("euler", &[("preset", "pose-para")]),
        ];
        let pose = c
            .estimate(request(face.clone()))
            .await
            .unwrap()
            .into_inner()
            .pose
            .unwrap();
        let conv = pose.conventions.expect("conventions asked for");
        assert_quaternion(
            conv.quaternion.as_ref().unwrap(),
            &rotation(yaw, pitch, roll),
            0.005,
        );
        // Pose_Para's own convention: x, y, z = pitch, yaw, roll, degrees.
        let e = conv.euler.unwrap();
        assert_eq!(e.angles.len(), 3);
        for (got, want) in e.angles.iter().zip([pitch, yaw, roll]) {
            assert!((got - want).abs() < 0.3, "{e:?} vs {pitch}, {yaw}, {roll}");
        }
        assert_eq!(e.units, "degrees");
        assert_eq!(e.matrix.len(), 9);
        assert!(conv.opencv.is_none() && conv.mediapipe.is_none());
        // Nothing asked, nothing added.
        face.conventions.clear();
        let plain = c.estimate(request(face)).await.unwrap().into_inner();
        assert!(plain.pose.unwrap().conventions.is_none());
    }
}

/// A webcam tilted 20° down: the world's rotation is the camera's orientation times the
/// camera-frame one, in each of the three forms.
#[tokio::test]
async fn a_tilted_camera_gives_the_pose_in_the_world() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let (yaw, pitch, roll) = (20.0, 5.0, -3.0);
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), (-20f64).to_radians());
    let half = (-10f64).to_radians();
    let m = tilt.matrix();
    for rotation_form in [
        Rotation::Euler(proto::EulerAngles {
            params: [("order".to_string(), "XYZ".to_string())].into(),
            angles: vec![-20.0, 0.0, 0.0],
        }),
        Rotation::Quaternion(proto::Quaternion {
            w: half.cos(),
            x: half.sin(),
            y: 0.0,
            z: 0.0,
        }),
        Rotation::Matrix(proto::RotationMatrix {
            values: (0..9).map(|k| m[(k / 3, k % 3)]).collect(),
        }),
    ] {
        let mut face = proto_face(&face68(yaw, pitch, roll), "", "fit", "");
        face.conventions = vec![convention("quaternion", &[])];
        face.camera_orientation = Some(proto::CameraOrientation {
            rotation: Some(rotation_form),
            axes: String::new(),
        });
        let pose = c
            .estimate(request(face))
            .await
            .unwrap()
            .into_inner()
            .pose
            .unwrap();
        let world = tilt * rotation(yaw, pitch, roll);
        assert_quaternion(
            pose.conventions.unwrap().quaternion.as_ref().unwrap(),
            &world,
            0.005,
        );
        // The camera-frame answer is unchanged.
        assert!((pose.yaw - yaw).abs() < 0.3, "{}", pose.yaw);
    }
}

#[tokio::test]
async fn bad_conventions_are_invalid_arguments_that_say_what_to_fix() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let base = proto_face(&face68(0.0, 0.0, 0.0), "", "", "");
    let orientation = |r: Rotation| {
        Some(proto::CameraOrientation {
            rotation: Some(r),
            axes: String::new(),
        })
    };
    let cases: Vec<(proto::Face, &str)> = vec![
        (
            proto::Face {
                conventions: vec![convention("matrix4", &[])],
                ..base.clone()
            },
            "unknown convention \"matrix4\"",
        ),
        (
            proto::Face {
                conventions: vec![convention("euler", &[("order", "XQZ")])],
                ..base.clone()
            },
            "not an Euler order",
        ),
        (
            proto::Face {
                conventions: vec![convention("quaternion", &[]), convention("quaternion", &[])],
                ..base.clone()
            },
            "requested twice",
        ),
        (
            proto::Face {
                conventions: vec![convention("opencv", &[("flavour", "x")])],
                ..base.clone()
            },
            "has no parameter \"flavour\"",
        ),
        (
            proto::Face {
                conventions: vec![convention("quaternion", &[]); 5],
                ..base.clone()
            },
            "at most once",
        ),
        (
            proto::Face {
                conventions: vec![convention("opencv", &[])],
                ..base.clone()
            },
            "send camera {fx, fy, cx, cy}",
        ),
        (
            proto::Face {
                conventions: vec![convention("opencv", &[])],
                camera: Some(proto::Camera {
                    fx: -5.0,
                    fy: 500.0,
                    cx: 320.0,
                    cy: 240.0,
                }),
                method: "fit".into(),
                ..base.clone()
            },
            "focal lengths must be positive",
        ),
        (
            proto::Face {
                camera_orientation: orientation(Rotation::Matrix(proto::RotationMatrix {
                    values: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0],
                })),
                ..base.clone()
            },
            "must be a rotation matrix",
        ),
        (
            proto::Face {
                camera_orientation: orientation(Rotation::Matrix(proto::RotationMatrix {
                    values: vec![1.0; 4],
                })),
                ..base.clone()
            },
            "it needs 9",
        ),
        (
            proto::Face {
                camera_orientation: orientation(Rotation::Quaternion(proto::Quaternion {
                    w: 1.0,
                    x: 1.0,
                    y: 0.0,
                    z: 0.0,
                })),
                ..base.clone()
            },
            "norm 1",
        ),
        (
            proto::Face {
                camera_orientation: Some(proto::CameraOrientation::default()),
                ..base.clone()
            },
            "set one of matrix, quaternion or euler",
        ),
        (
            proto::Face {
                camera_orientation: orientation(Rotation::Euler(proto::EulerAngles {
                    params: [("order".to_string(), "XYZ".to_string())].into(),
                    angles: vec![1.0, 2.0],
                })),
                ..base.clone()
            },
            "it needs 3",
        ),
    ];
    for (face, says) in cases {
        let s = c.estimate(request(face.clone())).await.unwrap_err();
        assert_eq!(s.code(), Code::InvalidArgument, "{face:?}: {s:?}");
        assert!(s.message().contains(says), "{says}: {}", s.message());
        // In a batch, the face's own error; the other face is still estimated.
        let batch = c
            .estimate_batch(proto::EstimateBatchRequest {
                faces: vec![face, base.clone()],
                model: String::new(),
            })
            .await
            .unwrap()
            .into_inner();
        match &batch.results[0].result {
            Some(face_result::Result::Error(e)) => {
                assert_eq!(e.code, "INVALID_ARGUMENT");
                assert!(e.message.contains(says), "{says}: {}", e.message);
            }
            other => panic!("{says}: {other:?}"),
        }
        assert!(matches!(
            batch.results[1].result,
            Some(face_result::Result::Pose(_))
        ));
    }
}

fn numbers(v: &Value) -> Vec<f64> {
    match v {
        Value::Array(a) => a.iter().flat_map(numbers).collect(),
        Value::Number(n) => vec![n.as_f64().unwrap()],
        _ => vec![],
    }
}

fn close(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: {a:?} vs {b:?}");
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x - y).abs() <= 1e-9 * (1.0 + x.abs()),
            "{what}: {a:?} vs {b:?}"
        );
    }
}

/// Every convention, with a camera and a tilted camera orientation: the gRPC answer carries
/// the numbers and names of the HTTP answer for the same face.
#[tokio::test]
async fn http_and_grpc_give_a_face_the_same_conventions() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let http = reqwest::Client::new();
    let points = face68(25.0, -8.0, 6.0);
    let body = json!({
        "landmarks": points,
        "method": "fit",
        "camera": {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0},
        "conventions": [
            "quaternion",
            {"name": "euler", "order": "zyx", "units": "radians", "axes": "opencv"},
            {"name": "opencv", "object_frame": "model"},
            "mediapipe",
        ],
        "camera_orientation": {"euler": {"order": "XYZ", "angles": [-15, 5, 0]}},
    });
    let v: Value = http
        .post(server.url("/v1/pose"))
        .json(&body)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let h = &v["conventions"];
    assert!(h["mediapipe"].is_object(), "{v}");

    let mut face = proto_face(&points, "", "fit", "");
    face.camera = Some(proto::Camera {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    });
    face.conventions = vec![
        convention("quaternion", &[]),
        convention(
            "euler",
            &[("order", "zyx"), ("units", "radians"), ("axes", "opencv")],
        ),
        convention("opencv", &[("object_frame", "model")]),
        convention("mediapipe", &[]),
    ];
    face.camera_orientation = Some(proto::CameraOrientation {
        rotation: Some(Rotation::Euler(proto::EulerAngles {
            params: [("order".to_string(), "XYZ".to_string())].into(),
            angles: vec![-15.0, 5.0, 0.0],
        })),
        axes: String::new(),
    });
    let pose = c
        .estimate(request(face))
        .await
        .unwrap()
        .into_inner()
        .pose
        .unwrap();
    assert_eq!(pose.warnings, numbers_free(&v["warnings"]));
    let g = pose.conventions.unwrap();
    let q = g.quaternion.unwrap();
    close(
        &[q.w, q.x, q.y, q.z],
        &["w", "x", "y", "z"].map(|k| h["quaternion"][k].as_f64().unwrap()),
        "quaternion",
    );
    let e = g.euler.unwrap();
    close(&e.angles, &numbers(&h["euler"]["angles"]), "euler angles");
    close(&e.matrix, &numbers(&h["euler"]["matrix"]), "euler matrix");
    for (got, key) in [
        (&e.order, "order"),
        (&e.kind, "kind"),
        (&e.units, "units"),
        (&e.axes, "axes"),
        (&e.matrices, "matrices"),
    ] {
        assert_eq!(got, h["euler"][key].as_str().unwrap(), "{key}");
    }
    assert_eq!(e.near_gimbal_lock, h["euler"]["near_gimbal_lock"]);
    let o = g.opencv.unwrap();
    close(&o.rvec, &numbers(&h["opencv"]["rvec"]), "rvec");
    close(&o.tvec, &numbers(&h["opencv"]["tvec"]), "tvec");
    close(
        &o.rotation,
        &numbers(&h["opencv"]["rotation"]),
        "opencv rotation",
    );
    close(
        &o.camera_matrix,
        &numbers(&h["opencv"]["camera_matrix"]),
        "camera matrix",
    );
    assert_eq!(o.camera_assumed, h["opencv"]["camera_assumed"]);
    assert_eq!(o.object_frame, "model");
    let m = g.mediapipe.unwrap();
    close(
        &m.matrix,
        &numbers(&h["mediapipe"]["matrix"]),
        "mediapipe matrix",
    );
    close(&m.data, &numbers(&h["mediapipe"]["data"]), "mediapipe data");
    assert_eq!((m.rows, m.columns), (4, 4));
    close(
        &[m.vertical_fov_deg],
        &[h["mediapipe"]["vertical_fov_deg"].as_f64().unwrap()],
        "fov",
    );
}

/// The strings of a JSON array.
fn numbers_free(v: &Value) -> Vec<String> {
    v.as_array()
        .map(|a| a.iter().map(|s| s.as_str().unwrap().to_string()).collect())
        .unwrap_or_default()
}
