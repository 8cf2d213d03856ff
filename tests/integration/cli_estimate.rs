//! `facepose estimate` end to end: faces projected from the default model's own mean shape at
//! known poses come back at those poses; CSV input; bad lines give error records.

use std::io::Write;
use std::process::{Command, Stdio};

use facepose_core::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
use facepose_core::model::default_model;
use nalgebra::Vector2;
use serde_json::{Value, json};

fn run(args: &[&str], input: &str) -> (i32, Vec<Value>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let lines = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    (
        out.status.code().unwrap_or(-1),
        lines,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

const POSES: [(f64, f64, f64); 5] = [
    (0.0, 0.0, 0.0),
    (25.0, -10.0, 5.0),
    (-40.0, 15.0, -12.0),
    (60.0, 5.0, 20.0),
    (-75.0, -20.0, 0.0),
];

fn projected() -> Vec<(EulerAngles, Vec<Vector2<f64>>)> {
    let (_, model) = default_model().unwrap();
    POSES
        .iter()
        .map(|&(y, p, r)| {
            let a = EulerAngles::new(y, p, r).unwrap();
            let cam =
                WeakPerspective::new(a.to_rotation(), 1.7, Vector2::new(240.0, -260.0)).unwrap();
            (a, model.mean.iter().map(|x| cam.project(x)).collect())
        })
        .collect()
}

fn rotation(v: &Value) -> nalgebra::Rotation3<f64> {
    let r = v["rotation"].as_array().unwrap();
    let rows: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| r[i][j].as_f64().unwrap()));
    facepose_core::geometry::rotation_from_rows(rows, 1e-6).unwrap()
}

#[test]
fn known_poses_come_back() {
    let faces = projected();
    let input: String = faces
        .iter()
        .enumerate()
        .map(|(k, (_, pts))| json!({"id": format!("face{k}"), "landmarks": pts.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>()}).to_string() + "\n")
        .collect();
    for method in ["auto", "fit", "fit-shape"] {
        let (code, out, err) = run(&["estimate", "--input", "-", "--method", method], &input);
        assert_eq!(code, 0, "{err}");
        assert_eq!(out.len(), faces.len());
        for (k, ((a, _), v)) in faces.iter().zip(&out).enumerate() {
            assert_eq!(v["id"], format!("face{k}"));
            let err = geodesic_deg(&rotation(v), &a.to_rotation());
            assert!(err < 0.5, "{method}: {a:?} -> {v}");
            assert!((v["yaw"].as_f64().unwrap() - a.yaw).abs() < 0.5);
            assert_eq!(v["visible"].as_array().unwrap().len(), 68);
            assert!(v["residual"].as_f64().unwrap() < 0.01);
        }
    }
    // The paper's regression is accurate within its training range.
    let (_, out, _) = run(
        &["estimate", "--input", "-", "--method", "regression"],
        &input,
    );
    for ((a, _), v) in faces.iter().zip(&out).take(3) {
        assert!(
            geodesic_deg(&rotation(v), &a.to_rotation()) < 3.0,
            "{a:?} -> {v}"
        );
    }
}

#[test]
fn csv_with_ids_and_missing_cells() {
    let faces = projected();
    let mut csv = String::from("id");
    for i in 0..68 {
        csv += &format!(",x{i},y{i}");
    }
    csv += "\n";
    for (k, (_, pts)) in faces.iter().enumerate() {
        csv += &format!("f{k}");
        for (i, p) in pts.iter().enumerate() {
            if i == 8 && k == 1 {
                csv += ",,";
            } else {
                csv += &format!(",{},{}", p.x, p.y);
            }
        }
        csv += "\n";
    }
    let (code, out, err) = run(&["estimate", "--input", "-", "--method", "fit"], &csv);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.len(), faces.len());
    assert_eq!(out[1]["id"], "f1");
    assert!(geodesic_deg(&rotation(&out[1]), &faces[1].0.to_rotation()) < 0.5);
}

