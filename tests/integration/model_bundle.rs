//! Model bundles: the committed default model is valid and rebuilds byte for byte with the
//! command in models/README.md; damaged bundles fail with messages that name the problem; writing
//! never leaves a partial bundle.

use crate::common;

use std::path::PathBuf;
use std::process::Command;

use facepose_core::model::bundle::{Bundle, BundleError};
use facepose_core::model::{DEFAULT_BUNDLE, default_model};
use facepose_files::store::{StoreError, load_model, write_bundle_dir};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("facepose-bundle-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn the_default_model_is_valid_and_serves_its_schemes() {
    let (bundle, model) = default_model().unwrap();
    assert_eq!(bundle.name, "default");
    assert_eq!(model.scheme.name, "ibug68");
    for s in ["ibug68", "inner51", "five"] {
        assert!(model.subset(s).is_ok(), "{s}");
    }
    assert!(model.morph.is_some());
    // The geometric constants are in the range the paper reports (0.45 and 0.50).
    assert!((0.35..0.6).contains(&model.geometry.lf) && (0.4..0.7).contains(&model.geometry.ln));
}

#[test]
fn the_default_model_rebuilds_byte_for_byte() {
    let out = tmp("rebuild");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    // The documented command (models/README.md) names the data relative to the repo root.
    let default_place = std::env::var_os("FACEPOSE_DATA").is_none();
    let data = if default_place {
        PathBuf::from("../shared/data")
    } else {
        common::data_dir()
    };
    // The command recorded in the bundle's provenance (also in models/README.md), with the
    // data paths moved when the data lives elsewhere.
    let committed = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    let args: Vec<String> = committed
        .provenance
        .command
        .split_whitespace()
        .skip(1)
        .map(|a| match a.strip_prefix("../shared/data/") {
            Some(rest) => data.join(rest).display().to_string(),
            None => a.to_string(),
        })
        .collect();
    assert_eq!(args.first().map(String::as_str), Some("train"));
    let status = Command::new(env!("CARGO_BIN_EXE_facepose"))
        .current_dir(&root)
        .args(&args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let text = std::fs::read_to_string(out.join("model.json")).unwrap();
    std::fs::remove_dir_all(&out).ok();
    if default_place {
        assert!(
            text == DEFAULT_BUNDLE,
            "models/default/model.json differs from a rebuild: rebuild it (models/README.md)"
        );
    } else {
        // Elsewhere the recorded paths differ; every other value must match.
        let mut rebuilt = Bundle::parse(&text).unwrap();
        rebuilt
            .provenance
            .sources
            .iter_mut()
            .zip(&committed.provenance.sources)
            .for_each(|(r, c)| r.path = c.path.clone());
        rebuilt.provenance.command = committed.provenance.command.clone();
        rebuilt.checksum = rebuilt.compute_checksum().unwrap();
        assert!(
            rebuilt == committed,
            "the rebuilt default model differs from models/default"
        );
    }
}

/// The default bundle as schema 1 wrote it: no stored visibility (whose loading runs HPR), and
/// without the `dlib5` subset, MediaPipe's face mesh, the uncertainty's calibration and the
/// detector regression, which came later (with their sources and command-line options taken out
/// of the provenance).
fn as_schema_1() -> Bundle {
    let mut b = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    b.schema_version = 1;
    b.visibility = None;
    b.training.subsets.retain(|s| s != "dlib5");
    b.regressions.retain(|r| r.scheme != "dlib5");
    b.mesh = None;
    b.calibration = None;
    b.detector_regressions.clear();
    let p = &mut b.provenance;
    p.sources.retain(|s| {
        !(s.path.ends_with("canonical_face_468.json")
            || s.path.ends_with("aflw2000_dev.jsonl")
            || s.path.starts_with("tests/fixtures/rendered/"))
    });
    p.command = p
        .command
        .replace(
            " --mesh ../shared/data/mediapipe/canonical_face_468.json",
            "",
        )
        .replace(
            " --calibrate ../shared/data/aflw2000/aflw2000_dev.jsonl",
            "",
        )
        .replace(" --detector-renders tests/fixtures/rendered", "");
    p.notes = p.notes.split("; face mesh:").next().unwrap().to_string();
    b.checksum = b.compute_checksum().unwrap();
    b
}

/// The checksum of models/default/model.json as schema 1 wrote it (at dc7c445), before the
/// bundle stored its visibility. Everything else in the file but the `dlib5` subset is unchanged
/// since.
const SCHEMA_1_CHECKSUM: &str =
    "sha256:06dcd51e6d2ff9a920025ed75a66a37c3dda8c229b77faec2d525b4265a21ef4";

#[test]
fn schema_1_bundles_keep_their_checksums() {
    let b = as_schema_1();
    assert_eq!(
        b.checksum, SCHEMA_1_CHECKSUM,
        "a schema 1 bundle no longer hashes as it did when written (or the default model's \
         content changed: then update SCHEMA_1_CHECKSUM from a schema 1 build)"
    );
}

#[test]
fn bundles_of_unknown_schema_versions_say_so_before_their_fields() {
    // A newer schema may add fields: the version is what the message names.
    let mut v: serde_json::Value = serde_json::from_str(DEFAULT_BUNDLE).unwrap();
    v["schema_version"] = 3.into();
    v["a_field_of_schema_3"] = serde_json::json!([1, 2]);
    let e = Bundle::parse(&v.to_string()).unwrap_err();
    assert!(
        e.to_string()
            .contains("reads versions 1 to 2, the file is version 3: a newer build"),
        "{e}"
    );
    // An unknown field in a version this build reads is named as such.
    v["schema_version"] = 2.into();
    let e = Bundle::parse(&v.to_string()).unwrap_err();
    assert!(e.to_string().contains("a_field_of_schema_3"), "{e}");
    // Schema 1 has no visibility field.
    let mut b = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    b.schema_version = 1;
    b.checksum = b.compute_checksum().unwrap();
    let e = Bundle::parse(&b.to_json()).unwrap().load().unwrap_err();
    assert!(
        e.to_string().contains("not a field of schema version 1"),
        "{e}"
    );
}

#[test]
fn stored_visibility_is_what_hpr_computes() {
    let stored = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    assert_eq!(stored.schema_version, 2);
    assert!(stored.visibility.is_some());
    let from_stored = stored.load().unwrap();
    // Schema 1 bundles still load, with HPR over the triangulation computing the visibility.
    let schema_1 = as_schema_1();
    assert!(!schema_1.to_json().contains("\"visibility\""));
    let from_hpr = Bundle::parse(&schema_1.to_json()).unwrap().load().unwrap();
    assert_eq!(from_stored.visibility.grid(), from_hpr.visibility.grid());
    assert!(from_stored.visibility.bits() == from_hpr.visibility.bits());
    // Not a trivial map: the profile views hide some points, the frontal one none.
    let profile = from_hpr.visibility.lookup_yaw_pitch(75.0, 0.0);
    assert!(profile.iter().any(|v| !v) && profile.iter().any(|v| *v));
    assert!(
        from_hpr
            .visibility
            .lookup_yaw_pitch(0.0, 0.0)
            .iter()
            .all(|v| *v)
    );
    // The schema 1 form has every subset but dlib5, in the same order.
    assert_eq!(from_stored.subsets.len(), from_hpr.subsets.len() + 1);
    for (a, b) in from_stored.subsets.iter().zip(&from_hpr.subsets) {
        assert!(
            a.regression.bins() == b.regression.bins(),
            "{}: the training views differ",
            a.scheme.name
        );
    }
}

fn edited(f: impl FnOnce(&mut Bundle), fix_checksum: bool) -> Result<(), BundleError> {
    let mut b = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    f(&mut b);
    if fix_checksum {
        b.checksum = b.compute_checksum().unwrap();
    }
    Bundle::parse(&b.to_json())?.load().map(|_| ())
}

#[test]
fn damaged_bundles_say_what_is_wrong() {
    let e = edited(|b| b.mean[3][1] += 0.5, false).unwrap_err();
    assert!(matches!(e, BundleError::Checksum { .. }), "{e}");
    let e = edited(|b| b.schema_version = 99, true).unwrap_err();
    assert!(e.to_string().contains("schema_version"), "{e}");
    let e = edited(|b| b.format = "other".into(), true).unwrap_err();
    assert!(e.to_string().contains("format"), "{e}");
    let e = edited(
        |b| {
            b.mean.pop();
        },
        true,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("mean"), "{e}");
    let e = edited(|b| b.triangles[0] = [0, 0, 1], true).unwrap_err();
    assert!(e.to_string().starts_with("triangles"), "{e}");
    let e = edited(
        |b| {
            b.regressions[1].matrices[0].pop();
        },
        true,
    )
    .unwrap_err();
    assert!(e.to_string().contains("regressions[1].matrices[0]"), "{e}");
    let e = edited(|b| b.visibility = None, true).unwrap_err();
    assert!(e.to_string().starts_with("visibility: missing"), "{e}");
    let e = edited(
        |b| {
            b.visibility.as_mut().unwrap().map.pop();
        },
        true,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("visibility.map"), "{e}");
    let e = edited(
        |b| b.visibility.as_mut().unwrap().views[2].replace_range(0..1, "x"),
        true,
    )
    .unwrap_err();
    assert!(
        e.to_string().starts_with("visibility.views[2]: row 0"),
        "{e}"
    );
    let e = edited(|b| b.visibility.as_mut().unwrap().views.truncate(1), true).unwrap_err();
    assert!(e.to_string().contains("regression grids"), "{e}");
    let e = edited(|b| b.created = "yesterday".into(), true).unwrap_err();
    assert!(e.to_string().contains("created"), "{e}");
    let e = edited(
        |b| {
            b.shape_basis.as_mut().unwrap().components[2].pop();
        },
        true,
    )
    .unwrap_err();
    assert!(e.to_string().contains("shape_basis"), "{e}");
    let e = edited(|b| b.geometry.lf *= 1.01, true).unwrap_err();
    assert!(e.to_string().contains("geometry.lf"), "{e}");
    let e = edited(|b| b.geometry.axis_tilt = f64::NAN, true).unwrap_err();
    assert!(e.to_string().contains("geometry.axis_tilt"), "{e}");
    let e = edited(|b| b.training.regression.coarse.roll.max = 10.0, true).unwrap_err();
    assert!(e.to_string().contains("roll"), "{e}");
    // Truncated text and a wrong type name the place.
    let e = Bundle::parse(&DEFAULT_BUNDLE[..DEFAULT_BUNDLE.len() / 2]).unwrap_err();
    assert!(matches!(e, BundleError::Parse { .. }), "{e}");
    let e = Bundle::parse(&DEFAULT_BUNDLE.replacen("\"version\": \"1\"", "\"version\": 1", 1))
        .unwrap_err();
    assert!(e.to_string().contains("version"), "{e}");
}

#[test]
fn writing_is_atomic_and_refuses_to_overwrite() {
    let dir = tmp("write");
    let b = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    write_bundle_dir(&dir, &b).unwrap();
    let (loaded, _) = load_model(&dir).unwrap();
    assert_eq!(loaded, b);
    assert!(matches!(
        write_bundle_dir(&dir, &b),
        Err(StoreError::Exists { .. })
    ));
    // No temporary directories are left beside it.
    let parent = dir.parent().unwrap();
    let stem = dir.file_name().unwrap().to_string_lossy().into_owned();
    let leftovers = std::fs::read_dir(parent)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(&format!(".{stem}.tmp"))
        })
        .count();
    assert_eq!(leftovers, 0);
    assert!(matches!(
        load_model(&tmp("absent")),
        Err(StoreError::Io { .. })
    ));
    std::fs::remove_dir_all(&dir).ok();
}

