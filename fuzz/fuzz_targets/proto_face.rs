//! The hand-coded protobuf messages (`Face`, within `EstimateRequest`) against prost's derived
//! code for the same `.proto`: the same messages accepted, the same values read. And the
//! codec's walk before decoding never panics on any bytes.
#![no_main]

use facepose_service::grpc::codec::{Bounded, DecodeLimits};
use facepose_service::proto;
use libfuzzer_sys::fuzz_target;
use prost::Message;

#[allow(clippy::all, dead_code, missing_docs)]
mod reference {
    include!("../../crates/service/src/proto/generated/reference/facepose.v1.rs");
}

fn same_face(a: &proto::Face, b: &reference::Face) {
    assert_eq!(a.landmarks.len(), b.landmarks.len());
    for (p, q) in a.landmarks.iter().zip(&b.landmarks) {
        assert_eq!(
            (p.x.to_bits(), p.y.to_bits(), p.missing),
            (q.x.to_bits(), q.y.to_bits(), q.missing)
        );
    }
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.xy), bits(&b.xy));
    assert_eq!(a.missing, b.missing);
    assert_eq!(
        (&a.scheme, &a.method, &a.id, &a.landmark_style),
        (&b.scheme, &b.method, &b.id, &b.landmark_style)
    );
    assert_eq!(a.camera.is_some(), b.camera.is_some());
}

fuzz_target!(|data: &[u8]| {
    let limits = DecodeLimits { max_batch: 8 };
    let _ = proto::EstimateRequest::check(data, &limits);
    let _ = proto::EstimateBatchRequest::check(data, &limits);
    let _ = proto::Frame::check(data, &limits);
    let ours = proto::Face::decode(data);
    let theirs = reference::Face::decode(data);
    match (&ours, &theirs) {
        (Ok(a), Ok(b)) => same_face(a, b),
        (Err(_), Err(_)) => {}
        _ => panic!(
            "hand-coded {:?} but prost {:?}",
            ours.map(drop),
            theirs.map(drop)
        ),
    }
    let ours = proto::EstimateRequest::decode(data);
    let theirs = reference::EstimateRequest::decode(data);
    assert_eq!(ours.is_ok(), theirs.is_ok());
    if let (Ok(a), Ok(b)) = (&ours, &theirs) {
        assert_eq!(a.face.is_some(), b.face.is_some());
        if let (Some(a), Some(b)) = (&a.face, &b.face) {
            same_face(a, b);
        }
    }
});
