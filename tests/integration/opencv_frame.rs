//! The conversion docs/API.md gives from facepose's camera frame (DESIGN.md: x right, y up, z
//! towards the viewer) to OpenCV's (x right, y down, z forward): `R_cv = diag(1, -1, -1) · R`,
//! `t_cv = (t_x, -t_y, -t_z)`, `rvec = Rodrigues(R_cv)`. A face is placed with OpenCV's
//! `rvec`/`tvec` and projected with OpenCV's pinhole formula (`projectPoints` without
//! distortion); facepose's answer, converted, must give them back. The numbers are the worked
//! example of docs/API.md.

use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::EulerAngles;
use facepose_core::model::default_model;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::Shape2;
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};

#[test]
fn facepose_pose_converts_to_opencv_rvec_and_tvec() {
    let (_, model) = default_model().unwrap();
    let k = Intrinsics {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    };
    // The worked example: yaw 30, pitch -10, roll 5 (Pose_Para), 10 mm right of the optical
    // axis, 20 mm above it, 600 mm in front of the camera.
    let angles = EulerAngles::new(30.0, -10.0, 5.0).unwrap();
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let r_cv = Rotation3::from_matrix_unchecked(flip * angles.to_rotation().matrix());
    let t_cv = Vector3::new(10.0, -20.0, 600.0);
    // OpenCV's projectPoints, no distortion: x' = X_c / Z_c, u = fx x' + cx, v = fy y' + cy.
    let pixels: Vec<Vector2<f64>> = model
        .mean
        .iter()
        .map(|x| {
            let c = r_cv * x + t_cv;
            Vector2::new(k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy)
        })
        .collect();
    let opts = EstimateOptions {
        method: Method::Fit,
        camera: Some(k),
        style: LandmarkStyle::Projected,
    };
    let e = estimate_with(&model, "ibug68", &Shape2::full(pixels).unwrap(), &opts).unwrap();
    // facepose's answer, in its own frame: the angles as placed, the face at negative z.
    assert!((e.angles.yaw - 30.0).abs() < 1e-3, "{:?}", e.angles);
    assert!((e.angles.pitch + 10.0).abs() < 1e-3, "{:?}", e.angles);
    assert!((e.angles.roll - 5.0).abs() < 1e-3, "{:?}", e.angles);
    let t = e.translation.unwrap();
    assert!((t - Vector3::new(10.0, 20.0, -600.0)).norm() < 1e-3, "{t}");
    // Converted as docs/API.md says, it is OpenCV's pose.
    let r_back = flip * e.rotation.matrix();
    assert!((r_back - r_cv.matrix()).norm() < 1e-6);
    let t_back = Vector3::new(t.x, -t.y, -t.z);
    assert!((t_back - t_cv).norm() < 1e-3);
    let rvec = Rotation3::from_matrix_unchecked(r_back).scaled_axis();
    let want = r_cv.scaled_axis();
    assert!((rvec - want).norm() < 1e-6, "{rvec} vs {want}");
    // The doc's printed rvec (rounded to 4 decimals).
    let doc = Vector3::new(-2.8466, -0.1912, 0.7526);
    assert!(
        (rvec - doc).norm() < 1e-3,
        "rvec {rvec:?}: update docs/API.md"
    );
}
