//! The `facepose` binary end to end: `reconstruct` on a multi-view file made from a known shape,
//! `eval-sfm` and `hpr` on the shared data, and errors for bad files.

use crate::common;

use std::process::Command;

use facepose_core::geometry::{
    EulerAngles, Scaling, WeakPerspective, align3, procrustes::rms_distance3,
};
use facepose_files::data::load_population;
use nalgebra::{Vector2, Vector3};
use serde_json::{Value, json};

fn facepose(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args(args)
        .output()
        .expect("run facepose")
}

#[test]
fn reconstruct_writes_the_shape_back() {
    let shape = load_population(&common::data_file("bfm68/population_249.json"))
        .unwrap()
        .shapes[3]
        .clone();
    let views: Vec<Value> = [
        (-25.0, 5.0),
        (-10.0, -5.0),
        (0.0, 0.0),
        (12.0, 4.0),
        (28.0, -6.0),
    ]
    .iter()
    .map(|&(yaw, pitch)| {
        let cam = WeakPerspective::new(
            EulerAngles::new(yaw, pitch, 3.0).unwrap().to_rotation(),
            2.0,
            Vector2::new(225.0, -225.0),
        )
        .unwrap();
        let pts: Vec<Value> = shape
            .iter()
            .enumerate()
            .map(|(i, x)| {
                if i == 5 && yaw > 20.0 {
                    Value::Null
                } else {
                    let p = cam.project(x);
                    json!([p.x, p.y])
                }
            })
            .collect();
        Value::Array(pts)
    })
    .collect();
    let dir = std::env::temp_dir().join(format!("facepose-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("views.json");
    let output = dir.join("shape.json");
    std::fs::write(
        &input,
        json!({"scheme": "ibug68", "views": views}).to_string(),
    )
    .unwrap();
    let out = facepose(&[
        "reconstruct",
        "--views",
        input.to_str().unwrap(),
        "--out",
        output.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&output).unwrap()).unwrap();
    let rec: Vec<Vector3<f64>> = v["shapes"][0]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            Vector3::new(
                p[0].as_f64().unwrap(),
                p[1].as_f64().unwrap(),
                p[2].as_f64().unwrap(),
            )
        })
        .collect();
    let sim = align3(&rec, &shape, Scaling::Similarity).unwrap();
    let moved: Vec<_> = rec.iter().map(|p| sim.apply(p)).collect();
    assert!(rms_distance3(&moved, &shape) < 1e-6);
    // Frontalized: the eye line is along x, the nose in front; scale 2 px/mm.
    assert!((rec[45].y - rec[36].y).abs() < 0.1 * (rec[45].x - rec[36].x).abs());
    assert!(rec[30].z > 0.0);
    assert!((sim.scale - 0.5).abs() < 1e-6);
    assert_eq!(v["subjects"][0]["missing_entries"], 1);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_files_fail_with_a_message() {
    let dir = std::env::temp_dir().join(format!("facepose-cli-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        (
            "{\"views\": [[[1, 2]]], \"subjects\": []}",
            "exactly one of",
        ),
        ("{\"scheme\": \"nope\", \"views\": []}", "unknown scheme"),
        (
            "{\"views\": [[[1, 2], [3, 4]]]}",
            "points, scheme ibug68 has 68",
        ),
        ("not json", "expected"),
    ];
    for (k, (text, needle)) in cases.iter().enumerate() {
        let p = dir.join(format!("bad{k}.json"));
        std::fs::write(&p, text).unwrap();
        let out = facepose(&["reconstruct", "--views", p.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{text}: {err}");
    }
    let out = facepose(&["reconstruct", "--views", "/nonexistent/views.json"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot read"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn hpr_prints_the_table() {
    let out = facepose(&["hpr", "--step", "30"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in ["mesh468", "ibug68 (from 468)", "ibug68 (68 alone)", "Katz"] {
        assert!(text.contains(needle), "{needle} missing:\n{text}");
    }
}

/// `facepose` run from `dir` with `FACEPOSE_DATA` set to `data` (or removed).
fn facepose_in(
    dir: &std::path::Path,
    data: Option<&std::path::Path>,
    args: &[&str],
) -> (i32, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_facepose"));
    c.args(args).current_dir(dir).env_remove("FACEPOSE_DATA");
    if let Some(d) = data {
        c.env("FACEPOSE_DATA", d);
    }
    let out = c.output().expect("run facepose");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_data_folder_is_found_at_run_time_and_the_error_says_where_it_looked() {
    // A working directory with no ../shared/data beside it: a binary that kept the path of the
    // checkout it was built in would still find the data from there.
    let dir = std::env::temp_dir().join(format!("facepose-cli-data-{}", std::process::id()));
    let work = dir.join("work");
    std::fs::create_dir_all(&work).unwrap();
    let data = std::path::absolute(common::data_file("mediapipe/canonical_face_468.json"))
        .unwrap()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    let hpr = [
        "hpr",
        "--step",
        "45",
        "--max-yaw",
        "45",
        "--max-pitch",
        "45",
    ];
    let (code, err) = facepose_in(&work, None, &hpr);
    assert_eq!(code, 2);
    assert!(
        err.contains("no shared data folder: looked at --data (not given), then FACEPOSE_DATA (not set), then ")
            && err.contains("work/../shared/data (no such folder)")
            && err.contains("give it with --data DIR or FACEPOSE_DATA=DIR"),
        "{err}"
    );
    // The flag, the variable, and the folder beside the working directory each find it.
    let with_flag: Vec<&str> = hpr
        .iter()
        .copied()
        .chain(["--data", data.to_str().unwrap()])
        .collect();
    assert_eq!(facepose_in(&work, None, &with_flag).0, 0);
    assert_eq!(facepose_in(&work, Some(&data), &hpr).0, 0);
    std::fs::create_dir_all(dir.join("shared")).unwrap();
    std::os::unix::fs::symlink(&data, dir.join("shared/data")).unwrap();
    assert_eq!(facepose_in(&work, None, &hpr).0, 0);
    // A folder that is named must exist: no silent fallback to another one.
    let (code, err) = facepose_in(
        &work,
        None,
        &[&hpr[..], &["--data", "/nonexistent/data"]].concat(),
    );
    assert_eq!(code, 2);
    assert!(
        err.contains("/nonexistent/data (from --data: no such folder)"),
        "{err}"
    );
    // A file missing inside the folder is named, with how to point at the data.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (code, err) = facepose_in(&work, Some(&empty), &["eval-sfm"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("empty/bfm68/population_249.json")
            && err.contains("point FACEPOSE_DATA, or --data"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
    // --help says where the commands look.
    for cmd in ["eval", "eval-sfm", "hpr"] {
        let out = facepose(&[cmd, "--help"]);
        let help = String::from_utf8_lossy(&out.stdout);
        assert!(
            help.contains("--data DIR, else $FACEPOSE_DATA, else ../shared/data from the working"),
            "{cmd}: {help}"
        );
    }
}

#[test]
fn eval_sfm_reports_progress_on_stderr_and_quiet_silences_it() {
    // A population of 8 shapes, so that the six conditions run in a moment.
    let full: Value = serde_json::from_str(
        &std::fs::read_to_string(common::data_file("bfm68/population_249.json")).unwrap(),
    )
    .unwrap();
    let mut small = full.clone();
    small["shapes"] = Value::Array(full["shapes"].as_array().unwrap()[..8].to_vec());
    let dir = std::env::temp_dir().join(format!("facepose-cli-progress-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let pop = dir.join("population_8.json");
    std::fs::write(&pop, small.to_string()).unwrap();
    let pop = pop.to_str().unwrap();

    let loud = facepose(&["eval-sfm", "--population", pop]);
    assert!(
        loud.status.success(),
        "{}",
        String::from_utf8_lossy(&loud.stderr)
    );
    let quiet = facepose(&["eval-sfm", "--population", pop, "--quiet"]);
    assert!(
        quiet.status.success(),
        "{}",
        String::from_utf8_lossy(&quiet.stderr)
    );
    std::fs::remove_dir_all(&dir).ok();

    // Standard output: the report alone, the same with and without progress.
    let stdout = String::from_utf8(loud.stdout).unwrap();
    assert_eq!(stdout, String::from_utf8(quiet.stdout).unwrap());
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(
        lines[0],
        format!("Structure from motion on {pop} (8 shapes), five views within ±30° yaw, seed 2011")
    );
    assert!(lines[2].starts_with("| noise"), "{stdout}");
    assert_eq!(lines.len(), 3 + 1 + 6, "{stdout}");
    assert!(
        lines[4..]
            .iter()
            .all(|l| l.split(" | ").nth(2) == Some("8")),
        "{stdout}"
    );

    // Standard error: every line is `[elapsed s] stage`, the elapsed time never decreasing;
    // each condition in turn starts at 0 and ends at all 8 shapes.
    let stderr = String::from_utf8(loud.stderr).unwrap();
    let mut last = 0.0;
    let mut stages = Vec::new();
    for line in stderr.lines() {
        let (time, stage) = line
            .strip_prefix('[')
            .and_then(|l| l.split_once(" s] "))
            .unwrap_or_else(|| panic!("not a progress line: {line:?}\n{stderr}"));
        let t: f64 = time.trim().parse().unwrap();
        assert!(t >= last, "{stderr}");
        last = t;
        stages.push(stage);
    }
    assert!(stages[0].starts_with("reading ") && stages[0].ends_with("population_8.json"));
    let mut at = 1;
    for c in 1..=6 {
        let name = format!("structure from motion: condition {c}/6: ");
        assert_eq!(stages[at], format!("{name}0/8 shapes (0%)"), "{stderr}");
        // Lines between (at most one every 2 s) count up; the last one has the stage's time.
        at += 1;
        while !stages[at].contains("8/8 shapes (100%), ") {
            assert!(stages[at].starts_with(&name), "{stderr}");
            at += 1;
        }
        assert!(stages[at].starts_with(&name), "{stderr}");
        at += 1;
    }
    assert_eq!(&stages[at..], ["done"], "{stderr}");

    assert_eq!(String::from_utf8(quiet.stderr).unwrap(), "");
}
