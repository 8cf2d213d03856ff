//! The uncertainty against AFLW2000-3D's ground truth: the 90% intervals, cross-validated by
//! face, hold the true angle for 88-92% of the faces on the landmark sets the calibration stands
//! for, and their width follows the actual error.

use crate::common;

use facepose_core::model::default_model;
use facepose_core::pose::Method;
use facepose_eval::aflw::Source;
use facepose_eval::uncertainty::{CALIBRATED_METHODS, coverage_rows, cross_validate, samples};
use facepose_files::data::load_aflw;

#[test]
fn cross_validated_intervals_cover_ninety_percent() {
    let faces = load_aflw(&common::data_file("aflw2000/aflw2000_dev.jsonl")).unwrap();
    let (_, model) = default_model().unwrap();
    let mut methods = vec![Method::Auto];
    methods.extend(CALIBRATED_METHODS);
    let labeled = samples(&model, &faces, &methods, &Source::ALL);
    let predicted = cross_validate(&labeled).unwrap();
    let rows = coverage_rows(&labeled, &predicted, &methods, &Source::ALL);
    assert!(rows.len() >= 15, "{} rows", rows.len());
    for r in &rows {
        let what = format!("{} on {}", r.method, r.source.name());
        assert_eq!(r.estimates, 491, "{what}");
        for k in 0..3 {
            let c = r.coverage[k];
            if r.source == Source::Fitted {
                // Projections of the very fit that defines the truth: conservative.
                assert!(c >= 0.95, "{what}, angle {k}: {c}");
            } else {
                assert!(
                    (0.88..=0.92).contains(&c),
                    "{what}, angle {k}: coverage {c}"
                );
            }
            assert!(
                r.spearman[k] > 0.15,
                "{what}, angle {k}: rho {}",
                r.spearman[k]
            );
        }
    }
}
