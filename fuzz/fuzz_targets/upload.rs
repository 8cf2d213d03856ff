//! The retraining upload (`POST /v1/models`): the body reader and the application's checks
//! (`prepare`: names, scheme, options, shapes, Procrustes analysis) never panic.
#![no_main]

use facepose_app::retrain::prepare;
use facepose_service::http::retrain::parse_upload;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(raw) = parse_upload(data) {
        let _ = prepare(raw);
    }
});
