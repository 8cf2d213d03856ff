//! The gRPC API of `facepose serve` with the generated tonic client, on the same port as HTTP:
//! unary, batch, bidirectional streaming with smoothing, the packed landmark form, models, the
//! standard health service and server reflection. Expected poses are those the faces were projected at.

use facepose_core::geometry::geodesic_deg;
use facepose_service::proto::{self, face_result};
use facepose_testkit::faces::*;
use facepose_testkit::server::Server;
use facepose_testkit::{Endpoint, open_stream};
use tokio_stream::StreamExt;
use tonic::Code;

fn assert_pose(p: &proto::Pose, (yaw, pitch, roll): (f64, f64, f64), tol: f64) {
    let err = geodesic_deg(&rotation_flat(&p.rotation), &rotation(yaw, pitch, roll));
    assert!(err < tol, "({yaw}, {pitch}, {roll}) -> {p:?}");
    assert!(
        (p.yaw - yaw).abs() < tol && (p.pitch - pitch).abs() < tol && (p.roll - roll).abs() < tol
    );
}

fn request(face: proto::Face, model: &str) -> proto::EstimateRequest {
    proto::EstimateRequest {
        face: Some(face),
        model: model.into(),
    }
}

#[tokio::test]
async fn mediapipe_faces_in_normalized_coordinates() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let size = [640.0, 480.0];
    let image_size = Some(proto::ImageSize {
        width: size[0],
        height: size[1],
    });
    for pose @ (y, p, r) in [(0.0, 0.0, 0.0), (35.0, -10.0, 12.0), (-55.0, 20.0, -8.0)] {
        let lm = face478_normalized(y, p, r, size);
        let mut face = proto_face(&lm, "", "", "mp");
        face.image_size = image_size;
        let pose_msg = c
            .estimate(request(face, ""))
            .await
            .unwrap()
            .into_inner()
            .pose
            .unwrap();
        assert_pose(&pose_msg, pose, 0.01);
        assert_eq!(pose_msg.scheme, "mediapipe478");
        assert_eq!(pose_msg.visible.len(), 478);
        assert!(pose_msg.warnings.is_empty());
    }
    // Bad input: INVALID_ARGUMENT saying what to fix.
    let lm = face478_normalized(10.0, 0.0, 0.0, size);
    let mut nan = lm.clone();
    nan[7][1] = f64::NAN;
    let with_size = |pts: &[[f64; 2]], scheme: &str| {
        let mut f = proto_face(pts, scheme, "", "");
        f.image_size = image_size;
        f
    };
    let cases = [
        (
            proto_face(&lm, "", "", ""),
            "look like normalized coordinates",
        ),
        (
            with_size(&lm[..470], "mediapipe478"),
            "expected 478 points, got 470",
        ),
        (with_size(&nan, ""), "landmark 7 y is not a finite number"),
        (
            with_size(
                &lm.iter().map(|p| [p[0] * 640.0, p[1]]).collect::<Vec<_>>(),
                "",
            ),
            "is not a normalized coordinate",
        ),
    ];
    for (face, want) in cases {
        let err = c.estimate(request(face, "")).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
        assert!(
            err.message().contains(want),
            "{:?} lacks {want:?}",
            err.message()
        );
    }
}

