//! The conventions against their written definitions: every Euler convention round-trips to
//! the same matrix (property tests over all 24 orders, both units, several axes and both matrix
//! senses, gimbal lock included); the presets give the numbers their tools define; bad input is
//! a typed error that says what to fix. The peers' own numbers are in crates/core/tests/.

use approx::assert_relative_eq;
use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use proptest::prelude::*;

use super::camera::{CameraOrientation, Placement, assumed_camera, image_size};
use super::euler::{Axes, EulerSpec, Kind, Matrices, Order, Units};
use super::peers::{ObjectFrame, OpenCvAnswer, rodrigues};
use super::request::{
    ConventionAnswer, ConventionError, ConventionRequest, PoseInput, answer, euler, quaternion,
};
use super::{EulerAngles, geodesic_deg};
use crate::estimate::Intrinsics;

const ORDERS: [&str; 12] = [
    "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ",
];

fn all_specs() -> Vec<EulerSpec> {
    let mut out = Vec::new();
    for o in ORDERS {
        for case in [o.to_string(), o.to_lowercase()] {
            let (order, kind) = Order::parse(&case).unwrap();
            for axes in [Axes::FACEPOSE, Axes::OPENCV, Axes::UNITY] {
                for matrices in [Matrices::Standard, Matrices::PosePara] {
                    for units in [Units::Degrees, Units::Radians] {
                        out.push(EulerSpec {
                            order,
                            kind,
                            units,
                            axes,
                            matrices,
                        });
                    }
                }
            }
        }
    }
    out
}

fn rot(yaw: f64, pitch: f64, roll: f64) -> Rotation3<f64> {
    EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation()
}

#[test]
fn pose_para_preset_is_faceposes_angles() {
    for (y, p, r) in [
        (30.0, -10.0, 5.0),
        (-75.0, 40.0, -120.0),
        (89.0, 170.0, 3.0),
    ] {
        let a = EulerSpec::POSE_PARA.angles(rot(y, p, r).matrix());
        assert_relative_eq!(a[0], p, epsilon = 1e-9);
        assert_relative_eq!(a[1], y, epsilon = 1e-9);
        assert_relative_eq!(a[2], r, epsilon = 1e-9);
    }
    // At gimbal lock both set the last angle (roll) to 0 and agree.
    let r = rot(90.0, 30.0, 20.0);
    let a = EulerSpec::POSE_PARA.angles(r.matrix());
    let b = EulerAngles::from_rotation(&r);
    assert_relative_eq!(a[0], b.pitch, epsilon = 1e-9);
    assert_eq!(a[2], 0.0);
}

/// Worked example of docs/API.md: Pose_Para yaw 30, pitch -10, roll 5 in each preset.
#[test]
#[allow(clippy::approx_constant)] // the docs' printed radians (30° is 0.5236)
fn worked_example_in_every_preset() {
    let r = rot(30.0, -10.0, 5.0);
    let got = |s: EulerSpec| s.angles(r.matrix());
    // three.js: same axes, standard matrices: the angles negated, radians.
    let t = got(EulerSpec::THREE);
    assert_relative_eq!(
        Vector3::from(t),
        Vector3::new(10f64.to_radians(), -30f64.to_radians(), -5f64.to_radians()),
        epsilon = 1e-12
    );
    // OpenFace: y and z flipped, standard matrices: pitch' = -pitch... R' = F R F with F =
    // diag(1,-1,-1) is Rx(p) Ry(-y) Rz(-r) in Pose_Para matrices = standard Rx(-p) Ry(y) Rz(r).
    let o = got(EulerSpec::OPENFACE);
    assert_relative_eq!(
        Vector3::from(o),
        Vector3::new(10f64.to_radians(), 30f64.to_radians(), 5f64.to_radians()),
        epsilon = 1e-12
    );
    // The printed numbers of docs/API.md (4 decimals).
    let unity = got(EulerSpec::UNITY);
    let doc = [[0.1745, -0.5236, -0.0873], [0.1745, 0.5236, 0.0873]];
    for (g, d) in [t, o].iter().zip(doc) {
        for k in 0..3 {
            assert!(
                (g[k] - d[k]).abs() < 1e-4,
                "{g:?} vs {d:?}: update docs/API.md"
            );
        }
    }
    // Unity: [y, x, z] degrees in RUF axes.
    let ud = [30.3813, -8.6492, -10.0384];
    for k in 0..3 {
        assert!(
            (unity[k] - ud[k]).abs() < 1e-4,
            "{unity:?}: update docs/API.md"
        );
    }
}

