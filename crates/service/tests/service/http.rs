//! The HTTP JSON API of `facepose serve`, black box: the server in-process on a loopback port.
//! Poses come from the default model's mean shape projected at known angles, so the expected
//! answers are independent of the estimator.

use facepose_core::geometry::geodesic_deg;
use facepose_testkit::Endpoint;
use facepose_testkit::faces::*;
use facepose_testkit::raw::*;
use facepose_testkit::server::Server;
use reqwest::StatusCode;
use serde_json::{Value, json};

const POSES: [(f64, f64, f64); 4] = [
    (0.0, 0.0, 0.0),
    (30.0, -12.0, 8.0),
    (-45.0, 15.0, -10.0),
    (65.0, 5.0, 20.0),
];

async fn post(c: &reqwest::Client, url: &str, body: &Value) -> (StatusCode, Value) {
    let r = c.post(url).json(body).send().await.unwrap();
    let status = r.status();
    let v = r.json::<Value>().await.unwrap();
    (status, v)
}

fn assert_pose(v: &Value, (yaw, pitch, roll): (f64, f64, f64), tol: f64) {
    let err = geodesic_deg(&rotation_json(&v["rotation"]), &rotation(yaw, pitch, roll));
    assert!(err < tol, "({yaw}, {pitch}, {roll}) -> {v}");
    for (k, want) in [("yaw", yaw), ("pitch", pitch), ("roll", roll)] {
        let got = v[k].as_f64().unwrap();
        assert!((got - want).abs() < tol, "{k}: {got} vs {want}");
    }
}

