//! `facepose serve` as an operator sees it: model folders and startup errors, overload and
//! timeouts (refused, not collapsed), and a graceful shutdown with streams open.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::service_support::*;
use facepose_core::model::bundle::Bundle;
use facepose_files::store::write_bundle_dir;
use facepose_service::proto;
use serde_json::{Value, json};
use tokio_stream::StreamExt;
use tonic::Code;

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "facepose-test-{name}-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos()
    ));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The default bundle under another name and version, re-checksummed.
fn renamed_bundle(name: &str, version: &str) -> Bundle {
    let mut b = Bundle::parse(facepose_core::model::DEFAULT_BUNDLE).unwrap();
    b.name = name.into();
    b.version = version.into();
    b.checksum = b.compute_checksum().unwrap();
    b
}

fn run_to_exit(args: &[&str]) -> (Option<i32>, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args(["serve", "--addr", "127.0.0.1:0"])
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[tokio::test]
async fn model_folders_and_startup_errors() {
    // A folder with another model and no `default`: both are served, the embedded default as
    // `default`; hidden folders (atomic writes in progress) are skipped.
    let dir = temp_dir("models");
    write_bundle_dir(&dir.join("alt"), &renamed_bundle("alt", "7")).unwrap();
    std::fs::create_dir_all(dir.join(".alt.tmp-1")).unwrap();
    std::fs::write(dir.join(".alt.tmp-1/model.json"), "{ half written").unwrap();
    let server = Server::start(&["--models", dir.to_str().unwrap()]);
    let c = reqwest::Client::new();
    let v: Value = c
        .get(server.url("/v1/models"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let names: Vec<_> = v["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| (m["name"].as_str().unwrap(), m["source"].as_str().unwrap()))
        .collect();
    assert_eq!(names.len(), 2, "{v}");
    assert!(names.contains(&("default", "embedded")), "{v}");
    assert!(
        names
            .iter()
            .any(|(n, s)| *n == "alt" && s.ends_with("alt/model.json")),
        "{v}"
    );
    let r: Value = c
        .post(server.url("/v1/pose"))
        .json(&json!({"landmarks": face68(15.0, 0.0, 0.0), "model": "alt", "method": "fit"}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(
        (r["model"].as_str(), r["model_version"].as_str()),
        (Some("alt"), Some("7"))
    );
    drop(server);

    // A broken bundle stops the start, naming the file and the field.
    let mut bad = renamed_bundle("broken", "1");
    bad.schema_version = 99;
    bad.checksum = bad.compute_checksum().unwrap();
    write_bundle_dir(&dir.join("broken"), &bad).unwrap();
    let (code, err) = run_to_exit(&["--models", dir.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("broken/model.json") && err.contains("schema_version"),
        "{err}"
    );
    std::fs::remove_dir_all(dir.join("broken")).unwrap();
    // Two models with one name.
    write_bundle_dir(&dir.join("alt2"), &renamed_bundle("alt", "8")).unwrap();
    let (code, err) = run_to_exit(&["--models", dir.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("two models are named \"alt\""), "{err}");
    // A models folder that does not exist, and bad flags.
    let (code, err) = run_to_exit(&["--models", "/nonexistent/models"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("/nonexistent/models"), "{err}");
    let (code, err) = run_to_exit(&["--request-timeout", "soon"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("--request-timeout"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test]
async fn overload_and_timeouts_are_refused_not_collapsed() {
    let server = Server::start(&["--max-concurrency", "1", "--request-timeout", "800ms"]);
    let c = reqwest::Client::new();
    let face = json!({"landmarks": face68(0.0, 0.0, 0.0), "method": "fit"});
    let proto_face = proto_face(&face68(0.0, 0.0, 0.0), "", "", "");
    let mut g = server.grpc().await;
    // A slow client holds the only slot: its body trickles in, and the time limit covers reading
    // it.
    let addr = server.addr;
    let slow = std::thread::spawn(move || {
        use std::io::{Read, Write};
        let t = Instant::now();
        let mut s = std::net::TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        s.write_all(
            b"POST /v1/pose HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{\"landm",
        )
        .unwrap();
        let mut text = String::new();
        let _ = s.read_to_string(&mut text);
        (text, t.elapsed())
    });
    // While it runs: HTTP 429 and gRPC UNAVAILABLE, at once.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let t = Instant::now();
    let r = c
        .post(server.url("/v1/pose"))
        .json(&face)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), reqwest::StatusCode::TOO_MANY_REQUESTS);
    assert_eq!(r.headers()["retry-after"], "1");
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["error"]["code"], "overloaded");
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("retry with backoff")
    );
    let err = g
        .estimate(proto::EstimateRequest {
            face: Some(proto_face),
            model: String::new(),
        })
        .await
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(err.code(), Code::Unavailable, "{err:?}");
    assert!(
        t.elapsed() < Duration::from_millis(250),
        "refusals must be immediate"
    );
    // Health does not queue behind the work.
    assert_eq!(raw_get(server.addr, "/healthz").unwrap().0, 200);
    let (text, took) = slow.join().unwrap();
    assert!(text.starts_with("HTTP/1.1 503"), "{text}");
    assert!(
        text.contains("\"code\":\"timeout\"") && text.contains("800ms"),
        "{text}"
    );
    assert!(took < Duration::from_secs(2), "{took:?}");
    // And then it serves normally.
    let r = c
        .post(server.url("/v1/pose"))
        .json(&json!({"landmarks": face68(0.0, 0.0, 0.0), "method": "fit"}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), reqwest::StatusCode::OK);
}

#[tokio::test]
async fn sigterm_drains_with_streams_open() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};

    let mut server = Server::start(&["--drain-timeout", "5s"]);
    let mut c = server.grpc().await;
    let (tx, mut out) = open_stream(&mut c, 4).await;
    tx.send(proto::Frame {
        frame_id: 1,
        faces: vec![proto_face(&face68(10.0, 0.0, 0.0), "", "fit", "")],
        ..Default::default()
    })
    .await
    .unwrap();
    assert_eq!(out.next().await.unwrap().unwrap().frame_id, 1);
    let mut health = HealthClient::new(server.channel().await);
    let mut watch = health
        .watch(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        watch.next().await.unwrap().unwrap().status,
        ServingStatus::Serving as i32
    );

    let t = Instant::now();
    server.terminate();
    // Health watchers hear NOT_SERVING; the pose stream is told to end; the process exits 0
    // well within the drain cap.
    let next = tokio::time::timeout(Duration::from_secs(3), watch.next())
        .await
        .unwrap();
    assert_eq!(
        next.unwrap().unwrap().status,
        ServingStatus::NotServing as i32
    );
    let end = tokio::time::timeout(Duration::from_secs(3), out.next())
        .await
        .unwrap_or_else(|_| panic!("the stream was not ended; logs:\n{}", server.logs()))
        .unwrap()
        .map(|_| ())
        .expect_err("an error status");
    assert_eq!(end.code(), Code::Unavailable);
    assert!(end.message().contains("shutting down"), "{end:?}");
    // The client, told to end, closes its side (as a tracking back end does).
    drop(tx);
    let status = server
        .wait_exit(Duration::from_secs(4))
        .await
        .unwrap_or_else(|| panic!("not exited; logs:\n{}", server.logs()));
    assert!(status.success(), "{status:?}\n{}", server.logs());
    assert!(t.elapsed() < Duration::from_secs(4));
    let logs = server.logs();
    assert!(
        logs.contains("draining") && logs.contains("signal=\"SIGTERM\""),
        "{logs}"
    );
    assert!(logs.contains("stopped"), "{logs}");
}

/// A request still in flight at the drain cap (here a body that stops arriving) is cut off:
/// the process closes its connection and exits with an error status, saying why.
#[tokio::test]
async fn a_drain_cut_short_by_its_cap_exits_with_an_error() {
    use tokio::io::AsyncWriteExt;

    let mut server = Server::start(&["--drain-timeout", "1s", "--request-timeout", "30s"]);
    let mut tcp = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    tcp.write_all(
        b"POST /v1/pose HTTP/1.1\r\nhost: facepose\r\ncontent-type: application/json\r\n\
          content-length: 100\r\n\r\n{\"landmarks\": [",
    )
    .await
    .unwrap();
    // The request is in flight once the server has read its head.
    tokio::time::sleep(Duration::from_millis(200)).await;

    let t = Instant::now();
    server.terminate();
    let status = server
        .wait_exit(Duration::from_secs(5))
        .await
        .unwrap_or_else(|| panic!("not exited; logs:\n{}", server.logs()));
    assert!(t.elapsed() >= Duration::from_secs(1), "{:?}", t.elapsed());
    assert_eq!(status.code(), Some(3), "{status:?}\n{}", server.logs());
    let logs = server.logs();
    assert!(logs.contains("drain timed out"), "{logs}");
    assert!(
        logs.contains(
            "the drain reached --drain-timeout (1s) and was cut short: open connections were \
             closed"
        ),
        "{logs}"
    );
    assert!(!logs.contains("stopped"), "{logs}");
    drop(tcp);
}
