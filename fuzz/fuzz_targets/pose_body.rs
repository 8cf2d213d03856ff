//! The pose request bodies (`POST /v1/pose`, `POST /v1/pose:batch`): the parsers never panic,
//! and what the one-pass readers accept, serde's derived reader reads the same.
#![no_main]

use facepose_service::http::pose::{parse_batch_request, parse_pose_request};
use facepose_service::http::request_json::{
    count_batch_faces, read_batch_request, read_pose_request,
};
use facepose_service::http::wire::{BatchRequest, PoseRequest};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
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
