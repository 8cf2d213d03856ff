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
    // While it runs: HTTP 429 and gRPC UNAVAILABLE, at once. On a loaded machine the slow
    // client may take a moment to get the slot: until it has, requests are served.
    let start = Instant::now();
    let (r, t) = loop {
        tokio::time::sleep(Duration::from_millis(50)).await;
        let t = Instant::now();
        let r = c
            .post(server.url("/v1/pose"))
            .json(&face)
            .send()
            .await
            .unwrap();
        if r.status() != reqwest::StatusCode::OK || start.elapsed() > Duration::from_secs(2) {
            break (r, t);
        }
    };
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

/// Reads from `s` until the server closes it or `limit` passes, writing back what `answer`
/// returns for each read: whether it closed in time.
fn until_closed(
    s: &mut std::net::TcpStream,
    limit: Duration,
    mut answer: impl FnMut(&[u8]) -> Vec<u8>,
) -> bool {
    use std::io::{Read, Write};
    let deadline = Instant::now() + limit;
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline {
        s.set_read_timeout(Some(
            deadline
                .saturating_duration_since(Instant::now())
                .max(Duration::from_millis(1)),
        ))
        .unwrap();
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(n) => {
                let reply = answer(&buf[..n]);
                s.write_all(&reply).unwrap();
            }
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => return true,
            Err(_) => break,
        }
    }
    false
}

/// Reads from `s` until the server closes it or `limit` passes: (bytes read, closed in time).
fn read_until_closed(s: &mut std::net::TcpStream, limit: Duration) -> (Vec<u8>, bool) {
    let mut got = Vec::new();
    let closed = until_closed(s, limit, |bytes| {
        got.extend_from_slice(bytes);
        Vec::new()
    });
    (got, closed)
}

#[tokio::test]
async fn slow_headers_and_idle_http1_connections_are_closed_after_the_header_timeout() {
    use std::io::Write;
    let server = Server::start(&["--header-timeout", "400ms"]);
    // Headers that never end (slowloris).
    let mut slow = std::net::TcpStream::connect(server.addr).unwrap();
    slow.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: ")
        .unwrap();
    let t = Instant::now();
    let (_, closed) = read_until_closed(&mut slow, Duration::from_secs(3));
    assert!(
        closed,
        "a connection whose headers never end stayed open for 3 s"
    );
    assert!(
        t.elapsed() >= Duration::from_millis(300),
        "{:?}",
        t.elapsed()
    );
    // A kept-alive connection after its request.
    let mut idle = std::net::TcpStream::connect(server.addr).unwrap();
    idle.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    let (answer, closed) = read_until_closed(&mut idle, Duration::from_secs(3));
    assert!(String::from_utf8_lossy(&answer).starts_with("HTTP/1.1 200"));
    assert!(closed, "an idle HTTP/1 connection stayed open for 3 s");
    // A connection that never sends a byte (it stayed until the idle timeout, 120 s).
    let mut silent = std::net::TcpStream::connect(server.addr).unwrap();
    let (answer, closed) = read_until_closed(&mut silent, Duration::from_secs(3));
    assert!(
        closed && answer.is_empty(),
        "a silent connection stayed open for 3 s"
    );
}

#[tokio::test]
async fn http1_headers_fit_in_a_64_kib_buffer() {
    // hyper's 400 KiB default: each connection's buffer grew to it while a body streamed in.
    let server = Server::start(&[]);
    for (kib, status) in [(60, 200), (70, 431)] {
        let head = format!(
            "GET /healthz HTTP/1.1\r\nHost: x\r\nX-Large: {}\r\nConnection: close\r\n\r\n",
            "v".repeat(kib * 1024)
        );
        let mut s = std::net::TcpStream::connect(server.addr).unwrap();
        std::io::Write::write_all(&mut s, head.as_bytes()).unwrap();
        let (answer, _) = read_until_closed(&mut s, Duration::from_secs(5));
        let answer = String::from_utf8_lossy(&answer);
        assert!(
            answer.starts_with(&format!("HTTP/1.1 {status}")),
            "{kib} KiB: {}",
            answer.lines().next().unwrap_or_default()
        );
    }
}

