//! Training speed on one core (issue targets: 249 shapes at the paper's grid, every subset,
//! ≤ 1 s; 10,000 shapes ≤ 20 s). `train/249 shapes, paper grid` is the paper's set-up on
//! ../shared/data/bfm68/population_249.json; `train/10000 shapes, wide grid` trains the default
//! grids (coarse model and five view bins) with a 40-component PCA basis on 10,000 faces drawn
//! (seeded) from the Basel morphable model's identity and expression priors. Both include the
//! generalized Procrustes mean, the ridge-parameter choice on validation faces and every subset.

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use criterion::{Criterion, criterion_group, criterion_main};
use facepose_core::model::train::{
    BasisSource, RegressionParams, TrainOptions, train_from_population,
};
use facepose_core::shape::ibug68;
use facepose_files::data::{data_dir, load_morphable_model, load_population};
use nalgebra::Vector3;
use rand::{SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, StandardNormal};
use std::hint::black_box;

fn sampled_faces(n: usize) -> Vec<Vec<Vector3<f64>>> {
    let m = load_morphable_model(&data_dir().join("bfm68/morphable_model.json")).unwrap();
    let mut rng = StdRng::seed_from_u64(10_000);
    (0..n)
        .map(|_| {
            let mut s = m.mean.clone();
            let bases = m
                .shape_basis
                .iter()
                .zip(&m.shape_coef_mean)
                .chain(m.expression_basis.iter().zip(&m.expression_coef_mean));
            for (basis, mean) in bases {
                let z: f64 = StandardNormal.sample(&mut rng);
                let c = mean + z;
                for (p, b) in s.iter_mut().zip(basis) {
                    *p += c * b;
                }
            }
            s
        })
        .collect()
}

fn training(c: &mut Criterion) {
    let scheme = ibug68();
    let pop = load_population(&data_dir().join("bfm68/population_249.json")).unwrap();
    let mut g = c.benchmark_group("train");
    g.sample_size(10);
    let paper = TrainOptions {
        regression: RegressionParams::paper(),
        ..TrainOptions::default()
    };
    g.bench_function("249 shapes, paper grid", |b| {
        b.iter(|| {
            train_from_population(&scheme, black_box(&pop.shapes), BasisSource::None, &paper)
                .unwrap()
        })
    });
    let many = sampled_faces(10_000);
    g.bench_function("10000 shapes, wide grid, 40-component basis", |b| {
        b.iter(|| {
            train_from_population(
                &scheme,
                black_box(&many),
                BasisSource::Pca(40),
                &TrainOptions::default(),
            )
            .unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, training);
criterion_main!(benches);
