//! Load generator for `facepose serve` (used by scripts/loadtest.sh; not installed with the
//! crate):
//!
//! - `loadgen stream`: gRPC `EstimateStream` load: S streams, each sending frames of F faces
//!   and keeping up to W frames in flight; prints poses/s and per-frame latency percentiles.
//!   Faces carry `Landmark` messages, or with `--packed` the packed `xy` form. The frames go
//!   out encoded in advance and of each result only whether each face got a pose is read
//!   ([`LightCodec`]): the generator shares the server's cores, and what it spends is taken
//!   from the server's measure. With `--ws`, the same over the WebSocket stream
//!   (`GET /v1/pose:stream`, JSON text; the answers' poses counted without parsing them).
//! - `loadgen ceiling BODY`: the server's own batch work (`http::answer_batch`: parse,
//!   estimate, serialize) on a `POST /v1/pose:batch` body, on T threads with no network and no
//!   server; prints faces/s, the most any server could answer on this machine at that moment.
//! - `loadgen bodies DIR`: writes the request bodies the script's wrk and h2load runs send:
//!   one-face JSON bodies (one a line, for wrk to cycle through), a batch JSON body, and a
//!   gRPC-framed `EstimateRequest` of the first face for h2load.
//!
//! Faces (`--faces-from`): `dev` (the default) are real ones, the AFLW2000-3D dev split's
//! re-annotated 68 landmarks (the faces with every |angle| <= 99°, in the file's order, cycled;
//! `five` takes their anchors' means), from the shared data (FACEPOSE_DATA, else
//! ../shared/data); `synthetic` are the default model's mean shape projected at varied poses
//! with 1 px of landmark noise (seeded), 68 points (`ibug68`) or five (`five`). `--method
//! default` sends no method: the server's default (`auto`).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::{SubsetMap, default_model};
use facepose_service::grpc::landmark_messages;
use facepose_service::proto;
use nalgebra::Vector2;
use prost::Message;
use prost::bytes::{BufMut, Bytes};
use rand::{Rng, SeedableRng, rngs::StdRng};
use serde_json::json;
use tokio_stream::StreamExt;
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};

struct Args {
    cmd: String,
    addr: String,
    streams: usize,
    faces: usize,
    window: usize,
    duration: Duration,
    scheme: String,
    method: String,
    batch: usize,
    dir: String,
    packed: bool,
    threads: usize,
    source: String,
    ws: bool,
}

fn parse_args() -> Args {
    let mut a = Args {
        cmd: String::new(),
        addr: "http://127.0.0.1:8080".into(),
        streams: 8,
        faces: 4,
        window: 8,
        duration: Duration::from_secs(10),
        scheme: "ibug68".into(),
        method: "fit".into(),
        batch: 1000,
        dir: ".".into(),
        packed: false,
        threads: 2,
        source: "dev".into(),
        ws: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().unwrap_or_else(|| panic!("{k} needs a value"));
        match k.as_str() {
            "--addr" => a.addr = v(),
            "--streams" => a.streams = v().parse().expect("--streams N"),
            "--faces" => a.faces = v().parse().expect("--faces N"),
            "--window" => a.window = v().parse().expect("--window N"),
            "--duration" => {
                a.duration = Duration::from_secs_f64(v().parse().expect("--duration seconds"))
            }
            "--scheme" => a.scheme = v(),
            "--method" => a.method = v(),
            "--batch" => a.batch = v().parse().expect("--batch N"),
            "--packed" => a.packed = true,
            "--ws" => a.ws = true,
            "--threads" => a.threads = v().parse().expect("--threads N"),
            "--faces-from" => a.source = v(),
            c if a.cmd.is_empty() => a.cmd = c.to_string(),
            d if a.cmd == "bodies" || a.cmd == "ceiling" => a.dir = d.to_string(),
            other => panic!("unknown argument {other}"),
        }
    }
    a
}