/// Plays a silent HTTP/2 client on `s` until the server closes it or `limit` passes: whether a
/// GOAWAY came, and whether the connection was closed in time.
fn answer_until_closed(s: &mut std::net::TcpStream, limit: Duration) -> (bool, bool) {
    let mut pending = Vec::new();
    let mut goaway = false;
    let closed = until_closed(s, limit, |bytes| {
        pending.extend_from_slice(bytes);
        let mut reply = Vec::new();
        while pending.len() >= 9 {
            let len = (usize::from(pending[0]) << 16)
                | (usize::from(pending[1]) << 8)
                | usize::from(pending[2]);
            if pending.len() < 9 + len {
                break;
            }
            let (kind, flags) = (pending[3], pending[4]);
            match (kind, flags & 1) {
                (4, 0) => reply.extend_from_slice(&[0, 0, 0, 4, 1, 0, 0, 0, 0]),
                (6, 0) => {
                    reply.extend_from_slice(&[0, 0, 8, 6, 1, 0, 0, 0, 0]);
                    reply.extend_from_slice(&pending[9..9 + len]);
                }
                (7, _) => goaway = true,
                _ => {}
            }
            pending.drain(..9 + len);
        }
        reply
    });
    (goaway, closed)
}

#[tokio::test]
async fn idle_http2_connections_are_closed_and_quiet_streams_are_not() {
    use std::io::Write;
    let server = Server::start(&["--idle-timeout", "500ms", "--keepalive", "60s"]);
    // A bare HTTP/2 client: the preface and empty settings, then nothing but the answers the
    // protocol asks for (settings and ping acknowledgements).
    let mut bare = std::net::TcpStream::connect(server.addr).unwrap();
    bare.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\x00\x00\x00\x04\x00\x00\x00\x00\x00")
        .unwrap();
    let (goaway, closed) = answer_until_closed(&mut bare, Duration::from_secs(4));
    assert!(closed, "an idle HTTP/2 connection stayed open for 4 s");
    assert!(goaway, "no GOAWAY before the close");
    // A stream with nothing to say for three idle timeouts stays open.
    let mut c = server.grpc().await;
    let (tx, mut results) = facepose_testkit::open_stream(&mut c, 4).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    tx.send(proto::Frame {
        frame_id: 7,
        faces: vec![proto_face(&face68(10.0, 0.0, 0.0), "", "", "")],
        ..Default::default()
    })
    .await
    .unwrap();
    let r = tokio_stream::StreamExt::next(&mut results)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(r.frame_id, 7);
}

