use facepose::data::*;
use facepose::estimate::morph_fit::MorphableBasis;
use facepose::estimate::Method;
use facepose::eval::aflw::*;
use facepose::geometry::procrustes;
use facepose::model::*;
use facepose::shape::ibug68;
fn main() {
    let t0 = std::time::Instant::now();
    let pop = load_population(&data_dir().join("bfm68/population_249.json")).unwrap();
    let mean = procrustes::generalized_procrustes(&pop.shapes, procrustes::GpaOptions::default()).unwrap();
    let mm = load_morphable_model(&data_dir().join("bfm68/morphable_model.json")).unwrap();
    let mut basis = mm.shape_basis.clone(); basis.extend(mm.expression_basis.clone());
    let mut pm = mm.shape_coef_mean.clone(); pm.extend(mm.expression_coef_mean.clone());
    let c0 = mm.mean.iter().sum::<nalgebra::Vector3<f64>>() / 68.0;
    let morph = MorphableBasis::new(mm.mean.iter().map(|p| p - c0).collect(), basis, pm).unwrap();
    let model = train(&ibug68(), &mean, &pop.shapes[100..], Some(morph), &TrainOptions::default()).unwrap();
    eprintln!("trained in {:?}; eps {:?}", t0.elapsed(), model.subsets.iter().map(|s| s.regression.epsilon()).collect::<Vec<_>>());
    eprintln!("geometry {:?}", model.geometry);
    let faces = load_aflw(&data_dir().join("aflw2000/aflw2000_dev.jsonl")).unwrap();
    let mut rows = vec![];
    for m in [Method::Fit, Method::Regression] {
        for s in Source::ALL {
            if m == Method::FitShape && s == Source::Five { continue; }
            let t = std::time::Instant::now();
            rows.push(evaluate(&model, &faces, m, s));
            eprintln!("{m} {:?} {:?}", s, t.elapsed() / 491);
        }
    }
    println!("{}", aflw_markdown(&rows));
    // signed errors by bin for fit on reannotated
    for src in [Source::Reannotated, Source::Fitted] {
        let mut b = [[0.0f64; 4]; 3];
        for f in faces.iter().filter(|f| f.within_99) {
            let (sch, lm) = landmarks(f, src).unwrap();
            let e = facepose::estimate::estimate(&model, sch, &lm, Method::Fit).unwrap().angles;
            let k = ((f.yaw.abs() / 30.0) as usize).min(2);
            let sgn = f.yaw.signum();
            b[k][0] += e.pitch - f.pitch; b[k][1] += sgn * (e.yaw - f.yaw); b[k][2] += sgn * (e.roll - f.roll); b[k][3] += 1.0;
        }
        for k in 0..3 { println!("{src:?} bin {k}: signed pitch {:.2} yaw*sign {:.2} roll*sign {:.2} (n {})", b[k][0]/b[k][3], b[k][1]/b[k][3], b[k][2]/b[k][3], b[k][3]); }
    }
}
