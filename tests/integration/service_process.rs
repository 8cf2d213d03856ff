//! `facepose serve` as a process, for what only a process shows: start-up errors and their
//! exit status, SIGTERM's drain (with streams open, with retraining jobs accepted), a drain cut
//! short (exit 3), kill -9 while versions are written, the memory a hostile request costs. Everything else about the service is
//! tested in-process (crates/service/tests).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use facepose_core::model::bundle::Bundle;
use facepose_files::store::{MODEL_FILE, load_model, write_bundle_dir};
use facepose_service::proto;
use facepose_testkit::faces::*;
use facepose_testkit::process::Process;
use facepose_testkit::registry::*;
use facepose_testkit::{Endpoint, open_stream};
use rand::{Rng, SeedableRng, rngs::StdRng};
use reqwest::StatusCode;
use serde_json::{Value, json};
use tokio_stream::StreamExt;
use tonic::Code;

const BIN: &str = env!("CARGO_BIN_EXE_facepose");

/// A server on `dir` with the admin token in the environment and a short poll period.
fn admin_server(dir: &TempDir, poll: &str) -> Process {
    Process::start_with(
        BIN,
        &["--models", dir.arg(), "--registry-poll", poll],
        None,
        &[("FACEPOSE_ADMIN_TOKEN", ADMIN_TOKEN)],
    )
}

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
    let server = Process::start(BIN, &["--models", dir.to_str().unwrap()]);
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
async fn sigterm_drains_with_streams_open() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};

    let mut server = Process::start(BIN, &["--drain-timeout", "5s"]);
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

    let mut server = Process::start(BIN, &["--drain-timeout", "1s", "--request-timeout", "30s"]);
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

/// (c) kill -9 at random moments while versions are written and activated, 22 times: every
/// restart serves the active version, and the pointer never names a partial version. The
/// moments spread over 1.5 times what a job takes on the machine (measured first).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_during_writes_never_leaves_a_partial_version_active() {
    let dir = TempDir::new("crash");
    let c = client();
    let mut rng = StdRng::seed_from_u64(20111);
    let shapes = population(24, |p| p);
    let body = json!({"shapes": shapes_json(&shapes), "options": quick_options()});
    // How long a job takes on this machine, upload to written version, in a folder of its own:
    // the kills come at up to 1.5 times that after the start, so that some rounds write
    // versions however fast the machine is.
    let job_time = {
        let calibration = TempDir::new("crash-calibration");
        let server = admin_server(&calibration, "100ms");
        let t = Instant::now();
        let (s, job) = json_of(upload(&c, &server, &body).await).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{job}");
        let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
        assert_eq!(job["state"], "succeeded", "{job}");
        t.elapsed()
    };
    let max_delay = (job_time.as_millis() as u64 * 3 / 2).max(350);
    let (mut active, mut versions) = ("1".to_string(), Vec::new());
    // At least 22 rounds, and more (up to 60) until three versions have been written: whether
    // a round writes one depends on the machine's speed in that round, not only on the delay.
    for round in 0..60 {
        if round >= 22 && versions.len() >= 3 {
            break;
        }
        let mut server = admin_server(&dir, "100ms");
        // It started, so the active version loaded; it is the one the folder names.
        assert_eq!(served_version(&c, &server).await, active, "round {round}");
        // A retraining job, and activations back and forth among the versions there are.
        let upload = {
            let (c, url, body) = (c.clone(), server.url("/v1/models"), body.clone());
            tokio::spawn(async move {
                let _ = c
                    .post(url)
                    .bearer_auth(ADMIN_TOKEN)
                    .json(&body)
                    .send()
                    .await;
            })
        };
        let flips = {
            let (c, base) = (c.clone(), server.base.clone());
            let mut choices = versions.clone();
            choices.push("1".into());
            let seed = rng.random::<u64>();
            tokio::spawn(async move {
                let mut rng = StdRng::seed_from_u64(seed);
                loop {
                    let v = &choices[rng.random_range(0..choices.len())];
                    let url = format!("{base}/v1/models/default/versions/{v}:activate");
                    if c.post(url).bearer_auth(ADMIN_TOKEN).send().await.is_err() {
                        break;
                    }
                }
            })
        };
        let delay = rng.random_range(0..max_delay);
        tokio::time::sleep(Duration::from_millis(delay)).await;
        server.kill9();
        let _ = upload.await;
        let _ = flips.await;
        (active, versions) = check_folder(dir.path(), &versions);
    }
    assert!(
        versions.len() >= 3,
        "only {versions:?} were written in 60 rounds (a job takes {job_time:?} here, kills \
         within {max_delay} ms): the rounds were too short to test much"
    );
    let server = admin_server(&dir, "100ms");
    assert_eq!(served_version(&c, &server).await, active);
    let (s, v) = json_of(
        c.post(server.url("/v1/pose"))
            .json(&json!({"landmarks": face68(10.0, 0.0, 0.0)}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        (s, v["model_version"].as_str()),
        (StatusCode::OK, Some(active.as_str())),
        "{v}"
    );
    assert!(!versions.is_empty());
}

/// SIGTERM with retraining jobs accepted (one training, one queued behind it): the drain waits
/// for both, so the uploads the server said 202 to are not lost; their versions are in the
/// folder when the process exits 0.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_waits_for_the_accepted_retraining_jobs() {
    let dir = TempDir::new("drain-jobs");
    let mut server = Process::start_with(
        BIN,
        &[
            "--models",
            dir.arg(),
            "--registry-poll",
            "1s",
            "--drain-timeout",
            "30s",
        ],
        None,
        &[("FACEPOSE_ADMIN_TOKEN", ADMIN_TOKEN)],
    );
    let c = client();
    let body = json!({"shapes": shapes_json(&population(120, |p| p)),
        "options": quick_options(), "activate": false});
    for _ in 0..2 {
        let (s, job) = post_admin(&c, &server, "/v1/models", &body).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{job}");
    }
    drop(c);
    server.terminate();
    let status = server
        .wait_exit(Duration::from_secs(30))
        .await
        .unwrap_or_else(|| panic!("not exited; logs:\n{}", server.logs()));
    assert!(status.success(), "{status:?}\n{}", server.logs());
    for version in ["2", "3"] {
        let file = dir
            .path()
            .join("default/versions")
            .join(version)
            .join(MODEL_FILE);
        assert!(
            load_model(&file).is_ok(),
            "version {version} missing; logs:\n{}",
            server.logs()
        );
    }
}

