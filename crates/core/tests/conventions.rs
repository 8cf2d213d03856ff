//! facepose's conventions against the tools that define them (issue 39), from the fixtures that
//! scripts/convention-fixtures.sh makes with those tools (tests/fixtures/conventions/): scipy's
//! Euler angles and quaternions, OpenCV's `solvePnP` / `Rodrigues` / `projectPoints`, and
//! MediaPipe's own face-geometry calculator, on synthetic faces and on the detector fixtures'
//! real landmarks. No Python runs here.
//!
//! `cargo test -p facepose-core --locked --test conventions -- --nocapture` prints every figure.

// The figures are this test's report (as the benches print theirs): the core itself prints
// nothing.
#![allow(clippy::disallowed_macros)]

use std::sync::OnceLock;

use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::convention::camera::nearest_rotation;
use facepose_core::geometry::convention::peers::MEDIAPIPE_CAMERA;
use facepose_core::geometry::convention::{
    Axes, CameraPose, ConventionAnswer, ConventionRequest, EulerSpec, ImageSize, Matrices,
    MeshFrame, ObjectFrame, Order, Placement, PoseInput, Refit, Units, answer, image_size,
};
use facepose_core::geometry::{geodesic_deg, procrustes::Similarity3};
use facepose_core::model::{PoseModel, default_model};
use facepose_core::pose::{Estimate, EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::Shape2;
use nalgebra::{Matrix3, Matrix4, Rotation3, Vector2, Vector3};
use serde_json::Value;

const SCIPY: &str = include_str!("../../../tests/fixtures/conventions/scipy.json");
const OPENCV: &str = include_str!("../../../tests/fixtures/conventions/opencv.json");
const MEDIAPIPE: &str = include_str!("../../../tests/fixtures/conventions/mediapipe.json");
const MP_DETECTOR: &str = include_str!("../../../tests/fixtures/detectors/mediapipe.json");
const DLIB: &str = include_str!("../../../tests/fixtures/detectors/dlib.json");

fn model() -> &'static PoseModel {
    static MODEL: OnceLock<PoseModel> = OnceLock::new();
    MODEL.get_or_init(|| default_model().unwrap().1)
}

fn json(text: &str) -> Value {
    serde_json::from_str(text).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

fn vec3(v: &Value) -> Vector3<f64> {
    Vector3::new(f(&v[0]), f(&v[1]), f(&v[2]))
}

fn mat3(v: &Value) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| f(&v[i][j]))
}

fn mat4(v: &Value) -> Matrix4<f64> {
    Matrix4::from_fn(|i, j| f(&v[i][j]))
}

fn points(v: &Value, sx: f64, sy: f64, n: usize) -> Vec<Vector2<f64>> {
    v.as_array().unwrap()[..n]
        .iter()
        .map(|p| Vector2::new(f(&p[0]) * sx, f(&p[1]) * sy))
        .collect()
}

/// The angle in degrees between the rotation parts of two matrices (each made orthonormal).
fn angle_between(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    geodesic_deg(&nearest_rotation(a), &nearest_rotation(b))
}

/// A rotation from a Rodrigues vector.
fn rodrigues(v: Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(v).into_inner()
}

fn estimate(scheme: &str, px: Vec<Vector2<f64>>, camera: Option<Intrinsics>) -> Estimate {
    let opts = EstimateOptions {
        method: Method::Fit,
        camera,
        style: LandmarkStyle::Projected,
    };
    estimate_with(model(), scheme, &Shape2::full(px).unwrap(), &opts).unwrap()
}

/// What the wiring passes as [`PoseInput::refit`]: the same estimate under another camera.
fn refitter(
    scheme: &'static str,
    px: Vec<Vector2<f64>>,
) -> impl Fn(&Intrinsics) -> Option<CameraPose> {
    move |k: &Intrinsics| {
        let e = estimate(scheme, px.clone(), Some(*k));
        Some(CameraPose {
            rotation: e.rotation,
            translation: e.translation?,
        })
    }
}