#[test]
fn rebuilt_matrix_is_the_convention_s_own() {
    let r = rot(20.0, 35.0, -50.0);
    for spec in all_specs() {
        let e = euler(&spec, &r);
        let m = Matrix3::from_fn(|i, j| e.matrix[i][j]);
        assert_relative_eq!(m, spec.axes.express(r.matrix()), epsilon = 1e-9);
        assert_relative_eq!(spec.rotation(e.angles), *r.matrix(), epsilon = 1e-9);
    }
}

#[test]
fn extrinsic_is_the_reversed_intrinsic() {
    let r = rot(-25.0, 60.0, 10.0);
    let (zyx, _) = Order::parse("ZYX").unwrap();
    let (xyz, _) = Order::parse("xyz").unwrap();
    let a = EulerSpec {
        order: xyz,
        kind: Kind::Extrinsic,
        ..EulerSpec::THREE
    }
    .angles(r.matrix());
    let b = EulerSpec {
        order: zyx,
        kind: Kind::Intrinsic,
        ..EulerSpec::THREE
    }
    .angles(r.matrix());
    assert_relative_eq!(
        Vector3::from(a),
        Vector3::new(b[2], b[1], b[0]),
        epsilon = 1e-12
    );
}

#[test]
fn quaternion_is_hamilton_with_non_negative_w() {
    // A half turn plus a bit about z: nalgebra may give w < 0 for some inputs; the answer never.
    for r in [
        rot(0.0, 0.0, 179.0),
        rot(170.0_f64.min(90.0), 175.0, -179.0),
        Rotation3::from_axis_angle(&Vector3::x_axis(), 3.0),
    ] {
        let q = quaternion(&r);
        assert!(q.w >= 0.0);
        let nq = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q.w, q.x, q.y, q.z,
        ));
        let v = Vector3::new(0.3, -1.0, 2.0);
        assert_relative_eq!(nq * v, r * v, epsilon = 1e-12);
    }
    // A 90° turn about +z (standard): Hamilton q = (cos 45°, 0, 0, sin 45°).
    let q = quaternion(&Rotation3::from_axis_angle(
        &Vector3::z_axis(),
        90f64.to_radians(),
    ));
    let h = 0.5f64.sqrt();
    assert_relative_eq!(
        Vector3::new(q.w, q.x, q.z),
        Vector3::new(h, 0.0, h),
        epsilon = 1e-12
    );
}

