//! Estimator speed on real faces, one core: every method over the AFLW2000-3D dev faces (every
//! |angle| <= 99°), on their three landmark sets (fitted, re-annotated, and five points from the
//! re-annotated ones), through the public entry point (`pose::estimate`).
//!
//! - Criterion: `real/{method}/{landmarks}` estimates every face once per iteration, so its
//!   time divided by the face count (the throughput line) is the mean cost per face.
//! - Per face: the cost varies from face to face (the shape fit's rounds, the regression's
//!   view bins and hidden-point patterns), so a table gives its distribution: each face is
//!   estimated 15 times after 3 warm-up runs, its cost is the median of those, and the table
//!   gives the mean, p50, p99 and maximum over the faces.
//! - The regression solves a ridge system per missing-point pattern and caches it: the last
//!   table gives, for patterns never seen before (three random points of a face left out, a
//!   new draw each time), the first estimate's cost (cold: the solve) and the second's (warm:
//!   the cache), which is what a server pays when every request brings a new pattern.
//!
//! `cargo bench --bench real_faces` (needs the shared data: FACEPOSE_DATA, else ../shared/data).

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput};
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::{Shape2, ibug68};
use facepose_files::data::{data_dir, load_aflw};
use nalgebra::Vector2;
use rand::seq::index::sample;
use rand::{SeedableRng, rngs::StdRng};

/// (landmark set, scheme, faces).
type FaceSet = (&'static str, &'static str, Vec<Shape2>);

fn face_sets() -> Vec<FaceSet> {
    let path = data_dir().join("aflw2000/aflw2000_dev.jsonl");
    let faces = load_aflw(&path).unwrap_or_else(|e| panic!("{e}"));
    let shape = |pts: &[[f64; 2]]| {
        Shape2::full(pts.iter().map(|p| Vector2::new(p[0], p[1])).collect()).unwrap()
    };
    let kept: Vec<_> = faces.iter().filter(|f| f.within_99).collect();
    let fitted: Vec<Shape2> = kept.iter().map(|f| shape(&f.landmarks_fitted)).collect();
    let reannotated: Vec<Shape2> = kept
        .iter()
        .map(|f| shape(&f.landmarks_reannotated))
        .collect();
    let five = reannotated
        .iter()
        .map(|s| s.to_five(&ibug68()).unwrap())
        .collect();
    vec![
        ("fitted", "ibug68", fitted),
        ("reannotated", "ibug68", reannotated),
        ("five", "five", five),
    ]
}

const METHODS: [Method; 5] = [
    Method::Auto,
    Method::FitShape,
    Method::Fit,
    Method::Regression,
    Method::Geometry,
];

fn supported(m: Method, scheme: &str) -> bool {
    !(m == Method::FitShape && scheme == "five")
}

fn criterion_benches(c: &mut Criterion, model: &PoseModel, sets: &[FaceSet]) {
    for (set, scheme, faces) in sets {
        let mut group = c.benchmark_group(format!("real/{set}"));
        group.throughput(Throughput::Elements(faces.len() as u64));
        group.sample_size(10);
        group.measurement_time(Duration::from_secs(3));
        for m in METHODS.into_iter().filter(|&m| supported(m, scheme)) {
            // One pass first: the regression's caches warm, as a server's are.
            for f in faces {
                let _ = estimate(model, scheme, f, m);
            }
            group.bench_function(m.to_string(), |b| {
                b.iter(|| {
                    for f in faces {
                        black_box(estimate(model, scheme, black_box(f), m).unwrap());
                    }
                })
            });
        }
        group.finish();
    }
}

/// Mean, p50, p99 and maximum of `v` (µs).
fn summary(mut v: Vec<f64>) -> [f64; 4] {
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    [
        v.iter().sum::<f64>() / v.len() as f64,
        q(0.5),
        q(0.99),
        v[v.len() - 1],
    ]
}

fn time_us(f: impl Fn()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64() * 1e6
}

fn distribution(model: &PoseModel, sets: &[FaceSet]) {
    println!("\nPer-face cost (µs, median of 15 runs of each face after 3 warm-up runs):\n");
    println!("| method | landmarks | faces | mean | p50 | p99 | max |");
    println!("|---|---|---|---|---|---|---|");
    for m in METHODS {
        for (set, scheme, faces) in sets {
            if !supported(m, scheme) {
                continue;
            }
            let per_face: Vec<f64> = faces
                .iter()
                .map(|f| {
                    let run = || {
                        black_box(estimate(model, scheme, black_box(f), m).unwrap());
                    };
                    for _ in 0..3 {
                        run();
                    }
                    let mut t: Vec<f64> = (0..15).map(|_| time_us(run)).collect();
                    t.sort_by(f64::total_cmp);
                    t[7]
                })
                .collect();
            let [mean, p50, p99, max] = summary(per_face);
            println!(
                "| {m} | {set} | {} | {mean:.1} | {p50:.1} | {p99:.1} | {max:.1} |",
                faces.len()
            );
        }
    }
}

fn new_patterns(model: &PoseModel, sets: &[FaceSet]) {
    let faces = &sets[1].2;
    let mut rng = StdRng::seed_from_u64(2011);
    let (mut cold, mut warm) = (Vec::new(), Vec::new());
    for f in faces {
        // Three random points left out: a pattern this process has not seen (the chance of a
        // repeat among C(68, 3) = 50,116 is small, and a repeat would only lower the figure).
        let mut pts: Vec<Option<[f64; 2]>> = f.points().iter().map(|p| Some([p.x, p.y])).collect();
        for i in sample(&mut rng, pts.len(), 3) {
            pts[i] = None;
        }
        let lm = Shape2::from_options(&pts).unwrap();
        let run = || {
            black_box(estimate(model, "ibug68", &lm, Method::Regression).unwrap());
        };
        cold.push(time_us(run));
        warm.push(time_us(run));
    }
    println!(
        "\nRegression, a new missing-point pattern per face (re-annotated faces, three random points \
         missing; µs):\n"
    );
    println!("| estimate | faces | mean | p50 | p99 | max |");
    println!("|---|---|---|---|---|---|");
    for (what, v) in [
        ("first (cold: solves the pattern)", cold),
        ("second (warm: cached)", warm),
    ] {
        let n = v.len();
        let [mean, p50, p99, max] = summary(v);
        println!("| {what} | {n} | {mean:.1} | {p50:.1} | {p99:.1} | {max:.1} |");
    }
}

fn main() {
    let (_, model) = default_model().unwrap();
    let sets = face_sets();
    let mut c = Criterion::default().configure_from_args();
    criterion_benches(&mut c, &model, &sets);
    c.final_summary();
    distribution(&model, &sets);
    new_patterns(&model, &sets);
}
