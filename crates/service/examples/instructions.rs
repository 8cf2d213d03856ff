//! The per-face work of the estimators and of the service's JSON path, repeated, for counting
//! instructions under callgrind: a machine-independent measure (the same count on a busy or a
//! quiet machine), next to criterion's times. `scripts/instructions.sh` runs each entry and
//! prints instructions per call (the run's total minus a run that does no calls, over the calls).
//!
//! ```sh
//! cargo build --release --example instructions
//! valgrind --tool=callgrind target/release/examples/instructions fit 1000
//! ```
//!
//! The face is the one of benches/estimate.rs: the default model's mean at yaw 25°, pitch -10°,
//! roll 5° with 1.2 px of landmark noise; the JSON body is that face's landmarks at full precision
//! (or the body in the file given after CALLS, to compare parsers on the same text). The
//! `…-dev-fitted` and `…-dev-reannotated` entries estimate instead the AFLW2000-3D dev faces
//! (every |angle| <= 99°, as benches/real_faces.rs) in turn, one a call: with CALLS a multiple
//! of their count, the mean over the faces (they need the shared data: FACEPOSE_DATA, else
//! ../shared/data). The `estimate-mediapipe-…` entries estimate MediaPipe's 478 points on the
//! astronaut photograph (tests/fixtures/detectors/mediapipe.json). The `grpc-batch64-…`
//! entries decode an `EstimateBatch` request of 64 such faces (`xy` packed, or landmark
//! messages) as the server does: its body in 16 KiB chunks through the pose calls' guard and
//! tonic's framing to the codec's decoder (a call is one request: divide by 64 for a face).

