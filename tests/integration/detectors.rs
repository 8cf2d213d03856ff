//! Real detectors on a real photograph: dlib's 68-point and 5-point predictors on scikit-image's
//! astronaut and on copies whose true pose change is known (tests/fixtures/detectors/, made by
//! scripts/dlib-landmarks.sh). The two predictors see the same face, so the poses from
//! `ibug68` and `dlib5` must agree; mirroring flips yaw and roll, an in-plane rotation by θ
//! moves roll by θ, scaling and cropping change nothing. And dlib's five points sent as the
//! other five-point layout (`five`) must not pass for a face.

use facepose_core::geometry::EulerAngles;
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::{Estimate, EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::Shape2;
use nalgebra::Vector2;
use serde::Deserialize;

#[derive(Deserialize)]
struct Fixture {
    faces: Vec<Face>,
}

#[derive(Deserialize)]
struct Face {
    image: String,
    ibug68: Vec<[f64; 2]>,
    dlib5: Vec<[f64; 2]>,
}

fn fixture() -> Vec<Face> {
    let text = include_str!("../fixtures/detectors/dlib_astronaut.json");
    serde_json::from_str::<Fixture>(text).unwrap().faces
}

fn model() -> &'static PoseModel {
    static MODEL: std::sync::OnceLock<PoseModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

fn pose(scheme: &str, pts: &[[f64; 2]]) -> Estimate {
    let shape = Shape2::full(pts.iter().map(|p| Vector2::new(p[0], p[1])).collect()).unwrap();
    // dlib's predictors are trained on 300-W: 2D-style landmarks.
    let opts = EstimateOptions {
        method: Method::Auto,
        camera: None,
        style: LandmarkStyle::Contour,
    };
    estimate_with(model(), scheme, &shape, &opts).unwrap()
}

fn face<'a>(faces: &'a [Face], name: &str) -> &'a Face {
    faces
        .iter()
        .find(|f| f.image.ends_with(name))
        .unwrap_or_else(|| panic!("fixture has no {name}"))
}

fn max_diff(a: EulerAngles, b: EulerAngles) -> f64 {
    [a.yaw - b.yaw, a.pitch - b.pitch, a.roll - b.roll]
        .iter()
        .fold(0.0, |m: f64, d| m.max(d.abs()))
}

#[test]
fn dlib5_and_ibug68_from_the_same_face_agree() {
    for f in fixture() {
        let full = pose("ibug68", &f.ibug68).angles;
        let five = pose("dlib5", &f.dlib5).angles;
        let d = max_diff(full, five);
        assert!(d < 6.0, "{}: ibug68 {full:?} vs dlib5 {five:?}", f.image);
    }
}

#[test]
fn dlib_points_follow_the_known_transforms() {
    let faces = fixture();
    for scheme in ["ibug68", "dlib5"] {
        let get = |name: &str| {
            let f = face(&faces, name);
            pose(
                scheme,
                if scheme == "dlib5" {
                    &f.dlib5
                } else {
                    &f.ibug68
                },
            )
            .angles
        };
        let o = get("original");
        let m = get("mirrored");
        let mirrored = EulerAngles::new(-o.yaw, o.pitch, -o.roll).unwrap();
        assert!(
            max_diff(m, mirrored) < 3.0,
            "{scheme} mirrored: {m:?} vs {o:?}"
        );
        for (name, roll_change) in [("rotated+20", -20.0), ("rotated-20", 20.0)] {
            let r = get(name);
            let want = EulerAngles::new(o.yaw, o.pitch, o.roll + roll_change).unwrap();
            assert!(
                max_diff(r, want) < 3.0,
                "{scheme} {name}: {r:?} vs {want:?}"
            );
        }
        for name in ["scaled0.6", "cropped"] {
            let r = get(name);
            assert!(max_diff(r, o) < 3.0, "{scheme} {name}: {r:?} vs {o:?}");
        }
    }
}

#[test]
fn dlib_five_points_read_as_the_other_five_point_layout_do_not_fit_a_face() {
    for f in fixture() {
        let right = pose("dlib5", &f.dlib5);
        let wrong = pose("five", &f.dlib5);
        assert!(
            wrong.residual > 5.0 * right.residual,
            "{}: residual as five {} vs as dlib5 {}",
            f.image,
            wrong.residual,
            right.residual
        );
    }
}
