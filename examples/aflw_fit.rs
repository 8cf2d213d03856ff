use facepose::data::*;
use facepose::estimate::*;
use facepose::geometry::*;
use facepose::hpr::PaperHpr;
use facepose::shape::*;
fn wrap(d: f64) -> f64 { let mut d = d % 360.0; if d > 180.0 { d -= 360.0 } if d < -180.0 { d += 360.0 } d }
fn main() {
    let pop = load_population(&data_dir().join("bfm68/population_249.json")).unwrap();
    let mean = procrustes::generalized_procrustes(&pop.shapes, procrustes::GpaOptions::default()).unwrap();
    let mm = load_morphable_model(&data_dir().join("bfm68/morphable_model.json")).unwrap();
    let mut mm_mean = mm.mean.clone();
    for (k, b) in mm.shape_basis.iter().enumerate() { for (p, q) in mm_mean.iter_mut().zip(b) { *p += mm.shape_coef_mean[k] * q; } }
    for (k, b) in mm.expression_basis.iter().enumerate() { for (p, q) in mm_mean.iter_mut().zip(b) { *p += mm.expression_coef_mean[k] * q; } }
    let c = mm_mean.iter().sum::<nalgebra::Vector3<f64>>() / 68.0; for p in mm_mean.iter_mut() { *p -= c; }
    let mean = if std::env::var("MM").is_ok() { mm_mean } else { mean };
    let hpr = PaperHpr::from_frontal(&mean).unwrap();
    let map = VisibilityMap::build_default(&mean, &hpr).unwrap();
    let faces = load_aflw(&data_dir().join("aflw2000/aflw2000_dev.jsonl")).unwrap();
    let contour: Vec<usize> = (0..17).collect();
    let mut basis: Vec<Vec<nalgebra::Vector3<f64>>> = mm.shape_basis.clone(); basis.extend(mm.expression_basis.clone());
    let mut pm = mm.shape_coef_mean.clone(); pm.extend(mm.expression_coef_mean.clone());
    let c0 = mm.mean.iter().sum::<nalgebra::Vector3<f64>>() / 68.0;
    let morph = facepose::estimate::morph_fit::MorphableBasis::new(mm.mean.iter().map(|p| p - c0).collect(), basis, pm).unwrap();
    for noise in [0.003, 0.01, 0.03, 0.1] { for src in ["fitted", "reann"] {
        let (mut e, mut n) = ([0.0; 3], 0);
        let mut bins = [(0.0, 0); 3];
        let t0 = std::time::Instant::now();
        for f in faces.iter().filter(|f| f.within_99) {
            let lm = if src == "fitted" { &f.landmarks_fitted } else { &f.landmarks_reannotated };
            let s = Shape2::from_options(&lm.iter().map(|p| Some(*p)).collect::<Vec<_>>()).unwrap();
            let fit = facepose::estimate::morph_fit::fit_morphable(&morph, &s, &contour, None, facepose::estimate::morph_fit::MorphOptions { noise, ..Default::default() }).unwrap();
            let a = EulerAngles::from_rotation(&fit.camera.rotation);
            let err = [wrap(a.pitch - f.pitch).abs(), wrap(a.yaw - f.yaw).abs(), wrap(a.roll - f.roll).abs()];
            for k in 0..3 { e[k] += err[k]; } n += 1;
            let b = ((f.yaw.abs() / 30.0) as usize).min(2); bins[b].0 += (err[0]+err[1]+err[2])/3.0; bins[b].1 += 1;
        }
        let m = e.map(|v| v / n as f64);
        println!("morph noise {noise} {src:7} pitch {:.2} yaw {:.2} roll {:.2} mean {:.3} bins {:.2} {:.2} {:.2} ({:?})", m[0], m[1], m[2], (m[0]+m[1]+m[2])/3.0, bins[0].0/bins[0].1 as f64, bins[1].0/bins[1].1 as f64, bins[2].0/bins[2].1 as f64, t0.elapsed() / n);
    }}
    for (name, opts, use_map, cw) in [
        ("plain", FitOptions { robust: false, hpr_aware: false, ..Default::default() }, false, 1.0),
        ("robust", FitOptions { robust: true, hpr_aware: false, ..Default::default() }, false, 1.0),
        ("robust+hpr", FitOptions::default(), true, 1.0),
        ("robust+hpr cw0.3", FitOptions { contour_weight: 0.3, ..Default::default() }, true, 0.3),
        ("robust+hpr cw0", FitOptions { contour_weight: 0.0, ..Default::default() }, true, 0.0),
    ] {
        let _ = cw;
        for src in ["fitted", "reann"] {
            let (mut e, mut n) = ([0.0; 3], 0); let mut bias = [0.0; 3];
            for f in faces.iter().filter(|f| f.within_99) {
                let lm = if src == "fitted" { &f.landmarks_fitted } else { &f.landmarks_reannotated };
                let s = Shape2::from_options(&lm.iter().map(|p| Some(*p)).collect::<Vec<_>>()).unwrap();
                let fit = fit_rigid(&mean, &s, &contour, if use_map { Some(&map) } else { None }, opts).unwrap();
                let a = EulerAngles::from_rotation(&fit.rotation);
                bias[0] += wrap(a.pitch - f.pitch); bias[1] += wrap(a.yaw - f.yaw); bias[2] += wrap(a.roll - f.roll); e[0] += wrap(a.pitch - f.pitch).abs(); e[1] += wrap(a.yaw - f.yaw).abs(); e[2] += wrap(a.roll - f.roll).abs(); n += 1;
            }
            let m = e.map(|v| v / n as f64);
            println!("{name:20} {src:7} n={n} pitch {:.2} yaw {:.2} roll {:.2} mean {:.3} bias {:.2} {:.2} {:.2}", m[0], m[1], m[2], (m[0]+m[1]+m[2])/3.0, bias[0]/n as f64, bias[1]/n as f64, bias[2]/n as f64);
        }
    }
}