#[tokio::test]
async fn unary_batch_and_models() {
    let server = Server::start(&["--max-batch", "50", "--max-body", "64KiB"]);
    let mut c = server.grpc().await;
    for pose @ (y, p, r) in [(0.0, 0.0, 0.0), (35.0, -10.0, 12.0), (-55.0, 20.0, -8.0)] {
        let resp = c
            .estimate(request(proto_face(&face68(y, p, r), "", "", "a"), ""))
            .await
            .unwrap()
            .into_inner();
        let pose_msg = resp.pose.unwrap();
        assert_pose(&pose_msg, pose, 0.5);
        assert_eq!(pose_msg.scheme, "ibug68");
        assert_eq!(pose_msg.visible.len(), 68);
        assert!(pose_msg.residual < 0.01);
        assert_eq!(resp.id, "a");
        assert_eq!(resp.model, "default");
        let resp = c
            .estimate(request(
                proto_face(&face5(y, p, r), "five", "fit", ""),
                "default",
            ))
            .await
            .unwrap()
            .into_inner();
        assert_pose(&resp.pose.unwrap(), pose, 1.0);
    }
    // Missing points.
    let mut face = proto_face(&face68(20.0, 5.0, 0.0), "", "fit", "");
    for i in 0..17 {
        face.landmarks[i].missing = true;
        face.landmarks[i].x = f64::NAN; // ignored when missing
    }
    let resp = c.estimate(request(face, "")).await.unwrap().into_inner();
    assert_pose(&resp.pose.unwrap(), (20.0, 5.0, 0.0), 0.5);

    // Errors: the same classes and messages as HTTP.
    let ok = face68(10.0, 0.0, 0.0);
    let mut nan = proto_face(&ok, "", "", "");
    nan.landmarks[3].y = f64::NAN;
    let mut inf = proto_face(&ok, "", "", "");
    inf.landmarks[0].x = f64::INFINITY;
    let cases = [
        (
            request(proto_face(&ok[..10], "", "", ""), ""),
            Code::InvalidArgument,
            "10 landmarks, and no scheme of this model has that many",
        ),
        (
            request(nan, ""),
            Code::InvalidArgument,
            "landmark 3 y is not a finite number",
        ),
        (
            request(inf, ""),
            Code::InvalidArgument,
            "landmark 0 x is not a finite number",
        ),
        (
            request(proto_face(&[[5.0, 5.0]; 68], "", "", ""), ""),
            Code::InvalidArgument,
            "degenerate",
        ),
        (
            request(proto_face(&ok, "mediapipe999", "", ""), ""),
            Code::InvalidArgument,
            "this model serves ibug68",
        ),
        (
            request(proto_face(&ok, "", "magic", ""), ""),
            Code::InvalidArgument,
            "unknown method",
        ),
        (
            request(proto_face(&ok, "", "", ""), "nope"),
            Code::NotFound,
            "unknown model \"nope\"",
        ),
        (
            proto::EstimateRequest {
                face: None,
                model: String::new(),
            },
            Code::InvalidArgument,
            "missing face",
        ),
    ];
    for (req, code, want) in cases {
        let err = c
            .estimate(req)
            .await
            .map(|_| ())
            .expect_err("an error status");
        assert_eq!(err.code(), code, "{err:?}");
        assert!(
            err.message().contains(want),
            "{:?} lacks {want:?}",
            err.message()
        );
    }

    // Batch: per-face results, the limit, and the message size limit.
    let faces = vec![
        proto_face(&face68(-30.0, 10.0, 5.0), "", "fit", "good"),
        proto_face(&ok[..3], "", "", "short"),
        proto_face(&face5(15.0, 0.0, 0.0), "five", "geometry", "five"),
    ];
    let resp = c
        .estimate_batch(proto::EstimateBatchRequest {
            faces,
            model: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!((resp.succeeded, resp.failed), (2, 1));
    assert_eq!(resp.results.len(), 3);
    assert_eq!(resp.results[0].id, "good");
    match &resp.results[0].result {
        Some(face_result::Result::Pose(p)) => assert_pose(p, (-30.0, 10.0, 5.0), 0.5),
        other => panic!("{other:?}"),
    }
    match &resp.results[1].result {
        Some(face_result::Result::Error(e)) => {
            assert_eq!(e.code, "INVALID_ARGUMENT");
            assert!(
                e.message
                    .contains("3 landmarks, and no scheme of this model has that many")
            );
        }
        other => panic!("{other:?}"),
    }
    match &resp.results[2].result {
        Some(face_result::Result::Pose(p)) => assert_eq!(p.method, "geometry"),
        other => panic!("{other:?}"),
    }
    let err = c
        .estimate_batch(proto::EstimateBatchRequest {
            faces: vec![proto_face(&face5(0.0, 0.0, 0.0), "five", "", ""); 51],
            model: String::new(),
        })
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::ResourceExhausted);
    assert!(
        err.message()
            .contains("51 faces in one request; the limit is 50")
    );
    let err = c
        .estimate_batch(proto::EstimateBatchRequest {
            faces: vec![proto_face(&ok, "", "", ""); 60],
            model: String::new(),
        })
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::ResourceExhausted, "{err:?}");
    assert!(
        err.message()
            .contains("over the limit of 65536 bytes (--max-body)"),
        "{err:?}"
    );

    // Models.
    let list = c
        .list_models(proto::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert_eq!(list.default_model, "default");
    assert_eq!(list.models.len(), 1);
    let m = &list.models[0];
    assert!(m.is_default);
    assert_eq!(
        m.schemes
            .iter()
            .map(|s| (s.name.as_str(), s.points))
            .collect::<Vec<_>>(),
        [
            ("ibug68", 68),
            ("inner51", 51),
            ("five", 5),
            ("dlib5", 5),
            ("mediapipe468", 468),
            ("mediapipe478", 478)
        ]
    );
    let m = c
        .get_model(proto::GetModelRequest {
            name: "default".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert!(m.checksum.starts_with("sha256:"));
    let err = c
        .get_model(proto::GetModelRequest {
            name: "nope".into(),
        })
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::NotFound);

    // The service answers after all of that, and the metrics counted it.
    let text = reqwest::get(server.url("/metrics"))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        text.contains(r#"facepose_grpc_requests_total{rpc="Estimate",code="OK"}"#),
        "{text}"
    );
    assert!(
        text.contains(r#"facepose_grpc_requests_total{rpc="Estimate",code="NOT_FOUND"} 1"#),
        "{text}"
    );
}

/// The face with its landmarks in the packed form: `xy`, and `missing` for the missing ones
/// (their coordinates replaced by NaN, which the server must ignore).
fn packed(face: &proto::Face) -> proto::Face {
    let mut f = face.clone();
    f.landmarks.clear();
    f.xy = face
        .landmarks
        .iter()
        .flat_map(|l| if l.missing { [f64::NAN; 2] } else { [l.x, l.y] })
        .collect();
    f.missing = (0..face.landmarks.len() as u32)
        .filter(|&i| face.landmarks[i as usize].missing)
        .rev()
        .collect();
    f
}

#[tokio::test]
async fn packed_landmarks_are_the_same_faces() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let mut holes = proto_face(&face68(25.0, -5.0, 10.0), "", "fit", "holes");
    for i in [0, 1, 2, 30, 67] {
        holes.landmarks[i].missing = true;
    }
    let faces = [
        proto_face(&face68(-40.0, 10.0, -5.0), "", "", "whole"),
        holes,
        proto_face(&face5(15.0, 5.0, 0.0), "five", "geometry", "five"),
        proto_face(&face68(0.0, 0.0, 0.0)[..60], "", "", "short"),
    ];
    // Unary: the same answers, bit for bit (and the same errors).
    for face in &faces {
        let a = c.estimate(request(face.clone(), "")).await;
        let b = c.estimate(request(packed(face), "")).await;
        match (a, b) {
            (Ok(a), Ok(b)) => assert_eq!(a.into_inner(), b.into_inner(), "{}", face.id),
            (Err(a), Err(b)) => assert_eq!((a.code(), a.message()), (b.code(), b.message())),
            (a, b) => panic!("{}: {a:?} against {b:?}", face.id),
        }
    }
    // Batch and stream: the forms mix freely between faces.
    let mixed: Vec<proto::Face> = faces
        .iter()
        .enumerate()
        .map(|(k, f)| if k % 2 == 0 { packed(f) } else { f.clone() })
        .collect();
    let plain = c
        .estimate_batch(proto::EstimateBatchRequest {
            faces: faces.to_vec(),
            model: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    let batch = c
        .estimate_batch(proto::EstimateBatchRequest {
            faces: mixed.clone(),
            model: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!((plain.succeeded, plain.failed), (3, 1));
    assert_eq!(batch, plain);
    let (tx, mut out) = open_stream(&mut c, 4).await;
    tx.send(frame(1, mixed, None)).await.unwrap();
    let res = out.next().await.unwrap().unwrap();
    assert_eq!(res.faces, plain.results);

    // Packed landmarks that do not fit together say what is wrong, per face.
    let ok = face68(10.0, 0.0, 0.0);
    let both = proto::Face {
        xy: vec![1.0, 2.0],
        ..proto_face(&ok, "", "", "")
    };
    let odd = proto::Face {
        xy: vec![1.0; 135],
        ..proto::Face::default()
    };
    let stray = proto::Face {
        missing: vec![3],
        ..proto_face(&ok, "", "", "")
    };
    let out_of_range = proto::Face {
        missing: vec![68],
        ..packed(&proto_face(&ok, "", "", ""))
    };
    for (face, want) in [
        (both, "both Face.landmarks (68) and Face.xy (2 numbers)"),
        (
            odd,
            "Face.xy has 135 numbers: it needs an x and a y per landmark",
        ),
        (stray, "Face.missing goes with Face.xy"),
        (
            out_of_range,
            "Face.missing has index 68, but Face.xy has 68 landmarks",
        ),
    ] {
        let err = c
            .estimate(request(face.clone(), ""))
            .await
            .map(|_| ())
            .expect_err("an error status");
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
        assert!(
            err.message().contains(want),
            "{:?} lacks {want:?}",
            err.message()
        );
        let batch = c
            .estimate_batch(proto::EstimateBatchRequest {
                faces: vec![face, proto_face(&ok, "", "", "")],
                model: String::new(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!((batch.succeeded, batch.failed), (1, 1));
        match &batch.results[0].result {
            Some(face_result::Result::Error(e)) => {
                assert_eq!(e.code, "INVALID_ARGUMENT");
                assert!(e.message.contains(want), "{e:?}");
            }
            other => panic!("{other:?}"),
        }
    }
}

fn frame(id: u64, faces: Vec<proto::Face>, smoothing: Option<proto::Smoothing>) -> proto::Frame {
    proto::Frame {
        frame_id: id,
        timestamp_us: 1_000_000 + id as i64 * 33_333,
        faces,
        model: String::new(),
        smoothing,
    }
}

fn pose_of(r: &proto::FaceResult) -> &proto::Pose {
    match &r.result {
        Some(face_result::Result::Pose(p)) => p,
        other => panic!("{other:?}"),
    }
}

#[tokio::test]
async fn streams_answer_every_frame_in_order_and_can_smooth() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    // Two faces per frame turning in opposite directions; frame 3 has a bad face.
    let (tx, mut out) = open_stream(&mut c, 16).await;
    for k in 0..6u64 {
        let yaw = -30.0 + 10.0 * k as f64;
        let mut faces = vec![
            proto_face(&face68(yaw, 5.0, 0.0), "", "fit", "left"),
            proto_face(&face5(-yaw, -5.0, 3.0), "five", "fit", "right"),
        ];
        if k == 3 {
            faces.push(proto_face(&[[1.0, 1.0]; 68], "", "", "bad"));
        }
        tx.send(frame(k, faces, None)).await.unwrap();
        let res = out.next().await.unwrap().unwrap();
        assert_eq!(res.frame_id, k);
        assert_eq!(res.timestamp_us, 1_000_000 + k as i64 * 33_333);
        assert_eq!(res.model, "default");
        assert_pose(pose_of(&res.faces[0]), (yaw, 5.0, 0.0), 0.5);
        assert_pose(pose_of(&res.faces[1]), (-yaw, -5.0, 3.0), 1.0);
        assert!(!pose_of(&res.faces[0]).smoothed);
        if k == 3 {
            assert_eq!(res.faces[2].id, "bad");
            match &res.faces[2].result {
                Some(face_result::Result::Error(e)) => assert!(e.message.contains("degenerate")),
                other => panic!("{other:?}"),
            }
        }
    }
    // The client closes: the stream ends with OK.
    drop(tx);
    assert!(out.next().await.is_none());

    // Smoothing: a still face with landmark jitter comes out steadier than it goes in.
    let (tx, mut out) = open_stream(&mut c, 64).await;
    let truth = rotation(20.0, -5.0, 3.0);
    let clean = face68(20.0, -5.0, 3.0);
    let mut seed = 12345u64;
    let mut noise = move || {
        // A small LCG: uniform in [-2.5, 2.5) pixels.
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 5.0
    };
    let n = 60u64;
    let (mut raw_err, mut smooth_err) = (0.0, 0.0);
    for k in 0..n {
        let noisy: Vec<[f64; 2]> = clean
            .iter()
            .map(|p| [p[0] + noise(), p[1] + noise()])
            .collect();
        // One Euro parameters and no filter named: the One Euro filter, as before the Kalman
        // filter existed.
        let smoothing = (k == 0).then_some(proto::Smoothing {
            enabled: true,
            min_cutoff_hz: 0.5,
            ..Default::default()
        });
        // The same face twice: tracked (smoothed) under its id and raw in a second stream-less
        // comparison below.
        tx.send(frame(
            k,
            vec![proto_face(&noisy, "", "fit", "t1")],
            smoothing,
        ))
        .await
        .unwrap();
        let res = out.next().await.unwrap().unwrap();
        let smoothed = pose_of(&res.faces[0]);
        assert!(smoothed.smoothed);
        let raw = c
            .estimate(request(proto_face(&noisy, "", "fit", ""), ""))
            .await
            .unwrap()
            .into_inner()
            .pose
            .unwrap();
        if k >= 20 {
            raw_err += geodesic_deg(&rotation_flat(&raw.rotation), &truth).powi(2);
            smooth_err += geodesic_deg(&rotation_flat(&smoothed.rotation), &truth).powi(2);
        }
    }
    assert!(
        smooth_err < raw_err / 4.0,
        "squared error smoothed {smooth_err} raw {raw_err}"
    );
    // Bad smoothing parameters end the stream with INVALID_ARGUMENT.
    tx.send(frame(
        n,
        vec![],
        Some(proto::Smoothing {
            enabled: true,
            min_cutoff_hz: -1.0,
            ..Default::default()
        }),
    ))
    .await
    .unwrap();
    let err = out
        .next()
        .await
        .unwrap()
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(
        err.message()
            .contains("cutoff frequencies must be positive"),
        "{err:?}"
    );
    assert!(out.next().await.is_none());
}

/// The default filter (Kalman): each pose carries its uncertainty, a still face with jitter
/// comes out steadier, a frame the detector lost (every point thrown) comes with a large
/// uncertainty and barely moves the track, a confident frame of another pose (a track switched
/// to another face) is gated out, and an unknown filter is refused.
#[tokio::test]
async fn kalman_smoothing_weighs_frames_and_gates_wild_ones() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let (tx, mut out) = open_stream(&mut c, 64).await;
    let truth = rotation(20.0, -5.0, 3.0);
    let clean = face68(20.0, -5.0, 3.0);
    let mut seed = 777u64;
    let mut uniform = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let (mut raw_err, mut smooth_err) = (0.0, 0.0);
    let n = 60u64;
    for k in 0..n {
        // Frame 40: every point off by up to ±40 px (the face is about 100 px wide).
        let amp = if k == 40 { 80.0 } else { 5.0 };
        let base = if k == 50 {
            face68(-25.0, 10.0, 0.0)
        } else {
            clean.clone()
        };
        let noisy: Vec<[f64; 2]> = base
            .iter()
            .map(|p| [p[0] + amp * uniform(), p[1] + amp * uniform()])
            .collect();
        let smoothing = (k == 0).then_some(proto::Smoothing {
            enabled: true,
            ..Default::default()
        });
        tx.send(frame(k, vec![proto_face(&noisy, "", "", "t1")], smoothing))
            .await
            .unwrap();
        let res = out.next().await.unwrap().unwrap();
        let pose = pose_of(&res.faces[0]);
        assert!(pose.smoothed);
        let u = pose.uncertainty.as_ref().expect("an uncertainty");
        let yaw = u.yaw.as_ref().unwrap();
        assert!(yaw.sd > 0.0 && yaw.interval90.len() == 2 && yaw.interval90[0] < yaw.interval90[1]);
        let raw = c
            .estimate(request(proto_face(&noisy, "", "", ""), ""))
            .await
            .unwrap()
            .into_inner()
            .pose
            .unwrap();
        assert!(!raw.gated && raw.uncertainty.is_some());
        let err = geodesic_deg(&rotation_flat(&pose.rotation), &truth);
        if k == 40 {
            // Taken, but weighed by its uncertainty: the track stays.
            assert!(yaw.sd > 10.0, "{u:?}");
            assert!(err < 2.0, "the lost frame moved the track {err}°");
        } else if k == 50 {
            assert!(pose.gated, "the other pose was taken: {pose:?}");
            assert!(err < 2.0, "the other pose moved the track {err}°");
        } else if k > 1 {
            assert!(!pose.gated, "frame {k} gated");
            assert!(yaw.sd < 10.0, "frame {k}: {u:?}");
        }
        if k >= 20 && k != 40 && k != 50 {
            raw_err += geodesic_deg(&rotation_flat(&raw.rotation), &truth).powi(2);
            smooth_err += geodesic_deg(&rotation_flat(&pose.rotation), &truth).powi(2);
        }
    }
    assert!(
        smooth_err < raw_err / 2.0,
        "squared error smoothed {smooth_err} raw {raw_err}"
    );
    tx.send(frame(
        n,
        vec![],
        Some(proto::Smoothing {
            enabled: true,
            filter: 7,
            ..Default::default()
        }),
    ))
    .await
    .unwrap();
    let err = out
        .next()
        .await
        .unwrap()
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("unknown filter 7"), "{err:?}");
}

#[tokio::test]
async fn health_reflection_and_unknown_methods() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;

    let server = Server::start(&[]);
    let channel = server.channel().await;
    let mut health = HealthClient::new(channel.clone());
    for service in ["", "facepose.v1.PoseService"] {
        let r = health
            .check(HealthCheckRequest {
                service: service.into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.status, ServingStatus::Serving as i32, "{service:?}");
    }
    let err = health
        .check(HealthCheckRequest {
            service: "nope.Service".into(),
        })
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::NotFound);

    let mut reflection = ServerReflectionClient::new(channel.clone());
    let req = |m| ServerReflectionRequest {
        host: String::new(),
        message_request: Some(m),
    };
    let mut resp = reflection
        .server_reflection_info(tokio_stream::iter(vec![
            req(MessageRequest::ListServices(String::new())),
            req(MessageRequest::FileContainingSymbol(
                "facepose.v1.PoseService".into(),
            )),
        ]))
        .await
        .unwrap()
        .into_inner();
    match resp.next().await.unwrap().unwrap().message_response {
        Some(MessageResponse::ListServicesResponse(l)) => {
            let names: Vec<_> = l.service.iter().map(|s| s.name.as_str()).collect();
            for want in [
                "facepose.v1.PoseService",
                "grpc.health.v1.Health",
                "grpc.reflection.v1.ServerReflection",
            ] {
                assert!(names.contains(&want), "{names:?}");
            }
        }
        other => panic!("{other:?}"),
    }
    match resp.next().await.unwrap().unwrap().message_response {
        Some(MessageResponse::FileDescriptorResponse(f)) => {
            assert!(!f.file_descriptor_proto.is_empty())
        }
        other => panic!("{other:?}"),
    }

    // An unknown gRPC method gets UNIMPLEMENTED, not an HTTP 404 page.
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.unwrap();
    let err = grpc
        .unary::<proto::ListModelsRequest, proto::ListModelsResponse, _>(
            tonic::Request::new(proto::ListModelsRequest {}),
            "/facepose.v1.Nothing/Here".parse().unwrap(),
            tonic_prost::ProstCodec::default(),
        )
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::Unimplemented);
}

/// The count of `facepose_grpc_requests_total` for one RPC and code, 0 when absent.
fn grpc_count(metrics: &str, rpc: &str, code: &str) -> u64 {
    metrics
        .lines()
        .filter(|l| l.starts_with("facepose_grpc_requests_total{"))
        .filter(|l| {
            l.contains(&format!("rpc=\"{rpc}\"")) && l.contains(&format!("code=\"{code}\""))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<u64>().ok())
        .sum()
}

#[tokio::test]
async fn malformed_protobuf_is_invalid_argument_and_counted() {
    use facepose_testkit::raw_grpc;
    let server = Server::start(&[]);
    let c = facepose_testkit::registry::client();
    // A face whose length runs past the message's end (prost: "buffer underflow").
    let broken = vec![0x0a, 0xff, 0xff, 0xff, 0xff, 0x0f];
    for rpc in ["Estimate", "EstimateBatch"] {
        let s = raw_grpc::unary(server.channel().await, rpc, broken.clone())
            .await
            .unwrap_err();
        assert_eq!(s.code(), Code::InvalidArgument, "{rpc}: {s:?}");
        assert!(s.message().contains("not valid protobuf"), "{rpc}: {s:?}");
        assert!(s.metadata().get("x-facepose-refused-by-codec").is_none());
    }
    let s = raw_grpc::first_answer(server.channel().await, "EstimateStream", vec![broken])
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
    let metrics = facepose_testkit::registry::metrics_text(&c, &server).await;
    assert_eq!(
        grpc_count(&metrics, "Estimate", "INVALID_ARGUMENT"),
        1,
        "{metrics}"
    );
    assert_eq!(grpc_count(&metrics, "EstimateBatch", "INVALID_ARGUMENT"), 1);
    assert_eq!(
        grpc_count(&metrics, "EstimateStream", "INVALID_ARGUMENT"),
        1
    );
}

#[tokio::test]
async fn messages_over_the_body_limit_are_counted() {
    use facepose_testkit::raw_grpc;
    let server = Server::start(&["--max-body", "64KiB"]);
    let c = facepose_testkit::registry::client();
    let s = raw_grpc::unary(server.channel().await, "Estimate", vec![0; 70 * 1024])
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
    assert!(s.message().contains("--max-body"), "{s:?}");
    let metrics = facepose_testkit::registry::metrics_text(&c, &server).await;
    assert_eq!(
        grpc_count(&metrics, "Estimate", "RESOURCE_EXHAUSTED"),
        1,
        "{metrics}"
    );
}

#[tokio::test]
async fn batches_over_the_limit_are_refused_before_decoding_in_calls_and_streams() {
    use facepose_testkit::raw_grpc;
    let server = Server::start(&["--max-batch", "100"]);
    // 20,000 empty faces: 40 KB sent, about 4 MB decoded.
    let batch = [0x0a, 0x00].repeat(20_000);
    let s = raw_grpc::unary(server.channel().await, "EstimateBatch", batch)
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
    assert!(s.message().contains("at least 101 faces"), "{s:?}");
    assert!(s.message().contains("--max-batch"), "{s:?}");
    let frame = [0x1a, 0x00].repeat(20_000);
    let s = raw_grpc::first_answer(server.channel().await, "EstimateStream", vec![frame])
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
    assert!(s.message().contains("at least 101 faces"), "{s:?}");
    // A face of more points than any scheme has, in the packed form (24 KB: walked first).
    let face = proto::Face {
        xy: vec![1.0; 2 * 1500],
        ..Default::default()
    };
    let s = server
        .grpc()
        .await
        .estimate(request(face, ""))
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
    assert!(s.message().contains("more than 1000 landmarks"), "{s:?}");
}

#[tokio::test]
async fn long_names_are_invalid_arguments_with_short_messages() {
    // A 20,000-character name made a 17.5 KB grpc-message, which clients refuse ("Stream
    // removed", RESOURCE_EXHAUSTED) instead of reading the status.
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let long = "x".repeat(20_000);
    let face = || proto_face(&face68(10.0, 0.0, 0.0), "", "", "");
    let mut requests = vec![request(face(), &long)];
    for set in [
        (|f: &mut proto::Face, s: &str| f.scheme = s.into()) as fn(&mut proto::Face, &str),
        |f, s| f.method = s.into(),
        |f, s| f.landmark_style = s.into(),
    ] {
        let mut f = face();
        set(&mut f, &long);
        requests.push(request(f, ""));
    }
    for r in requests {
        let s = c.estimate(r).await.unwrap_err();
        assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
        assert!(s.message().contains("at most 64 characters"), "{s:?}");
        assert!(s.message().len() < 200);
    }
    let s = c
        .get_model(proto::GetModelRequest { name: long.clone() })
        .await
        .unwrap_err();
    assert!(s.message().len() <= 1024, "{} bytes", s.message().len());
}

#[tokio::test]
async fn a_large_header_block_costs_its_own_call_only() {
    // hyper's 16 KiB header list limit made h2 read a 100 KiB header block as a CONTINUATION
    // flood: GOAWAY, and every other call on the connection (this open stream) ended with it.
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let (tx, mut out) = open_stream(&mut c, 4).await;
    let face = || proto_face(&face68(10.0, 0.0, 0.0), "", "", "");
    tx.send(frame(0, vec![face()], None)).await.unwrap();
    assert_eq!(out.next().await.unwrap().unwrap().frame_id, 0);
    for (kib, ok) in [(100, true), (300, false)] {
        let mut r = tonic::Request::new(request(face(), ""));
        let value = "v".repeat(kib * 1024);
        r.metadata_mut().insert("x-large", value.parse().unwrap());
        let answer = c.clone().estimate(r).await;
        assert_eq!(answer.is_ok(), ok, "{kib} KiB: {answer:?}");
        // The stream on the same connection goes on.
        tx.send(frame(kib as u64, vec![face()], None))
            .await
            .unwrap();
        let res = out.next().await.unwrap().unwrap();
        assert_eq!(res.frame_id, kib as u64);
        assert!(pose_of(&res.faces[0]).yaw > 9.0);
    }
}
