//! Answers in the caller's conventions over HTTP (`conventions`, `camera_orientation`): faces of
//! the default model's mean shape at known poses, so the expected quaternions and angles come
//! from the pose itself, built here with nalgebra, not from the service.

use facepose_testkit::Endpoint;
use facepose_testkit::faces::*;
use facepose_testkit::server::Server;
use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use reqwest::StatusCode;
use serde_json::{Value, json};

async fn post(c: &reqwest::Client, url: &str, body: &Value) -> (StatusCode, Value) {
    let r = c.post(url).json(body).send().await.unwrap();
    let status = r.status();
    (status, r.json::<Value>().await.unwrap())
}

/// The answer's quaternion against the expected rotation's, up to its sign (`w ≥ 0` is the
/// answer's choice).
fn assert_quaternion(q: &Value, want: &Rotation3<f64>, tol: f64) {
    let w = UnitQuaternion::from_rotation_matrix(want);
    let got = ["w", "x", "y", "z"].map(|k| q[k].as_f64().unwrap());
    assert!(got[0] >= 0.0, "{q}");
    let s = if w.w < 0.0 { -1.0 } else { 1.0 };
    let want = [w.w, w.i, w.j, w.k].map(|v| s * v);
    for (g, e) in got.iter().zip(want) {
        assert!((g - e).abs() < tol, "{q} vs {want:?}");
    }
}

#[tokio::test]
async fn known_poses_in_the_callers_conventions() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (30.0, -12.0, 8.0), (-45.0, 15.0, -10.0)] {
        let body = json!({
            "landmarks": face68(yaw, pitch, roll),
            "method": "fit",
            "conventions": ["quaternion", {"name": "euler", "preset": "pose-para"}],
        });
        let (status, v) = post(&c, &url, &body).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        let r = rotation(yaw, pitch, roll);
        assert_quaternion(&v["conventions"]["quaternion"], &r, 0.005);
        // Pose_Para's own convention: x, y, z = pitch, yaw, roll, degrees.
        let e = &v["conventions"]["euler"];
        let angles: Vec<f64> = e["angles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a.as_f64().unwrap())
            .collect();
        for (got, want) in angles.iter().zip([pitch, yaw, roll]) {
            assert!((got - want).abs() < 0.3, "{e} vs {pitch}, {yaw}, {roll}");
        }
        assert_eq!(e["units"], "degrees");
        // Nothing asked, nothing added.
        let (_, plain) = post(&c, &url, &json!({"landmarks": face68(yaw, pitch, roll)})).await;
        assert!(plain.get("conventions").is_none(), "{plain}");
    }
}

/// A webcam tilted 20° down: the world's rotation is the camera's orientation times the
/// camera-frame one.
#[tokio::test]
async fn a_tilted_camera_gives_the_pose_in_the_world() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let (yaw, pitch, roll) = (20.0, 5.0, -3.0);
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), (-20f64).to_radians());
    let half = (-10f64).to_radians();
    for orientation in [
        json!({"euler": {"order": "XYZ", "angles": [-20, 0, 0]}}),
        json!({"quaternion": {"w": half.cos(), "x": half.sin(), "y": 0, "z": 0}}),
        json!({"matrix": [
            [1.0, 0.0, 0.0],
            [0.0, tilt[(1, 1)], tilt[(1, 2)]],
            [0.0, tilt[(2, 1)], tilt[(2, 2)]],
        ]}),
    ] {
        let (status, v) = post(
            &c,
            &server.url("/v1/pose"),
            &json!({
                "landmarks": face68(yaw, pitch, roll),
                "method": "fit",
                "conventions": ["quaternion"],
                "camera_orientation": orientation,
            }),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{v}");
        let world = tilt * rotation(yaw, pitch, roll);
        assert_quaternion(&v["conventions"]["quaternion"], &world, 0.005);
        // The camera-frame answer is unchanged.
        assert!((v["yaw"].as_f64().unwrap() - yaw).abs() < 0.3, "{v}");
    }
}

#[tokio::test]
async fn batches_take_the_batch_conventions_and_a_face_its_own() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let (status, v) = post(
        &c,
        &server.url("/v1/pose:batch"),
        &json!({
            "conventions": ["quaternion"],
            "faces": [
                {"landmarks": face68(10.0, 0.0, 0.0)},
                {"landmarks": face68(-10.0, 0.0, 0.0), "conventions": [{"name": "euler", "order": "zyx", "units": "radians"}]},
            ],
        }),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    let results = v["results"].as_array().unwrap();
    assert!(results[0]["conventions"]["quaternion"].is_object(), "{v}");
    assert!(results[0]["conventions"].get("euler").is_none(), "{v}");
    assert_eq!(results[1]["conventions"]["euler"]["order"], "zyx", "{v}");
    assert!(results[1]["conventions"].get("quaternion").is_none(), "{v}");
}

