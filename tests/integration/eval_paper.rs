//! The paper's protocol (`facepose_eval::paper`) on a small cut of the bfm68 population and a
//! small grid, against expectations that do not come from the code under test: a rigid fit of
//! a shape's own exact projections recovers the pose, the regression trained on the mean's views
//! nearly reproduces them, the geometric method reads yaw off a level face, and a test shape
//! other than the mean can only do worse. Then `facepose eval --protocol all` end to end.

use crate::common;

use std::process::Command;

use facepose_core::model::PoseModel;
use facepose_core::pose::Method;
use facepose_core::shape::ibug68;
use facepose_core::synth::{AngleRange, PoseGrid};
use facepose_eval::paper::{
    PaperEntry, PaperOptions, Perturbation, Stage, default_entries, paper_protocol,
    train_paper_model,
};
use facepose_eval::progress::{Phase, Progress, Silent};
use facepose_files::data::load_population;
use nalgebra::Vector3;

fn population() -> Vec<Vec<Vector3<f64>>> {
    load_population(&common::data_file("bfm68/population_249.json"))
        .unwrap()
        .shapes
}

fn small_options(yaw: AngleRange, pitch: AngleRange) -> PaperOptions {
    PaperOptions {
        grid: PoseGrid {
            yaw,
            pitch,
            roll: AngleRange::fixed(0.0),
        },
        stride: 1,
        robustness_samples: 12,
        ..PaperOptions::default()
    }
}

fn model(shapes: &[Vec<Vector3<f64>>]) -> PoseModel {
    train_paper_model(&ibug68(), &shapes[..20], 8, 7).unwrap()
}

#[test]
fn training_stage_on_the_mean_and_testing_stage_on_other_shapes() {
    let shapes = population();
    let model = model(&shapes);
    let r = AngleRange::new(-10.0, 10.0, 5.0).unwrap();
    let opts = small_options(r, r);
    let entries = default_entries(
        &model,
        &[
            Method::Geometry,
            Method::Regression,
            Method::Fit,
            Method::FitShape,
        ],
    );
    assert_eq!(
        entries,
        vec![
            PaperEntry::new(Method::Geometry, "five"),
            PaperEntry::new(Method::Regression, "five"),
            PaperEntry::new(Method::Regression, "inner51"),
            PaperEntry::new(Method::Regression, "ibug68"),
            PaperEntry::new(Method::Fit, "five"),
            PaperEntry::new(Method::Fit, "ibug68"),
            PaperEntry::new(Method::FitShape, "ibug68"),
        ]
    );
    let test = &shapes[20..24];
    let seen = std::sync::Mutex::new(Vec::<Progress>::new());
    let record = |p: Progress| seen.lock().unwrap().push(p);
    let rep = paper_protocol(&model, test, &entries, &opts, &record).unwrap();
    assert_eq!((rep.test_shapes, rep.poses, rep.test_views), (4, 25, 100));
    // Progress: the three phases in order, each counting from 0 to its total one step at a
    // time (poses of the grid; robustness conditions times entries).
    let seen = seen.into_inner().unwrap();
    let conditions = opts.noise.len() + opts.missing.len();
    let mut at = 0;
    for (phase, total) in [
        (Phase::PaperTraining, 25),
        (Phase::PaperTesting, 25),
        (Phase::PaperRobustness, conditions * entries.len()),
    ] {
        let steps: Vec<(usize, usize)> = seen[at..]
            .iter()
            .take_while(|p| p.phase == phase)
            .map(|p| (p.done, p.total))
            .collect();
        assert_eq!(
            steps,
            (0..=total).map(|d| (d, total)).collect::<Vec<_>>(),
            "{phase:?}"
        );
        at += steps.len();
    }
    assert_eq!(
        at,
        seen.len(),
        "reports after the last phase: {:?}",
        &seen[at..]
    );
    let row = |label: &str, stage: Stage| {
        rep.rows
            .iter()
            .find(|r| r.label == label && r.stage == stage)
            .unwrap_or_else(|| panic!("no row {label} {stage:?}"))
    };
    // The mean's own exact projections: the rigid fit recovers the pose.
    for label in ["fit, 68 points", "fit, 5 points"] {
        let t = row(label, Stage::Training);
        assert_eq!((t.estimates, t.failures), (25, 0));
        assert!(t.mae_yaw < 1e-6 && t.mae_pitch < 1e-6, "{t:?}");
        assert!(t.geodesic < 1e-6, "{t:?}");
    }
    // The regression, trained on the mean's views over ±40°, nearly reproduces them near frontal.
    for label in ["regression, 68 points", "regression, 51 points"] {
        let t = row(label, Stage::Training);
        assert!(t.mae_yaw < 1.0 && t.mae_pitch < 1.0, "{t:?}");
        assert!(
            (t.mse_yaw - t.mae_yaw.powi(2)) > -1e-12,
            "MSE >= MAE²: {t:?}"
        );
    }
    // Another face is not the mean: the rigid fit can only lose, but stays within degrees.
    let fit = row("fit, 68 points", Stage::Testing);
    assert_eq!(fit.estimates, 100);
    assert!(fit.mae_yaw > 1e-3 && fit.mae_yaw < 5.0, "{fit:?}");
    assert!(fit.mae_pitch > 1e-3 && fit.mae_pitch < 5.0, "{fit:?}");

    // Maps: one per entry, every pose seen with stride 1.
    assert_eq!(rep.heat_maps.len(), entries.len());
    for m in &rep.heat_maps {
        assert_eq!((m.yaw.len(), m.pitch.len(), m.values.len()), (5, 5, 25));
        assert!(m.values.iter().all(|v| v.is_some_and(f64::is_finite)));
    }
    let fit_map = rep
        .heat_maps
        .iter()
        .find(|m| m.label == "fit, 68 points")
        .unwrap();
    let mean_cell = fit_map.values.iter().flatten().sum::<f64>() / 25.0;
    let mean_row = 0.5 * (fit.mae_yaw + fit.mae_pitch);
    assert!(
        (mean_cell - mean_row).abs() < 1e-9,
        "{mean_cell} vs {mean_row}"
    );

    // Robustness: every condition for every entry; five points drop at most one.
    assert_eq!(rep.robustness.len(), entries.len() * 8);
    for r in &rep.robustness {
        if let Perturbation::Missing(k) = r.perturbation {
            let n = if r.entry.scheme == "five" {
                k.min(1)
            } else {
                k
            };
            assert_eq!(r.dropped, n, "{r:?}");
        }
        if r.entry.method == Method::Geometry && r.perturbation == Perturbation::Missing(5) {
            assert_eq!(r.failures, 12, "the geometric method needs all five points");
        }
    }
    let fit_noise = |f: f64| {
        rep.robustness
            .iter()
            .find(|r| r.label == "fit, 68 points" && r.perturbation == Perturbation::Noise(f))
            .unwrap()
            .mae
    };
    assert!(
        fit_noise(0.05) > fit_noise(0.0),
        "5% noise must cost something"
    );

    // Seeded: the same run gives the same numbers.
    let again = paper_protocol(&model, test, &entries, &opts, &Silent).unwrap();
    assert_eq!(
        serde_json::to_string(&rep).unwrap(),
        serde_json::to_string(&again).unwrap()
    );
}