/// The estimate's placement: perspective with intrinsics, else the weak fit at its rotation.
fn placement(
    e: &Estimate,
    shape: &[Vector3<f64>],
    px: &[Vector2<f64>],
    k: Option<Intrinsics>,
) -> Placement {
    match (e.translation, k) {
        (Some(t), Some(k)) => Placement::Perspective {
            translation: t,
            camera: k,
        },
        _ => Placement::fit_weak(shape, &Shape2::full(px.to_vec()).unwrap(), &e.rotation).unwrap(),
    }
}

fn mesh_frame() -> MeshFrame {
    let (mesh, _) = model().mesh_scheme("mediapipe468").unwrap();
    MeshFrame::of_served_mesh(&mesh.source().vertices).unwrap()
}

// ---------------------------------------------------------------------------------------------
// scipy: Euler angles in every order, quaternions.

/// Every order, intrinsic and extrinsic, against scipy's `as_euler` on 24 random rotations, the
/// identity and 16 rotations at or within 1e-7° of gimbal lock: the same angles to 1e-9 rad
/// wherever neither side is at the lock; at the lock the same matrix and, as scipy, the third
/// angle 0. Quaternions: scipy's `as_quat(canonical=True)` to 1e-12.
#[test]
fn euler_angles_and_quaternions_agree_with_scipy() {
    let doc = json(SCIPY);
    let (mut same, mut locked, mut worst) = (0, 0, 0.0f64);
    for rot in doc["rotations"].as_array().unwrap() {
        let m = mat3(&rot["matrix"]);
        let r = nearest_rotation(&m);
        let q = facepose_core::geometry::convention::request::quaternion(&r);
        let want = &rot["quaternion_wxyz"];
        let got = [q.w, q.x, q.y, q.z];
        if got[0] > 1e-9 {
            for k in 0..4 {
                assert!((got[k] - f(&want[k])).abs() < 1e-12, "{got:?} vs {want}");
            }
        }
        for (seq, e) in rot["euler_radians"].as_object().unwrap() {
            let (order, kind) = Order::parse(seq).unwrap();
            let spec = EulerSpec {
                order,
                kind,
                units: Units::Radians,
                axes: Axes::FACEPOSE,
                matrices: Matrices::Standard,
            };
            let a = facepose_core::geometry::convention::request::euler(&spec, &r);
            let scipy: Vec<f64> = e["angles"].as_array().unwrap().iter().map(f).collect();
            let scipy_lock = e["gimbal_lock"].as_bool().unwrap();
            // Both rebuild the matrix (near the lock to 1e-6: the angles are ill-conditioned
            // there and the fixture's matrix is rounded to 1e-15).
            let rebuilt = spec.rotation(a.angles);
            let tol = if a.near_gimbal_lock { 1e-6 } else { 1e-9 };
            let err = (rebuilt - r.matrix()).abs().max();
            assert!(err < tol, "{seq}: {err}");
            let theirs = spec.rotation([scipy[0], scipy[1], scipy[2]]);
            assert!(
                (theirs - r.matrix()).abs().max() < 1e-6,
                "{seq} {scipy:?} {:?} {}",
                a.angles,
                (theirs - r.matrix()).abs().max()
            );
            if scipy_lock || a.near_gimbal_lock {
                locked += 1;
                if scipy_lock {
                    assert_eq!(scipy[2].abs(), 0.0, "{seq}");
                }
                // Exactly at the lock both set the third angle to 0 and agree.
                if a.angles[2] == 0.0 {
                    let d =
                        facepose_core::geometry::wrap_deg((a.angles[0] - scipy[0]).to_degrees());
                    assert!(d.abs() < 1e-4, "{seq} {:?} vs {scipy:?}", a.angles);
                }
                continue;
            }
            for k in 0..3 {
                let d = facepose_core::geometry::wrap_deg((a.angles[k] - scipy[k]).to_degrees());
                worst = worst.max(d.abs().to_radians());
                assert!(
                    d.abs().to_radians() < 1e-9,
                    "{seq}: {:?} vs {scipy:?}",
                    a.angles
                );
            }
            same += 1;
        }
    }
    eprintln!(
        "scipy: {same} (rotation, order) pairs agree to {worst:.1e} rad; {locked} at or near gimbal lock agree in the matrix"
    );
    assert!(same >= 24 * 25);
}

