//! The model registry of `facepose serve`, black box: the real binary on loopback ports, with a
//! models folder in a temporary directory. Retraining through HTTP changes the served model;
//! activations under load fail no request; kill -9 at random moments never leaves a partial
//! version active; malformed uploads get 4xx with messages; the auth matrix; two replicas
//! sharing one folder converge. Expectations are independent of the server: poses the faces
//! were projected at, the deformation applied to the uploaded shapes, and the folder as read
//! by the library.

use std::time::{Duration, Instant};

use facepose_core::geometry::geodesic_deg;
use facepose_files::store::{MODEL_FILE, load_model};
use facepose_testkit::faces::*;
use facepose_testkit::raw::*;
use facepose_testkit::registry::*;
use facepose_testkit::server::Server;
use facepose_testkit::{Endpoint, open_stream};
use nalgebra::Vector3;
use reqwest::StatusCode;
use serde_json::{Value, json};
use tokio_stream::StreamExt;
use tonic::Code;

/// A server on `dir` with the admin token in the environment and a short poll period.
fn admin_server(dir: &TempDir, poll: &str) -> Server {
    Server::start_admin(
        &["--models", dir.arg(), "--registry-poll", poll],
        ADMIN_TOKEN,
    )
}

/// (a) An upload of deeper faces (the population with z stretched 1.5 times) becomes the
/// served model: its mean is 1.5 times as deep as the old one, faces projected from it come back
/// at their poses, and the old model, rolled back to, gets those faces wrong.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retraining_changes_the_served_model() {
    let dir = TempDir::new("retrain");
    let server = admin_server(&dir, "1s");
    let c = client();
    let old = load_model_default();
    let old_checksum = {
        let (_, v) = get(&c, &server, "/v1/models/default").await;
        assert_eq!(v["version"], "1");
        v["checksum"].as_str().unwrap().to_string()
    };
    let shapes = population(120, |p| Vector3::new(p.x, p.y, 1.5 * p.z));
    let body = json!({"shapes": shapes_json(&shapes), "options": quick_options(),
        "notes": "deeper faces"});
    let r = upload(&c, &server, &body).await;
    assert_eq!(r.status(), StatusCode::ACCEPTED);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let (_, job) = json_of(r).await;
    assert_eq!(
        location,
        format!("/v1/models/jobs/{}", job["id"].as_str().unwrap())
    );
    assert!(
        job["state"] == "queued" || job["state"] == "running",
        "{job}"
    );
    assert_eq!(job["validation"]["kept"], 120, "{job}");
    let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["version"], "2");
    assert_eq!(job["progress"], 1.0);

    // The folder holds the new version, active; it is what the server serves.
    let file = dir.path().join("default/versions/2").join(MODEL_FILE);
    let (bundle, new) = load_model(&file).unwrap();
    assert_eq!(
        std::fs::read_to_string(dir.path().join("default/ACTIVE")).unwrap(),
        "2\n"
    );
    let (_, v) = get(&c, &server, "/v1/models/default").await;
    assert_eq!(v["version"], "2");
    assert_eq!(v["checksum"], bundle.checksum);
    assert_ne!(v["checksum"], old_checksum);
    assert!(
        v["provenance"]["notes"]
            .as_str()
            .unwrap()
            .starts_with("deeper faces")
    );
    // Its mean is the deformed population's: 1.5 times as deep as the old mean (the old one is
    // the mean of 1249 faces of the same model, so a few percent apart).
    let ratio = nose_depth(&new.mean) / nose_depth(&old.mean);
    assert!((ratio - 1.5).abs() < 0.08, "depth ratio {ratio}");

    // Faces projected from the new mean come back at their poses; with the old model (rolled
    // back to) they do not.
    let poses = [(30.0, 0.0, 0.0), (-40.0, 10.0, 5.0), (20.0, -15.0, -8.0)];
    let errors = |v: &Value| -> Vec<f64> {
        poses
            .iter()
            .zip(v["results"].as_array().unwrap())
            .map(|(&(y, p, r), res)| {
                geodesic_deg(&rotation_json(&res["rotation"]), &rotation(y, p, r))
            })
            .collect()
    };
    let batch = json!({"method": "fit", "faces": poses.iter()
        .map(|&(y, p, r)| json!({"landmarks": project(&new.mean, y, p, r)}))
        .collect::<Vec<_>>()});
    let (s, v) = json_of(
        c.post(server.url("/v1/pose:batch"))
            .json(&batch)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v["model_version"], "2");
    let new_err = errors(&v);
    assert!(new_err.iter().all(|e| *e < 0.5), "new model: {new_err:?}");
    // It carries the default model's calibration: its answers keep their uncertainty.
    assert_eq!(new.calibration, old.calibration);
    assert!(old.calibration.is_some());
    for res in v["results"].as_array().unwrap() {
        assert!(
            res["uncertainty"]["yaw"]["sd"].as_f64().unwrap() > 0.0,
            "{res}"
        );
    }
    let (s, _) = activate(&c, &server, "1").await;
    assert_eq!(s, StatusCode::OK);
    let (_, v) = json_of(
        c.post(server.url("/v1/pose:batch"))
            .json(&batch)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(v["model_version"], "1");
    let old_err = errors(&v);
    assert!(
        old_err.iter().all(|e| *e > 5.0),
        "the old model should be off on deeper faces: {old_err:?}"
    );
    // Rolled forward again.
    let (s, v) = activate(&c, &server, "2").await;
    assert_eq!((s, v["version"].as_str()), (StatusCode::OK, Some("2")));
}

