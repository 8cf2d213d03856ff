//! Helpers of the service tests: start the real binary on a free loopback port, wait until it is
//! ready, and faces projected from the default model's mean shape at known poses (the
//! independent expectation: the service must give those poses back).
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::{SubsetMap, default_model};
use facepose_service::proto;
use nalgebra::{Rotation3, Vector2};

/// A running `facepose serve`; killed when dropped.
pub struct Server {
    child: Child,
    pub addr: SocketAddr,
    pub base: String,
    logs: Arc<Mutex<String>>,
    started: Instant,
}

impl Server {
    /// Starts `facepose serve --addr 127.0.0.1:0 <args>` and waits for `/readyz`.
    pub fn start(args: &[&str]) -> Server {
        Self::start_in(args, None)
    }

    /// As [`Server::start`], in a working directory.
    pub fn start_in(args: &[&str], dir: Option<&std::path::Path>) -> Server {
        Self::start_with(args, dir, &[])
    }

    /// As [`Server::start_in`], with environment variables.
    pub fn start_with(
        args: &[&str],
        dir: Option<&std::path::Path>,
        envs: &[(&str, &str)],
    ) -> Server {
        let started = Instant::now();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_facepose"));
        cmd.args(["serve", "--addr", "127.0.0.1:0"]);
        if !args.contains(&"--log") {
            cmd.args(["--log", "info"]);
        }
        cmd.args(args)
            .env_remove("FACEPOSE_ADDR")
            .env_remove("FACEPOSE_LOG_FORMAT")
            .env_remove("FACEPOSE_ADMIN_TOKEN")
            .env_remove("FACEPOSE_ADMIN_TOKEN_FILE")
            .envs(envs.iter().copied())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        if let Some(d) = dir {
            cmd.current_dir(d);
        }
        let mut child = cmd.spawn().expect("spawn facepose serve");
        let stderr = child.stderr.take().unwrap();
        let logs = Arc::new(Mutex::new(String::new()));
        let (tx, rx) = std::sync::mpsc::channel();
        let sink = logs.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if let Some(a) = line.split("addr=").nth(1) {
                    let a = a.split_whitespace().next().unwrap_or("").to_string();
                    let _ = tx.send(a);
                }
                let mut l = sink.lock().unwrap();
                l.push_str(&line);
                l.push('\n');
            }
        });
        let addr: SocketAddr = match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(a) => a.parse().expect("bound address"),
            Err(_) => {
                let _ = child.kill();
                panic!(
                    "the server did not log its address; logs:\n{}",
                    logs.lock().unwrap()
                );
            }
        };
        let server = Server {
            child,
            addr,
            base: format!("http://{addr}"),
            logs,
            started,
        };
        server.wait_ready(Duration::from_secs(30));
        server
    }

    /// Polls `/readyz` until it answers 200.
    pub fn wait_ready(&self, limit: Duration) -> Duration {
        let t = Instant::now();
        while t.elapsed() < limit {
            if raw_get(self.addr, "/readyz").is_some_and(|(s, _)| s == 200) {
                return self.started.elapsed();
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        panic!("not ready after {limit:?}; logs:\n{}", self.logs());
    }

    pub fn logs(&self) -> String {
        self.logs.lock().unwrap().clone()
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Kills the process with SIGKILL and waits for it.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Sends SIGTERM.
    pub fn terminate(&self) {
        let ok = Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status()
            .expect("kill")
            .success();
        assert!(ok, "kill -TERM failed");
    }

    /// Waits for the process to exit, at most `limit`.
    ///
    /// Async, so that the test's own clients keep running meanwhile: a drain closes a
    /// connection only once its client has answered the server's GOAWAY and PING, which a
    /// client whose runtime is blocked in a sleep never does (the drain then waits for its cap).
    pub async fn wait_exit(&mut self, limit: Duration) -> Option<ExitStatus> {
        let t = Instant::now();
        while t.elapsed() < limit {
            if let Ok(Some(s)) = self.child.try_wait() {
                return Some(s);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        None
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    pub async fn channel(&self) -> tonic::transport::Channel {
        tonic::transport::Endpoint::from_shared(self.base.clone())
            .unwrap()
            .connect()
            .await
            .expect("gRPC connect")
    }

    pub async fn grpc(
        &self,
    ) -> proto::pose_service_client::PoseServiceClient<tonic::transport::Channel> {
        proto::pose_service_client::PoseServiceClient::new(self.channel().await)
    }
}

/// Opens an `EstimateStream` on `c`: the sender of its frames (up to `capacity` waiting) and
/// its results.
pub async fn open_stream(
    c: &mut proto::pose_service_client::PoseServiceClient<tonic::transport::Channel>,
    capacity: usize,
) -> (
    tokio::sync::mpsc::Sender<proto::Frame>,
    tonic::Streaming<proto::FrameResult>,
) {
    let (tx, rx) = tokio::sync::mpsc::channel(capacity);
    let out = c
        .estimate_stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap()
        .into_inner();
    (tx, out)
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A bare HTTP/1.1 GET: (status, body), or `None` if the connection failed.
pub fn raw_get(addr: SocketAddr, path: &str) -> Option<(u16, String)> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(1)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let (status, body) = parse_answer(&text);
    (status != 0).then_some((status, body))
}

/// The status and body of an HTTP/1.1 answer read whole (status 0 when there is none).
pub fn parse_answer(text: &str) -> (u16, String) {
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let body = text.split("\r\n\r\n").nth(1).unwrap_or("").to_string();
    (status, body)
}

/// A bare HTTP/1.1 POST with the given content type and body bytes: (status, body).
pub fn raw_post(addr: SocketAddr, path: &str, content_type: &str, body: &[u8]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    s.write_all(body).unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    parse_answer(&text)
}

/// The head of an HTTP/1.1 JSON POST declaring `length` body bytes (plus `extra` header lines),
/// without the body: (status, body) of the answer.
pub fn raw_head_only_post(addr: SocketAddr, path: &str, length: u64, extra: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {length}\r\n{extra}\r\n"
    )
    .unwrap();
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    parse_answer(&text)
}

/// A chunked HTTP/1.1 POST of JSON whose length is not declared: (status, body).
pub fn raw_chunked_post(addr: SocketAddr, path: &str, chunks: &[&[u8]]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    )
    .unwrap();
    for c in chunks {
        // The server may answer and close before the whole body is sent.
        if write!(s, "{:x}\r\n", c.len()).is_err() || s.write_all(c).is_err() {
            break;
        }
        let _ = s.write_all(b"\r\n");
    }
    let _ = s.write_all(b"0\r\n\r\n");
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    parse_answer(&text)
}

/// The default model, loaded once per test process.
pub fn model() -> &'static facepose_core::model::PoseModel {
    static MODEL: std::sync::OnceLock<facepose_core::model::PoseModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

/// The 68 landmarks (image pixels) of the default model's mean shape seen at a known pose by a
/// weak-perspective camera.
pub fn face68(yaw: f64, pitch: f64, roll: f64) -> Vec<[f64; 2]> {
    let model = model();
    let cam = camera(yaw, pitch, roll);
    model
        .mean
        .iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x, p.y]
        })
        .collect()
}