// ---------------------------------------------------------------------------------------------
// OpenCV.

fn opencv_answer(
    e: &Estimate,
    p: Placement,
    size: ImageSize,
    frame: ObjectFrame,
    refit: Option<Refit<'_>>,
) -> (Vector3<f64>, Vector3<f64>, Matrix3<f64>) {
    let out = answer(
        &[ConventionRequest::OpenCv(frame)],
        &PoseInput {
            rotation: e.rotation,
            placement: Some(p),
            image_size: Some(size),
            orientation: None,
            mesh: None,
            refit,
        },
    )
    .unwrap();
    let ConventionAnswer::OpenCv(a) = &out.answers[0] else {
        panic!()
    };
    let k = Matrix3::from_fn(|i, j| a.camera_matrix[i][j]);
    (Vector3::from(a.rvec), Vector3::from(a.tvec), k)
}

/// `cv2.projectPoints` without distortion, written out; checked against OpenCV's own output
/// through the fixtures' reprojection residuals.
fn project_points(
    obj: &[[f64; 3]],
    rvec: Vector3<f64>,
    tvec: Vector3<f64>,
    k: &Matrix3<f64>,
) -> Vec<Vector2<f64>> {
    let r = rodrigues(rvec);
    obj.iter()
        .map(|x| {
            let c = r * Vector3::from(*x) + tvec;
            Vector2::new(
                k[(0, 0)] * c.x / c.z + k[(0, 2)],
                k[(1, 1)] * c.y / c.z + k[(1, 2)],
            )
        })
        .collect()
}

fn rms(a: &[Vector2<f64>], b: &[Vector2<f64>]) -> f64 {
    (a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm_squared())
        .sum::<f64>()
        / a.len() as f64)
        .sqrt()
}

/// Synthetic faces (the model's mean at known poses before a known camera): with the camera's
/// intrinsics facepose's `opencv` is solvePnP's answer (to 1e-4° and 1e-3 mm), in both object
/// frames; `projectPoints` with it gives the landmarks back. Without intrinsics (the assumed
/// camera, fx = width) it is the weak fit carried into that camera: measured against solvePnP
/// with the same assumed camera.
#[test]
fn opencv_rvec_tvec_are_solvepnps() {
    let doc = json(OPENCV);
    let mean = &model().mean;
    let obj_cv = ObjectFrame::OpenCv.object_points(mean);
    let obj_model = ObjectFrame::Model.object_points(mean);
    let (mut worst_assumed_deg, mut worst_assumed_rel_t) = (0.0f64, 0.0f64);
    let (mut worst_refit, mut worst_refit_mm) = (0.0f64, 0.0f64);
    for face in doc["synthetic"].as_array().unwrap() {
        let c = &face["camera"];
        let k = Intrinsics {
            fx: f(&c[0]),
            fy: f(&c[1]),
            cx: f(&c[2]),
            cy: f(&c[3]),
        };
        let size = image_size(f(&face["image_size"][0]), f(&face["image_size"][1])).unwrap();
        let px = points(&face["landmarks"], 1.0, 1.0, 68);
        let e = estimate("ibug68", px.clone(), Some(k));
        let p = placement(&e, mean, &px, Some(k));
        for (frame, key, obj) in [
            (ObjectFrame::OpenCv, "solvepnp", &obj_cv),
            (ObjectFrame::Model, "solvepnp_model_frame", &obj_model),
        ] {
            let (rvec, tvec, kk) = opencv_answer(&e, p, size, frame, None);
            let want = &face[key];
            let d = angle_between(&rodrigues(rvec), &rodrigues(vec3(&want["rvec"])));
            let dt = (tvec - vec3(&want["tvec"])).norm();
            assert!(
                d < 1e-4 && dt < 1e-3,
                "{:?} {key}: {d}° {dt} mm",
                face["pose_para"]
            );
            let back = rms(&project_points(obj, rvec, tvec, &kk), &px);
            assert!(back < 1e-3, "{back} px");
        }
        // No intrinsics: the assumed camera.
        let e = estimate("ibug68", px.clone(), None);
        let p = placement(&e, mean, &px, None);
        let want = &face["solvepnp_assumed_camera"];
        let wt = vec3(&want["tvec"]);
        // Refitted under the assumed camera: solvePnP's answer.
        let refit = refitter("ibug68", px.clone());
        let (rvec, tvec, _) = opencv_answer(&e, p, size, ObjectFrame::OpenCv, Some(&refit));
        let d_refit = angle_between(&rodrigues(rvec), &rodrigues(vec3(&want["rvec"])));
        let dt_refit = (tvec - wt).norm();
        worst_refit = worst_refit.max(d_refit);
        worst_refit_mm = worst_refit_mm.max(dt_refit);
        // Carried over from the weak fit.
        let (rvec, tvec, kk) = opencv_answer(&e, p, size, ObjectFrame::OpenCv, None);
        let d = angle_between(&rodrigues(rvec), &rodrigues(vec3(&want["rvec"])));
        let rel = (tvec - wt).norm() / wt.norm();
        let back = rms(&project_points(&obj_cv, rvec, tvec, &kk), &px);
        eprintln!(
            "opencv synthetic {:?} assumed camera: refitted {d_refit:.1e}° {dt_refit:.1e} mm from solvePnP; carried over {d:.2}° and {:.1} mm ({:.1}%), projectPoints {back:.2} px (solvePnP's {:.2} px)",
            face["pose_para"],
            (tvec - wt).norm(),
            rel * 100.0,
            f(&want["rms_px"])
        );
        worst_assumed_deg = worst_assumed_deg.max(d);
        worst_assumed_rel_t = worst_assumed_rel_t.max(rel);
    }
    eprintln!(
        "opencv synthetic, assumed camera: refitted worst {worst_refit:.2}° {worst_refit_mm:.1} mm; carried over worst {worst_assumed_deg:.2}°, tvec {:.1}%",
        worst_assumed_rel_t * 100.0
    );
    assert!(worst_refit < BOUND_SYNTH_REFIT_DEG && worst_refit_mm < BOUND_SYNTH_REFIT_MM);
    assert!(
        worst_assumed_deg < BOUND_SYNTH_ASSUMED_DEG,
        "{worst_assumed_deg}"
    );
    assert!(
        worst_assumed_rel_t < BOUND_SYNTH_ASSUMED_REL_T,
        "{worst_assumed_rel_t}"
    );
}