/// Versions written and never activated were never collected: a job leaves the newest
/// `--keep-inactive-versions` inactive ones besides the active one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_prunes_old_inactive_versions() {
    let dir = TempDir::new("prune");
    for v in ["2", "3", "4"] {
        place_default_copy(dir.path(), v);
    }
    let server = Server::start_admin(
        &["--models", dir.arg(), "--keep-inactive-versions", "1"],
        ADMIN_TOKEN,
    );
    let c = client();
    let body = json!({"shapes": shapes_json(&population(40, |p| p)), "options": quick_options()});
    let r = upload(&c, &server, &body).await;
    assert_eq!(r.status(), StatusCode::ACCEPTED);
    let (_, job) = json_of(r).await;
    let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
    assert_eq!(
        (job["state"].as_str(), job["version"].as_str()),
        (Some("succeeded"), Some("5")),
        "{job}"
    );
    // Active 5; of the inactive 4, 3, 2 on disk the newest stays.
    let (_, v) = get(&c, &server, "/v1/models/default/versions").await;
    let ids: Vec<&str> = v["versions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["version"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["1", "4", "5"], "{v}");
    for gone in ["2", "3"] {
        assert!(!dir.path().join("default/versions").join(gone).exists());
    }
    assert!(server.logs().contains("inactive versions pruned"));
}

fn load_model_default() -> facepose_core::model::PoseModel {
    facepose_core::model::default_model().unwrap().1
}

