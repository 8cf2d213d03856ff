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
    // Per-group mean displacement between reannotated and fitted, in units of IOD, at yaw bins
    let groups: [(&str, Vec<usize>); 6] = [("jaw", (0..17).collect()), ("brows", (17..27).collect()), ("nose", (27..36).collect()), ("eyes", (36..48).collect()), ("mouth", (48..68).collect()), ("all", (0..68).collect())];
    for (name, g) in &groups {
        let mut d = nalgebra::Vector2::zeros(); let mut n = 0.0; let mut rms = 0.0;
        for f in faces.iter().filter(|f| f.within_99 && f.yaw.abs() < 30.0) {
            let iod = ((f.landmarks_fitted[36][0]-f.landmarks_fitted[45][0]).powi(2) + (f.landmarks_fitted[36][1]-f.landmarks_fitted[45][1]).powi(2)).sqrt();
            for &i in g { let dd = nalgebra::Vector2::new(f.landmarks_reannotated[i][0]-f.landmarks_fitted[i][0], f.landmarks_reannotated[i][1]-f.landmarks_fitted[i][1]) / iod; d += dd; rms += dd.norm_squared(); n += 1.0; }
        }
        println!("{name:6} mean reann-fitted (IOD units, image x,y): {:.3} {:.3}  rms {:.3}", d.x/n, d.y/n, (rms/n).sqrt());
    }
    for (name, subset) in [("all68", (0..68).collect::<Vec<usize>>()), ("inner51", (17..68).collect()), ("no-mouth", (0..48).collect()), ("eyes+nose+brows", (17..48).collect())] {
        for src in ["fitted", "reann"] {
            let (mut e, mut n) = ([0.0; 3], 0); let mut bias = 0.0;
            for f in faces.iter().filter(|f| f.within_99) {
                let lm = if src == "fitted" { &f.landmarks_fitted } else { &f.landmarks_reannotated };
                let s = Shape2::from_options(&lm.iter().enumerate().map(|(i, p)| subset.contains(&i).then_some(*p)).collect::<Vec<_>>()).unwrap();
                let rot = fit_rigid(&morph.prior_shape(), &s, &[], None, FitOptions { hpr_aware: false, ..Default::default() }).unwrap().rotation;
                let a = EulerAngles::from_rotation(&rot);
                let err = [wrap(a.pitch - f.pitch).abs(), wrap(a.yaw - f.yaw).abs(), wrap(a.roll - f.roll).abs()];
                bias += wrap(a.pitch - f.pitch);
                for k in 0..3 { e[k] += err[k]; } n += 1;
            }
            let m = e.map(|v| v / n as f64);
            println!("{name:16} {src:7} pitch {:.2} yaw {:.2} roll {:.2} mean {:.3} pitch bias {:.2}", m[0], m[1], m[2], (m[0]+m[1]+m[2])/3.0, bias / n as f64);
        }
    }
}
