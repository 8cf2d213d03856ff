//! Landmark styles on synthetic faces at large yaw: 2D-style annotations put the hidden jaw
//! points on the visible outline. `contour` style leaves those out and recovers the pose;
//! `projected` style (the default, right for 3D-style landmarks) is pulled by them.

use facepose_core::geometry::{EulerAngles, WeakPerspective, geodesic_deg};
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::Shape2;
use nalgebra::Vector2;

/// The mean shape at `a`, with each jaw point that HPR hides moved horizontally onto the
/// outline of the visible face at its height (the extreme visible point within 6 px of it, on
/// the side the face turns away from).
/// The default model, loaded once per test process.
fn model() -> &'static PoseModel {
    static MODEL: std::sync::OnceLock<PoseModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

fn two_d_style(a: EulerAngles) -> Shape2 {
    let model = model();
    let r = a.to_rotation();
    let cam = WeakPerspective::new(r, 2.0, Vector2::new(300.0, -250.0)).unwrap();
    let proj: Vec<Vector2<f64>> = model.mean.iter().map(|x| cam.project(x)).collect();
    let visible = model.visibility.lookup(&r);
    let mut out = proj.clone();
    for j in 0..17 {
        if visible[j] {
            continue;
        }
        let near = proj
            .iter()
            .zip(visible)
            .filter(|(p, v)| **v && (p.y - proj[j].y).abs() < 6.0)
            .map(|(p, _)| p.x);
        // Yaw > 0 turns the nose to image-left: the far side's outline is the leftmost point.
        let edge = if a.yaw > 0.0 {
            near.fold(f64::INFINITY, f64::min)
        } else {
            near.fold(f64::NEG_INFINITY, f64::max)
        };
        if edge.is_finite() {
            out[j].x = edge;
        }
    }
    Shape2::full(out).unwrap()
}

#[test]
fn contour_style_leaves_out_hidden_jaw_points_on_the_outline() {
    let model = model();
    for method in [Method::Fit, Method::FitShape] {
        let (mut projected, mut contour) = (0.0, 0.0);
        let poses = [(60.0, 0.0), (70.0, 10.0), (-65.0, -10.0), (-75.0, 5.0)];
        for (yaw, pitch) in poses {
            let truth = EulerAngles::new(yaw, pitch, 0.0).unwrap();
            let lm = two_d_style(truth);
            let err = |style| {
                let opts = EstimateOptions {
                    method,
                    style,
                    ..EstimateOptions::default()
                };
                let e = estimate_with(model, "ibug68", &lm, &opts).unwrap();
                geodesic_deg(&e.rotation, &truth.to_rotation())
            };
            projected += err(LandmarkStyle::Projected) / poses.len() as f64;
            contour += err(LandmarkStyle::Contour) / poses.len() as f64;
        }
        assert!(
            contour < 1.0 && contour < 0.5 * projected,
            "{method}: contour style {contour:.2} deg, projected style {projected:.2} deg"
        );
    }
}

#[test]
fn styles_agree_on_a_frontal_face() {
    let model = model();
    let truth = EulerAngles::new(5.0, -5.0, 3.0).unwrap();
    let lm = two_d_style(truth);
    let rot = |style| {
        let opts = EstimateOptions {
            method: Method::Fit,
            style,
            ..EstimateOptions::default()
        };
        estimate_with(model, "ibug68", &lm, &opts).unwrap().rotation
    };
    let d = geodesic_deg(&rot(LandmarkStyle::Projected), &rot(LandmarkStyle::Contour));
    assert!(d < 1e-9, "{d}");
}
