//! Real detectors on real photographs (tests/fixtures/detectors/, made by
//! scripts/detector-landmarks.sh): dlib's 68-point and 5-point predictors on scikit-image's
//! astronaut, on copies of it whose true pose change is known, and on three small faces of
//! scikit-image's LFW subset.
//!
//! The expectations do not come from facepose: two predictors that see the same face must give
//! the same pose; mirroring the image flips yaw and roll; turning the image in its plane turns the
//! rotation about the camera's axis (`R' = Rz(θ) · R`, which moves roll by θ and leaves yaw and
//! pitch alone when they are 0); scaling and cropping change nothing. And dlib's five points sent
//! as the other five-point layout (`five`) must not pass for a face.

use facepose_core::geometry::convention::rz;
use facepose_core::geometry::{EulerAngles, wrap_deg};
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::{Estimate, EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::Shape2;
use nalgebra::{Matrix3, Rotation3, Vector2};
use serde::Deserialize;

#[derive(Deserialize)]
struct Fixture<F> {
    faces: Vec<F>,
}

#[derive(Deserialize)]
struct DlibFace {
    image: String,
    ibug68: Vec<[f64; 2]>,
    dlib5: Vec<[f64; 2]>,
}

fn dlib() -> &'static [DlibFace] {
    static FACES: std::sync::OnceLock<Vec<DlibFace>> = std::sync::OnceLock::new();
    FACES.get_or_init(|| {
        let text = include_str!("../fixtures/detectors/dlib.json");
        serde_json::from_str::<Fixture<DlibFace>>(text)
            .unwrap()
            .faces
    })
}

fn model() -> &'static PoseModel {
    static MODEL: std::sync::OnceLock<PoseModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

fn pose(scheme: &str, pts: &[[f64; 2]], style: LandmarkStyle) -> Estimate {
    let shape = Shape2::full(pts.iter().map(|p| Vector2::new(p[0], p[1])).collect()).unwrap();
    let opts = EstimateOptions {
        method: Method::Auto,
        camera: None,
        style,
    };
    estimate_with(model(), scheme, &shape, &opts).unwrap()
}

/// dlib's predictors are trained on 300-W: 2D-style landmarks.
fn dlib_pose(scheme: &str, pts: &[[f64; 2]]) -> Estimate {
    pose(scheme, pts, LandmarkStyle::Contour)
}

fn by_name<'a, F>(faces: &'a [F], name: &str, image: impl Fn(&F) -> &str) -> &'a F {
    faces
        .iter()
        .find(|f| image(f) == name)
        .unwrap_or_else(|| panic!("fixture has no {name}"))
}

/// The largest difference of the three angles, degrees.
fn max_diff(a: EulerAngles, b: EulerAngles) -> f64 {
    [a.yaw - b.yaw, a.pitch - b.pitch, a.roll - b.roll]
        .iter()
        .fold(0.0, |m: f64, d| m.max(wrap_deg(*d).abs()))
}

/// What a copy of the photograph does to the true rotation.
#[derive(Clone, Copy, Debug)]
enum Change {
    /// Scaled or cropped: nothing.
    Same,
    /// Mirrored left to right: `S R S` with `S = diag(-1, 1, 1)` (yaw and roll change sign).
    Mirror,
    /// Turned in the image plane so that roll grows by this many degrees (clockwise on screen):
    /// `Rz(θ) · R`.
    Roll(f64),
}

impl Change {
    fn apply(self, r: &Rotation3<f64>) -> EulerAngles {
        let m = match self {
            Change::Same => *r.matrix(),
            Change::Mirror => {
                let s = Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, 1.0, 1.0));
                s * r.matrix() * s
            }
            Change::Roll(deg) => rz(deg) * r.matrix(),
        };
        EulerAngles::from_rotation(&Rotation3::from_matrix_unchecked(m))
    }
}

/// The astronaut's copies (scripts/detector_landmarks.py), with their change of pose: skimage
/// turns an image anticlockwise for a positive angle, so `rotated+20` moves roll by -20.
const COPIES: [(&str, Change); 7] = [
    ("astronaut/mirrored", Change::Mirror),
    ("astronaut/rotated+20", Change::Roll(-20.0)),
    ("astronaut/rotated-20", Change::Roll(20.0)),
    ("astronaut/rotated+40", Change::Roll(-40.0)),
    ("astronaut/rotated-40", Change::Roll(40.0)),
    ("astronaut/scaled0.6", Change::Same),
    ("astronaut/cropped", Change::Same),
];

/// The copies on which dlib's predictors hold: turned by 40° the face is beyond what dlib's
/// 68-point predictor follows (on `rotated-40` its points give a roll of 11° where 44° is due,
/// and its five points lie up to 30 px from the 68 points' corners), and the 25-pixel LFW faces
/// are too coarse for its five points (`lfw_subset/0`: 14° from its 68 points).
fn dlib_holds(image: &str) -> bool {
    image == "astronaut/original"
        || COPIES
            .iter()
            .any(|(name, c)| *name == image && !matches!(c, Change::Roll(d) if d.abs() > 30.0))
}

#[test]
fn dlib5_and_ibug68_from_the_same_face_agree() {
    for f in dlib().iter().filter(|f| dlib_holds(&f.image)) {
        let full = dlib_pose("ibug68", &f.ibug68).angles;
        let five = dlib_pose("dlib5", &f.dlib5).angles;
        let d = max_diff(full, five);
        assert!(d < 6.0, "{}: ibug68 {full:?} vs dlib5 {five:?}", f.image);
    }
}

#[test]
fn dlib_points_follow_the_known_transforms() {
    for scheme in ["ibug68", "dlib5"] {
        let get = |name: &str| {
            let f = by_name(dlib(), name, |f| &f.image);
            dlib_pose(
                scheme,
                if scheme == "dlib5" {
                    &f.dlib5
                } else {
                    &f.ibug68
                },
            )
        };
        let o = get("astronaut/original").rotation;
        for (name, change) in COPIES.iter().filter(|(name, _)| dlib_holds(name)) {
            let got = get(name).angles;
            let want = change.apply(&o);
            assert!(
                max_diff(got, want) < 3.0,
                "{scheme} {name}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn dlib_five_points_read_as_the_other_five_point_layout_do_not_fit_a_face() {
    for f in dlib() {
        let right = dlib_pose("dlib5", &f.dlib5);
        let wrong = dlib_pose("five", &f.dlib5);
        assert!(
            wrong.residual > 5.0 * right.residual,
            "{}: residual as five {} vs as dlib5 {}",
            f.image,
            wrong.residual,
            right.residual
        );
    }
}