/// The high-water mark of a process's resident memory (VmHWM), bytes.
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM in /proc/PID/status");
    kib * 1024
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_8_mib_grpc_message_of_empty_faces_costs_little_memory_and_time() {
    use facepose_testkit::raw_grpc;
    // 4,194,272 empty faces in 8 MiB, under the default --max-body: decoded whole, they took
    // 950 MB and 3.9 s before the batch limit was checked.
    let p = Process::start(BIN, &[]);
    let channel = p.channel().await;
    let mut c = p.grpc().await;
    let ok = c
        .estimate(proto::EstimateRequest {
            face: Some(proto_face(&face68(10.0, 0.0, 0.0), "", "", "")),
            model: String::new(),
        })
        .await;
    assert!(ok.is_ok(), "{ok:?}");
    let before = peak_rss(p.pid());
    let started = Instant::now();
    // Four calls and four streams at once: tonic held each message whole (32 MiB at once)
    // before the codec's walk; now each call ends at its 1001st face.
    let mut calls = Vec::new();
    for _ in 0..4 {
        let unary = channel.clone();
        calls.push(tokio::spawn(async move {
            raw_grpc::unary(unary, "EstimateBatch", [0x0a, 0x00].repeat(4_194_272))
                .await
                .unwrap_err()
        }));
        let stream = channel.clone();
        calls.push(tokio::spawn(async move {
            let frame = [0x1a, 0x00].repeat(4_194_272);
            raw_grpc::first_answer(stream, "EstimateStream", vec![frame])
                .await
                .unwrap_err()
        }));
    }
    for call in calls {
        let s = call.await.unwrap();
        assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
        assert!(s.message().contains("at least 1001 faces"), "{s:?}");
    }
    let elapsed = started.elapsed();
    let grown = peak_rss(p.pid()).saturating_sub(before);
    assert!(
        grown < 16 << 20,
        "eight 8 MiB messages, at once, raised the peak RSS by {} MiB",
        grown >> 20
    );
    assert!(elapsed < Duration::from_secs(3), "{elapsed:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_8_mb_json_body_of_empty_faces_or_null_landmarks_costs_little_memory() {
    // Parsed whole before the limits applied, 480,000 empty faces took 165 MB and 1.6 million
    // null landmarks 70 MB; then held whole before they were checked, 8 MB each at once. Now
    // each is refused at the byte that crosses its limit, four at a time.
    let p = Process::start(BIN, &[]);
    let c = client();
    let faces = format!(
        "{{\"faces\": [{}]}}",
        vec!["{\"landmarks\":[]}"; 480_000].join(",")
    );
    let nulls = format!("{{\"landmarks\": [{}]}}", vec!["null"; 1_600_000].join(","));
    // The same faces with a key spelled with an escape (which the one-pass reader leaves to
    // serde), and a 7 MB scheme name.
    let escaped = faces.replacen("\"landmarks\"", "\"l\\u0061ndmarks\"", 1);
    let long = format!(
        "{{\"landmarks\": [], \"scheme\": \"{}\"}}",
        "s".repeat(7 << 20)
    );
    let r = c
        .post(p.url("/v1/pose"))
        .json(&json!({"landmarks": face68(5.0, 0.0, 0.0)}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    let before = peak_rss(p.pid());
    let cases = [
        (
            "/v1/pose:batch",
            &faces,
            StatusCode::PAYLOAD_TOO_LARGE,
            "at least 1001 faces",
        ),
        (
            "/v1/pose:batch",
            &escaped,
            StatusCode::PAYLOAD_TOO_LARGE,
            "at least 1001 faces",
        ),
        (
            "/v1/pose",
            &nulls,
            StatusCode::UNPROCESSABLE_ENTITY,
            "more than 1000 landmarks",
        ),
        (
            "/v1/pose",
            &long,
            StatusCode::UNPROCESSABLE_ENTITY,
            "more than 64 KiB",
        ),
    ];
    for (path, body, expected, words) in cases {
        let calls = (0..4).map(|_| {
            let c = c.clone();
            let (url, body) = (p.url(path), body.clone());
            async move {
                let r = c
                    .post(url)
                    .header("content-type", "application/json")
                    .body(body)
                    .send()
                    .await
                    .unwrap();
                (r.status(), r.text().await.unwrap())
            }
        });
        let calls: Vec<_> = calls.map(tokio::spawn).collect();
        for call in calls {
            let (status, text) = call.await.unwrap();
            assert_eq!(status, expected, "{path}, {} bytes: {text}", body.len());
            assert!(text.contains(words), "{path}, {} bytes: {text}", body.len());
        }
    }
    let grown = peak_rss(p.pid()).saturating_sub(before);
    assert!(
        grown < 16 << 20,
        "16 bodies of 8 MB, four at a time, raised the peak RSS by {} MiB",
        grown >> 20
    );
}