#[tokio::test]
async fn bad_conventions_say_what_to_fix() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    let face = face68(0.0, 0.0, 0.0);
    for (extra, says) in [
        (
            json!({"conventions": ["matrix4"]}),
            "unknown convention \"matrix4\"",
        ),
        (
            json!({"conventions": [{"name": "euler", "order": "XQZ"}]}),
            "not an Euler order",
        ),
        (
            json!({"conventions": ["quaternion", "quaternion"]}),
            "requested twice",
        ),
        (
            json!({"conventions": [{"name": "opencv", "flavour": "x"}]}),
            "has no parameter \"flavour\"",
        ),
        (
            json!({"conventions": ["opencv"]}),
            "send camera {fx, fy, cx, cy}",
        ),
        (
            json!({"camera_orientation": {"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}}),
            "must be a rotation matrix",
        ),
        (
            json!({"camera_orientation": {"quaternion": {"w": 1, "x": 1, "y": 0, "z": 0}}}),
            "norm 1",
        ),
    ] {
        let mut body = json!({"landmarks": face});
        for (k, v) in extra.as_object().unwrap() {
            body[k] = v.clone();
        }
        let (status, v) = post(&c, &url, &body).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body} -> {v}");
        let message = v["error"]["message"].as_str().unwrap_or_default();
        assert!(message.contains(says), "{body}: {message}");
    }
}

/// `cv2.projectPoints(mean_opencv, rvec, tvec, K, None)`, written out, gives back the sent
/// landmarks: the scheme route's OpenCV object points and the `opencv` answer fit together.
#[tokio::test]
async fn opencv_object_points_project_to_the_landmarks() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let landmarks = face68(25.0, -10.0, 6.0);
    // A long focal length: the test faces are weak-perspective views.
    let (f, cx, cy) = (200_000.0, 320.0, 240.0);
    let (status, v) = post(
        &c,
        &server.url("/v1/pose"),
        &json!({
            "landmarks": landmarks,
            "method": "fit",
            "camera": {"fx": f, "fy": f, "cx": cx, "cy": cy},
            "conventions": ["opencv"],
        }),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    let o = &v["conventions"]["opencv"];
    let scheme: Value = c
        .get(server.url("/v1/models/default/schemes/ibug68"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let rvec = Vector3::from_iterator((0..3).map(|k| o["rvec"][k].as_f64().unwrap()));
    let tvec = Vector3::from_iterator((0..3).map(|k| o["tvec"][k].as_f64().unwrap()));
    let r = Rotation3::new(rvec);
    let points = scheme["mean_opencv"].as_array().unwrap();
    assert_eq!(points.len(), 68);
    let mut sq = 0.0;
    for (p, want) in points.iter().zip(&landmarks) {
        let x = Vector3::from_iterator((0..3).map(|k| p[k].as_f64().unwrap()));
        let cam = r * x + tvec;
        assert!(cam.z > 0.0, "a point behind OpenCV's camera: {cam}");
        let (u, w) = (f * cam.x / cam.z + cx, f * cam.y / cam.z + cy);
        sq += (u - want[0]).powi(2) + (w - want[1]).powi(2);
    }
    let rms = (sq / 68.0).sqrt();
    // Within the fit's residual (RMS over the inter-ocular distance, eye centres 36-41 and
    // 42-47), with room for the weak-perspective views seen through a pinhole.
    let centre = |r: std::ops::Range<usize>| {
        let n = r.len() as f64;
        r.fold([0.0, 0.0], |a, i| {
            [a[0] + landmarks[i][0] / n, a[1] + landmarks[i][1] / n]
        })
    };
    let (l, rr) = (centre(36..42), centre(42..48));
    let iod = (l[0] - rr[0]).hypot(l[1] - rr[1]);
    let residual_px = v["residual"].as_f64().unwrap() * iod;
    eprintln!(
        "projectPoints RMS {rms:.4} px, the fit's residual {residual_px:.4} px, IOD {iod:.1} px"
    );
    assert!(
        rms <= 2.0 * residual_px + 0.1,
        "projectPoints RMS {rms} px against the fit's residual {residual_px} px"
    );
}
