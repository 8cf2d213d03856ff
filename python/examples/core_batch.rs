//! The Rust side of scripts/python-bench.sh: the batch loop of `facepose.estimate` over the
//! AFLW2000-3D dev faces, in Rust, with the core compiled as the Python extension's is (this
//! workspace's release profile): every face through `pose::estimate` once per run, as
//! crates/core/benches/real_faces.rs does. Prints, per landmark set and method, the minimum and
//! the median over the runs of the time per face (µs); the minimum is what a run takes when
//! no other process preempts it.
//!
//! `cargo run --release --example core_batch -- DATASET [RUNS]`

#![allow(clippy::disallowed_methods, clippy::disallowed_macros)]

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use facepose_core::model::default_model;
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::{Shape2, ibug68};
use facepose_files::data::load_aflw;
use nalgebra::Vector2;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: core_batch DATASET [RUNS]");
    let runs: usize = args.get(2).map_or(30, |r| r.parse().expect("RUNS"));
    let faces = load_aflw(Path::new(path)).unwrap_or_else(|e| panic!("{e}"));
    let (_, model) = default_model().unwrap();
    let shape = |pts: &[[f64; 2]]| {
        Shape2::full(pts.iter().map(|p| Vector2::new(p[0], p[1])).collect()).unwrap()
    };
    let kept: Vec<_> = faces.iter().filter(|f| f.within_99).collect();
    let fitted: Vec<Shape2> = kept.iter().map(|f| shape(&f.landmarks_fitted)).collect();
    let rean: Vec<Shape2> = kept
        .iter()
        .map(|f| shape(&f.landmarks_reannotated))
        .collect();
    let five: Vec<Shape2> = rean.iter().map(|s| s.to_five(&ibug68()).unwrap()).collect();
    for (set, scheme, faces) in [
        ("fitted", "ibug68", &fitted),
        ("reannotated", "ibug68", &rean),
        ("five", "five", &five),
    ] {
        for method in [Method::Auto, Method::Fit] {
            for f in faces.iter() {
                let _ = estimate(&model, scheme, f, method);
            }
            let mut t: Vec<f64> = (0..runs)
                .map(|_| {
                    let start = Instant::now();
                    for f in faces.iter() {
                        black_box(estimate(&model, scheme, black_box(f), method).unwrap());
                    }
                    start.elapsed().as_secs_f64() * 1e6 / faces.len() as f64
                })
                .collect();
            t.sort_by(f64::total_cmp);
            println!("{set} {method} {:.3} {:.3}", t[0], t[runs / 2]);
        }
    }
}