/// A bundle's detector regressions read the model's own scheme (dlib's 68 in `ibug68`) or a
/// mesh scheme, with `2n + 1` weight rows: the default model's two load; one row short, or a
/// scheme the model does not serve, is refused by name; without the mesh only the own-scheme
/// one still has its points.
#[test]
fn detector_regressions_read_the_own_scheme_or_a_mesh_scheme() {
    let base = Bundle::parse(DEFAULT_BUNDLE).unwrap();
    let schemes: Vec<&str> = base
        .detector_regressions
        .iter()
        .map(|d| d.scheme.as_str())
        .collect();
    assert_eq!(schemes, ["mediapipe478", "ibug68"]);
    let model = base.load().unwrap();
    assert!(model.detector("ibug68").is_some() && model.detector("mediapipe478").is_some());
    // An edited bundle with its checksum made right again: only the regressions are wrong.
    let sealed = |mut b: Bundle| {
        b.checksum = b.compute_checksum().unwrap();
        b
    };
    let refused = |b: &Bundle| {
        let Err(e) = sealed(b.clone()).load() else {
            panic!("a bundle with a wrong detector regression loaded");
        };
        let e = e.to_string();
        assert!(e.contains("detector_regressions"), "{e}");
    };
    let mut short = base.clone();
    short.detector_regressions[1].weights.pop();
    refused(&short);
    let mut unknown = base.clone();
    unknown.detector_regressions[1].scheme = "inner51".into();
    refused(&unknown);
    let mut no_mesh = base.clone();
    no_mesh.mesh = None;
    refused(&no_mesh);
    no_mesh
        .detector_regressions
        .retain(|d| d.scheme == "ibug68");
    let model = sealed(no_mesh).load().unwrap();
    assert!(model.detector("ibug68").is_some());
}
