//! Estimator speed on one core: one face of 68 points (the default model's mean projected at a
//! known pose with 1% landmark noise). `estimator/*` times each method's own computation;
//! `estimate/*` the public entry point, which adds per-point visibility, the residual and the
//! conversion to angles.

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use criterion::{Criterion, criterion_group, criterion_main};
use facepose_core::estimate::morph_fit::{MorphOptions, fit_morphable};
use facepose_core::estimate::{FitOptions, fit_rigid};
use facepose_core::geometry::{EulerAngles, WeakPerspective};
use facepose_core::model::default_model;
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::{Shape2, ibug68};
use nalgebra::Vector2;
use rand::{SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use std::hint::black_box;

fn face() -> Shape2 {
    let (_, model) = default_model().unwrap();
    let cam = WeakPerspective::new(
        EulerAngles::new(25.0, -10.0, 5.0).unwrap().to_rotation(),
        1.8,
        Vector2::new(225.0, -225.0),
    )
    .unwrap();
    let mut rng = StdRng::seed_from_u64(1);
    let noise = Normal::new(0.0, 1.2).unwrap();
    Shape2::full(
        model
            .mean
            .iter()
            .map(|x| cam.project(x) + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)))
            .collect(),
    )
    .unwrap()
}

fn estimators(c: &mut Criterion) {
    let (_, model) = default_model().unwrap();
    let lm = face();
    let five = lm.to_five(&ibug68()).unwrap();
    let rigid = FitOptions::default();
    c.bench_function("estimator/fit (rigid)/68 points", |b| {
        b.iter(|| fit_rigid(black_box(&model.mean), black_box(&lm), &[], None, rigid).unwrap())
    });
    let basis = model.morph.as_ref().unwrap();
    c.bench_function("estimator/fit-shape/68 points", |b| {
        b.iter(|| fit_morphable(basis, black_box(&lm), &[], None, MorphOptions::default()).unwrap())
    });
    let subset = model.subset("ibug68").unwrap();
    let hidden = |yaw: f64, pitch: f64, out: &mut [bool]| {
        subset.map.hidden_into(
            &model.scheme,
            model.visibility.lookup_yaw_pitch(yaw, pitch),
            out,
        )
    };
    // Warm the per-pattern cache (the HPR second pass), as a service is after its first query.
    let _ = subset.regression.estimate(&lm, &hidden);
    c.bench_function("estimator/regression/68 points", |b| {
        b.iter(|| subset.regression.estimate(black_box(&lm), &hidden).unwrap())
    });
    for m in [
        Method::Fit,
        Method::FitShape,
        Method::Regression,
        Method::Geometry,
        Method::Auto,
    ] {
        let _ = estimate(&model, "ibug68", &lm, m);
        c.bench_function(&format!("estimate/{m}/68 points"), |b| {
            b.iter(|| estimate(&model, "ibug68", black_box(&lm), m).unwrap())
        });
    }
    for m in [Method::Fit, Method::Regression, Method::Geometry] {
        let _ = estimate(&model, "five", &five, m);
        c.bench_function(&format!("estimate/{m}/five"), |b| {
            b.iter(|| estimate(&model, "five", black_box(&five), m).unwrap())
        });
    }
}

criterion_group!(benches, estimators);
criterion_main!(benches);