#[test]
fn bad_lines_give_error_records_and_the_run_goes_on() {
    let good = json!({"id": 1, "landmarks": projected()[0].1.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>()}).to_string();
    let input = [
        "not json".to_string(),
        json!({"id": "short", "landmarks": [[1, 2]]}).to_string(),
        json!({"id": "nan", "landmarks": vec![json!(["NaN", 1]); 68]}).to_string(),
        json!({"id": "same", "landmarks": vec![[3.0, 3.0]; 68]}).to_string(),
        json!({"id": "empty", "landmarks": vec![Value::Null; 68]}).to_string(),
        good,
    ]
    .join("\n");
    let (code, out, _) = run(&["estimate", "--input", "-"], &input);
    assert_eq!(code, 0);
    assert_eq!(out.len(), 6);
    assert!(out[0]["error"].as_str().unwrap().contains("JSON"));
    assert!(
        out[1]["error"]
            .as_str()
            .unwrap()
            .contains("expected 68 points, got 1")
    );
    assert!(out[2]["error"].as_str().unwrap().contains("landmark 0"));
    assert!(out[3]["error"].as_str().unwrap().contains("degenerate"));
    assert!(out[4]["error"].as_str().unwrap().contains("points"));
    assert_eq!(out[5]["id"], 1);
    assert!(out[5].get("error").is_none());
    // Unusable arguments end the run.
    let (code, _, err) = run(&["estimate", "--input", "-", "--method", "magic"], "");
    assert_eq!(code, 2);
    assert!(err.contains("unknown method"), "{err}");
    let (code, _, err) = run(
        &["estimate", "--input", "-", "--scheme", "mediapipe468"],
        "",
    );
    assert_eq!(code, 2);
    assert!(err.contains("serves ibug68"), "{err}");
}

#[test]
fn camera_intrinsics_give_pose_and_position_under_perspective() {
    // The mean shape 40 cm in front of a 800 px camera, off-centre: a weak-perspective fit is
    // off by about a degree here, the perspective refinement is not.
    use facepose_core::estimate::Intrinsics;
    let (_, model) = default_model().unwrap();
    let k = Intrinsics {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    };
    let t = nalgebra::Vector3::new(40.0, -25.0, -400.0);
    let mut input = String::new();
    let mut plain_input = String::new();
    let mut truth = Vec::new();
    for (i, &(y, p, r)) in POSES[..4].iter().enumerate() {
        let a = EulerAngles::new(y, p, r).unwrap();
        let rot = a.to_rotation();
        let pts: Vec<[f64; 2]> = model
            .mean
            .iter()
            .map(|x| {
                let q = k.project(&(rot * x + t)).unwrap();
                [q.x, q.y]
            })
            .collect();
        let line = if i % 2 == 0 {
            json!({"id": i, "landmarks": pts, "camera": {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0}})
        } else {
            json!({"id": i, "landmarks": pts})
        };
        input.push_str(&format!("{line}\n"));
        plain_input.push_str(&format!("{}\n", json!({"id": i, "landmarks": pts})));
        truth.push(a);
    }
    // Lines 1 and 3 take the camera from the flag; lines 0 and 2 bring their own.
    let (code, out, err) = run(
        &[
            "estimate",
            "--input",
            "-",
            "--method",
            "fit",
            "--camera",
            "800,800,320,240",
        ],
        &input,
    );
    assert_eq!(code, 0, "{err}");
    for (o, a) in out.iter().zip(&truth) {
        let e = geodesic_deg(&rotation(o), &a.to_rotation());
        assert!(e < 0.01, "{o}: {e} deg");
        let tr: Vec<f64> = o["translation"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert!(
            (tr[0] - t.x).abs() < 0.5 && (tr[1] - t.y).abs() < 0.5 && (tr[2] - t.z).abs() < 2.0,
            "{tr:?}"
        );
    }
    // Without a camera the same faces are off by weak perspective, and have no position.
    let (_, plain, _) = run(
        &["estimate", "--input", "-", "--method", "fit"],
        &plain_input,
    );
    assert!(plain.iter().all(|o| o.get("translation").is_none()));
    let weak: f64 = plain
        .iter()
        .zip(&truth)
        .map(|(o, a)| geodesic_deg(&rotation(o), &a.to_rotation()))
        .fold(0.0, f64::max);
    assert!(
        weak > 0.1,
        "weak perspective should be visibly off here: {weak}"
    );
    // A bad camera is an error record for that line, or an unusable argument.
    let (_, bad, _) = run(
        &["estimate", "--input", "-"],
        &format!(
            "{}\n",
            json!({"landmarks": [[1.0, 2.0]], "camera": {"fx": -1}})
        ),
    );
    assert!(
        bad[0]["error"].as_str().unwrap().contains("camera"),
        "{}",
        bad[0]
    );
    let (code, _, err) = run(&["estimate", "--input", "-", "--camera", "1,2,3"], "");
    assert_ne!(code, 0);
    assert!(err.contains("fx,fy,cx,cy"), "{err}");
}
