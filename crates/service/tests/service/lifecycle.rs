//! Overload and timeouts, in-process: refused, not collapsed.

use std::time::{Duration, Instant};

use facepose_service::proto;
use facepose_testkit::Endpoint;
use facepose_testkit::faces::*;
use facepose_testkit::raw::*;
use facepose_testkit::server::Server;
use serde_json::{Value, json};
use tonic::Code;

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