/// `n` faces in `scheme`, image pixels, from `a.source`; `seed` picks where the real faces
/// start, or seeds the synthetic ones.
fn faces(n: usize, a: &Args, seed: u64) -> Vec<Vec<[f64; 2]>> {
    match a.source.as_str() {
        "dev" => dev_faces(n, &a.scheme, seed),
        "synthetic" => synthetic_faces(n, &a.scheme, seed),
        other => panic!("--faces-from dev or synthetic, not {other}"),
    }
}

/// `n` of the AFLW2000-3D dev faces' re-annotated landmarks (every |angle| <= 99°), cycled from
/// face `start` (modulo their count), in `scheme` (`ibug68`, or `five` from them).
fn dev_faces(n: usize, scheme: &str, start: u64) -> Vec<Vec<[f64; 2]>> {
    use facepose_core::shape::{Shape2, ibug68};
    let path = facepose_files::data::data_dir().join("aflw2000/aflw2000_dev.jsonl");
    let all = facepose_files::data::load_aflw(&path).unwrap_or_else(|e| panic!("{e}"));
    let ibug = ibug68();
    let kept: Vec<Vec<[f64; 2]>> = all
        .iter()
        .filter(|f| f.within_99)
        .map(|f| match scheme {
            "ibug68" => f.landmarks_reannotated.clone(),
            "five" => {
                let pts = f.landmarks_reannotated.iter().map(|p| Some(*p));
                let shape = Shape2::from_options(&pts.collect::<Vec<_>>()).expect("a shape");
                let five = shape.to_five(&ibug).expect("five points");
                five.points().iter().map(|p| [p.x, p.y]).collect()
            }
            other => panic!("real faces come as ibug68 or five, not {other}"),
        })
        .collect();
    let first = start as usize % kept.len();
    kept.iter().cycle().skip(first).take(n).cloned().collect()
}

/// `n` synthetic faces in `scheme`.
fn synthetic_faces(n: usize, scheme: &str, seed: u64) -> Vec<Vec<[f64; 2]>> {
    let (_, model) = default_model().expect("default model");
    let mut rng = StdRng::seed_from_u64(seed);
    let points = match scheme {
        "five" => SubsetMap::Anchors.map_points(&model.scheme, &model.mean),
        _ => model.mean.clone(),
    };
    (0..n)
        .map(|_| {
            let a = EulerAngles::new(
                rng.random_range(-60.0..60.0),
                rng.random_range(-25.0..25.0),
                rng.random_range(-20.0..20.0),
            )
            .expect("finite angles");
            let cam = WeakPerspective::new(a.to_rotation(), 2.0, Vector2::new(320.0, -240.0))
                .expect("camera");
            points
                .iter()
                .map(|x| {
                    let p = cam.project(x);
                    [
                        p.x + rng.random_range(-1.0..1.0),
                        p.y + rng.random_range(-1.0..1.0),
                    ]
                })
                .collect()
        })
        .collect()
}

fn proto_face(points: &[[f64; 2]], a: &Args) -> proto::Face {
    let (landmarks, xy) = if a.packed {
        (vec![], points.iter().flatten().copied().collect())
    } else {
        (landmark_messages(points), vec![])
    };
    proto::Face {
        landmarks,
        scheme: a.scheme.clone(),
        method: a.wire_method().to_string(),
        camera: None,
        id: String::new(),
        landmark_style: String::new(),
        xy,
        missing: vec![],
        image_size: None,
        conventions: Vec::new(),
        camera_orientation: None,
    }
}

impl Args {
    /// The method as requests carry it: none (empty) for `default`.
    fn wire_method(&self) -> &str {
        if self.method == "default" {
            ""
        } else {
            &self.method
        }
    }

    /// A request body's JSON: `landmarks` or `faces`, the scheme, and the method unless it is
    /// the default.
    fn body(&self, key: &str, value: serde_json::Value) -> serde_json::Value {
        let mut body = json!({ key: value, "scheme": self.scheme });
        if !self.wire_method().is_empty() {
            body["method"] = json!(self.method);
        }
        body
    }
}

/// How many one-face bodies `bodies` writes (wrk cycles through them).
const SINGLE_BODIES: usize = 491;

