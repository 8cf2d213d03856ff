//! MediaPipe input on synthetic faces: the served model's face mesh (MediaPipe's canonical mesh
//! in the model's frame) at known poses, projected as MediaPipe reports its landmarks (every
//! point, hidden or not: its landmarks are mesh vertices), with Gaussian landmark noise, and each
//! method's error per angle.
//!
//! - **Poses.** Drawn uniformly (seeded) over |yaw| ≤ 90°, |pitch| ≤ 60°, |roll| ≤ 45°.
//! - **Views.** Weak perspective at a scale giving an inter-ocular distance (eye centres, frontal)
//!   of 60-100 px, translated near the centre of a 450 px image; the same draws for every method
//!   and noise level.
//! - **Noise.** σ a fraction of that inter-ocular distance (as in the paper's protocol).
//! - **Measures.** Mean absolute error of yaw, pitch and roll (wrapped to ±180°), the mean
//!   geodesic error, and the failures (left out of the means).
//!
//! Pure: the model comes in, rows go out.

use nalgebra::{Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use facepose_core::error::{Error, Result};
use facepose_core::geometry::convention::wrap_deg;
use facepose_core::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
use facepose_core::model::PoseModel;
use facepose_core::model::mesh::MEDIAPIPE478;
use facepose_core::pose::{Method, estimate};
use facepose_core::shape::Shape2;

/// Parameters of the protocol.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshOptions {
    /// Faces per noise level.
    pub samples: usize,
    /// Noise levels, σ as a fraction of the inter-ocular distance.
    pub noise: Vec<f64>,
    /// Largest |yaw|, |pitch|, |roll| (degrees).
    pub max_angles: [f64; 3],
    /// Seed of the random draws.
    pub seed: u64,
}

impl Default for MeshOptions {
    fn default() -> Self {
        MeshOptions {
            samples: 1000,
            noise: vec![0.0, 0.005, 0.01],
            max_angles: [90.0, 60.0, 45.0],
            seed: 2011,
        }
    }
}

/// One method at one noise level.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshRow {
    /// The scheme the landmarks are sent in.
    pub scheme: String,
    /// The method asked for.
    pub method: Method,
    /// The method `auto` chose (the same as `method` otherwise).
    pub resolved: Method,
    /// Landmark noise, σ as a fraction of the inter-ocular distance.
    pub noise: f64,
    /// Faces estimated.
    pub faces: usize,
    /// Faces the method failed on.
    pub failed: usize,
    /// Mean absolute error of yaw, pitch, roll (degrees).
    pub mae: [f64; 3],
    /// Mean geodesic error (degrees).
    pub geodesic: f64,
}

/// The seeded draws: (pose, scale, translation, noise directions in σ units).
type Draw = (EulerAngles, f64, Vector2<f64>, Vec<Vector2<f64>>);