use axum::body::Bytes;
use facepose_app::estimate::{FaceInput, FaceScratch};
use facepose_app::pose::{FaceSpec, estimate_face};
use facepose_app::registry::load_models;
use facepose_app::tracking::Smoothed;
use facepose_core::estimate::morph_fit::{MorphOptions, fit_morphable};
use facepose_core::estimate::{FitOptions, fit_rigid};
use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::default_model;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate, estimate_with};
use facepose_core::shape::Shape2;
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_files::data::{data_dir, load_aflw};
use facepose_service::grpc::codec::{FaceposeDecoder, Prebuilt};
use facepose_service::grpc::convert::pose_message;
use facepose_service::grpc::frame_guard::{FrameGuard, GuardedBody, Rpc};
use facepose_service::grpc::landmark_messages;
use facepose_service::http::pose::{parse_pose_request, pose_request};
use facepose_service::http::pose_body::{BodyKind, PoseBody};
use facepose_service::proto;
use nalgebra::Vector2;
use prost::Message;
use rand::{SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use std::hint::black_box;
use std::pin::Pin;
use std::task::{Context, Poll};
use tonic::codec::Streaming;

/// What can be counted.
const ENTRIES: [&str; 23] = [
    "none",
    "fit",
    "fit-shape",
    "estimate-fit",
    "estimate-auto",
    "estimate-regression",
    "parse-pose-body",
    "estimate-face-fit",
    "grpc-decode-landmarks",
    "grpc-decode-xy",
    "parse-pose-body-chunked",
    "guard-grpc-landmarks",
    "grpc-estimate-xy",
    "estimate-auto-dev-fitted",
    "estimate-auto-dev-reannotated",
    "estimate-fit-dev-fitted",
    "estimate-fit-dev-reannotated",
    "estimate-mediapipe-auto",
    "estimate-mediapipe-fit",
    "estimate-dlib-auto",
    "estimate-dlib-fit-shape",
    "grpc-batch64-xy",
    "grpc-batch64-landmarks",
];

/// MediaPipe's 478 points on the astronaut photograph (tests/fixtures/detectors/), in pixels.
fn mediapipe_face() -> Shape2 {
    let doc: serde_json::Value = serde_json::from_str(include_str!(
        "../../../tests/fixtures/detectors/mediapipe.json"
    ))
    .expect("the MediaPipe fixture is JSON");
    let face = &doc["faces"][0];
    let pts: Vec<Option<[f64; 2]>> = face["landmarks"]
        .as_array()
        .expect("landmarks")
        .iter()
        .map(|p| Some([p[0].as_f64().unwrap(), p[1].as_f64().unwrap()]))
        .collect();
    let size = ImageSize {
        width: face["image_size"][0].as_f64().unwrap(),
        height: face["image_size"][1].as_f64().unwrap(),
    };
    pixel_shape(&pts, Some(size)).expect("the fixture's face converts")
}

/// dlib's 68 points on the astronaut photograph (tests/fixtures/detectors/), in pixels.
fn dlib_face() -> Shape2 {
    let doc: serde_json::Value =
        serde_json::from_str(include_str!("../../../tests/fixtures/detectors/dlib.json"))
            .expect("the dlib fixture is JSON");
    let pts: Vec<Vector2<f64>> = doc["faces"][0]["ibug68"]
        .as_array()
        .expect("ibug68")
        .iter()
        .map(|p| Vector2::new(p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
        .collect();
    Shape2::full(pts).expect("the fixture's face converts")
}

/// The AFLW2000-3D dev faces of `set` (`fitted` or `reannotated`), every |angle| <= 99°.
fn dev_faces(set: &str) -> Vec<Shape2> {
    let path = data_dir().join("aflw2000/aflw2000_dev.jsonl");
    let faces = load_aflw(&path).unwrap_or_else(|e| panic!("{e}"));
    faces
        .iter()
        .filter(|f| f.within_99)
        .map(|f| {
            let pts = match set {
                "fitted" => &f.landmarks_fitted,
                _ => &f.landmarks_reannotated,
            };
            Shape2::full(pts.iter().map(|p| Vector2::new(p[0], p[1])).collect()).unwrap()
        })
        .collect()
}

/// A request body already received, in the chunks HTTP/2 delivers (16 KiB DATA frames).
struct Received(Vec<Bytes>);

impl http_body::Body for Received {
    type Data = Bytes;
    type Error = std::convert::Infallible;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        _: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, Self::Error>>> {
        Poll::Ready(self.0.pop().map(|b| Ok(http_body::Frame::data(b))))
    }
}

/// `body` (one framed `EstimateBatchRequest`) decoded as the server decodes it: through the
/// guard of `EstimateBatch` and the codec's decoder, under tonic's `Streaming`.
fn server_decode(body: &Bytes) -> proto::EstimateBatchRequest {
    let mut chunks: Vec<Bytes> = (0..body.len())
        .step_by(16 * 1024)
        .map(|at| body.slice(at..(at + 16 * 1024).min(body.len())))
        .collect();
    chunks.reverse();
    let prebuilt = Prebuilt::default();
    let guarded = GuardedBody::new(
        axum::body::Body::new(Received(chunks)),
        FrameGuard::new(Rpc::EstimateBatch, 1000).building_into(prebuilt.clone()),
    );
    let decoder = FaceposeDecoder::<proto::EstimateBatchRequest>::new(Some(prebuilt));
    let mut stream = Streaming::new_request(decoder, guarded, None, None);
    let mut message = std::pin::pin!(stream.message());
    match message
        .as_mut()
        .poll(&mut Context::from_waker(std::task::Waker::noop()))
    {
        Poll::Ready(Ok(Some(request))) => request,
        other => panic!(
            "the batch decodes at once: {:?}",
            other.map(|r| r.map(drop))
        ),
    }
}

fn main() {
    let usage = || {
        eprintln!(
            "usage: instructions <{}> CALLS [BODY_FILE]\n\
             BODY_FILE: a /v1/pose body for parse-pose-body instead of the built-in one",
            ENTRIES.join("|")
        );
        std::process::exit(2)
    };
    let mut args = std::env::args().skip(1);
    let (Some(what), Some(calls)) = (args.next(), args.next()) else {
        usage()
    };
    let Ok(calls) = calls.parse::<usize>() else {
        usage()
    };
    if !ENTRIES.contains(&what.as_str()) {
        usage()
    }
    let body_file = args.next();
    let (_, model) = default_model().expect("the embedded default model loads");
    let cam = WeakPerspective::new(
        EulerAngles::new(25.0, -10.0, 5.0).unwrap().to_rotation(),
        1.8,
        Vector2::new(225.0, -225.0),
    )
    .unwrap();
    let mut rng = StdRng::seed_from_u64(1);
    let noise = Normal::new(0.0, 1.2).unwrap();
    let points: Vec<Vector2<f64>> = model
        .mean
        .iter()
        .map(|x| cam.project(x) + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)))
        .collect();
    let lm = Shape2::full(points.clone()).unwrap();
    let body = serde_json::json!({
        "landmarks": points.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>(),
        "scheme": "ibug68",
        "method": "fit",
    })
    .to_string();
    let body = match body_file {
        Some(path) => std::fs::read_to_string(&path).expect("the body file is readable UTF-8"),
        None => body,
    };
    let set = load_models(None).expect("the default model set loads");
    let served = set.get(None).unwrap().clone();
    let request = parse_pose_request(body.as_bytes()).unwrap();
    let spec = FaceSpec {
        landmarks: &request.landmarks.0,
        scheme: request.scheme.as_deref(),
        method: request.method.as_deref(),
        ..FaceSpec::default()
    };
    let basis = model
        .morph
        .as_ref()
        .expect("the default model has a shape basis");
    let rigid = FitOptions::default();
    // The same face as a gRPC EstimateRequest, its landmarks as messages or packed.
    let xy: Vec<[f64; 2]> = points.iter().map(|p| [p.x, p.y]).collect();
    let grpc_face = proto::Face {
        landmarks: landmark_messages(&xy),
        scheme: "ibug68".into(),
        method: "fit".into(),
        ..Default::default()
    };
    let grpc_request = |face: proto::Face| {
        proto::EstimateRequest {
            face: Some(face),
            model: String::new(),
        }
        .encode_to_vec()
    };
    let with_messages = grpc_request(grpc_face.clone());
    let packed_face = proto::Face {
        landmarks: vec![],
        xy: xy.iter().flatten().copied().collect(),
        ..grpc_face.clone()
    };
    let packed = grpc_request(packed_face.clone());
    let frame = |message: &[u8]| {
        let mut framed = vec![0];
        framed.extend_from_slice(&(message.len() as u32).to_be_bytes());
        framed.extend_from_slice(message);
        framed
    };
    let framed = frame(&with_messages);
    // 64 such faces in one EstimateBatch request, framed, as HTTP/2 DATA frames of 16 KiB.
    let batch64 = |face: &proto::Face| {
        let faces = (0..64)
            .map(|i| proto::Face {
                id: format!("f{i}"),
                ..face.clone()
            })
            .collect();
        let request = proto::EstimateBatchRequest {
            faces,
            model: String::new(),
        };
        Bytes::from(frame(&request.encode_to_vec()))
    };
    let batch64_xy = batch64(&packed_face);
    let batch64_landmarks = batch64(&grpc_face);
    // Warm the regression's per-pattern cache, as a service is after its first query.
    let _ = estimate(&model, "ibug68", &lm, Method::Regression);
    let dev = match what.rsplit_once("-dev-") {
        Some((_, set)) => dev_faces(set),
        None => Vec::new(),
    };
    let mp = mediapipe_face();
    let dlib = dlib_face();
    let contour = |method| EstimateOptions {
        method,
        camera: None,
        style: LandmarkStyle::Contour,
    };
    let mut scratch = FaceScratch::default();
    for call in 0..calls {
        match what.as_str() {
            "fit" => drop(black_box(
                fit_rigid(black_box(&model.mean), black_box(&lm), &[], None, rigid).unwrap(),
            )),
            "fit-shape" => drop(black_box(
                fit_morphable(basis, black_box(&lm), &[], None, MorphOptions::default()).unwrap(),
            )),
            "estimate-fit" => drop(black_box(
                estimate(&model, "ibug68", black_box(&lm), Method::Fit).unwrap(),
            )),
            "estimate-auto" => drop(black_box(
                estimate(&model, "ibug68", black_box(&lm), Method::Auto).unwrap(),
            )),
            "estimate-regression" => drop(black_box(
                estimate(&model, "ibug68", black_box(&lm), Method::Regression).unwrap(),
            )),
            "parse-pose-body" => drop(black_box(
                parse_pose_request(black_box(body.as_bytes())).unwrap(),
            )),
            "estimate-face-fit" => {
                drop(black_box(estimate_face(&served, black_box(&spec)).unwrap()))
            }
            "grpc-decode-landmarks" => drop(black_box(
                proto::EstimateRequest::decode(black_box(with_messages.as_slice())).unwrap(),
            )),
            "grpc-decode-xy" => drop(black_box(
                proto::EstimateRequest::decode(black_box(packed.as_slice())).unwrap(),
            )),
            // The body checked and read as it arrives, in chunks of 1 KiB.
            "parse-pose-body-chunked" => {
                let bytes = black_box(body.as_bytes());
                let mut r = PoseBody::new(BodyKind::Pose);
                for chunk in bytes.chunks(1024) {
                    r.feed(chunk).unwrap();
                }
                drop(black_box(pose_request(r, bytes).unwrap()));
            }
            "guard-grpc-landmarks" => {
                let mut g = FrameGuard::new(Rpc::Estimate, 1000).scanning_from(0);
                drop(black_box(g.feed(black_box(&framed))));
            }
            // A gRPC face's whole path without conventions: decode the packed request, the
            // face's spec (landmarks and conventions from reused scratch), fit, encode the pose.
            "grpc-estimate-xy" => {
                let req = proto::EstimateRequest::decode(black_box(packed.as_slice())).unwrap();
                let face = req.face.unwrap();
                let spec = face.spec(&mut scratch).unwrap();
                let pose = estimate_face(&served, &spec).unwrap();
                let message = pose_message(&pose, Smoothed::default());
                drop(black_box(message.encode_to_vec()));
            }
            // A large request as the server reads it: the body through the pose calls' guard,
            // tonic's framing and the codec's decoder.
            "grpc-batch64-xy" => drop(black_box(server_decode(black_box(&batch64_xy)))),
            "grpc-batch64-landmarks" => {
                drop(black_box(server_decode(black_box(&batch64_landmarks))))
            }
            // MediaPipe's points as `auto` answers them (the detector regression) and as it
            // did before it (the rigid fit of the mesh).
            "estimate-mediapipe-auto" => drop(black_box(
                estimate(&model, "mediapipe478", black_box(&mp), Method::Auto).unwrap(),
            )),
            "estimate-mediapipe-fit" => drop(black_box(
                estimate(&model, "mediapipe478", black_box(&mp), Method::Fit).unwrap(),
            )),
            // dlib's 68 points sent as docs/API.md advises (`landmark_style: contour`), as
            // `auto` answers them (the detector regression) and as it did before it (the shape
            // fit).
            "estimate-dlib-auto" => drop(black_box(
                estimate_with(&model, "ibug68", black_box(&dlib), &contour(Method::Auto)).unwrap(),
            )),
            "estimate-dlib-fit-shape" => drop(black_box(
                estimate_with(
                    &model,
                    "ibug68",
                    black_box(&dlib),
                    &contour(Method::FitShape),
                )
                .unwrap(),
            )),
            dev_entry if dev_entry.contains("-dev-") => {
                let method = if dev_entry.starts_with("estimate-auto") {
                    Method::Auto
                } else {
                    Method::Fit
                };
                let face = &dev[call % dev.len()];
                drop(black_box(
                    estimate(&model, "ibug68", black_box(face), method).unwrap(),
                ));
            }
            _ => {}
        }
    }
}