#[tokio::test]
async fn connections_past_the_cap_get_a_503_and_a_freed_slot_is_reused() {
    let server = Server::start(&["--max-connections", "3"]);
    // Three connections that hold a slot each. The start-up's readiness probe may still hold
    // one for a moment on a loaded machine: a connection refused meanwhile gets its 503 at
    // once, so it is opened again (a held one has nothing to read).
    let hold = || {
        let t = Instant::now();
        loop {
            let mut c = std::net::TcpStream::connect(server.addr).unwrap();
            c.set_read_timeout(Some(Duration::from_millis(200)))
                .unwrap();
            let mut byte = [0u8; 1];
            match std::io::Read::read(&mut c, &mut byte) {
                Err(e)
                    if e.kind() == std::io::ErrorKind::WouldBlock
                        || e.kind() == std::io::ErrorKind::TimedOut =>
                {
                    return c;
                }
                _ => assert!(t.elapsed() < Duration::from_secs(3), "no slot was free"),
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    let held: Vec<_> = (0..3).map(|_| hold()).collect();
    let (status, body) = raw_post(server.addr, "/v1/pose", "application/json", b"{}");
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("--max-connections"), "{body}");
    drop(held);
    let t = Instant::now();
    loop {
        if raw_get(server.addr, "/healthz").is_some_and(|(s, _)| s == 200) {
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(3),
            "the slots were not freed"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// An HTTP/1.1 keep-alive connection that has answered one request: whether the server
/// closes it within `within`.
fn closed_within(addr: std::net::SocketAddr, within: Duration) -> bool {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    s.set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let t = Instant::now();
    let mut buf = [0u8; 4096];
    while t.elapsed() < within {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => return true,
        }
    }
    false
}

#[test]
fn connections_past_their_maximum_age_are_closed() {
    // Without the flag a kept-alive connection stays (the header timeout is 30 s).
    let server = Server::start(&[]);
    assert!(!closed_within(server.addr, Duration::from_millis(1500)));
    // With it, it goes after about its age (±10%), checked once a tick.
    let server = Server::start(&["--max-connection-age", "500ms"]);
    let t = Instant::now();
    assert!(closed_within(server.addr, Duration::from_secs(3)));
    assert!(
        t.elapsed() >= Duration::from_millis(440),
        "{:?}",
        t.elapsed()
    );
    // And it is counted.
    let metrics = raw_get(server.addr, "/metrics").unwrap().1;
    let aged: f64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("facepose_connections_aged_total "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no facepose_connections_aged_total in\n{metrics}"));
    assert!(aged >= 1.0, "{aged}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_calls_go_on_across_aged_connections_and_streams_get_their_grace() {
    let server = Server::start(&[
        "--max-connection-age",
        "400ms",
        "--max-connection-age-grace",
        "600ms",
    ]);
    // Unary calls on one channel for 2 s: its connection is asked to go several times (GOAWAY),
    // and the channel opens a new one. A call caught by a GOAWAY may fail in the client's
    // transport (the retry that gRPC advises with connection ageing); none may fail otherwise,
    // and most go on.
    let mut g = server.grpc().await;
    let t = Instant::now();
    let (mut calls, mut unavailable) = (0, 0);
    while t.elapsed() < Duration::from_secs(2) {
        let r = g
            .estimate(proto::EstimateRequest {
                face: Some(proto_face(&face68(10.0, 0.0, 0.0), "", "fit", "")),
                model: String::new(),
            })
            .await;
        match r {
            Ok(_) => {}
            // A call the client sends as the connection closes fails in the client's transport:
            // tonic's channel may still pick the closing connection (UNAVAILABLE, CANCELLED
            // "connection closed", INTERNAL "GoAway"). No answer of the server may be an error.
            Err(e)
                if std::error::Error::source(&e)
                    .is_some_and(|s| s.is::<tonic::transport::Error>()) =>
            {
                unavailable += 1
            }
            Err(e) => panic!("call {calls} failed: {e:?}"),
        }
        calls += 1;
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(
        calls > 20 && unavailable * 5 <= calls,
        "{unavailable} of {calls} unavailable"
    );
    // A stream left open on an aged connection is cut after the grace: the tracker's client
    // reopens it (on a new pod after a scale-out).
    // The time counts from before the connection opens: the cut comes at its age + grace.
    let t = Instant::now();
    let mut g = server.grpc().await;
    let (tx, mut results) = facepose_testkit::open_stream(&mut g, 4).await;
    let mut frames = 0u64;
    let ended = loop {
        let frame = proto::Frame {
            frame_id: frames,
            faces: vec![proto_face(&face68(0.0, 0.0, 0.0), "", "fit", "t")],
            ..Default::default()
        };
        if tx.send(frame).await.is_err() {
            break t.elapsed();
        }
        match tokio::time::timeout(Duration::from_secs(3), results.message()).await {
            Ok(Ok(Some(_))) => frames += 1,
            Ok(_) => break t.elapsed(),
            Err(_) => panic!("no answer within 3 s"),
        }
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "the stream was never cut"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    // Age 360-440 ms, then 600 ms of grace; ticks of 400 ms.
    assert!(
        ended >= Duration::from_millis(900),
        "cut after {ended:?}, {frames} frames"
    );
    assert!(ended <= Duration::from_millis(2500), "cut after {ended:?}");
}