#[test]
fn parses_names_and_parameters_and_says_what_to_fix() {
    use ConventionRequest as C;
    assert_eq!(C::parse("quaternion", &[]).unwrap(), C::Quaternion);
    let e = C::parse("euler", &[("order", "zyx"), ("units", "radians")]).unwrap();
    let C::Euler(s) = e else { panic!() };
    assert_eq!(
        (s.kind, s.units, s.axes),
        (Kind::Extrinsic, Units::Radians, Axes::FACEPOSE)
    );
    let C::Euler(s) = C::parse("euler", &[("preset", "openface")]).unwrap() else {
        panic!()
    };
    assert_eq!(s, EulerSpec::OPENFACE);
    let C::Euler(s) = C::parse("euler", &[("preset", "6drepnet"), ("units", "radians")]).unwrap()
    else {
        panic!()
    };
    assert_eq!(s.units, Units::Radians);
    assert_eq!(s.matrices, Matrices::PosePara);
    let list =
        C::parse_list("quaternion, euler:order=YXZ:axes=RUF, opencv:object_frame=model, mediapipe")
            .unwrap();
    assert_eq!(list.len(), 4);
    assert_eq!(list[2], C::OpenCv(ObjectFrame::Model));

    let msg = |r: Result<C, ConventionError>| r.unwrap_err().to_string();
    let m = msg(C::parse("eulerr", &[]));
    assert!(
        m.contains("unknown convention") && m.contains("euler"),
        "{m}"
    );
    let m = msg(C::parse("euler", &[("order", "XXY")]));
    assert!(m.contains("XXY") && m.contains("same axis"), "{m}");
    let m = msg(C::parse("euler", &[("order", "XyZ")]));
    assert!(m.contains("mixed case"), "{m}");
    let m = msg(C::parse("euler", &[("order", "XYW")]));
    assert!(m.contains("x, y or z"), "{m}");
    let m = msg(C::parse(
        "euler",
        &[("order", "XYZ"), ("kind", "extrinsic")],
    ));
    assert!(m.contains("\"xyz\""), "{m}");
    let m = msg(C::parse("euler", &[]));
    assert!(m.contains("order") && m.contains("openface"), "{m}");
    let m = msg(C::parse("euler", &[("order", "XYZ"), ("axes", "RUR")]));
    assert!(m.contains("R/L"), "{m}");
    let m = msg(C::parse("euler", &[("order", "XYZ"), ("units", "grad")]));
    assert!(m.contains("degrees or radians"), "{m}");
    let m = msg(C::parse("euler", &[("ordre", "XYZ")]));
    assert!(m.contains("ordre") && m.contains("order"), "{m}");
    let m = msg(C::parse("opencv", &[("object_frame", "world")]));
    assert!(m.contains("object_frame"), "{m}");
    let m = C::parse_list("quaternion,quaternion")
        .unwrap_err()
        .to_string();
    assert!(m.contains("twice"), "{m}");
    assert!(C::parse_list("euler:order").is_err());
    for e in [
        ConventionError::UnknownName { name: "x".into() },
        ConventionError::NotARotation("x".into()),
        ConventionError::BadIntrinsics("x".into()),
    ] {
        assert!(e.is_invalid_argument());
    }
    assert!(!ConventionError::NoMesh("x".into()).is_invalid_argument());
}

#[test]
fn a_camera_orientation_must_be_a_rotation() {
    let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let m = CameraOrientation::from_rows(mirror, Axes::FACEPOSE)
        .unwrap_err()
        .to_string();
    assert!(m.contains("determinant"), "{m}");
    let scaled = [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]];
    assert!(CameraOrientation::from_rows(scaled, Axes::FACEPOSE).is_err());
    let nan = [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(CameraOrientation::from_rows(nan, Axes::FACEPOSE).is_err());
    assert!(CameraOrientation::from_quaternion(1.0, 1.0, 0.0, 0.0, Axes::FACEPOSE).is_err());
    assert!(CameraOrientation::from_quaternion(1.0, 0.0, 0.0, 0.0, Axes::FACEPOSE).is_ok());
    // A camera mounted upside down (a half turn about its optical axis) stays a half turn.
    let flipped = [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]];
    let c = CameraOrientation::from_rows(flipped, Axes::FACEPOSE).unwrap();
    assert_relative_eq!(c.rotation().angle(), std::f64::consts::PI, epsilon = 1e-12);
}