#[tokio::test]
async fn known_poses_come_back() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    for &pose in &POSES {
        let (y, p, r) = pose;
        for method in ["auto", "fit", "fit-shape"] {
            let (status, v) = post(
                &c,
                &url,
                &json!({"landmarks": face68(y, p, r), "method": method, "id": "f1"}),
            )
            .await;
            assert_eq!(status, StatusCode::OK, "{v}");
            assert_pose(&v, pose, 0.5);
            assert_eq!(v["id"], "f1");
            assert_eq!(v["scheme"], "ibug68");
            assert_eq!(v["model"], "default");
            assert!(v["model_version"].is_string());
            assert_ne!(v["method"], "auto");
            assert_eq!(v["visible"].as_array().unwrap().len(), 68);
            assert!(v["residual"].as_f64().unwrap() < 0.01, "{v}");
            assert!(v.get("translation").is_none());
        }
        // The five-point scheme and the 51-point inner scheme.
        let (status, v) = post(
            &c,
            &url,
            &json!({"landmarks": face5(y, p, r), "scheme": "five", "method": "fit"}),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{v}");
        assert_pose(&v, pose, 1.0);
        let inner: Vec<_> = face68(y, p, r)[17..].to_vec();
        let (status, v) = post(
            &c,
            &url,
            &json!({"landmarks": inner, "scheme": "inner51", "method": "fit"}),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{v}");
        assert_pose(&v, pose, 0.5);
    }
    // The paper's regression within its training range, and the geometric method on five
    // points (coarser by design).
    let (status, v) = post(
        &c,
        &url,
        &json!({"landmarks": face68(20.0, -10.0, 0.0), "method": "regression"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_pose(&v, (20.0, -10.0, 0.0), 3.0);
    assert_eq!(v["method"], "regression");
    // Missing points (null) do not bias the estimate.
    let mut pts: Vec<Value> = face68(30.0, -12.0, 8.0).iter().map(|p| json!(p)).collect();
    for i in (0..17).chain([30, 48]) {
        pts[i] = Value::Null;
    }
    let (status, v) = post(&c, &url, &json!({"landmarks": pts, "method": "fit"})).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_pose(&v, (30.0, -12.0, 8.0), 0.5);
    // 2D-style landmarks (hidden jaw points on the outline) are accepted too.
    let (status, v) = post(
        &c,
        &url,
        &json!({"landmarks": face68(20.0, 0.0, 0.0), "method": "fit", "landmark_style": "contour"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_pose(&v, (20.0, 0.0, 0.0), 1.0);
    // Camera intrinsics add the face's position.
    let (status, v) = post(
        &c,
        &url,
        &json!({"landmarks": face68(10.0, 0.0, 0.0), "camera": {"fx": 900, "fy": 900, "cx": 320, "cy": 240}}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_eq!(v["translation"].as_array().unwrap().len(), 3);
    assert!(v["translation"][2].as_f64().unwrap() < 0.0, "{v}");
    // HTTP/2 without TLS (h2c) on the same port, and the request id.
    let h2 = reqwest::Client::builder()
        .http2_prior_knowledge()
        .build()
        .unwrap();
    let r = h2
        .post(&url)
        .header("x-request-id", "test-123")
        .json(&json!({"landmarks": face68(0.0, 0.0, 0.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.version(), reqwest::Version::HTTP_2);
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["x-request-id"], "test-123");
    let r = c.get(server.url("/healthz")).send().await.unwrap();
    assert_eq!(r.headers()["x-request-id"].len(), 16);
}

/// Every answer of the default model carries an uncertainty per angle: a standard deviation
/// and a 90% interval centred on the angle, 1.645 of them wide on each side; a profile face's
/// roll and pitch are less certain than a frontal face's, and fewer points widen it.
#[tokio::test]
async fn answers_carry_their_uncertainty() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    let sd = |v: &Value, angle: &str| v["uncertainty"][angle]["sd"].as_f64().unwrap();
    let mut seen = Vec::new();
    for (pose, method) in [
        ((0.0, 0.0, 0.0), "auto"),
        ((70.0, 0.0, 0.0), "auto"),
        ((0.0, 0.0, 0.0), "regression"),
    ] {
        let body = json!({"landmarks": face68(pose.0, pose.1, pose.2), "method": method});
        let (status, v) = post(&c, &url, &body).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        for angle in ["yaw", "pitch", "roll"] {
            let u = &v["uncertainty"][angle];
            let (s, lo, hi) = (
                u["sd"].as_f64().unwrap(),
                u["interval90"][0].as_f64().unwrap(),
                u["interval90"][1].as_f64().unwrap(),
            );
            let a = v[angle].as_f64().unwrap();
            assert!(s > 0.0 && s < 110.0, "{v}");
            assert!(((lo + hi) / 2.0 - a).abs() < 1e-9, "{v}");
            assert!(
                ((hi - lo) / 2.0 - 1.644_853_626_951_472_2 * s).abs() < 1e-6,
                "{v}"
            );
        }
        seen.push(v);
    }
    assert!(
        sd(&seen[1], "roll") > sd(&seen[0], "roll"),
        "{} vs {}",
        seen[1],
        seen[0]
    );
    // The same noisy face with half its points missing: wider.
    let mut seed = 99u64;
    let mut noise = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 4.0
    };
    let noisy: Vec<[f64; 2]> = face68(0.0, 0.0, 0.0)
        .iter()
        .map(|p| [p[0] + noise(), p[1] + noise()])
        .collect();
    let mut half: Vec<Value> = noisy.iter().map(|p| json!(p)).collect();
    for p in half.iter_mut().step_by(2) {
        *p = Value::Null;
    }
    let (status, v) = post(&c, &url, &json!({"landmarks": half, "method": "fit"})).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    let (_, full) = post(&c, &url, &json!({"landmarks": noisy, "method": "fit"})).await;
    assert!(sd(&v, "yaw") > sd(&full, "yaw"), "{v} vs {full}");
}

#[tokio::test]
async fn mediapipe_faces_in_normalized_coordinates() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    let size = [1280.0, 720.0];
    for &pose in &POSES {
        let (y, p, r) = pose;
        let lm = face478_normalized(y, p, r, size);
        // The scheme by name, and by the number of points.
        for scheme in [json!("mediapipe478"), Value::Null] {
            let body = json!({"landmarks": lm, "image_size": size, "scheme": scheme});
            let (status, v) = post(&c, &url, &body).await;
            assert_eq!(status, StatusCode::OK, "{v}");
            assert_pose(&v, pose, 0.01);
            assert_eq!(v["scheme"], "mediapipe478");
            assert_eq!(v["method"], "fit");
            assert_eq!(v["visible"].as_array().unwrap().len(), 478);
            assert_eq!(v["warnings"], json!([]));
        }
        // The 468-point form.
        let body = json!({"landmarks": lm[..468], "image_size": size});
        let (status, v) = post(&c, &url, &body).await;
        assert_eq!(status, StatusCode::OK, "{v}");
        assert_eq!(v["scheme"], "mediapipe468");
        assert_pose(&v, pose, 0.01);
    }
    // The same in a batch, image_size at the batch's level.
    let lm = face478_normalized(30.0, -12.0, 8.0, size);
    let body = json!({"image_size": size, "faces": [{"landmarks": lm, "id": 1}]});
    let (status, v) = post(&c, &server.url("/v1/pose:batch"), &body).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_pose(&v["results"][0], (30.0, -12.0, 8.0), 0.01);
    // A new user's mistakes, each a 422 that says what to fix.
    let pixels: Vec<[f64; 2]> = lm
        .iter()
        .map(|p| [p[0] * size[0], p[1] * size[1]])
        .collect();
    let cases = [
        // Normalized coordinates without the image size (a 16:9 frame's).
        (json!({"landmarks": lm}), "look like normalized coordinates"),
        // Pixels said to be normalized.
        (
            json!({"landmarks": pixels, "image_size": size}),
            "is not a normalized coordinate",
        ),
        (
            json!({"landmarks": lm, "image_size": [0, 720]}),
            "image_size",
        ),
        (
            json!({"landmarks": lm[..477], "image_size": size, "scheme": "mediapipe478"}),
            "expected 478 points, got 477",
        ),
        (
            json!({"landmarks": lm[..300], "image_size": size}),
            "300 landmarks, and no scheme of this model has that many",
        ),
        // MediaPipe's first 68 points sent as ibug68.
        (
            json!({"landmarks": pixels[..68], "scheme": "ibug68"}),
            "do not look like a face in scheme ibug68",
        ),
    ];
    for (body, want) in &cases {
        let (status, v) = post(&c, &url, body).await;
        assert_eq!(status.as_u16(), 422, "{v}");
        let msg = v["error"]["message"].as_str().unwrap();
        assert!(msg.contains(want), "{msg:?} lacks {want:?}");
    }
}

#[tokio::test]
async fn batches_have_per_face_results_and_a_limit() {
    let server = Server::start(&["--max-batch", "4"]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose:batch");
    let body = json!({
        "method": "fit",
        "faces": [
            {"landmarks": face68(30.0, -12.0, 8.0), "id": 1},
            {"landmarks": [[1, 2], [3, 4]], "id": "short"},
            {"landmarks": face5(-45.0, 15.0, -10.0), "scheme": "five", "id": 2.5},
            {"landmarks": vec![[3.0, 3.0]; 68], "method": "geometry"},
        ]
    });
    let (status, v) = post(&c, &url, &body).await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_eq!(v["succeeded"], 2);
    assert_eq!(v["failed"], 2);
    assert_eq!(v["model"], "default");
    let r = v["results"].as_array().unwrap();
    assert_eq!(r.len(), 4);
    assert_pose(&r[0], (30.0, -12.0, 8.0), 0.5);
    assert_eq!(r[0]["id"], 1);
    assert_eq!(r[1]["id"], "short");
    assert_eq!(r[1]["error"]["code"], "invalid_argument");
    assert!(
        r[1]["error"]["message"]
            .as_str()
            .unwrap()
            .contains("2 landmarks, and no scheme of this model has that many")
    );
    assert_pose(&r[2], (-45.0, 15.0, -10.0), 1.0);
    assert_eq!(r[2]["scheme"], "five");
    assert_eq!(r[2]["id"], 2.5);
    assert!(r[3].get("id").is_none());
    assert!(
        r[3]["error"]["message"]
            .as_str()
            .unwrap()
            .contains("degenerate")
    );
    // An empty batch is fine; one over the limit is refused with the limit in the message.
    let (status, v) = post(&c, &url, &json!({"faces": []})).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(v["results"].as_array().unwrap().len(), 0);
    let five = vec![json!({"landmarks": face68(0.0, 0.0, 0.0)}); 5];
    let (status, v) = post(&c, &url, &json!({"faces": five})).await;
    assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE);
    assert_eq!(v["error"]["code"], "payload_too_large");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("5 faces in one request; the limit is 4"),
        "{v}"
    );
    // A big batch goes through the blocking pool with the same answers.
    let server = Server::start(&[]);
    let faces: Vec<Value> = (0..200)
        .map(|k| json!({"landmarks": face68(-60.0 + k as f64 * 0.6, 10.0, -5.0), "id": k}))
        .collect();
    let (status, v) = post(
        &c,
        &server.url("/v1/pose:batch"),
        &json!({"faces": faces, "method": "fit"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    for (k, r) in v["results"].as_array().unwrap().iter().enumerate() {
        assert_eq!(r["id"], k);
        assert_pose(r, (-60.0 + k as f64 * 0.6, 10.0, -5.0), 0.5);
    }
}

#[tokio::test]
async fn models_health_metrics_and_openapi() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let get = |path: &str| c.get(server.url(path)).send();
    let r = get("/v1/models").await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["default_model"], "default");
    let m = &v["models"][0];
    assert_eq!(m["name"], "default");
    assert_eq!(m["scheme"], "ibug68");
    assert_eq!(m["default"], true);
    assert_eq!(
        m["schemes"],
        json!([{"name": "ibug68", "points": 68}, {"name": "inner51", "points": 51}, {"name": "five", "points": 5}, {"name": "dlib5", "points": 5}, {"name": "mediapipe468", "points": 468}, {"name": "mediapipe478", "points": 478}])
    );
    assert!(m["checksum"].as_str().unwrap().starts_with("sha256:"));
    assert!(
        m["methods"]
            .as_array()
            .unwrap()
            .contains(&json!("fit-shape"))
    );
    let v: Value = get("/v1/models/default")
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(v["name"], "default");
    assert!(
        v["provenance"]["command"]
            .as_str()
            .unwrap()
            .contains("train")
    );
    let r = get("/v1/models/nope").await.unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    let v: Value = r.json().await.unwrap();
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("unknown model \"nope\"; loaded models: default")
    );
    let r = get("/healthz").await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.json::<Value>().await.unwrap()["status"], "alive");
    let r = get("/readyz").await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.json::<Value>().await.unwrap()["status"], "ready");
    // Some traffic, then the metrics show it.
    let _ = post(
        &c,
        &server.url("/v1/pose"),
        &json!({"landmarks": face68(0.0, 0.0, 0.0), "method": "fit"}),
    )
    .await;
    let _ = post(&c, &server.url("/v1/pose"), &json!({"landmarks": []})).await;
    let r = get("/metrics").await.unwrap();
    assert!(
        r.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/plain")
    );
    let text = r.text().await.unwrap();
    for want in [
        r#"facepose_http_requests_total{route="/v1/pose",method="POST",status="200"} 1"#,
        r#"facepose_http_requests_total{route="/v1/pose",method="POST",status="422"} 1"#,
        r#"facepose_http_request_duration_seconds_bucket{route="/v1/pose",method="POST",le="#,
        r#"facepose_poses_total{transport="http",method="fit"} 1"#,
        r#"facepose_estimate_errors_total{transport="http",code="invalid_argument"} 1"#,
        r#"facepose_model_info{name="default",version="#,
        "facepose_ready 1",
    ] {
        assert!(text.contains(want), "{want} not in\n{text}");
    }
    let v: Value = get("/openapi.json").await.unwrap().json().await.unwrap();
    assert!(v["openapi"].as_str().unwrap().starts_with('3'));
    for p in ["/v1/pose", "/v1/pose:batch", "/v1/models/{name}", "/readyz"] {
        assert!(v["paths"][p].is_object(), "{p}");
    }
    // Unknown routes and methods.
    let r = get("/v2/nothing").await.unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    assert!(
        r.json::<Value>().await.unwrap()["error"]["message"]
            .as_str()
            .unwrap()
            .contains("no route GET /v2/nothing")
    );
    let r = get("/v1/pose").await.unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
    assert_eq!(
        r.json::<Value>().await.unwrap()["error"]["code"],
        "method_not_allowed"
    );
}

/// `[x, y, z]` rows of a JSON array.
fn points3(v: &Value) -> Vec<[f64; 3]> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|p| std::array::from_fn(|k| p[k].as_f64().unwrap()))
        .collect()
}

/// Pose_Para's `R = Rx(pitch) · Ry(yaw) · Rz(roll)` written out from ../shared/DESIGN.md's
/// matrices, and the weak-perspective image mapping `[u, -v] = s (R X)[0:2] + t`: what a
/// client (the demo page) does with a scheme's mean shape, independent of the core's code.
fn project_by_hand(x: [f64; 3], (yaw, pitch, roll): (f64, f64, f64)) -> [f64; 2] {
    let (sp, cp) = pitch.to_radians().sin_cos();
    let (sy, cy) = yaw.to_radians().sin_cos();
    let (sr, cr) = roll.to_radians().sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]];
    let ry = [[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]];
    let rz = [[cr, sr, 0.0], [-sr, cr, 0.0], [0.0, 0.0, 1.0]];
    let mul = |a: [[f64; 3]; 3], b: [[f64; 3]; 3]| -> [[f64; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
    };
    let r = mul(mul(rx, ry), rz);
    let rot = |i: usize| (0..3).map(|k| r[i][k] * x[k]).sum::<f64>();
    let (s, t) = (2.5, [320.0, -240.0]);
    [s * rot(0) + t[0], -(s * rot(1) + t[1])]
}

#[tokio::test]
async fn schemes_give_the_mean_shape_that_projects_to_a_known_pose() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let get = |path: String| c.get(server.url(&path)).send();
    let models: Value = get("/v1/models".into())
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let mut schemes = 0;
    for s in models["models"][0]["schemes"].as_array().unwrap() {
        let name = s["name"].as_str().unwrap();
        let r = get(format!("/v1/models/default/schemes/{name}"))
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::OK, "{name}");
        let v: Value = r.json().await.unwrap();
        assert_eq!(v["scheme"], name);
        assert_eq!(v["model"], "default");
        assert_eq!(v["model_version"], models["models"][0]["version"]);
        let n = s["points"].as_u64().unwrap() as usize;
        assert_eq!(v["points"].as_array().unwrap().len(), n, "{name}");
        let mean = points3(&v["mean"]);
        assert_eq!(mean.len(), n, "{name}");
        // The model frame: the subject's left eye (image-right) at larger x, the eyes above
        // the mouth, and (where the scheme has one) the nose tip nearest the camera.
        let at = |key: &str| -> Option<[f64; 3]> {
            let idx: Vec<usize> = v["anchors"][key]
                .as_array()
                .unwrap()
                .iter()
                .map(|i| i.as_u64().unwrap() as usize)
                .collect();
            (!idx.is_empty()).then(|| {
                std::array::from_fn(|k| {
                    idx.iter().map(|&i| mean[i][k]).sum::<f64>() / idx.len() as f64
                })
            })
        };
        let (left, right) = (at("eye_left").unwrap(), at("eye_right").unwrap());
        assert!(
            left[0] < -20.0 && right[0] > 20.0,
            "{name}: eyes at {left:?} {right:?}"
        );
        if let (Some(nose), Some(mouth)) = (at("nose_tip"), at("mouth_left")) {
            assert!(mouth[1] < left[1], "{name}: the mouth below the eyes");
            let deepest = mean.iter().map(|p| p[2]).fold(f64::MIN, f64::max);
            assert!(
                nose[2] > deepest - 5.0,
                "{name}: nose tip z {} of {deepest}",
                nose[2]
            );
        }
        // Projected by hand at a known pose, the mean shape comes back as that pose.
        for pose in [(30.0, -10.0, 5.0), (-50.0, 15.0, -8.0)] {
            let landmarks: Vec<[f64; 2]> = mean.iter().map(|&x| project_by_hand(x, pose)).collect();
            let (status, answer) = post(
                &c,
                &server.url("/v1/pose"),
                &json!({"landmarks": landmarks, "scheme": name, "method": "fit"}),
            )
            .await;
            assert_eq!(status, StatusCode::OK, "{name}: {answer}");
            assert_pose(&answer, pose, 0.5);
        }
        schemes += 1;
    }
    assert!(schemes >= 4, "{models}");
    // ibug68's five anchors are the five-point scheme's points: one mean shape for both.
    let ibug: Value = get("/v1/models/default/schemes/ibug68".into())
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let five: Value = get("/v1/models/default/schemes/five".into())
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let (ibug_mean, five_mean) = (points3(&ibug["mean"]), points3(&five["mean"]));
    assert_eq!(ibug["anchors"]["eye_left"], json!([36, 37, 38, 39, 40, 41]));
    for (k, key) in [
        "eye_left",
        "eye_right",
        "nose_tip",
        "mouth_left",
        "mouth_right",
    ]
    .iter()
    .enumerate()
    {
        let idx = ibug["anchors"][key].as_array().unwrap();
        for d in 0..3 {
            let m = idx
                .iter()
                .map(|i| ibug_mean[i.as_u64().unwrap() as usize][d])
                .sum::<f64>()
                / idx.len() as f64;
            assert!(
                (m - five_mean[k][d]).abs() < 1e-9,
                "{key}[{d}]: {m} vs {}",
                five_mean[k][d]
            );
        }
    }
    assert_eq!(ibug["contour"].as_array().unwrap().len(), 17);
    assert_eq!(ibug["mirror"][36], 45);

    // Unknown schemes and models are 404 with what there is; an overlong name is 422.
    let r = get("/v1/models/default/schemes/mediapipe9".into())
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["error"]["code"], "not_found");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .starts_with("model \"default\" serves no scheme \"mediapipe9\"; it serves ibug68, inner51, five, dlib5"),
        "{v}"
    );
    let r = get("/v1/models/nope/schemes/five".into()).await.unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    let v: Value = r.json().await.unwrap();
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .starts_with("unknown model \"nope\""),
        "{v}"
    );
    let r = get(format!("/v1/models/default/schemes/{}", "x".repeat(65)))
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
    let r = get("/v1/models/default/schemes/%C0".into()).await.unwrap();
    assert_eq!(r.status(), StatusCode::BAD_REQUEST);
    assert_eq!(
        r.json::<Value>().await.unwrap()["error"]["code"],
        "malformed_path"
    );
    let r = c
        .post(server.url("/v1/models/default/schemes/five"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
}

/// Three landmarks present out of 68.
fn few_points() -> Vec<Value> {
    let mut v = vec![Value::Null; 68];
    v[36] = json!([100.0, 100.0]);
    v[45] = json!([140.0, 100.0]);
    v[30] = json!([120.0, 130.0]);
    v
}

/// Every class of bad input: the status and a message that says what to fix.
#[tokio::test]
async fn bad_input_says_what_to_fix() {
    let server = Server::start(&["--max-body", "64KiB"]);
    let url = server.url("/v1/pose");
    let c = reqwest::Client::new();
    let ok = face68(10.0, 0.0, 0.0);
    let json_cases: Vec<(Value, u16, &str)> = vec![
        (
            json!({"landmarks": face68(0.0, 0.0, 0.0)[..5]}),
            422,
            "5 landmarks fit more than one scheme, so name it: five [",
        ),
        (
            json!({"landmarks": face5(0.0, 0.0, 0.0), "scheme": "five", "method": "fit-shape"}),
            422,
            "fit-shape does not take scheme five",
        ),
        (
            json!({"landmarks": vec![Value::Null; 68]}),
            422,
            "needs at least",
        ),
        (
            json!({"landmarks": few_points(), "method": "fit"}),
            422,
            "needs at least 4 points present, got 3",
        ),
        (
            json!({"landmarks": vec![[3.5, 3.5]; 68]}),
            422,
            "degenerate",
        ),
        (
            json!({"landmarks": (0..68).map(|i| [i as f64, 2.0 * i as f64 + 1.0]).collect::<Vec<_>>()}),
            422,
            "degenerate",
        ),
        (
            json!({"landmarks": vec![[-0.0, -0.0]; 68]}),
            422,
            "degenerate",
        ),
        (
            json!({"landmarks": (0..68).map(|i| [1e308 * (i % 2) as f64, 5.0]).collect::<Vec<_>>()}),
            422,
            "out of range",
        ),
        (
            json!({"landmarks": ok, "scheme": "mediapipe999"}),
            422,
            "this model serves ibug68, inner51, five",
        ),
        (
            json!({"landmarks": ok, "method": "magic"}),
            422,
            "unknown method \"magic\"",
        ),
        (
            json!({"landmarks": ok, "model": "nope"}),
            404,
            "unknown model \"nope\"",
        ),
        (
            json!({"landmarks": ok, "camera": {"fx": -1, "fy": 1, "cx": 0, "cy": 0}}),
            422,
            "focal lengths must be positive",
        ),
        (
            json!({"landmarks": ok, "camera": {"fx": 1}}),
            422,
            "missing field `fy`",
        ),
        (
            json!({"landmarks": ok, "method": "regression", "camera": {"fx": 900, "fy": 900, "cx": 0, "cy": 0}}),
            422,
            "weak-perspective only",
        ),
        (
            json!({"landmarks": "all of them"}),
            422,
            "landmarks: expected an array of landmarks, each [x, y] (pixels) or null, found a string",
        ),
        (
            json!({"landmarks": [[1, 2], {"x": 1}]}),
            422,
            "landmark 1 must be [x, y] numbers or null, found an object",
        ),
        (
            json!({"landmarks": [[1, 2], [3, [4]]]}),
            422,
            "landmark 1 y must be a number, found an array",
        ),
        (
            json!({"landmarks": [[1, 2], [3, "4"]]}),
            422,
            "landmark 1 y is the string \"4\"",
        ),
        (
            json!({"landmarks": [[1, 2, 3]]}),
            422,
            "landmark 0 must be [x, y] numbers or null: it has more than 2",
        ),
        (
            json!({"landmarks": [["NaN", 2]]}),
            422,
            "not a finite number",
        ),
        (
            json!({"landmarks": null, "scheme": null, "method": null, "model": null, "camera": null, "id": null}),
            422,
            "landmarks: expected an array of landmarks, each [x, y] (pixels) or null, found null",
        ),
        (
            json!({"landmarks": ok, "scheme": 68}),
            422,
            "scheme: invalid type: integer",
        ),
        (
            json!({"landmarks": ok, "id": {"a": 1}}),
            422,
            "id as a string or a number",
        ),
        (
            json!({"landmarks": ok, "methd": "fit"}),
            422,
            "unknown field `methd`",
        ),
        (
            json!({"landmarks": ok, "landmark_style": "sketch"}),
            422,
            "unknown landmark style \"sketch\"",
        ),
        (
            json!({"scheme": "ibug68"}),
            422,
            "missing field `landmarks`",
        ),
        (json!([1, 2]), 422, "the body must be a JSON object"),
        (json!(null), 422, "the body must be a JSON object"),
        (json!("landmarks"), 422, "the body must be a JSON object"),
    ];
    for (body, status, want) in &json_cases {
        let (s, v) = post(&c, &url, body).await;
        let msg = v["error"]["message"].as_str().unwrap_or_default();
        assert_eq!(s.as_u16(), *status, "{body}: {v}");
        assert!(msg.contains(want), "{body}: {msg:?} lacks {want:?}");
    }
    // Bodies that are not JSON values of ours.
    let raw_cases: [(&str, &[u8], u16, &str); 9] = [
        ("application/json", b"", 400, "empty request body"),
        (
            "application/json",
            b"{\"landmarks\": [[1, 2]",
            400,
            "malformed JSON",
        ),
        (
            "application/json",
            b"{landmarks: []}",
            400,
            "malformed JSON: key must be a string",
        ),
        (
            "application/json",
            b"{\"landmarks\": [[1, NaN]]}",
            422,
            "NaN and Infinity are not JSON numbers",
        ),
        (
            "application/json",
            b"{\"landmarks\": [[Infinity, 1]]}",
            422,
            "NaN and Infinity are not JSON numbers",
        ),
        (
            "application/json",
            b"{\"landmarks\": [[1e400, 1]]}",
            422,
            "landmark 0 x = 1e400 is out of range for a 64-bit float",
        ),
        (
            "application/json",
            b"{\"landmarks\": []} trailing",
            400,
            "trailing characters",
        ),
        (
            "text/plain",
            b"{}",
            415,
            "is not JSON: send Content-Type: application/json",
        ),
        (
            "application/x-www-form-urlencoded",
            b"landmarks=1",
            415,
            "send Content-Type: application/json",
        ),
    ];
    for (ct, body, status, want) in raw_cases {
        let (s, text) = raw_post(server.addr, "/v1/pose", ct, body);
        assert_eq!(s, status, "{}: {text}", String::from_utf8_lossy(body));
        assert!(
            text.contains(want),
            "{}: {text}",
            String::from_utf8_lossy(body)
        );
    }
    let r = c.post(&url).body("{}").send().await.unwrap();
    assert_eq!(r.status(), StatusCode::UNSUPPORTED_MEDIA_TYPE);
    assert!(r.text().await.unwrap().contains("missing Content-Type"));
    // Over the body limit, declared or streamed.
    let big = json!({"faces": vec![json!({"landmarks": face68(0.0, 0.0, 0.0)}); 40]});
    let (s, v) = post(&c, &server.url("/v1/pose:batch"), &big).await;
    assert_eq!(s, StatusCode::PAYLOAD_TOO_LARGE, "{v}");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("over the limit of 65536 bytes (--max-body)")
    );
    // Declared far over the limit, or with `Expect: 100-continue`: answered before the body.
    for extra in ["", "Expect: 100-continue\r\n"] {
        let (s, text) = raw_head_only_post(server.addr, "/v1/pose", 50_000_000, extra);
        assert_eq!(s, 413, "{extra}: {text}");
        assert!(text.contains("50000000 bytes is over the limit"), "{text}");
    }
    let (s, text) = raw_chunked_post(server.addr, "/v1/pose", &[&[b' '; 40_000][..]; 3]);
    assert_eq!(s, 413, "{text}");
    assert!(text.contains("over the limit of 65536 bytes"), "{text}");
    // Still alive and well.
    let (s, v) = post(&c, &url, &json!({"landmarks": ok, "method": "fit"})).await;
    assert_eq!(s, StatusCode::OK);
    assert_pose(&v, (10.0, 0.0, 0.0), 0.5);
}