/// (b) Several activations, then a retrain, while HTTP clients and a gRPC stream estimate
/// without pause: no request fails, and every version answers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn swaps_under_load_fail_no_request() {
    let dir = TempDir::new("load");
    place_default_copy(dir.path(), "2");
    let server = admin_server(&dir, "1s");
    let c = client();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let face = face68(25.0, -10.0, 5.0);
    let mut http = Vec::new();
    for _ in 0..3 {
        let (c, url, stop, face) = (
            c.clone(),
            server.url("/v1/pose"),
            stop.clone(),
            face.clone(),
        );
        http.push(tokio::spawn(async move {
            let mut versions = std::collections::BTreeMap::<String, usize>::new();
            let mut failures = Vec::new();
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let r = c
                    .post(&url)
                    .json(&json!({"landmarks": face, "method": "fit"}))
                    .send()
                    .await;
                match r {
                    Ok(r) if r.status() == StatusCode::OK => {
                        let v: Value = r.json().await.unwrap();
                        let err = geodesic_deg(
                            &rotation_json(&v["rotation"]),
                            &rotation(25.0, -10.0, 5.0),
                        );
                        // The retrained version (3) has another mean than the face's.
                        let tolerance = if v["model_version"] == "3" { 5.0 } else { 0.5 };
                        if err > tolerance {
                            failures.push(format!("pose off by {err}°"));
                        }
                        *versions
                            .entry(v["model_version"].as_str().unwrap().to_string())
                            .or_default() += 1;
                    }
                    Ok(r) => failures.push(format!("{} {}", r.status(), r.text().await.unwrap())),
                    Err(e) => failures.push(e.to_string()),
                }
            }
            (versions, failures)
        }));
    }
    // A stream, one frame after another.
    let mut grpc = server.grpc().await;
    let (tx, mut results) = open_stream(&mut grpc, 4).await;
    let stream_stop = stop.clone();
    let stream = tokio::spawn(async move {
        let mut frames = 0u64;
        let mut versions = std::collections::BTreeSet::new();
        while !stream_stop.load(std::sync::atomic::Ordering::Relaxed) {
            let frame = facepose_service::proto::Frame {
                frame_id: frames,
                faces: vec![proto_face(&face68(-30.0, 5.0, 0.0), "", "fit", "t")],
                ..Default::default()
            };
            tx.send(frame).await.unwrap();
            let r = results
                .next()
                .await
                .expect("a result per frame")
                .expect("no stream error");
            assert_eq!(r.frame_id, frames);
            let f = &r.faces[0];
            match &f.result {
                Some(facepose_service::proto::face_result::Result::Pose(p)) => {
                    let err = geodesic_deg(&rotation_flat(&p.rotation), &rotation(-30.0, 5.0, 0.0));
                    let tolerance = if r.model_version == "3" { 5.0 } else { 0.5 };
                    assert!(err < tolerance, "stream pose off by {err}°");
                }
                other => panic!("frame {frames}: {other:?}"),
            }
            versions.insert(r.model_version.clone());
            frames += 1;
        }
        drop(tx);
        assert!(results.next().await.is_none(), "the stream ends cleanly");
        (frames, versions)
    });
    // Eight swaps, each once requests have been answered on the version before.
    for k in 0..8 {
        let version = if k % 2 == 0 { "2" } else { "1" };
        let (s, v) = activate(&c, &server, version).await;
        assert_eq!(s, StatusCode::OK, "{v}");
        assert_eq!(v["version"], version);
        tokio::time::sleep(Duration::from_millis(60)).await;
    }
    // A retrain under the same load: trained beside it and swapped in as version 3.
    let shapes = population(40, |p| p);
    let (s, job) = post_admin(
        &c,
        &server,
        "/v1/models",
        &json!({"shapes": shapes_json(&shapes), "options": quick_options()}),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{job}");
    let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
    assert_eq!(
        (&job["state"], &job["version"]),
        (&json!("succeeded"), &json!("3")),
        "{job}"
    );
    assert_eq!(served_version(&c, &server).await, "3");
    tokio::time::sleep(Duration::from_millis(100)).await;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let mut seen = std::collections::BTreeMap::<String, usize>::new();
    let mut answered = 0;
    for h in http {
        let (versions, failures) = h.await.unwrap();
        assert!(failures.is_empty(), "{failures:?}");
        for (v, n) in versions {
            answered += n;
            *seen.entry(v).or_default() += n;
        }
    }
    let (frames, stream_versions) = stream.await.unwrap();
    assert!(
        answered > 50 && frames > 20,
        "{answered} requests, {frames} frames"
    );
    assert_eq!(seen.keys().collect::<Vec<_>>(), ["1", "2", "3"], "{seen:?}");
    assert!(stream_versions.len() >= 2, "{stream_versions:?}");
    let metrics = metrics_text(&c, &server).await;
    assert!(
        metrics.contains("facepose_model_swaps_total{name=\"default\"} 9"),
        "{}",
        metrics
            .lines()
            .filter(|l| l.contains("swaps"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// An HTTP/1.1 exchange written by hand: `head` (request line and headers, without the blank
/// line), then the body, written by another thread while this one reads the answer, so that an
/// answer sent before the whole body is read all the same. (status, body).
fn raw_exchange(
    server: &Server,
    head: String,
    body: impl FnOnce(&mut std::net::TcpStream) + Send + 'static,
) -> (u16, String) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(server.addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    write!(s, "{head}\r\nHost: x\r\nConnection: close\r\n\r\n").unwrap();
    let mut w = s.try_clone().unwrap();
    let writer = std::thread::spawn(move || body(&mut w));
    let mut text = Vec::new();
    let _ = s.read_to_end(&mut text);
    let _ = writer.join();
    parse_answer(&String::from_utf8_lossy(&text))
}

/// (d) Malformed or unusable uploads get 4xx answers that say what to fix; usable uploads with
/// a few bad shapes are accepted with the bad shapes listed; the server stays healthy.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_uploads_get_4xx_with_reasons() {
    let dir = TempDir::new("malformed");
    let server = admin_server(&dir, "1s");
    let c = client();
    let good = population(12, |p| p);
    let post_text = |text: String, ct: &'static str| {
        c.post(server.url("/v1/models"))
            .bearer_auth(ADMIN_TOKEN)
            .header("content-type", ct)
            .body(text)
            .send()
    };
    let (s, v) = json_of(
        post_text("{\"shapes\": [[[1, 2, 3]".into(), "application/json")
            .await
            .unwrap(),
    )
    .await;
    assert_error(
        s,
        &v,
        StatusCode::BAD_REQUEST,
        "malformed_json",
        "malformed JSON",
    );
    // A point of too many numbers is as unusable as one of too few: 422 both (it was a 400
    // "trailing characters" for one more).
    for (body, want) in [
        (
            "{\"shapes\": [[[1, 2, 3, 4]]]}",
            "invalid length 4, expected a point of 3 numbers",
        ),
        (
            "{\"shapes\": [[[1, 2]]]}",
            "invalid length 2, expected a point of 3 numbers",
        ),
        (
            "{\"subjects\": [{\"views\": [[[1, 2, 3]]]}]}",
            "invalid length 3, expected a point of 2 numbers",
        ),
    ] {
        let (s, v) = json_of(post_text(body.into(), "application/json").await.unwrap()).await;
        assert_error(
            s,
            &v,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_argument",
            want,
        );
    }
    let (s, v) = json_of(post_text("{}".into(), "text/plain").await.unwrap()).await;
    assert_error(
        s,
        &v,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_media_type",
        "application/json",
    );
    // NaN as Python's json.dumps writes it: the message names the coordinate.
    let mut marked = good.clone();
    marked[1][5].z = 123456.75;
    let text = json!({"shapes": shapes_json(&marked)})
        .to_string()
        .replace("123456.75", "NaN");
    let (s, v) = json_of(post_text(text, "application/json").await.unwrap()).await;
    assert_error(
        s,
        &v,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid_argument",
        "NaN and Infinity are not JSON numbers",
    );
    assert!(
        v["error"]["message"]
            .as_str()
            .unwrap()
            .contains("shapes[1][5][2]"),
        "{v}"
    );

    let cases: Vec<(Value, &str)> = vec![
        (json!({"shape": []}), "unknown field `shape`"),
        (
            json!({"options": quick_options()}),
            "no shapes: give \"shapes\"",
        ),
        (
            json!({"shapes": shapes_json(&good[..3])}),
            "3 shapes; at least 10 are needed (options.min_shapes)",
        ),
        (
            json!({"shapes": shapes_json(&good.iter().map(|s| s[..67].to_vec()).collect::<Vec<_>>())}),
            "only 0 of 12 shapes are usable; at least 10 are needed (options.min_shapes): shape 0: point_count: 67 points; scheme ibug68 has 68",
        ),
        (
            json!({"shapes": shapes_json(&good.iter().map(|s| s.iter().map(|p| Vector3::new(-p.x, p.y, p.z)).collect()).collect::<Vec<_>>())}),
            "shape 0: mirrored: the nose tip is",
        ),
        (
            json!({"shapes": shapes_json(&good), "subjects": []}),
            "not both",
        ),
        (
            json!({"shapes": shapes_json(&good), "scheme": "mediapipe468"}),
            "scheme \"mediapipe468\" is not built in",
        ),
        (
            json!({"shapes": shapes_json(&good), "model": "../etc"}),
            "invalid model name \"../etc\"",
        ),
        (
            json!({"shapes": shapes_json(&good), "options": {"grid": "fine"}}),
            "options.grid \"fine\"",
        ),
        (
            json!({"shapes": shapes_json(&good), "options": {"epsilons": [-1]}}),
            "options.epsilons: -1",
        ),
        (
            json!({"subjects": [{"views": views_of(&good[0])}], "options": {"min_shapes": 3}}),
            "1 subjects; at least 3",
        ),
        (
            json!({"subjects": (0..3).map(|k| json!({"views": views_of(&good[k]).as_array().unwrap()[..2]})).collect::<Vec<_>>(), "options": {"min_shapes": 3}}),
            "subject 0: reconstruction: 2 views; structure from motion needs at least 3",
        ),
    ];
    for (body, want) in cases {
        let (s, v) = post_admin(&c, &server, "/v1/models", &body).await;
        assert_error(
            s,
            &v,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid_argument",
            want,
        );
    }
    // Too few usable shapes: the report lists each one.
    let mirrored: Vec<_> = good
        .iter()
        .map(|s| s.iter().map(|p| Vector3::new(-p.x, p.y, p.z)).collect())
        .collect();
    let (_, v) = post_admin(
        &c,
        &server,
        "/v1/models",
        &json!({"shapes": shapes_json(&mirrored)}),
    )
    .await;
    let dropped = v["error"]["details"]["validation"]["dropped"]
        .as_array()
        .unwrap();
    assert_eq!(dropped.len(), 12);
    assert!(dropped.iter().all(|d| d["reason"] == "mirrored"), "{v}");

    // Over the 64 MiB upload limit: declared, and streamed without a length.
    let (s, body) = raw_exchange(
        &server,
        format!(
            "POST /v1/models HTTP/1.1\r\nAuthorization: Bearer {ADMIN_TOKEN}\r\nContent-Type: application/json\r\nContent-Length: {}",
            (64 << 20) + 1
        ),
        |_| {},
    );
    assert_eq!(s, 413, "{body}");
    assert!(
        body.contains("over the limit of 67108864 bytes (--max-upload)"),
        "{body}"
    );
    let (s, body) = raw_exchange(
        &server,
        format!(
            "POST /v1/models HTTP/1.1\r\nAuthorization: Bearer {ADMIN_TOKEN}\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked"
        ),
        |w| {
            use std::io::Write;
            let chunk = vec![b' '; 1 << 20];
            let _ = w.write_all(b"1\r\n{\r\n");
            for _ in 0..66 {
                if write!(w, "{:x}\r\n", chunk.len()).is_err()
                    || w.write_all(&chunk).is_err()
                    || w.write_all(b"\r\n").is_err()
                {
                    return;
                }
            }
            let _ = w.write_all(b"1\r\n}\r\n0\r\n\r\n");
        },
    );
    assert_eq!(s, 413, "{body}");
    assert!(body.contains("--max-upload"), "{body}");

    // A few bad shapes among good ones: accepted, each bad one listed with its reason.
    let mut shapes = good.clone();
    shapes[3] = mirrored[3].clone();
    for i in (0..17).chain(48..68) {
        shapes[7][i].y -= 30.0;
    }
    shapes.extend(population(14, |p| p).into_iter().skip(12));
    let (s, job) = post_admin(
        &c,
        &server,
        "/v1/models",
        &json!({"shapes": shapes_json(&shapes), "options": quick_options(), "activate": false}),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{job}");
    let report = &job["validation"];
    assert_eq!(
        (report["total"].as_u64(), report["kept"].as_u64()),
        (Some(14), Some(12)),
        "{report}"
    );
    let reasons: Vec<(u64, &str)> = report["dropped"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| (d["index"].as_u64().unwrap(), d["reason"].as_str().unwrap()))
        .collect();
    assert_eq!(reasons, [(3, "mirrored"), (7, "outlier")]);
    let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
    assert_eq!(
        (job["state"].as_str(), job["version"].as_str()),
        (Some("succeeded"), Some("2")),
        "{job}"
    );
    // Not activated: version 1 still serves.
    assert_eq!(served_version(&c, &server).await, "1");

    // Multi-view subjects, rebuilt by structure from motion; one with too few views is dropped.
    let mut subjects: Vec<Value> = population(11, |p| p)
        .iter()
        .map(|s| json!({"views": views_of(s)}))
        .collect();
    subjects.insert(
        4,
        json!({"id": "short", "views": views_of(&good[4]).as_array().unwrap()[..2]}),
    );
    let (s, job) = post_admin(
        &c,
        &server,
        "/v1/models",
        &json!({"subjects": subjects, "options": quick_options(), "activate": false}),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{job}");
    let job = wait_job(&c, &server, job["id"].as_str().unwrap()).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["kind"], "subjects");
    assert_eq!(job["validation"]["kept"], 11, "{job}");
    assert_eq!(job["validation"]["dropped"][0]["index"], 4, "{job}");
    assert_eq!(
        job["validation"]["dropped"][0]["reason"], "reconstruction",
        "{job}"
    );

    // gRPC: chunks, with a shape whose coordinate is NaN (dropped, the rest trains).
    let mut grpc = server.grpc().await;
    let shape_msg = |s: &[Vector3<f64>]| facepose_service::proto::Shape3D {
        coords: s.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
    };
    let mut with_nan: Vec<_> = good.iter().map(|s| shape_msg(s)).collect();
    with_nan[2].coords[7] = f64::NAN;
    with_nan.push(shape_msg(&population(13, |p| p)[12]));
    use facepose_service::proto::{
        RetrainChunk, RetrainHeader, ShapeChunk, TrainingOptions, retrain_chunk::Part,
    };
    let header = RetrainChunk {
        part: Some(Part::Header(RetrainHeader {
            activate: Some(false),
            options: Some(TrainingOptions {
                grid: "paper".into(),
                components: Some(0),
                ..Default::default()
            }),
            ..Default::default()
        })),
    };
    let chunks = vec![
        header.clone(),
        RetrainChunk {
            part: Some(Part::Shapes(ShapeChunk {
                shapes: with_nan[..6].to_vec(),
            })),
        },
        RetrainChunk {
            part: Some(Part::Shapes(ShapeChunk {
                shapes: with_nan[6..].to_vec(),
            })),
        },
    ];
    let mut req = tonic::Request::new(tokio_stream::iter(chunks));
    req.metadata_mut().insert(
        "authorization",
        format!("Bearer {ADMIN_TOKEN}").parse().unwrap(),
    );
    let job = grpc.retrain(req).await.unwrap().into_inner();
    let v = job.validation.unwrap();
    assert_eq!((v.total, v.kept), (13, 12));
    assert_eq!(
        (v.dropped[0].index, v.dropped[0].reason.as_str()),
        (2, "non_finite")
    );
    assert!(
        v.dropped[0]
            .detail
            .contains("point 2 y is not a finite number"),
        "{:?}",
        v.dropped
    );
    let t = Instant::now();
    let job = loop {
        let j = grpc
            .get_job(facepose_service::proto::GetJobRequest { id: job.id.clone() })
            .await
            .unwrap()
            .into_inner();
        if j.state == "succeeded" || j.state == "failed" {
            break j;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "{j:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(
        (job.state.as_str(), job.version.as_str()),
        ("succeeded", "4"),
        "{job:?}"
    );
    let retrain_status = |chunks: Vec<RetrainChunk>| {
        let mut grpc = grpc.clone();
        async move {
            let mut req = tonic::Request::new(tokio_stream::iter(chunks));
            req.metadata_mut().insert(
                "authorization",
                format!("Bearer {ADMIN_TOKEN}").parse().unwrap(),
            );
            grpc.retrain(req).await.unwrap_err()
        }
    };
    let e = retrain_status(vec![RetrainChunk {
        part: Some(Part::Shapes(ShapeChunk {
            shapes: with_nan[..2].to_vec(),
        })),
    }])
    .await;
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(
        e.message()
            .contains("the first RetrainChunk must be the header"),
        "{e:?}"
    );
    let e = retrain_status(vec![
        header.clone(),
        RetrainChunk {
            part: Some(Part::Shapes(ShapeChunk {
                shapes: with_nan[..2].to_vec(),
            })),
        },
    ])
    .await;
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(
        e.message().contains("2 shapes; at least 10 are needed"),
        "{e:?}"
    );

    // Still healthy and serving.
    assert_eq!(get(&c, &server, "/readyz").await.0, StatusCode::OK);
    let (s, v) = json_of(
        c.post(server.url("/v1/pose"))
            .json(&json!({"landmarks": face68(15.0, 5.0, 0.0), "method": "fit"}))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(s, StatusCode::OK, "{v}");
    let (s, v) = get(&c, &server, "/v1/models/default/versions").await;
    assert_eq!(s, StatusCode::OK);
    let listed: Vec<&str> = v["versions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["version"].as_str().unwrap())
        .collect();
    assert_eq!(listed, ["1", "2", "3", "4"], "{v}");
    assert_eq!(v["active"], "1");
}

/// (e) Admin routes: disabled (403 / PERMISSION_DENIED) without a configured token; 401 /
/// UNAUTHENTICATED with a missing or wrong one; the right one works. Read-only routes never need
/// a token, and the token never shows in the logs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_auth_matrix() {
    let dir = TempDir::new("auth");
    place_default_copy(dir.path(), "2");
    let token_file = dir.path().join("admin-token");
    std::fs::write(&token_file, format!("{ADMIN_TOKEN}\n")).unwrap();
    let off = Server::start(&["--models", dir.arg()]);
    let on = Server::start(&[
        "--models",
        dir.arg(),
        "--admin-token-file",
        token_file.to_str().unwrap(),
        // Everything the server can log, so that a token in any message shows.
        "--log",
        "debug",
    ]);
    let c = client();
    let upload = json!({"shapes": []});
    // (method, path) of every admin route.
    let admin: [(&str, String); 3] = [
        ("POST", "/v1/models".into()),
        ("POST", "/v1/models/default/versions/2:activate".into()),
        ("DELETE", "/v1/models/default/versions/9".into()),
    ];
    let send = |server: &Server, method: &str, path: &str, auth: Option<String>| {
        let mut r = c
            .request(method.parse().unwrap(), server.url(path))
            .json(&upload);
        if let Some(a) = auth {
            r = r.header("authorization", a);
        }
        r.send()
    };
    for (method, path) in &admin {
        for auth in [None, Some(format!("Bearer {ADMIN_TOKEN}"))] {
            let r = send(&off, method, path, auth).await.unwrap();
            let (s, v) = json_of(r).await;
            assert_error(
                s,
                &v,
                StatusCode::FORBIDDEN,
                "forbidden",
                "admin routes are disabled on this server",
            );
        }
        for (auth, message) in [
            (None, "missing admin token"),
            (
                Some(format!("Bearer {ADMIN_TOKEN}x")),
                "invalid admin token",
            ),
            (Some("Bearer wrong".to_string()), "invalid admin token"),
            (
                Some(format!("Basic {ADMIN_TOKEN}")),
                "must be \"Bearer <token>\"",
            ),
            (Some(ADMIN_TOKEN.to_string()), "must be \"Bearer <token>\""),
        ] {
            let r = send(&on, method, path, auth).await.unwrap();
            let challenge = r
                .headers()
                .get("www-authenticate")
                .map(|h| h.to_str().unwrap().to_string());
            let (s, v) = json_of(r).await;
            assert_error(s, &v, StatusCode::UNAUTHORIZED, "unauthenticated", message);
            assert!(
                challenge.is_some_and(|h| h.starts_with("Bearer")),
                "{method} {path}"
            );
        }
    }
    // A large upload without the token gets its 401 too (the server drains the body before
    // answering, as for an over-limit body, so a client that writes it all reads the answer).
    let big = format!("{{\"shapes\": []}}{}", " ".repeat(3 << 20));
    let r = c
        .post(on.url("/v1/models"))
        .header("content-type", "application/json")
        .body(big)
        .send()
        .await
        .expect("an answer, not a broken pipe");
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
    // The right token: the route's own answer.
    let r = send(
        &on,
        "POST",
        &admin[0].1,
        Some(format!("Bearer {ADMIN_TOKEN}")),
    )
    .await
    .unwrap();
    let (s, v) = json_of(r).await;
    assert_error(
        s,
        &v,
        StatusCode::UNPROCESSABLE_ENTITY,
        "invalid_argument",
        "0 shapes",
    );
    // The scheme in any case (RFC 9110 §11.1): the route's own answer again.
    for scheme in ["BEARER", "bEaReR"] {
        let r = send(
            &on,
            "POST",
            &admin[0].1,
            Some(format!("{scheme} {ADMIN_TOKEN}")),
        )
        .await
        .unwrap();
        let (s, v) = json_of(r).await;
        assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY, "{scheme}: {v}");
    }
    // Two Authorization headers: refused, whichever is right (not judged by the first).
    for pair in [
        [format!("Bearer {ADMIN_TOKEN}"), "Bearer wrong".to_string()],
        ["Bearer wrong".to_string(), format!("Bearer {ADMIN_TOKEN}")],
    ] {
        let r = c
            .post(on.url(&admin[0].1))
            .json(&upload)
            .header("authorization", &pair[0])
            .header("authorization", &pair[1])
            .send()
            .await
            .unwrap();
        let (s, v) = json_of(r).await;
        assert_error(
            s,
            &v,
            StatusCode::UNAUTHORIZED,
            "unauthenticated",
            "send one Authorization header",
        );
    }
    let (s, v) = activate(&c, &on, "2").await;
    assert_eq!(
        (s, v["version"].as_str()),
        (StatusCode::OK, Some("2")),
        "{v}"
    );
    let r = send(
        &on,
        "DELETE",
        &admin[2].1,
        Some(format!("Bearer {ADMIN_TOKEN}")),
    )
    .await
    .unwrap();
    let (s, v) = json_of(r).await;
    assert_error(
        s,
        &v,
        StatusCode::NOT_FOUND,
        "not_found",
        "model \"default\" has no version \"9\"; it has 1, 2",
    );
    let r = send(
        &on,
        "DELETE",
        "/v1/models/default/versions/2",
        Some(format!("Bearer {ADMIN_TOKEN}")),
    )
    .await
    .unwrap();
    let (s, v) = json_of(r).await;
    assert_error(
        s,
        &v,
        StatusCode::CONFLICT,
        "conflict",
        "is active; activate another version first",
    );

    // gRPC, the same matrix.
    use facepose_service::proto::{
        ActivateVersionRequest, DeleteVersionRequest, RetrainChunk, RetrainHeader,
        retrain_chunk::Part,
    };
    let call = |server: &Server, auth: Option<String>, which: usize| {
        let server_base = server.base.clone();
        async move {
            let ch = tonic::transport::Endpoint::from_shared(server_base)
                .unwrap()
                .connect()
                .await
                .unwrap();
            let mut g = facepose_service::proto::pose_service_client::PoseServiceClient::new(ch);
            let meta = |m: &mut tonic::metadata::MetadataMap| {
                if let Some(a) = &auth {
                    m.insert("authorization", a.parse().unwrap());
                }
            };
            match which {
                0 => {
                    let chunks = vec![RetrainChunk {
                        part: Some(Part::Header(RetrainHeader::default())),
                    }];
                    let mut req = tonic::Request::new(tokio_stream::iter(chunks));
                    meta(req.metadata_mut());
                    g.retrain(req).await.map(|_| ())
                }
                1 => {
                    let mut req = tonic::Request::new(ActivateVersionRequest {
                        name: "default".into(),
                        version: "1".into(),
                    });
                    meta(req.metadata_mut());
                    g.activate_version(req).await.map(|_| ())
                }
                _ => {
                    let mut req = tonic::Request::new(DeleteVersionRequest {
                        name: "default".into(),
                        version: "9".into(),
                    });
                    meta(req.metadata_mut());
                    g.delete_version(req).await.map(|_| ())
                }
            }
        }
    };
    for which in 0..3 {
        for auth in [None, Some(format!("Bearer {ADMIN_TOKEN}"))] {
            let e = call(&off, auth, which).await.unwrap_err();
            assert_eq!(e.code(), Code::PermissionDenied, "{which}: {e:?}");
        }
        for auth in [None, Some("Bearer nope".to_string())] {
            let e = call(&on, auth, which).await.unwrap_err();
            assert_eq!(e.code(), Code::Unauthenticated, "{which}: {e:?}");
        }
    }
    let right = Some(format!("Bearer {ADMIN_TOKEN}"));
    let e = call(&on, right.clone(), 0).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    assert!(e.message().contains("no shapes"), "{e:?}");
    call(&on, right.clone(), 1).await.unwrap();
    assert_eq!(
        call(&on, right, 2).await.unwrap_err().code(),
        Code::NotFound
    );

    // Read-only routes need no token on either server.
    for server in [&off, &on] {
        for path in [
            "/v1/models",
            "/v1/models/default",
            "/v1/models/default/versions",
            "/healthz",
            "/readyz",
            "/metrics",
            "/openapi.json",
        ] {
            let r = c.get(server.url(path)).send().await.unwrap();
            assert_eq!(r.status(), StatusCode::OK, "{path}");
        }
        let (s, _) = get(
            &c,
            server,
            "/v1/models/jobs/0123456789abcdef0123456789abcdef",
        )
        .await;
        assert_eq!(s, StatusCode::NOT_FOUND);
        let r = c
            .post(server.url("/v1/pose"))
            .json(&json!({"landmarks": face68(0.0, 0.0, 0.0)}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::OK);
        let mut g = server.grpc().await;
        g.list_versions(facepose_service::proto::ListVersionsRequest {
            name: "default".into(),
        })
        .await
        .unwrap();
        g.list_models(facepose_service::proto::ListModelsRequest {})
            .await
            .unwrap();
    }
    assert!(
        !on.logs().contains(ADMIN_TOKEN) && !on.logs().contains("test-admin-token"),
        "the token is logged"
    );
    assert!(
        on.logs().contains("admin=\"enabled\"") || on.logs().contains("admin=enabled"),
        "{}",
        on.logs()
    );
}

/// (f) Two replicas sharing one models folder: an activation through either is served by the
/// other within the poll period; a version that does not load leaves the previous one serving
/// and shows in /readyz and the metrics.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replicas_sharing_a_folder_converge() {
    let dir = TempDir::new("replicas");
    place_default_copy(dir.path(), "2");
    let poll = Duration::from_millis(200);
    let a = admin_server(&dir, "200ms");
    let b = admin_server(&dir, "200ms");
    let c = client();
    // Waits until `server` serves `version`; the time it took.
    let follows = |server: &Server, version: &'static str| {
        let (c, url) = (c.clone(), server.url("/v1/pose"));
        async move {
            let t = Instant::now();
            loop {
                let v: Value = c
                    .post(&url)
                    .json(&json!({"landmarks": face68(20.0, 0.0, 0.0)}))
                    .send()
                    .await
                    .unwrap()
                    .json()
                    .await
                    .unwrap();
                if v["model_version"] == version {
                    return t.elapsed();
                }
                assert!(t.elapsed() < Duration::from_secs(10), "still {v}");
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        }
    };
    for (here, there, version) in [(&a, &b, "2"), (&b, &a, "1"), (&a, &b, "2")] {
        let (s, v) = activate(&c, here, version).await;
        assert_eq!(s, StatusCode::OK, "{v}");
        let took = follows(there, version).await;
        // The poll period, plus loading the model (~0.1 s) and slack for a busy machine: "a
        // few seconds" (the hard bound of 10 s is in `follows`).
        assert!(
            took < poll + Duration::from_secs(4),
            "followed after {took:?}"
        );
        let (_, v) = get(&c, there, "/v1/models/default/versions").await;
        assert_eq!(v["active"], version);
    }
    // A version whose bundle is damaged, made active behind the servers' backs.
    let broken = dir.path().join("default/versions/3");
    std::fs::create_dir_all(&broken).unwrap();
    std::fs::write(
        broken.join(MODEL_FILE),
        "{\"format\": \"facepose-model\", \"truncated",
    )
    .unwrap();
    std::fs::write(dir.path().join("default/.ACTIVE.tmp"), "3\n").unwrap();
    std::fs::rename(
        dir.path().join("default/.ACTIVE.tmp"),
        dir.path().join("default/ACTIVE"),
    )
    .unwrap();
    for server in [&a, &b] {
        let t = Instant::now();
        let v = loop {
            let (s, v) = get(&c, server, "/readyz").await;
            assert_eq!(s, StatusCode::OK, "still ready: {v}");
            if v["problems"].is_array() {
                break v;
            }
            assert!(
                t.elapsed() < Duration::from_secs(5),
                "no problem reported: {v}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        };
        assert_eq!(v["problems"][0]["model"], "default", "{v}");
        assert_eq!(v["problems"][0]["version"], "3", "{v}");
        assert!(
            v["problems"][0]["message"]
                .as_str()
                .unwrap()
                .contains("versions/3/model.json"),
            "{v}"
        );
        assert_eq!(served_version(&c, server).await, "2");
        let metrics = metrics_text(&c, server).await;
        assert!(
            metrics.contains("facepose_model_sync_problems 1"),
            "{metrics}"
        );
        assert!(
            metrics.contains("facepose_model_load_failures_total{name=\"default\"} 1"),
            "{metrics}"
        );
    }
    // The API refuses to activate it; activating a good version clears the problem everywhere.
    let (s, v) = activate(&c, &a, "3").await;
    assert_error(
        s,
        &v,
        StatusCode::CONFLICT,
        "conflict",
        "version 3 of model \"default\" does not load, so it is not activated",
    );
    let (s, _) = activate(&c, &a, "1").await;
    assert_eq!(s, StatusCode::OK);
    follows(&b, "1").await;
    for server in [&a, &b] {
        let t = Instant::now();
        while get(&c, server, "/readyz").await.1["problems"].is_array() {
            assert!(t.elapsed() < Duration::from_secs(5));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

/// Cancelling: three jobs accepted, the third (queued behind two) cancelled over gRPC never
/// trains, the other two write their versions; then every refusal over HTTP: the same job
/// again, a finished one, an unknown id, no token, no action.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_queued_job_can_be_cancelled() {
    let dir = TempDir::new("cancel");
    let server = admin_server(&dir, "1s");
    let c = client();
    let body = json!({"shapes": shapes_json(&population(120, |p| p)), "activate": false});
    let mut ids = Vec::new();
    for _ in 0..3 {
        let (s, job) = post_admin(&c, &server, "/v1/models", &body).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{job}");
        ids.push(job["id"].as_str().unwrap().to_string());
    }
    let mut grpc = server.grpc().await;
    let cancel = |id: &str, token: bool| {
        let mut req =
            tonic::Request::new(facepose_service::proto::CancelJobRequest { id: id.to_string() });
        if token {
            req.metadata_mut().insert(
                "authorization",
                format!("Bearer {ADMIN_TOKEN}").parse().unwrap(),
            );
        }
        req
    };
    let job = grpc
        .cancel_job(cancel(&ids[2], true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        (job.state.as_str(), job.version.as_str()),
        ("cancelled", "")
    );
    let e = grpc.cancel_job(cancel(&ids[2], false)).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let e = grpc.cancel_job(cancel("0123", true)).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");

    for (id, want) in ids.iter().zip(["succeeded", "succeeded", "cancelled"]) {
        let job = wait_job(&c, &server, id).await;
        assert_eq!(job["state"], want, "{job}");
    }
    // Versions 2 and 3 are written; the cancelled job wrote none.
    let versions = dir.path().join("default/versions");
    for v in ["2", "3"] {
        assert!(
            load_model(&versions.join(v).join(MODEL_FILE)).is_ok(),
            "version {v}"
        );
    }
    assert!(!versions.join("4").exists(), "{}", server.logs());
    assert!(
        server
            .logs()
            .contains("retraining job cancelled while queued")
    );

    let cancel_http = |id: &str| format!("/v1/models/jobs/{id}:cancel");
    let (s, e) = post_admin(&c, &server, &cancel_http(&ids[2]), &json!({})).await;
    assert_eq!(s, StatusCode::CONFLICT, "{e}");
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("already been cancelled"),
        "{e}"
    );
    let (s, e) = post_admin(&c, &server, &cancel_http(&ids[0]), &json!({})).await;
    assert_eq!(s, StatusCode::CONFLICT, "{e}");
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("already succeeded"),
        "{e}"
    );
    let (s, e) = post_admin(&c, &server, &cancel_http("nope"), &json!({})).await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{e}");
    let (s, e) = post_admin(
        &c,
        &server,
        &format!("/v1/models/jobs/{}", ids[0]),
        &json!({}),
    )
    .await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{e}");
    assert!(
        e["error"]["message"].as_str().unwrap().contains(":cancel"),
        "{e}"
    );
    let r = c
        .post(server.url(&cancel_http(&ids[0])))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
}

/// Retraining jobs behind a load balancer: any replica sharing the models folder answers for a
/// job another one runs (its record in the folder names that replica), and a cancel through
/// it takes effect there.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_are_seen_and_cancelled_through_any_replica() {
    let dir = TempDir::new("replica-jobs");
    let replica = |name: &str| {
        Server::start_admin(
            &[
                "--models",
                dir.arg(),
                "--registry-poll",
                "200ms",
                "--replica",
                name,
            ],
            ADMIN_TOKEN,
        )
    };
    let (a, b) = (replica("replica-a"), replica("replica-b"));
    let c = client();
    let body = json!({"shapes": shapes_json(&population(120, |p| p)), "activate": false});
    let mut ids = Vec::new();
    for _ in 0..3 {
        let (s, job) = post_admin(&c, &a, "/v1/models", &body).await;
        assert_eq!(s, StatusCode::ACCEPTED, "{job}");
        assert_eq!(job["replica"], "replica-a", "{job}");
        ids.push(job["id"].as_str().unwrap().to_string());
    }
    // The third is queued behind two trainings: B asks A to cancel it.
    let (s, asked) = post_admin(
        &c,
        &b,
        &format!("/v1/models/jobs/{}:cancel", ids[2]),
        &json!({}),
    )
    .await;
    assert_eq!(s, StatusCode::ACCEPTED, "{asked}");
    assert_eq!(asked["replica"], "replica-a", "{asked}");
    for (id, want) in ids.iter().zip(["succeeded", "succeeded", "cancelled"]) {
        let seen = wait_job(&c, &b, id).await;
        assert_eq!(seen["state"], want, "{seen}");
        // Both replicas tell the same story once the job has ended.
        let (s, here) = get(&c, &a, &format!("/v1/models/jobs/{id}")).await;
        assert_eq!(s, StatusCode::OK);
        assert_eq!(here, seen);
    }
    assert!(
        a.logs().contains("cancel asked through another replica"),
        "{}",
        a.logs()
    );
    // The gRPC view of the same job, through B.
    let mut grpc = b.grpc().await;
    let job = grpc
        .get_job(facepose_service::proto::GetJobRequest { id: ids[0].clone() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        (job.state.as_str(), job.replica.as_str()),
        ("succeeded", "replica-a")
    );
    // The model catalog does not list the records' folder.
    let (_, models) = get(&c, &b, "/v1/models").await;
    assert!(!models.to_string().contains(".jobs"), "{models}");
}

/// Generated clients (openapi-python-client, docs/API.md) send the action routes' last segment
/// percent-encoded: `1%3Aactivate`, `<id>%3Acancel`. The server decodes it before it looks for
/// the action, so they reach the same handlers as `1:activate` and `<id>:cancel`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn percent_encoded_actions_are_the_actions() {
    let dir = TempDir::new("encoded-actions");
    let server = admin_server(&dir, "1s");
    let c = client();
    for encoded in ["1%3Aactivate", "1%3aactivate"] {
        let path = format!("/v1/models/default/versions/{encoded}");
        let (s, v) = post_admin(&c, &server, &path, &json!({})).await;
        assert_eq!(s, StatusCode::OK, "{path}: {v}");
        assert_eq!(
            (&v["name"], &v["version"]),
            (&json!("default"), &json!("1"))
        );
    }
    // An unknown version or job: the action was found, the version or job was not.
    let id = "0123456789abcdef0123456789abcdef";
    for path in [
        "/v1/models/default/versions/7%3Aactivate".to_string(),
        format!("/v1/models/jobs/{id}%3Acancel"),
    ] {
        let (s, e) = post_admin(&c, &server, &path, &json!({})).await;
        assert_eq!(s, StatusCode::NOT_FOUND, "{path}: {e}");
        let message = e["error"]["message"].as_str().unwrap();
        assert!(!message.contains("no action"), "{path}: {message}");
        assert!(!message.contains("%3A"), "{path}: {message}");
    }
    // Without the suffix, encoded or not, there is no action.
    let (s, e) = post_admin(&c, &server, "/v1/models/default/versions/1%3A", &json!({})).await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{e}");
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("no action"),
        "{e}"
    );
}

/// The field names of `message NAME { ... }` in the service's .proto file.
fn proto_fields(message: &str) -> Vec<String> {
    let text = include_str!("../../../../proto/facepose/v1/pose.proto");
    let start = text
        .find(&format!("message {message} {{"))
        .unwrap_or_else(|| panic!("no message {message}"));
    let body = &text[start..start + text[start..].find("\n}").unwrap()];
    body.lines()
        .skip(1)
        .map(str::trim)
        .filter(|l| !l.starts_with("//") && l.contains(" = "))
        .map(|l| {
            l.split(" = ")
                .next()
                .unwrap()
                .split_whitespace()
                .last()
                .unwrap()
                .to_string()
        })
        .collect()
}

/// Every field of `message` is a key of the HTTP JSON `object`: one name for one thing.
fn assert_same_names(message: &str, object: &Value, transport_only: &[&str]) {
    for field in proto_fields(message) {
        if transport_only.contains(&field.as_str()) {
            continue;
        }
        assert!(
            object.get(&field).is_some(),
            "gRPC {message}.{field} has no HTTP key of that name in {object}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_json_uses_the_grpc_field_names() {
    let dir = TempDir::new("names");
    place_default_copy(dir.path(), "2");
    let server = Server::start(&["--models", dir.arg()]);
    let c = client();
    let (_, v) = get(&c, &server, "/v1/models").await;
    let m = &v["models"][0];
    assert_same_names("ModelInfo", m, &[]);
    assert_same_names("SchemeInfo", &m["schemes"][0], &[]);
    // The first name of is_default stays for older clients.
    assert_eq!(
        (&m["is_default"], &m["default"]),
        (&json!(true), &json!(true))
    );
    let (_, v) = get(&c, &server, "/v1/models/default/versions").await;
    assert_same_names("ListVersionsResponse", &v, &[]);
    assert_same_names("VersionInfo", &v["versions"][0], &[]);
    let (_, v) = get(&c, &server, "/v1/models/default").await;
    assert_same_names("ModelInfo", &v, &[]);
    let pose: Value = c
        .post(server.url("/v1/pose"))
        .json(&json!({"landmarks": face68(20.0, 5.0, 0.0), "method": "fit"}))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    // `smoothed` and `gated` belong to the gRPC stream; `translation` comes only with a camera,
    // `conventions` only when asked for (below).
    assert_same_names(
        "Pose",
        &pose,
        &["smoothed", "gated", "translation", "conventions"],
    );
    assert_same_names("Uncertainty", &pose["uncertainty"], &[]);
    assert_same_names("AngleUncertainty", &pose["uncertainty"]["yaw"], &[]);
    let pose: Value = c
        .post(server.url("/v1/pose"))
        .json(&json!({
            "landmarks": face68(20.0, 5.0, 0.0),
            "method": "fit",
            "camera": {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0},
            "conventions": ["quaternion", {"name": "euler", "preset": "unity"}, "opencv"],
        }))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let answers = &pose["conventions"];
    assert!(answers.is_object(), "{pose}");
    // This copy of the model has no MediaPipe mesh: the service tests of conventions check
    // MediaPipeConvention's fields against the HTTP answer.
    assert_same_names("Conventions", answers, &["mediapipe"]);
    assert_same_names("Quaternion", &answers["quaternion"], &[]);
    assert_same_names("EulerConvention", &answers["euler"], &[]);
    assert_same_names("OpenCvConvention", &answers["opencv"], &[]);
}
