//! HPR speed: one pose of a 68-point shape (the bfm68 mean), the paper's method, and the
//! spherical-flipping baseline for comparison; and one pose of MediaPipe's 468-vertex canonical
//! mesh with its own triangles (what training computes at every view, where the grid of
//! `PaperHpr` pays).

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use criterion::{Criterion, criterion_group, criterion_main};
use facepose_core::geometry::EulerAngles;
use facepose_core::hpr::{HprScratch, KatzHpr, PaperHpr, Triangulation};
use facepose_files::data::{data_dir, load_canonical_mesh, load_morphable_model};
use std::hint::black_box;

fn hpr(c: &mut Criterion) {
    let mm =
        load_morphable_model(&data_dir().join("bfm68/morphable_model.json")).expect("shared data");
    let shape = mm.mean;
    let hpr = PaperHpr::from_frontal(&shape).unwrap();
    let r = EulerAngles::new(35.0, -10.0, 5.0).unwrap().to_rotation();
    let rotated: Vec<_> = shape.iter().map(|p| r * p).collect();
    let mut scratch = HprScratch::default();
    let mut out = vec![false; shape.len()];
    c.bench_function("hpr/paper/68 points/one pose", |b| {
        b.iter(|| {
            hpr.visibility_into(black_box(&rotated), &mut scratch, &mut out)
                .unwrap()
        })
    });
    let mut rotated_buf = Vec::with_capacity(68);
    c.bench_function("hpr/paper/68 points/rotate + one pose", |b| {
        b.iter(|| {
            rotated_buf.clear();
            rotated_buf.extend(shape.iter().map(|p| black_box(r) * p));
            hpr.visibility_into(&rotated_buf, &mut scratch, &mut out)
                .unwrap()
        })
    });
    let mesh = load_canonical_mesh(&data_dir().join("mediapipe/canonical_face_468.json"))
        .expect("shared data");
    let tri = Triangulation::new(&mesh.vertices, mesh.triangles.clone()).unwrap();
    let mesh_hpr = PaperHpr::new(tri);
    let mesh_rotated: Vec<_> = mesh.vertices.iter().map(|p| r * p).collect();
    let mut mesh_out = vec![false; mesh.vertices.len()];
    c.bench_function("hpr/paper/468-vertex mesh/one pose", |b| {
        b.iter(|| {
            mesh_hpr
                .visibility_into(black_box(&mesh_rotated), &mut scratch, &mut mesh_out)
                .unwrap()
        })
    });
    let katz = KatzHpr::default();
    c.bench_function("hpr/katz/68 points/one pose", |b| {
        b.iter(|| katz.visibility(black_box(&rotated)).unwrap())
    });
}

criterion_group!(benches, hpr);
criterion_main!(benches);