#[tokio::test]
async fn long_names_are_refused_and_errors_never_echo_more_than_a_kilobyte() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let long = "x".repeat(20_000);
    let face = face68(10.0, 0.0, 0.0);
    for (field, status) in [
        ("model", StatusCode::UNPROCESSABLE_ENTITY),
        ("scheme", StatusCode::UNPROCESSABLE_ENTITY),
        ("method", StatusCode::UNPROCESSABLE_ENTITY),
        ("landmark_style", StatusCode::UNPROCESSABLE_ENTITY),
    ] {
        let mut body = json!({"landmarks": face});
        body[field] = json!(long);
        let (got, v) = post(&c, &server.url("/v1/pose"), &body).await;
        assert_eq!(got, status, "{field}: {v}");
        let message = v["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("at most 64 characters"),
            "{field}: {message}"
        );
        assert!(message.len() < 200, "{field}: {} bytes", message.len());
        // In a batch's face: the batch is outside its schema, refused whole.
        if field != "model" {
            let mut one = json!({"landmarks": face});
            one[field] = json!(long);
            let (got, v) = post(&c, &server.url("/v1/pose:batch"), &json!({"faces": [one]})).await;
            assert_eq!(got, StatusCode::UNPROCESSABLE_ENTITY, "{field}: {v}");
            let message = v["error"]["message"].as_str().unwrap();
            assert!(message.starts_with("faces[0]: "), "{field}: {message}");
            assert!(message.len() < 200, "{field}: {message}");
        }
    }
    // An unknown field's name is echoed by serde: within the bound, cut and saying so.
    let mut body = json!({"landmarks": face});
    body[&long] = json!(1);
    let (got, v) = post(&c, &server.url("/v1/pose"), &body).await;
    assert_eq!(got, StatusCode::UNPROCESSABLE_ENTITY, "{v}");
    let message = v["error"]["message"].as_str().unwrap();
    assert!(
        message.len() <= 1024 && message.ends_with("bytes cut)"),
        "{message}"
    );
}

