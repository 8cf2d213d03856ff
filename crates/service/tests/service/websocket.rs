//! `GET /v1/pose:stream`: the stream of frames over a WebSocket (issue 40), checked against
//! gRPC's `EstimateStream`, whose session it shares.

use std::time::Duration;

use facepose_service::proto;
use facepose_testkit::Endpoint;
use facepose_testkit::faces::*;
use facepose_testkit::server::Server;
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Opens a stream, with `origin` as the handshake's `Origin` when given.
async fn connect(server: &Server, origin: Option<&str>) -> Result<Ws, WsError> {
    let mut req = format!("ws://{}/v1/pose:stream", server.addr)
        .into_client_request()
        .unwrap();
    if let Some(o) = origin {
        req.headers_mut().insert("origin", o.parse().unwrap());
    }
    tokio_tungstenite::connect_async(req)
        .await
        .map(|(ws, _)| ws)
}

/// The handshake's HTTP status when it is refused.
async fn refused(server: &Server, origin: Option<&str>) -> u16 {
    match connect(server, origin).await {
        Err(WsError::Http(resp)) => resp.status().as_u16(),
        Ok(_) => panic!("the handshake was accepted"),
        Err(e) => panic!("{e}"),
    }
}

async fn send(ws: &mut Ws, v: Value) {
    ws.send(Message::text(v.to_string())).await.unwrap();
}

/// The next data or close message (pings are skipped).
async fn next(ws: &mut Ws) -> Message {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(10), ws.next())
            .await
            .expect("an answer within 10 s")
            .expect("the stream is open")
            .expect("a message");
        if !matches!(m, Message::Ping(_) | Message::Pong(_)) {
            return m;
        }
    }
}

async fn answer(ws: &mut Ws) -> Value {
    match next(ws).await {
        Message::Text(t) => serde_json::from_str(t.as_str()).unwrap(),
        other => panic!("{other:?}"),
    }
}

/// The close frame that ends the stream: its code and reason.
async fn closed(ws: &mut Ws) -> (u16, String) {
    match next(ws).await {
        Message::Close(Some(c)) => (u16::from(c.code), c.reason.to_string()),
        other => panic!("not a close: {other:?}"),
    }
}

fn face(id: &str, points: &[[f64; 2]]) -> Value {
    json!({"id": id, "landmarks": points, "method": "fit"})
}

#[tokio::test]
async fn frames_are_answered_in_order_with_smoothed_poses() {
    let server = Server::start(&[]);
    let mut ws = connect(&server, None).await.unwrap();
    for k in 0..6u64 {
        let yaw = -20.0 + 5.0 * k as f64;
        let mut faces = vec![face("t1", &face68(yaw, 5.0, 0.0))];
        if k == 3 {
            faces.push(face("bad", &[[1.0, 1.0]; 68]));
        }
        let mut frame =
            json!({"frame_id": k, "timestamp_us": 1_000_000 + k * 33_333, "faces": faces});
        if k == 0 {
            frame["smoothing"] = json!({"enabled": true});
        }
        send(&mut ws, frame).await;
    }
    for k in 0..6u64 {
        let a = answer(&mut ws).await;
        assert_eq!(a["frame_id"], k, "{a}");
        assert_eq!(a["timestamp_us"], 1_000_000 + k * 33_333);
        assert_eq!(a["model"], "default");
        let p = &a["faces"][0];
        assert_eq!(p["id"], "t1");
        assert_eq!(p["pose"]["smoothed"], true, "{a}");
        assert_eq!(p["pose"]["scheme"], "ibug68");
        for field in [
            "yaw", "pitch", "roll", "rotation", "residual", "method", "gated",
        ] {
            assert!(!p["pose"][field].is_null(), "{field}: {a}");
        }
        if k == 3 {
            let e = &a["faces"][1];
            assert_eq!(e["id"], "bad");
            assert_eq!(e["error"]["code"], "invalid_argument", "{a}");
            assert!(e["pose"].is_null());
        }
    }
    // Smoothing off: raw angles.
    send(&mut ws, json!({"frame_id": 9, "faces": [face("t1", &face68(10.0, 0.0, 0.0))], "smoothing": {"enabled": false}})).await;
    let a = answer(&mut ws).await;
    assert_eq!(a["faces"][0]["pose"]["smoothed"], false);
    assert!(
        (a["faces"][0]["pose"]["yaw"].as_f64().unwrap() - 10.0).abs() < 0.5,
        "{a}"
    );
    ws.close(None).await.unwrap();
}