/// Worked example of docs/API.md: a webcam tilted down 20° sees a face that looks straight at
/// it; in the world the face looks 20° up (Pose_Para pitch +20, chin up).
#[test]
fn a_tilted_camera_gives_the_pose_in_the_world() {
    let tilt = EulerSpec {
        order: Order::parse("XYZ").unwrap().0,
        ..EulerSpec::THREE
    };
    let c = CameraOrientation::from_euler(
        &EulerSpec {
            units: Units::Degrees,
            ..tilt
        },
        [-20.0, 0.0, 0.0],
    )
    .unwrap();
    // The optical axis (-z) points below the horizon.
    assert!((c.rotation() * -Vector3::z()).y < -0.3);
    let reqs = [ConventionRequest::Euler(EulerSpec::POSE_PARA)];
    let input = PoseInput {
        rotation: Rotation3::identity(),
        placement: None,
        image_size: None,
        orientation: Some(c),
        mesh: None,
        refit: None,
    };
    let out = answer(&reqs, &input).unwrap();
    let ConventionAnswer::Euler(e) = &out.answers[0] else {
        panic!()
    };
    assert_relative_eq!(
        Vector3::from(e.angles),
        Vector3::new(20.0, 0.0, 0.0),
        epsilon = 1e-9
    );
}

#[test]
fn the_same_camera_gives_the_perspective_pose_back() {
    let k = Intrinsics {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    };
    let r = rot(30.0, -10.0, 5.0);
    let t = Vector3::new(10.0, 20.0, -600.0);
    let p = Placement::Perspective {
        translation: t,
        camera: k,
    };
    let same = p.in_camera(&r, &k);
    assert_eq!((same.rotation, same.translation), (r, t));
    // Another camera with another focal length sees the same pixels: the pose through the view
    // and back is the original one.
    let k2 = Intrinsics {
        fx: 500.0,
        fy: 500.0,
        ..k
    };
    let there = p.in_camera(&r, &k2);
    let back = Placement::Perspective {
        translation: there.translation,
        camera: k2,
    }
    .in_camera(&there.rotation, &k);
    assert!(geodesic_deg(&back.rotation, &r) < 1e-9);
    assert_relative_eq!(back.translation, t, epsilon = 1e-9);
    assert_relative_eq!(
        k2.project(&there.translation).unwrap(),
        k.project(&t).unwrap(),
        epsilon = 1e-9
    );
    // The worked example of docs/API.md (tests/integration/opencv_frame.rs).
    let a = OpenCvAnswer::new(&same, &k, false, ObjectFrame::Model);
    assert_relative_eq!(
        Vector3::from(a.rvec),
        Vector3::new(-2.8466, -0.1912, 0.7526),
        epsilon = 1e-4
    );
    assert_relative_eq!(
        Vector3::from(a.tvec),
        Vector3::new(10.0, -20.0, 600.0),
        epsilon = 1e-12
    );
    let a = OpenCvAnswer::new(&same, &k, false, ObjectFrame::OpenCv);
    assert_relative_eq!(
        Vector3::from(a.rvec),
        Vector3::new(0.1933, 0.5147, 0.1308),
        epsilon = 1e-4
    );
}