#[tokio::test]
async fn ids_come_back_as_sent() {
    // An id of 2^64 came back as 1.8446744073709552e+19.
    let server = Server::start(&[]);
    let face = serde_json::to_string(&face5(10.0, 0.0, 0.0)).unwrap();
    for id in [
        "18446744073709551616",
        "-9223372036854775809",
        "7",
        "2.50",
        "1e3",
        "\"a\\u00e9\"",
    ] {
        let body = format!("{{\"landmarks\": {face}, \"scheme\": \"five\", \"id\": {id}}}");
        let (s, text) = raw_post(server.addr, "/v1/pose", "application/json", body.as_bytes());
        assert_eq!(s, 200, "{text}");
        let sent: Value = serde_json::from_str(id).unwrap();
        let got: Value = serde_json::from_str(&text).unwrap();
        if sent.is_string() {
            assert_eq!(got["id"], sent);
        } else {
            assert!(text.contains(&format!("\"id\":{id}")), "{id}: {text}");
        }
        let body = format!(
            "{{\"scheme\": \"five\", \"faces\": [{{\"landmarks\": {face}, \"id\": {id}}}, \
             {{\"landmarks\": [], \"id\": {id}}}]}}"
        );
        let (s, text) = raw_post(
            server.addr,
            "/v1/pose:batch",
            "application/json",
            body.as_bytes(),
        );
        assert_eq!(s, 200, "{text}");
        if !sent.is_string() {
            assert_eq!(text.matches(&format!("\"id\":{id}")).count(), 2, "{text}");
        }
    }
    for bad in ["true", "[1]", "{}"] {
        let body = format!("{{\"landmarks\": {face}, \"scheme\": \"five\", \"id\": {bad}}}");
        let (s, text) = raw_post(server.addr, "/v1/pose", "application/json", body.as_bytes());
        assert_eq!(s, 422, "{text}");
        assert!(text.contains("id as a string or a number"), "{text}");
    }
}

