//! The accuracy-speed frontier of the shape fit (`auto` on 68 points): for each number of
//! principal components the fit moves in its first step and in its robust step, the AFLW2000-3D
//! dev MAE of `auto` on every landmark set and the time per face of `auto` on the 68-point
//! sets, one core. `five` and `dlib5` resolve `auto` to the rigid fit, so their columns do not
//! move with the components: they are there to show it.
//!
//! `cargo run --release --example shape_fit_frontier [FIT,ROBUST ...]` (needs the shared data:
//! FACEPOSE_DATA, else ../shared/data). Without arguments, a fixed list of points. The times
//! are the fastest of several passes over the faces (each pass estimates every face once), so
//! they move less with the machine's load than one pass; compare them within one run.

// A program around the library: clippy.toml's no-I/O rule is the library's.
#![allow(
    clippy::disallowed_methods,
    clippy::disallowed_macros,
    clippy::disallowed_types
)]

use std::hint::black_box;
use std::time::Instant;

use facepose_core::model::default_model;
use facepose_core::pose::{Method, estimate};
use facepose_eval::aflw::{Source, evaluate, landmarks};
use facepose_files::data::{data_dir, load_aflw};

/// The (fit, robust) component counts shown without arguments: every component (the fit
/// before issue 19), then fewer.
const POINTS: [(usize, usize); 13] = [
    (50, 50),
    (50, 14),
    (40, 40),
    (40, 14),
    (34, 22),
    (34, 14),
    (32, 22),
    (32, 14),
    (32, 10),
    (30, 14),
    (26, 14),
    (20, 14),
    (16, 10),
];

const PASSES: usize = 15;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let points: Vec<(usize, usize)> = match std::env::args().skip(1).collect::<Vec<_>>() {
        a if a.is_empty() => POINTS.to_vec(),
        a => a
            .iter()
            .map(|s| {
                let (f, r) = s.split_once(',').ok_or("FIT,ROBUST")?;
                Ok((f.parse()?, r.parse()?))
            })
            .collect::<Result<_, Box<dyn std::error::Error>>>()?,
    };
    let faces = load_aflw(&data_dir().join("aflw2000/aflw2000_dev.jsonl"))?;
    let (_, mut model) = default_model()?;
    let basis = model
        .morph
        .take()
        .ok_or("the default model has no shape basis")?;
    let k = basis.components().len();
    let default = (basis.fit_components(), basis.robust_components());
    let sets = [Source::Fitted, Source::Reannotated];
    let inputs: Vec<Vec<(&str, _)>> = sets
        .iter()
        .map(|&s| {
            faces
                .iter()
                .filter(|f| f.within_99)
                .map(|f| landmarks(f, s))
                .collect::<Result<_, _>>()
        })
        .collect::<Result<_, _>>()?;
    println!(
        "The default model's basis: {} components; the default fit moves {} in its first step \
         and {} in its robust step.\n",
        basis.components().len(),
        default.0,
        default.1
    );
    println!(
        "| components (fit, robust) | fitted MAE (pitch / yaw / roll) | reannotated MAE (pitch / \
         yaw / roll) | five MAE | dlib5 MAE | fitted µs per face | reannotated µs per face |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (fit, robust) in points {
        let (fit, robust) = (fit.min(k), robust.min(fit.min(k)));
        model.morph = Some(basis.clone().with_fit_components(fit, robust));
        let mae: Vec<_> = Source::ALL
            .iter()
            .map(|&s| evaluate(&model, &faces, Method::Auto, s))
            .collect();
        let per_face: Vec<f64> = inputs
            .iter()
            .map(|lms| {
                (0..PASSES)
                    .map(|_| {
                        let t = Instant::now();
                        for (scheme, lm) in lms {
                            black_box(estimate(&model, scheme, black_box(lm), Method::Auto).ok());
                        }
                        t.elapsed().as_secs_f64() * 1e6 / lms.len() as f64
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let three = |r: &facepose_eval::aflw::AflwRow| {
            format!(
                "{:.3} ({:.3} / {:.3} / {:.3})",
                r.mae_mean, r.mae_pitch, r.mae_yaw, r.mae_roll
            )
        };
        let mark = if (fit, robust) == default {
            " (default)"
        } else {
            ""
        };
        println!(
            "| {fit}, {robust}{mark} | {} | {} | {:.3} | {:.3} | {:.1} | {:.1} |",
            three(&mae[0]),
            three(&mae[1]),
            mae[2].mae_mean,
            mae[3].mae_mean,
            per_face[0],
            per_face[1]
        );
    }
    Ok(())
}
