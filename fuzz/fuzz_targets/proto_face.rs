//! The hand-coded protobuf messages (`Face`, within `EstimateRequest`) against prost's derived
//! code for the same `.proto`: the same messages accepted, the same values read. And the guard
//! that checks a call's body as it arrives gives the same verdict however the body is cut, and
//! what it builds on the way (the pose calls' three requests) is what prost's derived code
//! decodes from the same bytes. A face that decodes is then read as the estimator takes it
//! (`FaceInput::spec`): its landmarks, and its conventions and camera orientation
//! (`Face.conventions`, `Face.camera_orientation`) parsed, never panicking.
#![no_main]

use facepose_app::estimate::{FaceInput, FaceScratch};
use facepose_service::grpc::codec::Prebuilt;
use facepose_service::grpc::frame_guard::{FrameGuard, Rpc};
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
    // Prost-derived on both sides, maps as BTreeMaps: the same values encode the same.
    assert_eq!(a.conventions.len(), b.conventions.len());
    for (p, q) in a.conventions.iter().zip(&b.conventions) {
        assert_eq!(p.encode_to_vec(), q.encode_to_vec());
    }
    assert_eq!(
        a.camera_orientation.as_ref().map(Message::encode_to_vec),
        b.camera_orientation.as_ref().map(Message::encode_to_vec)
    );
}

/// The guard's verdict on `data` as one uncompressed message of `rpc`, fed in `chunk`s (and
/// building into `sink`, if any).
fn guarded(rpc: Rpc, data: &[u8], chunk: usize, sink: Option<&Prebuilt>) -> bool {
    let mut body = vec![0];
    body.extend_from_slice(&(data.len() as u32).to_be_bytes());
    body.extend_from_slice(data);
    let mut g = FrameGuard::new(rpc, 8).scanning_from(0);
    if let Some(sink) = sink {
        g = g.building_into(sink.clone());
    }
    let mut ok = true;
    for c in body.chunks(chunk) {
        ok = g.feed(c).is_ok();
    }
    ok
}

/// What the guard of `rpc` builds from `data` (fed in `chunk`s), if it builds it, is what
/// prost's derived `R` decodes from it.
fn builds_as_prost<U: Message + Default + 'static, R: Message + Default>(
    rpc: Rpc,
    data: &[u8],
    chunk: usize,
) {
    let sink = Prebuilt::scanning_from(0);
    if guarded(rpc, data, chunk, Some(&sink))
        && let Some(built) = sink.take::<U>(data.len())
    {
        let theirs = R::decode(data).expect("the guard built a message prost refuses");
        assert_eq!(built.encode_to_vec(), theirs.encode_to_vec());
    }
}

fuzz_target!(|data: &[u8]| {
    let chunk = 1 + data.first().map_or(0, |&b| b as usize % 13);
    for rpc in [Rpc::Estimate, Rpc::EstimateBatch, Rpc::EstimateStream] {
        assert_eq!(
            guarded(rpc, data, chunk, None),
            guarded(rpc, data, data.len() + 5, None)
        );
    }
    builds_as_prost::<proto::EstimateRequest, reference::EstimateRequest>(Rpc::Estimate, data, chunk);
    builds_as_prost::<proto::EstimateBatchRequest, reference::EstimateBatchRequest>(
        Rpc::EstimateBatch,
        data,
        chunk,
    );
    builds_as_prost::<proto::Frame, reference::Frame>(Rpc::EstimateStream, data, chunk);
    let ours = proto::Face::decode(data);
    let theirs = reference::Face::decode(data);
    match (&ours, &theirs) {
        (Ok(a), Ok(b)) => {
            same_face(a, b);
            let mut scratch = FaceScratch::default();
            let _ = a.spec(&mut scratch);
        }
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