#[tokio::test]
async fn path_segments_that_do_not_decode_get_the_json_error() {
    let server = Server::start(&[]);
    for path in [
        "/v1/models/%c0%ae",
        "/v1/models/%ff/versions",
        "/v1/models/jobs/%80",
    ] {
        let (s, text) = raw_get(server.addr, path).unwrap();
        assert_eq!(s, 400, "{path}: {text}");
        let v: Value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
        assert_eq!(v["error"]["code"], "malformed_path", "{v}");
        assert!(
            v["error"]["message"].as_str().unwrap().contains("UTF-8"),
            "{v}"
        );
    }
}

/// The OpenAPI document's schemas for what clients send: an integer id matches one branch of
/// `FaceId` (it matched two of `oneOf [string, integer, number]`), landmark lists are bounded,
/// and every status a path route answers for a bad name is listed.
#[tokio::test]
async fn the_document_describes_ids_landmarks_and_path_errors() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let (_, doc) = facepose_testkit::registry::get(&c, &server, "/openapi.json").await;
    let schemas = &doc["components"]["schemas"];
    let branches = schemas["FaceId"]["oneOf"].as_array().unwrap();
    let types: Vec<&str> = branches
        .iter()
        .map(|b| b["type"].as_str().unwrap())
        .collect();
    assert_eq!(types, ["string", "number"], "{}", schemas["FaceId"]);
    for (schema, field) in [("PoseRequest", "landmarks"), ("BatchFace", "landmarks")] {
        let l = &schemas[schema]["properties"][field];
        assert_eq!(l["maxItems"], 1000, "{schema}: {l}");
        assert_eq!(l["items"]["minItems"], 2, "{schema}: {l}");
        assert_eq!(l["items"]["maxItems"], 2, "{schema}: {l}");
        assert_eq!(
            l["items"]["type"],
            json!(["array", "null"]),
            "{schema}: {l}"
        );
    }
    // Values the server takes are valid, and values it refuses are not, where a schema can say.
    let pose = &schemas["PoseRequest"]["properties"];
    let methods = pose["method"]["enum"].as_array().unwrap();
    for m in ["auto", "fit", "fit-shape", "regression", "geometry", ""] {
        assert!(methods.contains(&json!(m)), "{m} not in {methods:?}");
    }
    assert_eq!(pose["scheme"]["maxLength"], 64);
    assert_eq!(
        schemas["Camera"]["properties"]["fx"]["exclusiveMinimum"],
        0.0
    );
    let example = &schemas["PoseRequest"]["example"];
    let r = c
        .post(server.url("/v1/pose"))
        .json(example)
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.status(),
        StatusCode::OK,
        "the document's example: {example}"
    );
    let upload = &schemas["RetrainRequest"]["properties"];
    let kinds: Vec<&Value> = upload["scheme"]["oneOf"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| &b["type"])
        .collect();
    assert!(kinds.contains(&&json!("string")), "{kinds:?}");
    assert_eq!(
        upload["shapes"]["items"]["items"]["minItems"], 3,
        "{}",
        upload["shapes"]
    );
    let activate = &doc["paths"]["/v1/models/{name}/versions/{version}"]["post"]["parameters"][1];
    assert_eq!(
        activate["schema"]["pattern"], "^[^:/]+:activate$",
        "{activate}"
    );
    // Bad names on every route with path parameters: the status is one the document lists.
    let long = "m".repeat(65);
    let routes = [
        ("get", "/v1/models/{name}", "/v1/models/NAME"),
        (
            "get",
            "/v1/models/{name}/versions",
            "/v1/models/NAME/versions",
        ),
        (
            "post",
            "/v1/models/{name}/versions/{version}",
            "/v1/models/NAME/versions/1:activate",
        ),
        (
            "delete",
            "/v1/models/{name}/versions/{version}",
            "/v1/models/NAME/versions/1",
        ),
        ("get", "/v1/models/jobs/{id}", "/v1/models/jobs/NAME"),
        (
            "post",
            "/v1/models/jobs/{id}",
            "/v1/models/jobs/NAME:cancel",
        ),
    ];
    let admin = Server::start_admin(&[], "0123456789abcdef-admin");
    for (method, template, path) in routes {
        let listed = doc["paths"][template][method]["responses"]
            .as_object()
            .unwrap_or_else(|| panic!("{method} {template}"));
        for name in ["..", "Upper", "a%20b", long.as_str(), "%c0%ae"] {
            let url = admin.url(&path.replace("NAME", name));
            let r = c
                .request(method.to_uppercase().parse().unwrap(), url)
                .bearer_auth("0123456789abcdef-admin")
                .send()
                .await
                .unwrap();
            let status = r.status().as_u16().to_string();
            assert!(
                listed.contains_key(&status),
                "{method} {path} with {name:?}: {status} not in {:?}",
                listed.keys().collect::<Vec<_>>()
            );
        }
    }
}