/// The five points (eye centres, nose tip, mouth corners) of the same face.
pub fn face5(yaw: f64, pitch: f64, roll: f64) -> Vec<[f64; 2]> {
    let model = model();
    let cam = camera(yaw, pitch, roll);
    SubsetMap::Anchors
        .map_points(&model.scheme, &model.mean)
        .iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x, p.y]
        })
        .collect()
}

fn camera(yaw: f64, pitch: f64, roll: f64) -> WeakPerspective {
    WeakPerspective::new(
        EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation(),
        2.1,
        Vector2::new(320.0, -240.0),
    )
    .unwrap()
}

pub fn rotation(yaw: f64, pitch: f64, roll: f64) -> Rotation3<f64> {
    EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation()
}

/// Row-major 3x3 from JSON, checked to be a rotation.
pub fn rotation_json(v: &serde_json::Value) -> Rotation3<f64> {
    let rows: [[f64; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| v[i][j].as_f64().expect("rotation entries are numbers"))
    });
    facepose_core::geometry::rotation_from_rows(rows, 1e-6).unwrap()
}

/// Row-major 9 doubles from gRPC, checked to be a rotation.
pub fn rotation_flat(v: &[f64]) -> Rotation3<f64> {
    assert_eq!(v.len(), 9);
    let rows: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| v[3 * i + j]));
    facepose_core::geometry::rotation_from_rows(rows, 1e-6).unwrap()
}

pub fn proto_face(points: &[[f64; 2]], scheme: &str, method: &str, id: &str) -> proto::Face {
    proto::Face {
        landmarks: facepose_service::grpc::landmark_messages(points),
        scheme: scheme.into(),
        method: method.into(),
        camera: None,
        id: id.into(),
        landmark_style: String::new(),
        xy: vec![],
        missing: vec![],
    }
}