/// Measured bounds: the largest of the run with a margin of about a third (the test's output
/// prints every figure). "Carried over": no refit, the weak fit placed in the assumed camera
/// through its view; "refitted": `PoseInput::refit` given, the perspective fit redone in that
/// camera (on the synthetic faces 3 of 5 agree with solvePnP to 1e-7°, 2 by 0.15-0.23°: two
/// least-squares fits of the same cost stopping apart; on the real ones projectPoints' residual
/// is within 0.6% of solvePnP's optimum).
const BOUND_SYNTH_ASSUMED_DEG: f64 = 2.1;
const BOUND_SYNTH_REFIT_DEG: f64 = 0.3;
const BOUND_SYNTH_REFIT_MM: f64 = 2.0;
const BOUND_SYNTH_ASSUMED_REL_T: f64 = 0.075;
const BOUND_REAL_ASSUMED_DEG: f64 = 7.5;
const BOUND_REAL_REFIT_DEG: f64 = 0.5;
const BOUND_REAL_REFIT_EXCESS: f64 = 0.01;

/// The real dlib landmarks with the assumed camera: facepose's `opencv` against solvePnP's on
/// the same points and camera, and `projectPoints` with facepose's rvec/tvec against the
/// landmarks, compared with the fit's own residual in pixels.
#[test]
fn opencv_on_real_landmarks() {
    let doc = json(OPENCV);
    let dlib = json(DLIB);
    let mean = &model().mean;
    let obj_cv = ObjectFrame::OpenCv.object_points(mean);
    let (mut worst, mut worst_refit, mut worst_excess) = (0.0f64, 0.0f64, 0.0f64);
    for (face, d) in doc["real"]["faces"]
        .as_array()
        .unwrap()
        .iter()
        .zip(dlib["faces"].as_array().unwrap())
    {
        assert_eq!(face["image"], d["image"]);
        let size = image_size(f(&face["image_size"][0]), f(&face["image_size"][1])).unwrap();
        let px = points(&d["ibug68"], 1.0, 1.0, 68);
        let e = estimate("ibug68", px.clone(), None);
        let p = placement(&e, mean, &px, None);
        let want = &face["solvepnp_assumed_camera"];
        let wt = vec3(&want["tvec"]);
        let refit = refitter("ibug68", px.clone());
        let (rvec, tvec, kk) = opencv_answer(&e, p, size, ObjectFrame::OpenCv, Some(&refit));
        let d_refit = angle_between(&rodrigues(rvec), &rodrigues(vec3(&want["rvec"])));
        let back_refit = rms(&project_points(&obj_cv, rvec, tvec, &kk), &px);
        let dt_refit = (tvec - wt).norm();
        worst_refit = worst_refit.max(d_refit);
        worst_excess = worst_excess.max(back_refit / f(&want["rms_px"]) - 1.0);
        let (rvec, tvec, kk) = opencv_answer(&e, p, size, ObjectFrame::OpenCv, None);
        let deg = angle_between(&rodrigues(rvec), &rodrigues(vec3(&want["rvec"])));
        let back = rms(&project_points(&obj_cv, rvec, tvec, &kk), &px);
        eprintln!(
            "opencv real {:22} refitted: {d_refit:5.2}° {dt_refit:5.1} mm from solvePnP, projectPoints {back_refit:5.2} px",
            face["image"].as_str().unwrap()
        );
        let Placement::Weak { scale, translation } = p else {
            panic!()
        };
        let weak_rms = rms(
            &mean
                .iter()
                .map(|x| {
                    let q = scale * (e.rotation * x).xy() + translation;
                    Vector2::new(q.x, -q.y)
                })
                .collect::<Vec<_>>(),
            &px,
        );
        eprintln!(
            "opencv real {:22} carried: {deg:5.2}° and {:6.1} mm ({:4.1}%) from solvePnP; projectPoints {back:5.2} px, weak fit {weak_rms:5.2} px, solvePnP {:5.2} px",
            face["image"].as_str().unwrap(),
            (tvec - wt).norm(),
            (tvec - wt).norm() / wt.norm() * 100.0,
            f(&want["rms_px"])
        );
        worst = worst.max(deg);
    }
    eprintln!(
        "opencv real, assumed camera: refitted worst {worst_refit:.2}°, projectPoints at most {:.1}% above solvePnP's residual; carried over worst {worst:.2}°",
        worst_excess * 100.0
    );
    assert!(worst < BOUND_REAL_ASSUMED_DEG);
    assert!(worst_refit < BOUND_REAL_REFIT_DEG && worst_excess < BOUND_REAL_REFIT_EXCESS);
}