#[tokio::test]
async fn a_batch_outside_its_schema_is_refused_whole() {
    // Such batches got a 200 with each face's error; the schema rules them out.
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose:batch");
    let good = json!({"landmarks": face5(10.0, 0.0, 0.0)});
    let long = "s".repeat(65);
    for (body, words) in [
        (
            json!({"scheme": long, "faces": [good]}),
            "at most 64 characters",
        ),
        (
            json!({"scheme": "five", "faces": [good, {"landmarks": face5(0.0, 0.0, 0.0), "method": "bogus"}]}),
            "faces[1]: ",
        ),
        (
            json!({"scheme": "five", "faces": [good], "landmark_style": "sketch"}),
            "unknown landmark style",
        ),
        (
            json!({"scheme": "five", "faces": [{"landmarks": face5(0.0, 0.0, 0.0), "camera": {"fx": 0, "fy": 900, "cx": 0, "cy": 0}}]}),
            "faces[0]: ",
        ),
        (
            json!({"scheme": "five", "faces": [{"landmarks": [[1, 2], null, [5, 6], [7, 8], [9, 2e9]]}]}),
            "faces[0]: invalid parameter landmarks: landmark 4 y = 2e9 is out of range",
        ),
    ] {
        let (status, v) = post(&c, &url, &body).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}: {v}");
        let m = v["error"]["message"].as_str().unwrap();
        assert!(m.contains(words), "{words:?} not in {m:?}");
    }
    // What the schema cannot say stays the face's own error.
    let (status, v) = post(
        &c,
        &url,
        &json!({"scheme": "five", "faces": [good, {"landmarks": [[1, 2]]}, {"landmarks": face5(0.0, 0.0, 0.0), "scheme": "nope"}]}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{v}");
    assert_eq!(
        (v["succeeded"].as_u64(), v["failed"].as_u64()),
        (Some(1), Some(2)),
        "{v}"
    );
}

/// The admin routes (path, method), one per kind of admin operation.
const ADMIN_ROUTES: [(&str, &str); 4] = [
    ("/v1/models", "POST"),
    ("/v1/models/default/versions/1:activate", "POST"),
    ("/v1/models/default/versions/1", "DELETE"),
    ("/v1/models/jobs/j-nope:cancel", "POST"),
];

/// A browser's preflight, as Chromium sends it before a `fetch()` of another origin.
async fn preflight(
    c: &reqwest::Client,
    url: &str,
    origin: &str,
    method: &str,
    headers: &str,
) -> reqwest::Response {
    let mut r = c
        .request(reqwest::Method::OPTIONS, url)
        .header("origin", origin)
        .header("access-control-request-method", method);
    if !headers.is_empty() {
        r = r.header("access-control-request-headers", headers);
    }
    r.send().await.unwrap()
}

fn header<'a>(r: &'a reqwest::Response, name: &str) -> Option<&'a str> {
    r.headers().get(name).map(|v| v.to_str().unwrap())
}