fn bodies(a: &Args) {
    let dir = std::path::Path::new(&a.dir);
    std::fs::create_dir_all(dir).expect("bodies dir");
    let singles = faces(SINGLE_BODIES, a, 0);
    let one = &singles[0];
    let lines: Vec<String> = singles
        .iter()
        .map(|f| a.body("landmarks", json!(f)).to_string())
        .collect();
    std::fs::write(dir.join("poses.jsonl"), lines.join("\n") + "\n").expect("write");
    let batch: Vec<_> = faces(a.batch, a, 0)
        .into_iter()
        .map(|f| json!({ "landmarks": f }))
        .collect();
    let batch = a.body("faces", json!(batch));
    std::fs::write(dir.join("batch.json"), batch.to_string()).expect("write");
    // gRPC framing: compressed flag 0, big-endian length, message.
    let req = proto::EstimateRequest {
        face: Some(proto_face(one, a)),
        model: String::new(),
    }
    .encode_to_vec();
    let mut framed = vec![0u8];
    framed.extend_from_slice(&(req.len() as u32).to_be_bytes());
    framed.extend_from_slice(&req);
    std::fs::write(dir.join("estimate.grpc"), framed).expect("write");
    println!(
        "wrote poses.jsonl ({SINGLE_BODIES} one-face bodies), batch.json ({} faces), \
         estimate.grpc to {}",
        a.batch,
        dir.display()
    );
}

/// Of a `FrameResult`, its faces only.
#[derive(Clone, PartialEq, Message)]
struct FrameOutcome {
    #[prost(message, repeated, tag = "3")]
    faces: Vec<FaceOutcome>,
}

/// Of a `FaceResult`, its pose unread (`bytes` over the same buffer: no copy, no decode).
#[derive(Clone, PartialEq, Message)]
struct FaceOutcome {
    #[prost(bytes = "bytes", optional, tag = "2")]
    pose: Option<Bytes>,
}

/// The stream's codec on the generator's side: encoded frames out, [`FrameOutcome`]s in.
struct LightCodec;

struct EncodedFrames;

struct Outcomes;

impl Codec for LightCodec {
    type Encode = Bytes;
    type Decode = FrameOutcome;
    type Encoder = EncodedFrames;
    type Decoder = Outcomes;
    fn encoder(&mut self) -> EncodedFrames {
        EncodedFrames
    }
    fn decoder(&mut self) -> Outcomes {
        Outcomes
    }
}

impl Encoder for EncodedFrames {
    type Item = Bytes;
    type Error = tonic::Status;
    fn encode(&mut self, frame: Bytes, dst: &mut EncodeBuf<'_>) -> Result<(), tonic::Status> {
        dst.put_slice(&frame);
        Ok(())
    }
}

impl Decoder for Outcomes {
    type Item = FrameOutcome;
    type Error = tonic::Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<FrameOutcome>, tonic::Status> {
        FrameOutcome::decode(src).map(Some).map_err(|e| {
            tonic::Status::internal(format!("a FrameResult that does not decode: {e}"))
        })
    }
}