// ---------------------------------------------------------------------------------------------
// MediaPipe.

fn mediapipe_answer(
    e: &Estimate,
    p: Placement,
    size: ImageSize,
    refit: Option<Refit<'_>>,
) -> (Matrix4<f64>, [f64; 16]) {
    let frame = mesh_frame();
    let out = answer(
        &[ConventionRequest::MediaPipe],
        &PoseInput {
            rotation: e.rotation,
            placement: Some(p),
            image_size: Some(size),
            orientation: None,
            mesh: Some(&frame),
            refit,
        },
    )
    .unwrap();
    let ConventionAnswer::MediaPipe(a) = &out.answers[0] else {
        panic!()
    };
    (Matrix4::from_fn(|i, j| a.matrix[i][j]), a.data)
}

fn split(m: &Matrix4<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    (
        m.fixed_view::<3, 3>(0, 0).into_owned(),
        m.fixed_view::<3, 1>(0, 3).into_owned(),
    )
}

/// The mesh frame is a similarity close to the identity (the canonical face is frontal and in
/// mm), found exactly from the served mesh.
#[test]
fn the_served_mesh_gives_its_canonical_frame() {
    let MeshFrame(Similarity3 {
        scale,
        rotation,
        translation,
    }) = mesh_frame();
    eprintln!(
        "mesh frame: scale {scale:.4}, rotation {:.2}°, translation {translation:?} mm",
        rotation.angle().to_degrees()
    );
    assert!((scale - 1.0).abs() < 0.2 && rotation.angle().to_degrees() < 10.0);
}