#[test]
fn opencv_and_mediapipe_say_what_they_lack() {
    let weak = Placement::Weak {
        scale: 2.0,
        translation: Vector2::new(300.0, -200.0),
    };
    let input = PoseInput {
        rotation: Rotation3::identity(),
        placement: Some(weak),
        image_size: None,
        orientation: None,
        mesh: None,
        refit: None,
    };
    let opencv = [ConventionRequest::OpenCv(ObjectFrame::OpenCv)];
    let m = answer(&opencv, &input).unwrap_err().to_string();
    assert!(m.contains("image_size"), "{m}");
    let size = image_size(640.0, 480.0).unwrap();
    let out = answer(
        &opencv,
        &PoseInput {
            image_size: Some(size),
            ..input
        },
    )
    .unwrap();
    assert_eq!(out.warnings.len(), 1);
    assert!(out.warnings[0].to_string().contains("fx = fy = 640"));
    let m = answer(
        &[ConventionRequest::MediaPipe],
        &PoseInput {
            image_size: Some(size),
            ..input
        },
    )
    .unwrap_err();
    assert!(!m.is_invalid_argument());
    assert!(image_size(0.0, 480.0).is_err());
    let bad = Placement::Perspective {
        translation: Vector3::new(0.0, 0.0, -500.0),
        camera: Intrinsics {
            fx: -1.0,
            fy: 800.0,
            cx: 0.0,
            cy: 0.0,
        },
    };
    let m = answer(
        &opencv,
        &PoseInput {
            placement: Some(bad),
            ..input
        },
    )
    .unwrap_err();
    assert!(m.to_string().contains("positive"), "{m}");
    assert!(m.is_invalid_argument());
    let nan = Placement::Perspective {
        translation: Vector3::new(0.0, 0.0, -500.0),
        camera: Intrinsics {
            fx: 800.0,
            fy: 800.0,
            cx: f64::NAN,
            cy: 0.0,
        },
    };
    let m = answer(
        &opencv,
        &PoseInput {
            placement: Some(nan),
            ..input
        },
    )
    .unwrap_err();
    assert!(m.to_string().contains("cx"), "{m}");
    // Nothing asked, nothing computed, nothing checked.
    assert!(
        answer(
            &[],
            &PoseInput {
                placement: Some(nan),
                ..input
            }
        )
        .unwrap()
        .answers
        .is_empty()
    );
    let _ = assumed_camera(size);
}

#[test]
fn rodrigues_picks_cv_s_sign_at_a_half_turn() {
    let r = Rotation3::from_axis_angle(&-Vector3::x_axis(), std::f64::consts::PI);
    let v = rodrigues(&r);
    assert!(v.x > 0.0);
}

/// Gimbal lock: at the middle angle's singular value the answer is finite, rebuilds the matrix,
/// sets the third angle to 0 (as scipy) and says it is near the lock; the quaternion is unaffected.
#[test]
fn gimbal_lock_is_documented_behaviour() {
    for o in ORDERS {
        for case in [o.to_string(), o.to_lowercase()] {
            let (order, kind) = Order::parse(&case).unwrap();
            let spec = EulerSpec {
                order,
                kind,
                units: Units::Degrees,
                axes: Axes::FACEPOSE,
                matrices: Matrices::Standard,
            };
            let mid = if order.is_tait_bryan() { 90.0 } else { 180.0 };
            for m in [mid, -mid, 0.0] {
                if order.is_tait_bryan() && m == 0.0 {
                    continue;
                }
                let r = Rotation3::from_matrix_unchecked(spec.rotation([25.0, m, 40.0]));
                let e = euler(&spec, &r);
                assert!(e.near_gimbal_lock, "{case} {m}");
                // As scipy: the third angle is 0, intrinsic or extrinsic.
                assert_eq!(e.angles[2], 0.0, "{case} {m}: {:?}", e.angles);
                assert_relative_eq!(spec.rotation(e.angles), *r.matrix(), epsilon = 1e-9);
            }
        }
    }
}

fn matrix_err(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    (a - b).abs().max()
}