/// The comma-separated values of a header, in lower case.
fn header_list(r: &reqwest::Response, name: &str) -> Vec<String> {
    header(r, name)
        .unwrap_or_default()
        .split(',')
        .map(|s| s.trim().to_ascii_lowercase())
        .filter(|s| !s.is_empty())
        .collect()
}

/// An answer a browser accepts for a call of `method` with `headers` from `origin`.
fn assert_preflight_allows(r: &reqwest::Response, origin: &str, method: &str, headers: &[&str]) {
    assert!(
        r.status() == StatusCode::OK || r.status() == StatusCode::NO_CONTENT,
        "{}",
        r.status()
    );
    assert_eq!(
        header(r, "access-control-allow-origin"),
        Some(origin),
        "{r:?}"
    );
    assert!(
        header_list(r, "access-control-allow-methods").contains(&method.to_ascii_lowercase()),
        "{r:?}"
    );
    let allowed = header_list(r, "access-control-allow-headers");
    for h in headers {
        assert!(allowed.iter().any(|a| a == h), "{h} not allowed: {r:?}");
    }
    assert_eq!(header(r, "access-control-max-age"), Some("600"), "{r:?}");
    assert_eq!(header(r, "access-control-allow-credentials"), None, "{r:?}");
}

/// A preflight answer a browser refuses: no allowed origin.
fn assert_preflight_refused(r: &reqwest::Response) {
    assert_eq!(header(r, "access-control-allow-origin"), None, "{r:?}");
    assert!(
        !header_list(r, "access-control-allow-headers").contains(&"authorization".to_string()),
        "{r:?}"
    );
}

