//! The service's per-face work on one core, without the network: parse a JSON body, estimate,
//! serialize the response; decode a gRPC request. With docs/PERFORMANCE.md's load figures it
//! says where a request's time goes.

use criterion::{Criterion, criterion_group, criterion_main};
use facepose_app::pose::{FaceSpec, estimate_face};
use facepose_app::registry::load_models;
use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::SubsetMap;
use facepose_service::grpc::landmark_messages;
use facepose_service::http::body::parse_json;
use facepose_service::http::pose::{parse_batch_request, parse_pose_request};
use facepose_service::http::wire::PoseRequest;
use facepose_service::proto;
use nalgebra::Vector2;
use prost::Message;
use serde_json::json;
use std::hint::black_box;

fn face(n68: bool) -> Vec<[f64; 2]> {
    let (_, model) = facepose_core::model::default_model().unwrap();
    let cam = WeakPerspective::new(
        EulerAngles::new(25.0, -10.0, 5.0).unwrap().to_rotation(),
        1.8,
        Vector2::new(225.7, -225.3),
    )
    .unwrap();
    let pts = if n68 {
        model.mean.clone()
    } else {
        SubsetMap::Anchors.map_points(&model.scheme, &model.mean)
    };
    pts.iter()
        .map(|x| {
            let p = cam.project(x);
            // Full-precision coordinates, as a client computing in doubles sends them.
            [p.x + 0.123456789, p.y - 0.987654321]
        })
        .collect()
}

fn service(c: &mut Criterion) {
    let set = load_models(None).unwrap();
    let model = set.get(None).unwrap().clone();
    for (name, scheme, pts) in [("68", "ibug68", face(true)), ("five", "five", face(false))] {
        let body = json!({"landmarks": pts, "scheme": scheme, "method": "fit"}).to_string();
        c.bench_function(&format!("http/parse one face/{name}"), |b| {
            b.iter(|| parse_pose_request(black_box(body.as_bytes())).unwrap())
        });
        // serde's derived reader, which the server falls back to for anything unusual.
        c.bench_function(&format!("http/parse one face, serde/{name}"), |b| {
            b.iter(|| parse_json::<PoseRequest>(black_box(body.as_bytes())).unwrap())
        });
        let req: PoseRequest = parse_pose_request(body.as_bytes()).unwrap();
        let spec = FaceSpec {
            landmarks: &req.landmarks.0,
            scheme: req.scheme.as_deref(),
            method: req.method.as_deref(),
            camera: None,
            style: None,
            image_size: None,
            conventions: &[],
            orientation: None,
        };
        c.bench_function(&format!("estimate_face fit/{name}"), |b| {
            b.iter(|| estimate_face(&model, black_box(&spec)).unwrap())
        });
        let p = estimate_face(&model, &spec).unwrap();
        c.bench_function(&format!("http/serialize one pose/{name}"), |b| {
            b.iter(|| serde_json::to_vec(black_box(&p.record)).unwrap())
        });
        let batch =
            json!({"faces": vec![json!({"landmarks": pts}); 100], "scheme": scheme}).to_string();
        c.bench_function(&format!("http/parse batch of 100/{name}"), |b| {
            b.iter(|| parse_batch_request(black_box(batch.as_bytes()), 1000).unwrap())
        });
        let face = proto::Face {
            landmarks: landmark_messages(&pts),
            scheme: scheme.into(),
            method: "fit".into(),
            ..Default::default()
        };
        let packed = proto::Face {
            landmarks: vec![],
            xy: pts.iter().flatten().copied().collect(),
            ..face.clone()
        };
        for (form, face) in [("landmarks", face), ("xy", packed)] {
            let grpc = proto::EstimateRequest {
                face: Some(face),
                model: String::new(),
            }
            .encode_to_vec();
            c.bench_function(&format!("grpc/decode one face ({form})/{name}"), |b| {
                b.iter(|| proto::EstimateRequest::decode(black_box(grpc.as_slice())).unwrap())
            });
        }
    }
}

criterion_group!(benches, service);
criterion_main!(benches);