/// Synthetic faces: MediaPipe's canonical mesh at known poses in MediaPipe's virtual camera.
/// With that camera's intrinsics facepose's `mediapipe` matrix is the true one (to 1e-3° and
/// 1e-3 cm), and so MediaPipe's (which is within 0.1° of the truth, given Face Mesh-like z);
/// without intrinsics, as a web app calls it, within the bounds below. The `data` layout is
/// column-major.
#[test]
fn mediapipe_matrix_is_mediapipes_on_synthetic_faces() {
    let doc = json(MEDIAPIPE);
    let (_, ms) = model().mesh_scheme("mediapipe468").unwrap();
    let (mut worst_deg, mut worst_cm) = (0.0f64, 0.0f64);
    let (mut worst_refit, mut worst_refit_cm) = (0.0f64, 0.0f64);
    for face in doc["synthetic"].as_array().unwrap() {
        let (w, h) = (f(&face["image_size"][0]), f(&face["image_size"][1]));
        let size = image_size(w, h).unwrap();
        let px = points(&face["landmarks"], w, h, 468);
        let truth = mat4(&face["true_matrix"]);
        let theirs = mat4(&face["mediapipe_matrix"]);
        let (tr, tt) = split(&truth);
        let (mr, mt) = split(&theirs);
        // With MediaPipe's camera as intrinsics: exact.
        let k = MEDIAPIPE_CAMERA.intrinsics(w, h);
        let e = estimate("mediapipe468", px.clone(), Some(k));
        let (m, data) = mediapipe_answer(&e, placement(&e, &ms.points, &px, Some(k)), size, None);
        let (r, t) = split(&m);
        let (d_true, dt_true) = (angle_between(&r, &tr), (t - tt).norm());
        assert!(
            d_true < 1e-3 && dt_true < 1e-3,
            "{:?}: {d_true}° {dt_true} cm",
            face["pose_para"]
        );
        assert_eq!(data[12..15], [m[(0, 3)], m[(1, 3)], m[(2, 3)]]);
        assert_eq!(data[1], m[(1, 0)]);
        // As a web app calls it: no intrinsics.
        let e = estimate("mediapipe468", px.clone(), None);
        let refit = refitter("mediapipe468", px.clone());
        let (m, _) = mediapipe_answer(&e, placement(&e, &ms.points, &px, None), size, Some(&refit));
        let (r, t) = split(&m);
        let (d_refit, dt_refit) = (angle_between(&r, &mr), (t - mt).norm());
        worst_refit = worst_refit.max(d_refit);
        worst_refit_cm = worst_refit_cm.max(dt_refit);
        let (m, _) = mediapipe_answer(&e, placement(&e, &ms.points, &px, None), size, None);
        let (r, t) = split(&m);
        let (d, dt) = (angle_between(&r, &mr), (t - mt).norm());
        eprintln!(
            "mediapipe synthetic {:?} {}x{}: with its camera {d_true:.1e}° {:.1e} mm from the truth (MediaPipe {:.3}°, {:.2} mm); without intrinsics, refitted {d_refit:.3}° {:.2} mm from MediaPipe's, carried over {d:.2}° and {:.1} mm",
            face["pose_para"],
            w,
            h,
            dt_true * 10.0,
            angle_between(&mr, &tr),
            (mt - tt).norm() * 10.0,
            dt_refit * 10.0,
            dt * 10.0
        );
        worst_deg = worst_deg.max(d);
        worst_cm = worst_cm.max(dt);
    }
    eprintln!(
        "mediapipe synthetic without intrinsics: refitted worst {worst_refit:.3}°, {:.2} mm; carried over worst {worst_deg:.2}°, {:.1} mm",
        worst_refit_cm * 10.0,
        worst_cm * 10.0
    );
    assert!(
        worst_refit < 1.0 && worst_refit_cm < 0.5,
        "the issue's 1° and a few mm"
    );
    assert!(worst_deg < BOUND_MP_SYNTH_DEG && worst_cm < BOUND_MP_SYNTH_CM);
}

