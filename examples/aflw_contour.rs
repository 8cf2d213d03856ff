use facepose::data::*;
use facepose::estimate::morph_fit::*;
use facepose::estimate::*;
use facepose::geometry::*;
use facepose::shape::*;
fn wrap(d: f64) -> f64 { let mut d = d % 360.0; if d > 180.0 { d -= 360.0 } if d < -180.0 { d += 360.0 } d }
fn main() {
    let mm = load_morphable_model(&data_dir().join("bfm68/morphable_model.json")).unwrap();
    let mut basis: Vec<Vec<nalgebra::Vector3<f64>>> = mm.shape_basis.clone(); basis.extend(mm.expression_basis.clone());
    let mut pm = mm.shape_coef_mean.clone(); pm.extend(mm.expression_coef_mean.clone());
    let c0 = mm.mean.iter().sum::<nalgebra::Vector3<f64>>() / 68.0;
    let morph = MorphableBasis::new(mm.mean.iter().map(|p| p - c0).collect(), basis, pm).unwrap();
    let faces = load_aflw(&data_dir().join("aflw2000/aflw2000_dev.jsonl")).unwrap();
    let counts = [0usize, 1, 2].map(|b| faces.iter().filter(|f| f.within_99 && ((f.yaw.abs() / 30.0) as usize).min(2) == b).count());
    println!("bin counts {counts:?}");
    for use_morph in [false, true] { for tau in [1000.0, 10.0, 20.0, 30.0] { for keep_near in [true] { for src in ["fitted", "reann"] {
        let (mut e, mut n) = ([0.0; 3], 0);
        let mut bins = [(0.0, 0); 3];
        for f in faces.iter().filter(|f| f.within_99) {
            let lm = if src == "fitted" { &f.landmarks_fitted } else { &f.landmarks_reannotated };
            let mut s = Shape2::from_options(&lm.iter().map(|p| Some(*p)).collect::<Vec<_>>()).unwrap();
            let first = fit_rigid(&morph.prior_shape(), &s, &[], None, FitOptions { hpr_aware: false, ..Default::default() }).unwrap();
            let yaw = EulerAngles::from_rotation(&first.rotation).yaw;
            if yaw.abs() > tau {
                // yaw > 0: the subject's right (image-left, jaw 0..8) turns away.
                let far: Vec<usize> = if yaw > 0.0 { (0..8).collect() } else { (9..17).collect() };
                s = s.with_missing(far);
                if !keep_near { s = s.with_missing(0..17); }
            }
            let rot = if use_morph { fit_morphable(&morph, &s, &[], None, MorphOptions { noise: 0.03, ..Default::default() }).unwrap().camera.rotation }
                      else { fit_rigid(&morph.prior_shape(), &s, &[], None, FitOptions { hpr_aware: false, ..Default::default() }).unwrap().rotation };
            let a = EulerAngles::from_rotation(&rot);
            let err = [wrap(a.pitch - f.pitch).abs(), wrap(a.yaw - f.yaw).abs(), wrap(a.roll - f.roll).abs()];
            for k in 0..3 { e[k] += err[k]; } n += 1;
            let b = ((f.yaw.abs() / 30.0) as usize).min(2); bins[b].0 += (err[0]+err[1]+err[2])/3.0; bins[b].1 += 1;
        }
        let m = e.map(|v| v / n as f64);
        println!("morph {use_morph} tau {tau} {src:7} pitch {:.2} yaw {:.2} roll {:.2} mean {:.3} bins {:.2} {:.2} {:.2}", m[0], m[1], m[2], (m[0]+m[1]+m[2])/3.0, bins[0].0/bins[0].1 as f64, bins[1].0/bins[1].1 as f64, bins[2].0/bins[2].1 as f64);
    }}}}
}