/// Runs `methods` on the model's `mediapipe478` scheme over the protocol's draws.
pub fn mesh_protocol(
    model: &PoseModel,
    methods: &[Method],
    opts: &MeshOptions,
) -> Result<Vec<MeshRow>> {
    let (_, ms) = model.mesh_scheme(MEDIAPIPE478).ok_or_else(|| {
        Error::param(
            "model",
            "this model has no face mesh: train it with --mesh (models/README.md)",
        )
    })?;
    let points = &ms.points;
    let a = &ms.scheme.anchors;
    let eye =
        |idx: &[usize]| idx.iter().map(|&i| points[i]).sum::<Vector3<f64>>() / idx.len() as f64;
    let iod_mm = (eye(&a.eye_right) - eye(&a.eye_left)).norm();
    let mut rng = StdRng::seed_from_u64(opts.seed);
    let unit = Normal::new(0.0, 1.0).map_err(|e| Error::param("noise", e.to_string()))?;
    let [my, mp, mr] = opts.max_angles;
    let draws: Vec<Draw> = (0..opts.samples)
        .map(|_| {
            let angles = EulerAngles::new(
                rng.random_range(-my..=my),
                rng.random_range(-mp..=mp),
                rng.random_range(-mr..=mr),
            )?;
            let scale = rng.random_range(60.0..=100.0) / iod_mm;
            let t = Vector2::new(
                rng.random_range(200.0..=250.0),
                -rng.random_range(200.0..=250.0),
            );
            let dirs = (0..points.len())
                .map(|_| Vector2::new(unit.sample(&mut rng), unit.sample(&mut rng)))
                .collect();
            Ok((angles, scale, t, dirs))
        })
        .collect::<Result<_>>()?;
    let mut rows = Vec::new();
    for &noise in &opts.noise {
        let faces: Vec<(EulerAngles, Shape2)> = draws
            .iter()
            .map(|(angles, scale, t, dirs)| {
                let cam = WeakPerspective::new(angles.to_rotation(), *scale, *t)?;
                let sigma = noise * scale * iod_mm;
                let pts = points
                    .iter()
                    .zip(dirs)
                    .map(|(x, d)| cam.project(x) + d * sigma)
                    .collect();
                Ok((*angles, Shape2::full(pts)?))
            })
            .collect::<Result<_>>()?;
        for &method in methods {
            rows.push(evaluate(model, &faces, method, noise));
        }
    }
    Ok(rows)
}

fn evaluate(
    model: &PoseModel,
    faces: &[(EulerAngles, Shape2)],
    method: Method,
    noise: f64,
) -> MeshRow {
    let (mut sum, mut geo, mut ok, mut failed) = ([0.0; 3], 0.0, 0usize, 0usize);
    let mut resolved = method;
    for (truth, shape) in faces {
        match estimate(model, MEDIAPIPE478, shape, method) {
            Ok(e) => {
                resolved = e.method;
                let got = [e.angles.yaw, e.angles.pitch, e.angles.roll];
                let want = [truth.yaw, truth.pitch, truth.roll];
                for k in 0..3 {
                    sum[k] += wrap_deg(got[k] - want[k]).abs();
                }
                geo += geodesic_deg(&e.rotation, &truth.to_rotation());
                ok += 1;
            }
            Err(_) => failed += 1,
        }
    }
    let n = ok.max(1) as f64;
    MeshRow {
        scheme: MEDIAPIPE478.into(),
        method,
        resolved,
        noise,
        faces: faces.len(),
        failed,
        mae: sum.map(|s| s / n),
        geodesic: geo / n,
    }
}

/// The rows as a Markdown table, one line per method and noise level.
pub fn mesh_markdown(rows: &[MeshRow], opts: &MeshOptions) -> String {
    let [my, mp, mr] = opts.max_angles;
    let mut s = format!(
        "MediaPipe's canonical face mesh (the served model's `mesh`, 478 points as Face \
         Landmarker gives them, every point present) at {} poses drawn uniformly over |yaw| ≤ \
         {my}°, |pitch| ≤ {mp}°, |roll| ≤ {mr}° (seed {}), inter-ocular distance 60-100 px; \
         noise σ as a fraction of the inter-ocular distance. Mean absolute error in degrees.\n\n\
         | method | noise σ | yaw | pitch | roll | mean | geodesic | failed |\n\
         |---|---|---|---|---|---|---|---|\n",
        opts.samples, opts.seed
    );
    for r in rows {
        let label = if r.method == Method::Auto {
            format!("auto ({})", r.resolved)
        } else {
            r.method.to_string()
        };
        s.push_str(&format!(
            "| {label} | {:.1}% | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {} / {} |\n",
            r.noise * 100.0,
            r.mae[0],
            r.mae[1],
            r.mae[2],
            r.mae.iter().sum::<f64>() / 3.0,
            r.geodesic,
            r.failed,
            r.faces
        ));
    }
    s
}