/// The same faces over gRPC's stream and the WebSocket, smoothing on with its defaults, give
/// the same angles: one session, one default filter.
#[tokio::test]
async fn the_default_filter_is_the_grpc_stream_s() {
    let server = Server::start(&[]);
    let mut c = server.grpc().await;
    let (tx, mut out) = facepose_testkit::open_stream(&mut c, 16).await;
    let mut ws = connect(&server, None).await.unwrap();
    for k in 0..8u64 {
        // A jump at frame 5: the gate's work, the same on both.
        let yaw = if k == 5 { 60.0 } else { -10.0 + 3.0 * k as f64 };
        let points = face68(yaw, 4.0, -2.0);
        let ts = 1_000_000 + k as i64 * 33_333;
        tx.send(proto::Frame {
            frame_id: k,
            timestamp_us: ts,
            faces: vec![proto_face(&points, "", "fit", "a")],
            model: String::new(),
            smoothing: (k == 0).then(|| proto::Smoothing {
                enabled: true,
                ..Default::default()
            }),
        })
        .await
        .unwrap();
        let g = tokio_stream::StreamExt::next(&mut out)
            .await
            .unwrap()
            .unwrap();
        let gp = match &g.faces[0].result {
            Some(proto::face_result::Result::Pose(p)) => p.clone(),
            other => panic!("{other:?}"),
        };
        let mut frame = json!({"frame_id": k, "timestamp_us": ts, "faces": [face("a", &points)]});
        if k == 0 {
            frame["smoothing"] = json!({"enabled": true});
        }
        send(&mut ws, frame).await;
        let w = answer(&mut ws).await;
        let wp = &w["faces"][0]["pose"];
        assert_eq!(wp["smoothed"], gp.smoothed);
        assert_eq!(wp["gated"], gp.gated, "frame {k}");
        for (name, g) in [("yaw", gp.yaw), ("pitch", gp.pitch), ("roll", gp.roll)] {
            let w = wp[name].as_f64().unwrap();
            assert!((w - g).abs() < 1e-9, "frame {k} {name}: {w} vs {g}");
        }
    }
}

#[tokio::test]
async fn a_frame_over_max_batch_closes_the_stream_with_1009() {
    let server = Server::start(&["--max-batch", "2"]);
    let mut ws = connect(&server, None).await.unwrap();
    let f = face68(0.0, 0.0, 0.0);
    send(
        &mut ws,
        json!({"frame_id": 1, "faces": [face("a", &f), face("b", &f)]}),
    )
    .await;
    assert_eq!(answer(&mut ws).await["faces"].as_array().unwrap().len(), 2);
    send(
        &mut ws,
        json!({"frame_id": 2, "faces": [face("a", &f), face("b", &f), face("c", &f)]}),
    )
    .await;
    let (code, reason) = closed(&mut ws).await;
    assert_eq!(code, 1009, "{reason}");
    assert!(reason.contains('3') && reason.contains('2'), "{reason}");
}

