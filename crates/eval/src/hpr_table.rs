//! Scores hidden-point removal against the truth of a dense mesh over a yaw x pitch grid.
//!
//! HPR sees only points; the truth comes from the mesh's own triangles ([`MeshVisibility`]:
//! ray casting plus the back-facing rule of the surface around each point). Three rows per
//! method:
//! - `mesh468`: HPR on the mesh's vertices, scored on every vertex;
//! - `ibug68 (from 468)`: the same HPR, scored on the 68 ibug points mapped onto the mesh (a
//!   mapped point is visible when all its source vertices are);
//! - `ibug68 (68 alone)`: HPR on the 68 mapped points only, the sparse case of a 68-point model.

use nalgebra::Vector3;
use serde::Serialize;

use crate::progress::{Observer, Phase, PhaseReport};
use facepose_core::error::Result;
use facepose_core::geometry::EulerAngles;
use facepose_core::hpr::{Confusion, DepthTest, KatzHpr, MeshVisibility, PaperHpr, SurfacePoint};
use facepose_core::synth::AngleRange;

/// The methods compared.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum HprMethod {
    /// The paper's four steps (centroid depth test).
    Paper,
    /// The paper's steps with the depth test against the triangle's plane.
    PaperPlaneDepth,
    /// Katz-Tal-Basri spherical flipping with the given parameters.
    Katz {
        /// Camera distance, in radii of the shape.
        camera_distance: f64,
        /// `gamma` of the flipping radius `max ‖p - C‖ · 10^gamma`.
        gamma: f64,
    },
}

impl HprMethod {
    fn label(&self) -> String {
        match self {
            HprMethod::Paper => "paper (centroid depth)".into(),
            HprMethod::PaperPlaneDepth => "paper (plane depth)".into(),
            HprMethod::Katz {
                camera_distance,
                gamma,
            } => format!("Katz (camera {camera_distance} r, gamma {gamma})"),
        }
    }
}

/// The point sets scored (see the module docs).
pub const POINT_SETS: [&str; 3] = ["mesh468", "ibug68 (from 468)", "ibug68 (68 alone)"];

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct HprRow {
    /// The point set's name.
    pub points: &'static str,
    /// The method.
    pub method: HprMethod,
    /// Its confusion counts against the ground truth.
    pub confusion: Confusion,
    /// Accuracy per |yaw| band: [0, 30), [30, 60), [60, 90].
    pub accuracy_by_yaw: [f64; 3],
}

struct Acc {
    all: Confusion,
    bands: [Confusion; 3],
}

/// Runs every method over the grid for the three point sets. `progress` sees
/// [`Phase::HprGrid`], one step per pose; [`crate::progress::Silent`] for none.
pub fn hpr_table(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    ibug68: &[Vec<usize>],
    yaw: AngleRange,
    pitch: AngleRange,
    katz: &[KatzHpr],
    progress: &dyn Observer,
) -> Result<Vec<HprRow>> {
    let truth = MeshVisibility::new(vertices, triangles.to_vec())?.with_back_face_rule(true);
    if let Some(k) = ibug68
        .iter()
        .position(|v| v.is_empty() || v.iter().any(|&i| i >= vertices.len()))
    {
        return Err(facepose_core::Error::param(
            format!("ibug68 mapping[{k}]"),
            format!(
                "needs one or more mesh vertex indices below {}, got {:?}",
                vertices.len(),
                ibug68[k]
            ),
        ));
    }
    let mapped: Vec<SurfacePoint> = ibug68
        .iter()
        .map(|v| SurfacePoint {
            vertices: v.clone(),
        })
        .collect();
    let mapped_pts: Vec<Vector3<f64>> = ibug68
        .iter()
        .map(|v| v.iter().map(|&i| vertices[i]).sum::<Vector3<f64>>() / v.len() as f64)
        .collect();
    let mut methods = vec![HprMethod::Paper, HprMethod::PaperPlaneDepth];
    methods.extend(katz.iter().map(|k| HprMethod::Katz {
        camera_distance: k.camera_distance,
        gamma: k.gamma,
    }));
    let paper468 = PaperHpr::from_frontal(vertices)?;
    let paper68 = PaperHpr::from_frontal(&mapped_pts)?;
    let predict = |m: HprMethod, hpr: &PaperHpr, pts: &[Vector3<f64>]| -> Result<Vec<bool>> {
        match m {
            HprMethod::Paper => hpr.visibility(pts),
            HprMethod::PaperPlaneDepth => hpr
                .clone()
                .with_depth_test(DepthTest::Plane)
                .visibility(pts),
            HprMethod::Katz {
                camera_distance,
                gamma,
            } => KatzHpr {
                camera_distance,
                gamma,
            }
            .visibility(pts),
        }
    };

    let mut acc: Vec<[Acc; 3]> = methods
        .iter()
        .map(|_| {
            std::array::from_fn(|_| Acc {
                all: Confusion::default(),
                bands: [Confusion::default(); 3],
            })
        })
        .collect();
    let mut report = PhaseReport::start(progress, Phase::HprGrid, yaw.len() * pitch.len());
    for y in yaw.values() {
        let band = ((y.abs() / 30.0) as usize).min(2);
        for p in pitch.values() {
            let r = EulerAngles::new(y, p, 0.0)?.to_rotation();
            let rv: Vec<_> = vertices.iter().map(|v| r * v).collect();
            let rp: Vec<_> = mapped_pts.iter().map(|v| r * v).collect();
            let truth468 = truth.vertex_visibility(&rv)?;
            let truth68 = truth.visibility(&rv, &mapped)?;
            for (m, a) in methods.iter().zip(acc.iter_mut()) {
                let pred468 = predict(*m, &paper468, &rv)?;
                let from468: Vec<bool> = ibug68
                    .iter()
                    .map(|v| v.iter().all(|&i| pred468[i]))
                    .collect();
                let alone = predict(*m, &paper68, &rp)?;
                for (k, (pred, t)) in [
                    (&pred468, &truth468),
                    (&from468, &truth68),
                    (&alone, &truth68),
                ]
                .into_iter()
                .enumerate()
                {
                    a[k].all.add_all(pred, t);
                    a[k].bands[band].add_all(pred, t);
                }
            }
            report.step();
        }
    }
    report.finish();
    let mut rows = Vec::new();
    for (k, points) in POINT_SETS.iter().enumerate() {
        for (m, a) in methods.iter().zip(&acc) {
            rows.push(HprRow {
                points,
                method: *m,
                confusion: a[k].all,
                accuracy_by_yaw: a[k].bands.map(|b| b.accuracy()),
            });
        }
    }
    Ok(rows)
}

/// The rows as a Markdown table.
pub fn hpr_markdown(rows: &[HprRow]) -> String {
    let mut s = String::from(
        "| points | method | accuracy | precision (hidden) | recall (hidden) | acc. \\|yaw\\| < 30 | 30-60 | 60-90 | points scored |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let c = &r.confusion;
        s.push_str(&format!(
            "| {} | {} | {:.2}% | {:.2}% | {:.2}% | {:.2}% | {:.2}% | {:.2}% | {} |\n",
            r.points,
            r.method.label(),
            100.0 * c.accuracy(),
            100.0 * c.precision(),
            100.0 * c.recall(),
            100.0 * r.accuracy_by_yaw[0],
            100.0 * r.accuracy_by_yaw[1],
            100.0 * r.accuracy_by_yaw[2],
            c.total()
        ));
    }
    s
}