proptest! {
    #[test]
    fn every_euler_convention_round_trips(
        spec_index in 0usize..288,
        a in -179.9f64..179.9, b in -179.9f64..179.9, c in -179.9f64..179.9,
        near_lock in proptest::bool::ANY, tiny in -1e-6f64..1e-6,
    ) {
        let spec = all_specs()[spec_index];
        // A rotation from any three angles; half the time the middle angle sits within a
        // micro-degree of gimbal lock.
        let lock = if spec.order.is_tait_bryan() { 90.0f64.copysign(b) } else if b.abs() > 90.0 { 180.0f64.copysign(b) } else { 0.0 };
        let b = if near_lock { lock + tiny } else { b };
        let to_units = |d: f64| match spec.units { Units::Degrees => d, Units::Radians => d.to_radians() };
        let r = spec.rotation([to_units(a), to_units(b), to_units(c)]);
        let back = spec.angles(&r);
        prop_assert!(back.iter().all(|v| v.is_finite()));
        let err = matrix_err(&spec.rotation(back), &r);
        prop_assert!(err < 1e-6, "{} matrix error {err}", spec.describe());
        // The quaternion and the matrix round-trip at full precision everywhere.
        let q = quaternion(&Rotation3::from_matrix_unchecked(r));
        let qr = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z));
        prop_assert!(matrix_err(&qr.to_rotation_matrix().into_inner(), &r) < 1e-12);
        // Away from the lock the angles come back themselves (the middle angle in its range).
        if !near_lock {
            let mid = to_units(b);
            let in_range = if spec.order.is_tait_bryan() { b.abs() < 89.0 } else { b > 1.0 && b < 179.0 };
            if in_range {
                prop_assert!((back[1] - mid).abs() < 1e-7, "{} {back:?} vs {b}", spec.describe());
            }
        }
    }

    #[test]
    fn opencv_answer_round_trips_through_rodrigues(yaw in -89.0f64..89.0, pitch in -89.0f64..89.0, roll in -179.0f64..179.0) {
        let r = rot(yaw, pitch, roll);
        let pose = super::camera::CameraPose { rotation: r, translation: Vector3::new(5.0, -3.0, -500.0) };
        let k = Intrinsics { fx: 700.0, fy: 700.0, cx: 320.0, cy: 240.0 };
        for frame in [ObjectFrame::OpenCv, ObjectFrame::Model] {
            let a = OpenCvAnswer::new(&pose, &k, false, frame);
            let back = Rotation3::new(Vector3::from(a.rvec));
            let m = Matrix3::from_fn(|i, j| a.rotation[i][j]);
            prop_assert!(matrix_err(back.matrix(), &m) < 1e-9);
            prop_assert!(Vector3::from(a.rvec).norm() <= std::f64::consts::PI + 1e-12);
            // projectPoints' formula on the served object points gives facepose's pixels.
            let x = Vector3::new(30.0, 20.0, 10.0);
            let obj = Vector3::from(frame.object_points(&[x])[0]);
            let c = m * obj + Vector3::from(a.tvec);
            let px = Vector2::new(k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy);
            let want = k.project(&(r * x + pose.translation)).unwrap();
            prop_assert!((px - want).norm() < 1e-9);
        }
    }

    /// The MediaPipe matrix gives the pose back: `R = M₃ₓ₃ Qᵀ`, `T = 10 σ M₃ − R c`.
    #[test]
    fn mediapipe_matrix_round_trips(yaw in -89.0f64..89.0, pitch in -89.0f64..89.0, roll in -179.0f64..179.0,
                                    tx in -200.0f64..200.0, ty in -200.0f64..200.0, depth in 200.0f64..3000.0,
                                    scale in 0.8f64..1.2, turn in -0.2f64..0.2) {
        use crate::geometry::procrustes::Similarity3;
        let sim = Similarity3 {
            scale,
            rotation: Rotation3::new(Vector3::new(turn, -turn / 2.0, turn / 3.0)),
            translation: Vector3::new(1.0, 12.0, -30.0),
        };
        let frame = super::peers::MeshFrame(sim);
        let pose = super::camera::CameraPose { rotation: rot(yaw, pitch, roll), translation: Vector3::new(tx, ty, -depth) };
        let a = super::peers::MediaPipeAnswer::new(&pose, &frame);
        let m = nalgebra::Matrix4::from_fn(|i, j| a.matrix[i][j]);
        prop_assert!((nalgebra::Matrix4::from_column_slice(&a.data) - m).abs().max() == 0.0);
        let r3 = m.fixed_view::<3, 3>(0, 0).into_owned();
        let r = r3 * sim.rotation.matrix().transpose();
        let t = 10.0 * scale * m.fixed_view::<3, 1>(0, 3).into_owned() - r * sim.translation;
        prop_assert!(matrix_err(&r, pose.rotation.matrix()) < 1e-12);
        prop_assert!((t - pose.translation).norm() < 1e-9);
        // Every canonical vertex lands on the same pixel as the model's point it became.
        let v = Vector3::new(3.0, -4.0, 7.5); // cm
        let p_mp = r3 * v + m.fixed_view::<3, 1>(0, 3).into_owned();
        let p_fp = pose.rotation * sim.apply(&(10.0 * v)) + pose.translation;
        prop_assert!((p_mp.xy() / -p_mp.z - p_fp.xy() / -p_fp.z).norm() < 1e-12);
    }

    #[test]
    fn camera_orientation_round_trips_in_any_axes(a in -170.0f64..170.0, b in -80.0f64..80.0, c in -170.0f64..170.0) {
        let spec = EulerSpec { units: Units::Degrees, axes: Axes::OPENCV, ..EulerSpec::OPENFACE };
        let o = CameraOrientation::from_euler(&spec, [a, b, c]).unwrap();
        let rows = super::peers::rows3(&spec.axes.express(o.rotation().matrix()));
        let o2 = CameraOrientation::from_rows(rows, Axes::OPENCV).unwrap();
        prop_assert!(geodesic_deg(o.rotation(), o2.rotation()) < 1e-9);
        let q = quaternion(&Rotation3::from_matrix_unchecked(spec.axes.express(o.rotation().matrix())));
        let o3 = CameraOrientation::from_quaternion(q.w, q.x, q.y, q.z, Axes::OPENCV).unwrap();
        prop_assert!(geodesic_deg(o.rotation(), o3.rotation()) < 1e-9);
    }
}

