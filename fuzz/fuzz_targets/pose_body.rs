//! The pose request bodies (`POST /v1/pose`, `POST /v1/pose:batch`): the parsers never panic,
//! what the one-pass reader builds, serde's derived reader reads the same, and the reader gives
//! the same verdict and request however the body is cut into chunks and never refuses a batch
//! that serde reads within its limits.
#![no_main]

use facepose_service::http::pose::{
    batch_request, parse_batch_request, parse_pose_request, pose_request,
};
use facepose_service::http::pose_body::{BodyKind, PoseBody, count_batch_faces};
use facepose_service::http::wire::{BatchRequest, PoseRequest};
use libfuzzer_sys::fuzz_target;

/// The reader's verdict on `data` fed in chunks of `chunk` bytes, the faces it counted, and
/// what it read (the request, or serde's error).
fn fed(kind: BodyKind, data: &[u8], chunk: usize) -> (bool, usize, String) {
    let mut r = PoseBody::new(kind);
    let mut ok = true;
    for c in data.chunks(chunk) {
        ok = r.feed(c).is_ok();
    }
    let faces = r.faces();
    let read = match kind {
        BodyKind::Pose => format!("{:?}", pose_request(r, data)),
        BodyKind::Batch { .. } => format!("{:?}", batch_request(r, data)),
    };
    (ok, faces, read)
}

fuzz_target!(|data: &[u8]| {
    let chunk = 1 + data.first().map_or(0, |&b| b as usize % 17);
    for kind in [BodyKind::Pose, BodyKind::Batch { max_faces: 3 }] {
        assert_eq!(fed(kind, data, chunk), fed(kind, data, data.len().max(1)));
    }
    if let Ok(batch) = serde_json::from_slice::<BatchRequest>(data)
        && batch.faces.len() <= 3
        && batch.faces.iter().all(|f| f.landmarks.0.len() <= 1000)
        && data.len() < 60_000
    {
        let (ok, ..) = fed(BodyKind::Batch { max_faces: 3 }, data, chunk);
        assert!(ok, "the reader refused a batch within its limits");
    }
    let _ = count_batch_faces(data);
    if let Ok(ours) = parse_pose_request(data) {
        let serde: PoseRequest = serde_json::from_slice(data).expect("serde reads what we read");
        assert_eq!(format!("{ours:?}"), format!("{serde:?}"));
    }
    if let Ok(ours) = parse_batch_request(data, usize::MAX) {
        let serde: BatchRequest = serde_json::from_slice(data).expect("serde reads what we read");
        assert_eq!(format!("{ours:?}"), format!("{serde:?}"));
        assert_eq!(count_batch_faces(data), ours.faces.len());
    }
});
