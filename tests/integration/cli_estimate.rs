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
    let (code, out, err) = run(&["estimate", "--input", "-"], &input);
    // Some faces failed: status 1, and the summary says how many.
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("1 of 6 faces estimated, 5 with errors"),
        "{err}"
    );
    assert_eq!(out.len(), 6);
    assert!(out[0]["error"].as_str().unwrap().contains("JSON"));
    assert!(
        out[1]["error"]
            .as_str()
            .unwrap()
            .contains("1 landmarks, and no scheme of this model has that many (ibug68: 68"),
        "{}",
        out[1]
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
        &["estimate", "--input", "-", "--scheme", "mediapipe999"],
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

/// The mean face at a known pose as a CSV row of `scheme`'s points, after `id`.
fn csv_row(id: &str, pts: &[Vector2<f64>]) -> String {
    let mut row = id.to_string();
    for p in pts {
        row += &format!(",{},{}", p.x, p.y);
    }
    row
}

#[test]
fn a_headerless_csv_with_text_ids_keeps_its_first_row() {
    let faces = projected();
    let rows: Vec<String> = faces[..3]
        .iter()
        .enumerate()
        .map(|(k, (_, pts))| csv_row(&format!("face{k}"), pts))
        .collect();
    let (code, out, err) = run(
        &["estimate", "--input", "-", "--format", "csv"],
        &rows.join("\n"),
    );
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.len(), 3, "3 rows in, 3 poses out");
    for (k, v) in out.iter().enumerate() {
        assert_eq!(v["id"], format!("face{k}"));
        assert!(
            geodesic_deg(&rotation(v), &faces[k].0.to_rotation()) < 0.5,
            "{v}"
        );
    }
    // A header without an id column is still a header; `--header no` takes it for a face.
    let mut header: Vec<String> = (0..68)
        .flat_map(|i| [format!("x{i}"), format!("y{i}")])
        .collect();
    header.truncate(136);
    let with_header = format!(
        "{}\n{}",
        header.join(","),
        rows[0].split_once(',').unwrap().1
    );
    let (code, out, _) = run(
        &["estimate", "--input", "-", "--format", "csv"],
        &with_header,
    );
    assert_eq!((code, out.len()), (0, 1));
    let (code, out, _) = run(
        &[
            "estimate", "--input", "-", "--format", "csv", "--header", "no",
        ],
        &with_header,
    );
    assert_eq!((code, out.len()), (1, 2));
    assert!(
        out[0]["error"].as_str().unwrap().contains("not numbers"),
        "{}",
        out[0]
    );
}

#[test]
fn the_exit_status_says_whether_anything_was_estimated() {
    let (code, out, err) = run(&["estimate", "--input", "-"], "");
    assert_eq!((code, out.len()), (3, 0));
    assert!(
        err.contains("nothing estimated: the input has no face"),
        "{err}"
    );
    let bad = json!({"id": "a", "landmarks": [[1, 2], [3, 4], [5, 6]]}).to_string();
    let (code, out, err) = run(&["estimate", "--input", "-"], &format!("{bad}\n{bad}"));
    assert_eq!((code, out.len()), (3, 2));
    assert!(
        err.contains("nothing estimated: every face failed"),
        "{err}"
    );
    // The help says what the statuses mean.
    let help = Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args(["estimate", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains("Exit status: 0 every face was estimated; 1 some"),
        "{help}"
    );
}

#[test]
fn the_scheme_follows_the_point_count_and_five_points_must_be_named() {
    let model = default_model().unwrap().1;
    let (truth, _) = projected()[1].clone();
    let cam = WeakPerspective::new(truth.to_rotation(), 2.0, Vector2::new(320.0, -240.0)).unwrap();
    let json_line = |name: &str| {
        let sub = model.subset(name).unwrap();
        let pts: Vec<[f64; 2]> = sub
            .mean
            .iter()
            .map(|x| cam.project(x))
            .map(|p| [p.x, p.y])
            .collect();
        json!({"id": name, "landmarks": pts}).to_string()
    };
    // 51 points: inner51, the only scheme with that many.
    let (code, out, err) = run(&["estimate", "--input", "-"], &json_line("inner51"));
    assert_eq!(code, 0, "{err}");
    assert_eq!(out[0]["scheme"], "inner51");
    assert!(geodesic_deg(&rotation(&out[0]), &truth.to_rotation()) < 1.0);
    // 5 points: two layouts have five, so the answer names both and how to choose.
    let (code, out, _) = run(&["estimate", "--input", "-"], &json_line("dlib5"));
    assert_eq!(code, 3);
    let e = out[0]["error"].as_str().unwrap();
    assert!(e.contains("5 landmarks fit more than one scheme"), "{e}");
    assert!(e.contains("five [eye_left, eye_right, nose_tip"), "{e}");
    assert!(e.contains("dlib5 [eye_right_outer"), "{e}");
    assert!(e.contains("--scheme"), "{e}");
    // Named, on the line or with the flag, they are estimated.
    let line = json_line("dlib5").replace("\"id\"", "\"scheme\": \"dlib5\", \"id\"");
    let (code, out, err) = run(&["estimate", "--input", "-"], &line);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out[0]["scheme"], "dlib5");
    assert!(geodesic_deg(&rotation(&out[0]), &truth.to_rotation()) < 1.0);
    // A count that does not match the named scheme says which schemes have it.
    let (code, out, _) = run(
        &["estimate", "--input", "-", "--scheme", "ibug68"],
        &json_line("five"),
    );
    assert_eq!(code, 3);
    let e = out[0]["error"].as_str().unwrap();
    assert!(
        e.contains("(5 points is five [") && e.contains("expected 68 points, got 5"),
        "{e}"
    );
}
