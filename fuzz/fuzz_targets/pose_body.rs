//! The pose request bodies (`POST /v1/pose`, `POST /v1/pose:batch`): the parsers never panic,
//! what the one-pass readers accept, serde's derived reader reads the same, and the guard that
//! checks a body as it arrives gives the same verdict however the body is cut into chunks and
//! never refuses a batch that serde reads within its limits.
#![no_main]

use facepose_service::http::body_guard::{BodyGuard, BodyKind};
use facepose_service::http::pose::{parse_batch_request, parse_pose_request};
use facepose_service::http::request_json::{
    count_batch_faces, read_batch_request, read_pose_request,
};
use facepose_service::http::wire::{BatchRequest, PoseRequest};
use libfuzzer_sys::fuzz_target;

/// The guard's verdict on `data` fed in chunks of `chunk` bytes, and the faces it counted.
fn guarded(kind: BodyKind, data: &[u8], chunk: usize) -> (bool, usize) {
    let mut g = BodyGuard::new(kind);
    let mut ok = true;
    for c in data.chunks(chunk) {
        ok = g.feed(c).is_ok();
    }
    (ok, g.faces())
}

fuzz_target!(|data: &[u8]| {
    let chunk = 1 + data.first().map_or(0, |&b| b as usize % 17);
    for kind in [BodyKind::Pose, BodyKind::Batch { max_faces: 3 }] {
        assert_eq!(
            guarded(kind, data, chunk),
            guarded(kind, data, data.len().max(1))
        );
    }
    if let Ok(batch) = serde_json::from_slice::<BatchRequest>(data)
        && batch.faces.len() <= 3
        && batch.faces.iter().all(|f| f.landmarks.0.len() <= 1000)
        && data.len() < 60_000
    {
        let (ok, _) = guarded(BodyKind::Batch { max_faces: 3 }, data, chunk);
        assert!(ok, "the guard refused a batch within its limits");
    }
    let _ = parse_pose_request(data);
    let _ = parse_batch_request(data, 1000);
    let _ = count_batch_faces(data);
    if let Some(ours) = read_pose_request(data) {
        let serde: PoseRequest = serde_json::from_slice(data).expect("serde reads what we read");
        assert_eq!(format!("{ours:?}"), format!("{serde:?}"));
    }
    if let Some(ours) = read_batch_request(data, usize::MAX) {
        let serde: BatchRequest = serde_json::from_slice(data).expect("serde reads what we read");
        assert_eq!(format!("{ours:?}"), format!("{serde:?}"));
        assert_eq!(count_batch_faces(data), ours.faces.len());
    }
});
