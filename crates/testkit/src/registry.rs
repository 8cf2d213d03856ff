//! Retraining through the service: models folders, shape sets to upload, and the admin calls,
//! over any server ([`Endpoint`]). Expectations come from the shared data and the library
//! reading the folder, not from the server.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use facepose_core::geometry::WeakPerspective;
use facepose_core::model::bundle::Bundle;
use facepose_files::store::{MODEL_FILE, load_model, write_bundle_dir};
use nalgebra::{Vector2, Vector3};
use reqwest::StatusCode;
use serde_json::{Value, json};

use crate::Endpoint;
use crate::faces::rotation;

/// The admin token of the tests' servers.
pub const ADMIN_TOKEN: &str = "test-admin-token-0123456789";

/// A temporary folder, removed when dropped.
pub struct TempDir(PathBuf);

impl TempDir {
    /// A new folder under the system's temporary one, its name holding `tag`.
    pub fn new(tag: &str) -> TempDir {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos();
        let d = std::env::temp_dir().join(format!(
            "facepose-registry-{tag}-{}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }

    /// Its path.
    pub fn path(&self) -> &Path {
        &self.0
    }

    /// Its path as a string, for a command-line flag.
    pub fn arg(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The first `n` shapes of bfm68 `population_249.json` (mm), each point mapped by `f`.
pub fn population(n: usize, f: impl Fn(Vector3<f64>) -> Vector3<f64>) -> Vec<Vec<Vector3<f64>>> {
    let path = facepose_files::data::data_dir().join("bfm68/population_249.json");
    let pop = facepose_files::data::load_population(&path).expect("the shared bfm68 population");
    pop.shapes
        .into_iter()
        .take(n)
        .map(|s| s.into_iter().map(&f).collect())
        .collect()
}

/// Shapes as JSON: one `[x, y, z]` per point.
pub fn shapes_json(shapes: &[Vec<Vector3<f64>>]) -> Value {
    json!(
        shapes
            .iter()
            .map(|s| s.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>())
            .collect::<Vec<_>>()
    )
}

/// Training options that train in a fraction of a second: a coarse grid, no bins.
pub fn quick_options() -> Value {
    json!({"grid": {"coarse": {"yaw": [-60, 60, 15], "pitch": [-30, 30, 15]}}, "components": 5})
}

/// A copy of the default bundle as version `version` of `DIR/default` (what an operator could
/// place there), written atomically.
pub fn place_default_copy(dir: &Path, version: &str) {
    let mut b = Bundle::parse(facepose_core::model::DEFAULT_BUNDLE).unwrap();
    b.version = version.into();
    b.created = format!("2026-11-2{version}T00:00:00Z");
    b.checksum = b.compute_checksum().unwrap();
    write_bundle_dir(&dir.join("default/versions").join(version), &b).unwrap();
}

/// An HTTP client with a 30 s timeout.
pub fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(Duration::from_secs(30))
        .build()
        .unwrap()
}

/// The status and the body as JSON (`null` if not JSON).
pub async fn json_of(r: reqwest::Response) -> (StatusCode, Value) {
    let status = r.status();
    let text = r.text().await.unwrap();
    let v = serde_json::from_str(&text).unwrap_or(Value::Null);
    (status, v)
}

/// `POST path` of `body` with the admin token: status and JSON body.
pub async fn post_admin(
    c: &reqwest::Client,
    server: &impl Endpoint,
    path: &str,
    body: &Value,
) -> (StatusCode, Value) {
    json_of(
        c.post(server.url(path))
            .bearer_auth(ADMIN_TOKEN)
            .json(body)
            .send()
            .await
            .unwrap(),
    )
    .await
}

/// Activates version `version` of model `default`: status and JSON body.
pub async fn activate(
    c: &reqwest::Client,
    server: &impl Endpoint,
    version: &str,
) -> (StatusCode, Value) {
    json_of(
        c.post(server.url(&format!("/v1/models/default/versions/{version}:activate")))
            .bearer_auth(ADMIN_TOKEN)
            .send()
            .await
            .unwrap(),
    )
    .await
}

/// `GET path`: status and JSON body.
pub async fn get(c: &reqwest::Client, server: &impl Endpoint, path: &str) -> (StatusCode, Value) {
    json_of(c.get(server.url(path)).send().await.unwrap()).await
}

/// `POST /v1/models` of `body` with the admin token: the answer whole (status, headers, job).
pub async fn upload(
    c: &reqwest::Client,
    server: &impl Endpoint,
    body: &Value,
) -> reqwest::Response {
    c.post(server.url("/v1/models"))
        .bearer_auth(ADMIN_TOKEN)
        .json(body)
        .send()
        .await
        .unwrap()
}

/// The server's Prometheus text.
pub async fn metrics_text(c: &reqwest::Client, server: &impl Endpoint) -> String {
    c.get(server.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap()
}

/// Polls a job until it ends (deadline 60 s).
pub async fn wait_job(c: &reqwest::Client, server: &impl Endpoint, id: &str) -> Value {
    let t = Instant::now();
    loop {
        let (s, j) = get(c, server, &format!("/v1/models/jobs/{id}")).await;
        assert_eq!(s, StatusCode::OK, "{j}");
        if j["state"] == "succeeded" || j["state"] == "failed" || j["state"] == "cancelled" {
            return j;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "job still {j}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// 68 landmarks of `mean` seen at a known pose by a weak-perspective camera.
pub fn project(mean: &[Vector3<f64>], yaw: f64, pitch: f64, roll: f64) -> Vec<[f64; 2]> {
    let cam =
        WeakPerspective::new(rotation(yaw, pitch, roll), 2.3, Vector2::new(300.0, -260.0)).unwrap();
    mean.iter()
        .map(|x| {
            let p = cam.project(x);
            [p.x, p.y]
        })
        .collect()
}

/// Depth of the nose tip (30) in front of the outer eye corners (36, 45), mm.
pub fn nose_depth(mean: &[Vector3<f64>]) -> f64 {
    mean[30].z - (mean[36].z + mean[45].z) / 2.0
}

/// The served model's version of `default`.
pub async fn served_version(c: &reqwest::Client, server: &impl Endpoint) -> String {
    let (s, v) = get(c, server, "/v1/models/default").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    v["version"].as_str().unwrap().to_string()
}

/// The folder as the library reads it: `ACTIVE` (if any) is one line naming a version that
/// loads, and every numbered version not in `known` loads (a version is complete once it has
/// its name, and immutable: the known ones were checked in an earlier round). Hidden
/// temporaries are ignored. Returns the active version and the numbered ones.
pub fn check_folder(dir: &Path, known: &[String]) -> (String, Vec<String>) {
    let model = dir.join("default");
    let active = match std::fs::read_to_string(model.join("ACTIVE")) {
        Ok(text) => {
            assert!(
                text.ends_with('\n') && text.lines().count() == 1,
                "torn pointer {text:?}"
            );
            text.trim().to_string()
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "1".to_string(),
        Err(e) => panic!("{e}"),
    };
    let mut versions = Vec::new();
    if let Ok(entries) = std::fs::read_dir(model.join("versions")) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                continue;
            }
            if !known.contains(&name) || name == active {
                let (b, _) = load_model(&e.path().join(MODEL_FILE))
                    .unwrap_or_else(|err| panic!("version {name} is incomplete: {err}"));
                assert_eq!(b.version, name);
            }
            versions.push(name);
        }
    }
    versions.sort_by_key(|v| v.parse::<u64>().unwrap());
    assert!(
        active == "1" || versions.contains(&active),
        "ACTIVE names {active}, not a complete version ({versions:?})"
    );
    (active, versions)
}

/// An error answer's code and message, checked against what is expected.
pub fn assert_error(status: StatusCode, v: &Value, want: StatusCode, code: &str, message: &str) {
    assert_eq!(status, want, "{v}");
    assert_eq!(v["error"]["code"], code, "{v}");
    let m = v["error"]["message"].as_str().unwrap();
    assert!(m.contains(message), "want {message:?} in {m:?}");
}

/// Views of `shape` from five yaws (image pixels), as a multi-view subject.
pub fn views_of(shape: &[Vector3<f64>]) -> Value {
    json!(
        [-30.0, -15.0, 0.0, 15.0, 30.0]
            .iter()
            .map(|&yaw| project(shape, yaw, 5.0, 0.0))
            .collect::<Vec<_>>()
    )
}