/// The worked example of docs/API.md "Answers in your convention": the face of the OpenCV
/// example (Pose_Para yaw 30, pitch -10, roll 5; 10 mm right, 20 mm up, 600 mm in front) in
/// every convention. Quaternion and Euler numbers are scipy's (`Rotation.from_euler("XYZ",
/// [10, -30, -5], degrees=True)`, the same rotation in standard matrices).
#[test]
#[allow(clippy::approx_constant)] // the docs' printed radians (30° is 0.5236)
fn worked_example_of_the_docs() {
    let (_, model) = crate::model::default_model().unwrap();
    let (mesh, _) = model.mesh_scheme("mediapipe468").unwrap();
    let frame = super::peers::MeshFrame::of_served_mesh(&mesh.source().vertices).unwrap();
    let k = Intrinsics {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    };
    let t = Vector3::new(10.0, 20.0, -600.0);
    let r = rot(30.0, -10.0, 5.0);
    let reqs =
        ConventionRequest::parse_list("quaternion,euler:preset=openface,opencv,mediapipe").unwrap();
    let input = PoseInput {
        rotation: r,
        placement: Some(Placement::Perspective {
            translation: t,
            camera: k,
        }),
        image_size: Some(image_size(640.0, 480.0).unwrap()),
        orientation: None,
        mesh: Some(&frame),
        refit: None,
    };
    // The service refits the landmarks under MediaPipe's camera: the model's points seen by
    // this camera, fitted again with MediaPipe's intrinsics.
    let px: Vec<nalgebra::Vector2<f64>> = model
        .mean
        .iter()
        .map(|x| k.project(&(r * x + t)).unwrap())
        .collect();
    let shape = crate::shape::Shape2::full(px).unwrap();
    let refit = |kk: &Intrinsics| {
        let opts = crate::pose::EstimateOptions {
            method: crate::pose::Method::Fit,
            camera: Some(*kk),
            style: crate::pose::LandmarkStyle::Projected,
        };
        let e = crate::pose::estimate_with(&model, "ibug68", &shape, &opts).ok()?;
        Some(super::camera::CameraPose {
            rotation: e.rotation,
            translation: e.translation?,
        })
    };
    let input = PoseInput {
        refit: Some(&refit),
        ..input
    };
    let out = answer(&reqs, &input).unwrap();
    assert!(out.warnings.is_empty());
    let close = |got: &[f64], want: &[f64], tol: f64| {
        assert!(
            got.iter().zip(want).all(|(g, w)| (g - w).abs() < tol),
            "{got:?} vs {want:?}: update docs/API.md"
        );
    };
    for a in &out.answers {
        match a {
            ConventionAnswer::Quaternion(q) => close(
                &[q.w, q.x, q.y, q.z],
                &[0.9604, 0.0954, -0.2539, -0.0645],
                1e-4,
            ),
            ConventionAnswer::Euler(e) => {
                close(&e.angles, &[0.1745, 0.5236, 0.0873], 1e-4);
                assert_eq!((e.order.as_str(), e.axes.as_str()), ("XYZ", "RDF"));
            }
            ConventionAnswer::OpenCv(o) => {
                close(&o.rvec, &[0.1933, 0.5147, 0.1308], 1e-4);
                close(&o.tvec, &[10.0, -20.0, 600.0], 1e-9);
                assert!(!o.camera_assumed);
            }
            ConventionAnswer::MediaPipe(m) => {
                // The same landmarks refitted in MediaPipe's 63° camera on the 640 x 480 image
                // (f = 391.6 px).
                close(&m.matrix[0], &[0.8550, 0.0768, -0.5128, 2.7756], 1e-4);
                close(&m.matrix[1], &[-0.1932, 0.9650, -0.1776, 3.7585], 1e-4);
                close(&m.matrix[2], &[0.4812, 0.2509, 0.8399, -32.8067], 1e-4);
                close(&m.data[12..16], &[2.7756, 3.7585, -32.8067, 1.0], 1e-4);
                close(
                    &m.data[0..4],
                    &[m.matrix[0][0], m.matrix[1][0], m.matrix[2][0], 0.0],
                    1e-15,
                );
            }
        }
    }
}