/// `loadgen ceiling`: [`facepose_service::http::pose::answer_batch`] on one body, over and over on
/// `a.threads` threads for `a.duration`, after a warm-up.
fn ceiling(a: &Args) {
    use facepose_app::Limits;
    let body = prost::bytes::Bytes::from(std::fs::read(&a.dir).expect("the batch body"));
    let set =
        std::sync::Arc::new(facepose_app::registry::load_models(None).expect("the default models"));
    let limits = Limits {
        max_batch: usize::MAX,
        max_body: usize::MAX,
        request_timeout: Duration::from_secs(3600),
        max_concurrency: 1,
        max_streams: 1,
        max_upload: 0,
        upload_timeout: Duration::from_secs(1),
    };
    let metrics = facepose_app::metrics::Metrics::new();
    // What the batch use case does around the transport's work, less the choice of thread.
    let answer = |b: &Bytes| {
        let mut run = facepose_app::estimate::BatchRun::new(
            set.clone(),
            limits,
            None,
            metrics.clone(),
            facepose_app::metrics::Transport::Http,
        );
        let out = facepose_service::http::pose::answer_batch(b.clone(), &mut run)
            .unwrap_or_else(|e| panic!("the body is refused: {e}"));
        run.finish();
        out
    };
    let first: serde_json::Value = serde_json::from_slice(&answer(&body)).expect("JSON");
    let faces = first["succeeded"].as_u64().unwrap_or(0) + first["failed"].as_u64().unwrap_or(0);
    let warm = Instant::now() + Duration::from_millis(500);
    while Instant::now() < warm {
        answer(&body);
    }
    let start = Instant::now();
    let until = start + a.duration;
    let bodies = std::thread::scope(|s| {
        let workers: Vec<_> = (0..a.threads.max(1))
            .map(|_| {
                s.spawn(|| {
                    let mut n = 0u64;
                    while Instant::now() < until {
                        std::hint::black_box(answer(&body));
                        n += 1;
                    }
                    n
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("worker"))
            .sum::<u64>()
    });
    let secs = start.elapsed().as_secs_f64();
    println!(
        "threads {} faces/body {faces}: {:.0} faces/s, {:.2} µs of thread time a face",
        a.threads.max(1),
        (bodies * faces) as f64 / secs,
        secs * a.threads.max(1) as f64 * 1e6 / (bodies * faces) as f64
    );
}

/// One WebSocket stream (`--ws`): returns (poses, per-frame latencies).
async fn one_ws_stream(a: &Args, seed: u64, until: Instant) -> (u64, Vec<Duration>) {
    use futures_util::SinkExt;
    use tokio_tungstenite::tungstenite::Message as WsMessage;
    let url = format!(
        "{}/v1/pose:stream",
        a.addr
            .replacen("http://", "ws://", 1)
            .replacen("https://", "wss://", 1)
    );
    let (ws, _) = tokio_tungstenite::connect_async(url.as_str())
        .await
        .expect("WebSocket handshake");
    let (mut tx, mut rx) = futures_util::StreamExt::split(ws);
    let method = a.wire_method().to_string();
    let pool: Vec<String> = faces(64 * a.faces, a, 61 * seed)
        .chunks(a.faces)
        .enumerate()
        .map(|(k, fs)| {
            let faces: Vec<_> = fs
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let mut face = json!({"id": i, "landmarks": f, "scheme": a.scheme});
                    if !method.is_empty() {
                        face["method"] = json!(method);
                    }
                    face
                })
                .collect();
            json!({"frame_id": k, "faces": faces}).to_string()
        })
        .collect();
    let mut sent: VecDeque<Instant> = VecDeque::new();
    let mut lat = Vec::new();
    let mut poses = 0u64;
    let mut k = 0usize;
    loop {
        while sent.len() < a.window && Instant::now() < until {
            let f = pool[k % pool.len()].clone();
            k += 1;
            sent.push_back(Instant::now());
            if tx.send(WsMessage::text(f)).await.is_err() {
                break;
            }
        }
        if sent.is_empty() {
            break;
        }
        match futures_util::StreamExt::next(&mut rx).await {
            Some(Ok(WsMessage::Text(t))) => {
                let t0 = sent.pop_front().expect("a frame in flight");
                lat.push(t0.elapsed());
                poses += t.as_str().matches("\"pose\":").count() as u64;
            }
            Some(Ok(WsMessage::Close(c))) => panic!("stream closed: {c:?}"),
            Some(Ok(_)) => {}
            Some(Err(e)) => panic!("stream error: {e}"),
            None => break,
        }
    }
    let _ = tx.send(WsMessage::Close(None)).await;
    (poses, lat)
}

/// One stream: returns (poses, per-frame latencies).
async fn one_stream(a: &Args, seed: u64, until: Instant) -> (u64, Vec<Duration>) {
    if a.ws {
        return one_ws_stream(a, seed, until).await;
    }
    let channel = tonic::transport::Endpoint::from_shared(a.addr.clone())
        .expect("--addr is a URL")
        .connect()
        .await
        .expect("connect");
    let mut client = tonic::client::Grpc::new(channel);
    let pool: Vec<Bytes> = faces(64 * a.faces, a, 61 * seed)
        .chunks(a.faces)
        .enumerate()
        .map(|(k, fs)| {
            let frame = proto::Frame {
                frame_id: k as u64,
                timestamp_us: 0,
                faces: fs.iter().map(|f| proto_face(f, a)).collect(),
                model: String::new(),
                smoothing: None,
            };
            Bytes::from(frame.encode_to_vec())
        })
        .collect();
    let (tx, rx) = tokio::sync::mpsc::channel::<Bytes>(a.window.max(1));
    client.ready().await.expect("the server is ready");
    let mut out = client
        .streaming(
            tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx)),
            tonic::codegen::http::uri::PathAndQuery::from_static(
                "/facepose.v1.PoseService/EstimateStream",
            ),
            LightCodec,
        )
        .await
        .expect("stream")
        .into_inner();
    let mut sent: VecDeque<Instant> = VecDeque::new();
    let mut lat = Vec::new();
    let mut poses = 0u64;
    let mut k = 0usize;
    loop {
        while sent.len() < a.window && Instant::now() < until {
            let f = pool[k % pool.len()].clone();
            k += 1;
            sent.push_back(Instant::now());
            if tx.send(f).await.is_err() {
                break;
            }
        }
        if sent.is_empty() {
            break;
        }
        match out.next().await {
            Some(Ok(r)) => {
                let t0 = sent.pop_front().expect("a frame in flight");
                lat.push(t0.elapsed());
                poses += r.faces.iter().filter(|f| f.pose.is_some()).count() as u64;
            }
            Some(Err(e)) => panic!("stream error: {e}"),
            None => break,
        }
    }
    (poses, lat)
}