const BOUND_MP_SYNTH_DEG: f64 = 3.7;
const BOUND_MP_SYNTH_CM: f64 = 1.9;
const BOUND_MP_REAL_DEG: f64 = 16.5;

/// The real MediaPipe landmarks of the detector fixtures: facepose's `mediapipe` matrix (from
/// x, y only) against MediaPipe's own (which also used Face Mesh's z), and against MediaPipe's
/// with z = 0: the measured share of z in the difference.
///
/// Measured (refitted in MediaPipe's camera): 7.5-12.4° on the astronaut and its copies, almost
/// all of it pitch (facepose reads the points 9-12° further chin down; the same gap as against
/// dlib's points in tests/integration/detectors.rs), 2.2-7.4° on the LFW faces (mostly yaw),
/// and 5-25 mm. Not within the 1°, and the measured reason: on synthetic faces, whose
/// x, y and z belong to one rigid canonical face, the two agree to 0.001° and 0.01 mm (the test
/// above), so the matrix, frames, units and layout are MediaPipe's; on real detector output
/// MediaPipe's matrix is a 3D Procrustes fit of 33 weighted points that leans on the network's
/// z (zeroing z moves MediaPipe's own answer by 12-22°), while facepose fits the x, y of all
/// 468 points, which do not sit on one rigid canonical face.
#[test]
fn mediapipe_matrix_on_real_landmarks() {
    let doc = json(MEDIAPIPE);
    let det = json(MP_DETECTOR);
    let (_, ms) = model().mesh_scheme("mediapipe478").unwrap();
    let mut worst = 0.0f64;
    for (face, z0) in det["faces"]
        .as_array()
        .unwrap()
        .iter()
        .zip(doc["real"]["faces"].as_array().unwrap())
    {
        assert_eq!(face["image"], z0["image"]);
        let (w, h) = (f(&face["image_size"][0]), f(&face["image_size"][1]));
        let px = points(&face["landmarks"], w, h, 478);
        let e = estimate("mediapipe478", px.clone(), None);
        let size = image_size(w, h).unwrap();
        let refit = refitter("mediapipe478", px.clone());
        let (m, _) = mediapipe_answer(&e, placement(&e, &ms.points, &px, None), size, Some(&refit));
        let (r, t) = split(&m);
        let (mr, mt) = split(&mat4(&face["facial_transformation_matrix"]));
        let (m_carried, _) = mediapipe_answer(&e, placement(&e, &ms.points, &px, None), size, None);
        let (rc, tc) = split(&m_carried);
        eprintln!(
            "mediapipe real {:22} carried over: {:5.2}° and {:5.1} mm from MediaPipe's",
            face["image"].as_str().unwrap(),
            angle_between(&rc, &mr),
            (tc - mt).norm() * 10.0
        );
        let (zr, zt) = split(&mat4(&z0["mediapipe_matrix_z0"]));
        let d = angle_between(&r, &mr);
        let pp = |m: &Matrix3<f64>| EulerSpec::POSE_PARA.angles(nearest_rotation(m).matrix());
        let (a, b) = (pp(&r), pp(&mr));
        eprintln!(
            "mediapipe real {:22} Pose_Para [pitch, yaw, roll] facepose {:5.1?} MediaPipe {:5.1?}",
            face["image"].as_str().unwrap(),
            a,
            b
        );
        eprintln!(
            "mediapipe real {:22} refitted: {d:5.2}° and {:5.1} mm from MediaPipe's; MediaPipe with z = 0: {:5.2}° and {:5.1} mm from it, {:5.2}° and {:5.1} mm from facepose's",
            face["image"].as_str().unwrap(),
            (t - mt).norm() * 10.0,
            angle_between(&zr, &mr),
            (zt - mt).norm() * 10.0,
            angle_between(&r, &zr),
            (t - zt).norm() * 10.0,
        );
        worst = worst.max(d);
    }
    eprintln!("mediapipe real: worst {worst:.2}°");
    assert!(worst < BOUND_MP_REAL_DEG);
}