/// Where each preset locks: Pose_Para (`XYZ`, middle yaw) at yaw ±90°, a face in profile;
/// Unity (`YXZ`, middle x) at pitch ±90°, a face looking straight up or down. There the
/// answer says so, the angles still rebuild the matrix, and the quaternion is as exact as
/// anywhere.
#[test]
fn each_preset_locks_where_its_middle_axis_is_at_90() {
    let cases = [
        (EulerSpec::POSE_PARA, rot(90.0, 20.0, 10.0), true),
        (EulerSpec::POSE_PARA, rot(10.0, 90.0, 20.0), false),
        (EulerSpec::UNITY, rot(0.0, 90.0, 0.0), true),
        (EulerSpec::UNITY, rot(0.0, -89.5, 0.0), true),
        (EulerSpec::UNITY, rot(0.0, 80.0, 0.0), false),
        (EulerSpec::OPENFACE, rot(-90.0, 5.0, 5.0), true),
    ];
    for (spec, r, locked) in cases {
        let e = euler(&spec, &r);
        assert_eq!(
            e.near_gimbal_lock,
            locked,
            "{}: {:?}",
            spec.describe(),
            e.angles
        );
        assert!(matrix_err(&spec.rotation(e.angles), r.matrix()) < 1e-9);
        let q = quaternion(&r);
        let qr = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q.w, q.x, q.y, q.z,
        ));
        assert!(matrix_err(&qr.to_rotation_matrix().into_inner(), r.matrix()) < 1e-14);
    }
    // The warning a request gets there.
    let reqs = [ConventionRequest::Euler(EulerSpec::UNITY)];
    let input = PoseInput {
        rotation: rot(0.0, 90.0, 0.0),
        placement: None,
        image_size: None,
        orientation: None,
        mesh: None,
        refit: None,
    };
    let out = answer(&reqs, &input).unwrap();
    assert!(out.warnings[0].to_string().contains("gimbal lock"));
}
