//! The WebSocket stream's text messages (`GET /v1/pose:stream`): the parser never panics, a
//! frame it reads has a smoothing that is either a filter or a clear error, and answering it
//! in a stream session (smoothing, tracks, per-face errors) never panics either: it gives an
//! answer that is JSON with one result per face, or a close with a valid code and a reason
//! that fits a close frame.
#![no_main]

use std::sync::{Arc, OnceLock};

use facepose_app::App;
use facepose_app::metrics::Transport;
use facepose_service::http::stream::{answer_text, close, parse_frame, smoothing_filter};
use libfuzzer_sys::fuzz_target;

/// A server's application with the default model, made once.
fn app() -> &'static Arc<App> {
    static APP: OnceLock<(tokio::runtime::Runtime, Arc<App>)> = OnceLock::new();
    &APP.get_or_init(|| {
        let settings = facepose_app::Settings {
            models: None,
            limits: facepose_app::Limits {
                max_batch: 4,
                max_body: 1 << 20,
                request_timeout: std::time::Duration::from_secs(5),
                max_concurrency: 4,
                max_streams: 4,
                max_upload: 1 << 20,
                upload_timeout: std::time::Duration::from_secs(5),
            },
            admin_token: facepose_app::auth::AdminToken::disabled(),
            max_queued_jobs: 1,
            registry_poll: std::time::Duration::from_secs(60),
            replica: "fuzz".into(),
            keep_inactive_versions: None,
        };
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let app = {
            let _enter = runtime.enter();
            App::with_models(
                settings,
                facepose_app::registry::load_models(None).unwrap(),
                tracing::Span::none(),
            )
        };
        (runtime, app)
    })
    .1
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(frame) = parse_frame(text) else {
        return;
    };
    if let Some(s) = &frame.smoothing {
        let _ = smoothing_filter(s);
    }
    let mut session = app()
        .open_stream(Transport::WebSocket)
        .expect("a stream slot");
    // Twice: the second frame meets the tracks the first left.
    for _ in 0..2 {
        match answer_text(&mut session, text) {
            Ok(json) => {
                let v: serde_json::Value = serde_json::from_str(&json).expect("the answer is JSON");
                assert_eq!(v["faces"].as_array().map(Vec::len), Some(frame.faces.len()));
            }
            Err(c) => {
                assert!(c.reason.len() <= 123, "{c:?}");
                assert!(
                    [
                        close::INVALID_PAYLOAD,
                        close::POLICY,
                        close::TOO_BIG,
                        close::INTERNAL
                    ]
                    .contains(&c.code),
                    "{c:?}"
                );
                break;
            }
        }
    }
});