#[tokio::test]
async fn unusable_messages_close_with_their_codes() {
    let server = Server::start(&[]);
    let cases: [(Message, u16, &str); 4] = [
        (Message::binary(vec![1u8, 2, 3]), 1003, "binary"),
        (Message::text("{\"faces\": 3}"), 1007, "faces"),
        (
            Message::text("{\"frame_id\": 1, \"extra\": 1}"),
            1007,
            "extra",
        ),
        (
            Message::text(json!({"smoothing": {"enabled": true, "filter": "median"}}).to_string()),
            1008,
            "median",
        ),
    ];
    for (msg, want, says) in cases {
        let mut ws = connect(&server, None).await.unwrap();
        ws.send(msg).await.unwrap();
        let (code, reason) = closed(&mut ws).await;
        assert_eq!(code, want, "{reason}");
        assert!(reason.contains(says), "{reason}");
    }
}

#[tokio::test]
async fn the_handshake_checks_the_origin() {
    let server = Server::start(&["--cors-origins", "https://app.example.com"]);
    assert_eq!(
        refused(&server, Some("https://evil.example.com")).await,
        403
    );
    assert!(
        connect(&server, Some("https://app.example.com"))
            .await
            .is_ok()
    );
    assert!(
        connect(&server, None).await.is_ok(),
        "no Origin: not a browser"
    );
    let own = format!("http://{}", server.addr);
    assert!(connect(&server, Some(&own)).await.is_ok(), "same origin");
    // Without --cors-origins only the server's own pages may.
    let closed_server = Server::start(&[]);
    assert_eq!(
        refused(&closed_server, Some("https://app.example.com")).await,
        403
    );
    let own = format!("http://{}", closed_server.addr);
    assert!(connect(&closed_server, Some(&own)).await.is_ok());
    // A plain GET is told what the route is.
    let r = reqwest::get(format!("{}/v1/pose:stream", server.base))
        .await
        .unwrap();
    assert!(r.status().is_client_error(), "{}", r.status());
}