#[tokio::test]
async fn cors_opens_every_v1_route_to_listed_origins_only() {
    use facepose_testkit::registry::ADMIN_TOKEN;
    let app = "https://app.example.com";
    let server = Server::start_admin(
        &["--cors-origins", &format!("{app},http://localhost:3000")],
        ADMIN_TOKEN,
    );
    let c = reqwest::Client::new();
    let pose = server.url("/v1/pose");

    // Chromium's preflight of fetch(POST, content-type: application/json).
    let r = preflight(&c, &pose, app, "POST", "content-type").await;
    assert_preflight_allows(&r, app, "POST", &["content-type", "x-request-id"]);
    // No admin token on the pose routes: authorization is not offered there.
    assert!(!header_list(&r, "access-control-allow-headers").contains(&"authorization".into()));
    assert!(header(&r, "x-request-id").is_some(), "{r:?}");
    let r = preflight(
        &c,
        &server.url("/v1/pose:batch"),
        "http://localhost:3000",
        "POST",
        "content-type,x-request-id",
    )
    .await;
    assert_preflight_allows(
        &r,
        "http://localhost:3000",
        "POST",
        &["content-type", "x-request-id"],
    );

    // The call itself: the pose, readable by the page, with its request id exposed.
    let r = c
        .post(&pose)
        .header("origin", app)
        .header("x-request-id", "cors-1")
        .json(&json!({"landmarks": face68(20.0, -5.0, 3.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, "access-control-allow-origin"), Some(app));
    assert!(header_list(&r, "access-control-expose-headers").contains(&"x-request-id".into()));
    assert!(header_list(&r, "vary").contains(&"origin".into()), "{r:?}");
    assert_eq!(header(&r, "x-request-id"), Some("cors-1"));
    assert_pose(&r.json::<Value>().await.unwrap(), (20.0, -5.0, 3.0), 0.5);
    // An error answer is readable too (the page can show its message).
    let r = c
        .post(&pose)
        .header("origin", app)
        .json(&json!({"landmarks": [[1, 2]]}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(header(&r, "access-control-allow-origin"), Some(app));

    // The read-only model routes.
    for path in [
        "/v1/models",
        "/v1/models/default",
        "/v1/models/default/schemes/five",
        "/v1/models/default/versions",
        "/v1/models/jobs/j-nope",
    ] {
        let r = preflight(&c, &server.url(path), app, "GET", "x-request-id").await;
        assert_preflight_allows(&r, app, "GET", &["x-request-id"]);
        let r = c
            .get(server.url(path))
            .header("origin", app)
            .send()
            .await
            .unwrap();
        assert_eq!(
            header(&r, "access-control-allow-origin"),
            Some(app),
            "{path}"
        );
    }

    // Admin routes: to listed origins, with authorization; the preflight never meets the
    // admin check (no token sent) nor the 405 of a route without OPTIONS.
    for (path, method) in ADMIN_ROUTES {
        let r = preflight(
            &c,
            &server.url(path),
            app,
            method,
            "authorization,content-type",
        )
        .await;
        assert_preflight_allows(&r, app, method, &["authorization", "content-type"]);
    }
    let r = c
        .post(server.url("/v1/models/jobs/j-nope:cancel"))
        .header("origin", app)
        .bearer_auth(ADMIN_TOKEN)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    assert_eq!(header(&r, "access-control-allow-origin"), Some(app));

    // Another origin gets nothing it could use, preflight or call.
    let evil = "https://evil.example";
    for (path, method) in [("/v1/pose", "POST"), ("/v1/models", "POST")] {
        let r = preflight(&c, &server.url(path), evil, method, "content-type").await;
        assert_preflight_refused(&r);
    }
    let r = c
        .post(&pose)
        .header("origin", evil)
        .json(&json!({"landmarks": face68(0.0, 0.0, 0.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, "access-control-allow-origin"), None);
    // A method the route does not have, and the operational routes: not opened.
    let r = preflight(&c, &pose, app, "PUT", "").await;
    assert_preflight_refused(&r);
    let r = preflight(&c, &server.url("/metrics"), app, "GET", "").await;
    assert_preflight_refused(&r);
    // An OPTIONS that is no preflight is the 405 it always was.
    let r = c
        .request(reqwest::Method::OPTIONS, &pose)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
    assert_eq!(header(&r, "access-control-allow-origin"), None);

    // Preflights count as answered (200), never as refusals.
    let metrics = facepose_testkit::registry::metrics_text(&c, &server).await;
    assert!(
        metrics.contains(
            r#"facepose_http_requests_total{route="/v1/pose",method="OPTIONS",status="200"} "#
        ),
        "{metrics}"
    );
    for line in metrics
        .lines()
        .filter(|l| l.starts_with("facepose_http_requests_total{") && l.contains("OPTIONS"))
    {
        assert!(
            line.contains(r#"status="200""#) || line.contains(r#"status="405""#),
            "{line}"
        );
    }
}

#[tokio::test]
async fn cors_any_origin_opens_the_routes_without_the_admin_token() {
    use facepose_testkit::registry::ADMIN_TOKEN;
    let server = Server::start_admin(&["--cors-origins", "*"], ADMIN_TOKEN);
    let c = reqwest::Client::new();
    let origin = "https://anywhere.example";
    for (path, method) in [
        ("/v1/pose", "POST"),
        ("/v1/pose:batch", "POST"),
        ("/v1/models", "GET"),
        ("/v1/models/default/schemes/ibug68", "GET"),
        ("/v1/models/default/versions", "GET"),
        ("/v1/models/jobs/j-nope", "GET"),
    ] {
        let r = preflight(&c, &server.url(path), origin, method, "content-type").await;
        assert_preflight_allows(&r, "*", method, &["content-type"]);
    }
    let r = c
        .post(server.url("/v1/pose"))
        .header("origin", origin)
        .json(&json!({"landmarks": face68(0.0, 0.0, 0.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(header(&r, "access-control-allow-origin"), Some("*"));

    // The admin routes are not opened to "*", preflight or call, token or not.
    for (path, method) in ADMIN_ROUTES {
        let r = preflight(
            &c,
            &server.url(path),
            origin,
            method,
            "authorization,content-type",
        )
        .await;
        assert_preflight_refused(&r);
        assert!(
            header(&r, "access-control-allow-methods").is_none(),
            "{r:?}"
        );
    }
    let r = c
        .post(server.url("/v1/models/jobs/j-nope:cancel"))
        .header("origin", origin)
        .bearer_auth(ADMIN_TOKEN)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    assert_eq!(header(&r, "access-control-allow-origin"), None);

    // gRPC on the same port is untouched.
    let mut g = server.grpc().await;
    let resp = g
        .estimate(facepose_service::proto::EstimateRequest {
            face: Some(proto_face(&face68(15.0, 5.0, -4.0), "", "", "")),
            model: String::new(),
        })
        .await
        .unwrap();
    assert!(resp.metadata().get("access-control-allow-origin").is_none());
    assert_pose_flat(resp.into_inner().pose.unwrap(), (15.0, 5.0, -4.0));
}

fn assert_pose_flat(p: facepose_service::proto::Pose, (yaw, pitch, roll): (f64, f64, f64)) {
    let err = geodesic_deg(&rotation_flat(&p.rotation), &rotation(yaw, pitch, roll));
    assert!(err < 0.5, "{p:?}");
}

#[tokio::test]
async fn cors_is_off_by_default() {
    let server = Server::start(&[]);
    let c = reqwest::Client::new();
    let url = server.url("/v1/pose");
    let r = preflight(&c, &url, "https://app.example.com", "POST", "content-type").await;
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
    let r = c
        .post(&url)
        .header("origin", "https://app.example.com")
        .json(&json!({"landmarks": face68(0.0, 0.0, 0.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    let cors: Vec<_> = r
        .headers()
        .keys()
        .filter(|k| k.as_str().starts_with("access-control-") || *k == "vary")
        .collect();
    assert!(cors.is_empty(), "{cors:?}");
}