async fn stream(a: Args) {
    let a = std::sync::Arc::new(a);
    // Warm up: connections, and the server's first requests.
    let warm = Instant::now() + Duration::from_millis(500);
    one_stream(&a, 99, warm).await;
    let start = Instant::now();
    let until = start + a.duration;
    let tasks: Vec<_> = (0..a.streams)
        .map(|s| {
            let a = a.clone();
            tokio::spawn(async move { one_stream(&a, s as u64, until).await })
        })
        .collect();
    let mut poses = 0;
    let mut lat = Vec::new();
    for t in tasks {
        let (p, l) = t.await.expect("stream task");
        poses += p;
        lat.extend(l);
    }
    let secs = start.elapsed().as_secs_f64();
    lat.sort();
    let pct = |q: f64| {
        lat.get(((lat.len() as f64 * q) as usize).min(lat.len().saturating_sub(1)))
            .map_or(0.0, |d| d.as_secs_f64() * 1e3)
    };
    println!(
        "{}streams {} faces/frame {} window {} scheme {} method {} encoding {}: {:.0} poses/s, {:.0} frames/s, frame latency p50 {:.3} ms p99 {:.3} ms",
        if a.ws { "WebSocket " } else { "" },
        a.streams,
        a.faces,
        a.window,
        a.scheme,
        a.method,
        if a.ws {
            "json"
        } else if a.packed {
            "xy"
        } else {
            "landmarks"
        },
        poses as f64 / secs,
        lat.len() as f64 / secs,
        pct(0.5),
        pct(0.99)
    );
}

fn main() {
    let a = parse_args();
    match a.cmd.as_str() {
        "bodies" => bodies(&a),
        "ceiling" => ceiling(&a),
        "stream" => tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime")
            .block_on(stream(a)),
        _ => eprintln!(
            "usage: loadgen stream [--addr URL] [--streams S] [--faces F] [--window W] [--duration SECS] [--scheme S] [--method M|default] [--faces-from dev|synthetic] [--packed | --ws]\n       loadgen bodies DIR [--batch N] [--scheme S] [--method M|default] [--faces-from dev|synthetic]\n       loadgen ceiling BODY [--threads T] [--duration SECS]"
        ),
    }
}