#[tokio::test]
async fn streams_share_max_streams_with_grpc() {
    let server = Server::start(&["--max-streams", "1"]);
    let mut ws = connect(&server, None).await.unwrap();
    // The gRPC stream is refused while the WebSocket holds the slot.
    let mut c = server.grpc().await;
    let (tx, rx) = tokio::sync::mpsc::channel::<proto::Frame>(1);
    let refused_grpc = match c
        .estimate_stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
    {
        Err(s) => s.code(),
        Ok(r) => {
            let _ = tx.send(proto::Frame::default()).await;
            let mut out = r.into_inner();
            tokio_stream::StreamExt::next(&mut out)
                .await
                .unwrap()
                .unwrap_err()
                .code()
        }
    };
    assert_eq!(refused_grpc, tonic::Code::Unavailable);
    // A second WebSocket too (503).
    assert_eq!(refused(&server, None).await, 503);
    // Closing the WebSocket frees it.
    ws.close(None).await.unwrap();
    while ws.next().await.is_some() {}
    let mut again = None;
    for _ in 0..100 {
        if let Ok(ws) = connect(&server, None).await {
            again = Some(ws);
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let mut ws = again.expect("the slot is freed");
    // And a gRPC stream holding it refuses the WebSocket.
    ws.close(None).await.unwrap();
    while ws.next().await.is_some() {}
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (tx, mut out) = facepose_testkit::open_stream(&mut c, 1).await;
    tx.send(proto::Frame::default()).await.unwrap();
    tokio_stream::StreamExt::next(&mut out)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(refused(&server, None).await, 503);
}

#[tokio::test]
async fn the_drain_closes_streams_with_1001() {
    let mut server = Server::start(&[]);
    let mut ws = connect(&server, None).await.unwrap();
    send(
        &mut ws,
        json!({"frame_id": 1, "faces": [face("a", &face68(0.0, 0.0, 0.0))]}),
    )
    .await;
    answer(&mut ws).await;
    server.terminate();
    let (code, reason) = closed(&mut ws).await;
    assert_eq!(code, 1001, "{reason}");
    assert!(reason.contains("shutting down"), "{reason}");
    assert_eq!(server.wait_exit(Duration::from_secs(5)).await, Some(Ok(())));
}

#[tokio::test]
async fn an_idle_stream_is_closed_and_pinged() {
    let server = Server::start(&["--ws-idle-timeout", "400ms", "--ws-ping-interval", "100ms"]);
    let mut ws = connect(&server, None).await.unwrap();
    // The server pings; the client's library answers.
    let first = tokio::time::timeout(Duration::from_secs(5), ws.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert!(matches!(first, Message::Ping(_)), "{first:?}");
    let (code, reason) = closed(&mut ws).await;
    assert_eq!(code, 1008, "{reason}");
    assert!(reason.contains("idle"), "{reason}");
}

/// A client that sends frames and reads none: once the sockets' buffers and the answer queue
/// are full the server closes the stream (1008), instead of holding more answers.
#[tokio::test]
async fn a_client_that_reads_too_slowly_is_closed() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let server = Server::start(&["--ws-queue", "2"]);
    let ws = connect(&server, None).await.unwrap();
    let (mut tx, mut rx) = ws.split();
    let faces: Vec<Value> = (0..100)
        .map(|i| face(&format!("f{i}"), &face68(i as f64 % 40.0 - 20.0, 0.0, 0.0)))
        .collect();
    let frame = json!({"frame_id": 0, "faces": faces}).to_string();
    let sent = 400;
    let accepted = Arc::new(AtomicUsize::new(0));
    let count = Arc::clone(&accepted);
    let sender = tokio::spawn(async move {
        for _ in 0..sent {
            if tx.send(Message::text(frame.clone())).await.is_err() {
                break;
            }
            count.fetch_add(1, Ordering::Relaxed);
        }
    });
    // Read nothing until the server stops taking frames (no frame accepted for a second: it
    // is closing, or blocked writing into full buffers), however slowly a loaded machine lets
    // it fill them; the server then waits 5 s for room for its close.
    let t = std::time::Instant::now();
    let (mut last, mut still) = (usize::MAX, 0);
    while still < 4 && !sender.is_finished() && t.elapsed() < Duration::from_secs(60) {
        tokio::time::sleep(Duration::from_millis(250)).await;
        let now = accepted.load(Ordering::Relaxed);
        still = if now == last { still + 1 } else { 0 };
        last = now;
    }
    // Now read: the answers that fitted in the buffers, then the close.
    let mut answers = 0;
    let mut close = None;
    while let Ok(Some(Ok(m))) = tokio::time::timeout(Duration::from_secs(10), rx.next()).await {
        match m {
            Message::Text(_) => answers += 1,
            Message::Close(c) => {
                close = c.map(|c| (u16::from(c.code), c.reason.to_string()));
                break;
            }
            _ => {}
        }
    }
    eprintln!(
        "{answers} answers of {sent} ({} frames accepted), closed after {:?}",
        accepted.load(Ordering::Relaxed),
        t.elapsed()
    );
    assert!(answers < sent, "{answers} answers");
    let (code, reason) = close.expect("a close frame");
    assert_eq!(code, 1008, "{reason}");
    assert!(reason.contains("too slowly"), "{reason}");
}

#[tokio::test]
async fn a_message_over_max_body_closes_with_1009() {
    let server = Server::start(&["--max-body", "64KiB"]);
    let mut ws = connect(&server, None).await.unwrap();
    let faces: Vec<Value> = (0..60)
        .map(|i| face(&i.to_string(), &face68(0.0, 0.0, 0.0)))
        .collect();
    let text = json!({"faces": faces}).to_string();
    assert!(text.len() > 64 * 1024, "{}", text.len());
    ws.send(Message::text(text)).await.unwrap();
    let (code, reason) = closed(&mut ws).await;
    assert_eq!(code, 1009, "{reason}");
    assert!(reason.contains("--max-body"), "{reason}");
}