#[test]
fn the_geometric_method_reads_yaw_off_a_level_face() {
    let shapes = population();
    let model = model(&shapes);
    // Pitch 0 only: the face axis keeps its length and the eye line stays level.
    let opts = small_options(
        AngleRange::new(-30.0, 30.0, 10.0).unwrap(),
        AngleRange::fixed(0.0),
    );
    let entries = [PaperEntry::new(Method::Geometry, "five")];
    let rep = paper_protocol(&model, &shapes[20..22], &entries, &opts, &Silent).unwrap();
    let t = &rep.rows[0];
    assert_eq!((t.stage, t.estimates, t.failures), (Stage::Training, 7, 0));
    assert!(t.mae_yaw < 1.0 && t.mae_pitch < 1.0, "{t:?}");
}

#[test]
fn bad_parameters_are_errors() {
    let shapes = population();
    let model = model(&shapes);
    let entries = [PaperEntry::new(Method::Fit, "ibug68")];
    let r = AngleRange::fixed(0.0);
    let mut opts = small_options(r, r);
    assert!(paper_protocol(&model, &[], &entries, &opts, &Silent).is_err());
    opts.stride = 0;
    assert!(paper_protocol(&model, &shapes[20..21], &entries, &opts, &Silent).is_err());
    opts.stride = 1;
    opts.iod_px = (0.0, 10.0);
    assert!(paper_protocol(&model, &shapes[20..21], &entries, &opts, &Silent).is_err());
    opts.iod_px = (60.0, 100.0);
    let wrong = vec![shapes[20][..5].to_vec()];
    assert!(paper_protocol(&model, &wrong, &entries, &opts, &Silent).is_err());
}

#[test]
fn eval_all_writes_the_report_and_its_plots() {
    let dir = std::env::temp_dir().join(format!("facepose-eval-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_facepose"))
        .args([
            "eval",
            "--protocol",
            "all",
            "--methods",
            "fit,geometry",
            "--stride",
            "200",
            "--samples",
            "5",
            "--components",
            "0",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    for needle in [
        "## The paper's protocol",
        "| fit, 68 points | training |",
        "| geometry, 5 points | testing |",
        "### Robustness",
        "![Robustness curves](paper-robustness.png)",
        "## Real faces",
        "| fit | reannotated |",
        "![Error against yaw](real-error-by-yaw.png)",
        "## Rendered benchmark: detector landmarks (issue 37)",
        "| oracle68 | fit |",
        "| mediapipe478 | mediapipe-matrix |",
    ] {
        assert!(
            report.contains(needle),
            "report lacks {needle:?}:\n{report}"
        );
    }
    assert!(
        !report.contains("| fit-shape"),
        "no basis, no fit-shape row"
    );
    for png in [
        "paper-heatmap.png",
        "paper-robustness.png",
        "real-error-by-yaw.png",
    ] {
        let bytes = std::fs::read(dir.join(png)).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{png}");
        assert!(bytes.len() > 10_000, "{png}: {} bytes", bytes.len());
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert!(
        json["paper"]["rows"]
            .as_array()
            .is_some_and(|r| r.len() == 6)
    );
    // fit on the four landmark sets, geometry on three (dlib5 names no nose tip or mouth).
    assert!(json["real"].as_array().is_some_and(|r| r.len() == 7));
    assert!(
        json["rendered"]["rows"]
            .as_array()
            .is_some_and(|r| !r.is_empty())
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
