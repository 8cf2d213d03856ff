//! The one place where the angle convention lives.
//!
//! Angles are degrees at every interface, in the 300W-LP / AFLW2000-3D `Pose_Para` convention:
//! pitch > 0 chin up; yaw > 0 the nose turns towards image-left (the subject turns to their own
//! right); roll > 0 the face turns clockwise on screen, and
//!
//! `R = Rx(pitch) · Ry(yaw) · Rz(roll)` with
//! `Rx=[[1,0,0],[0,c,s],[0,-s,c]]`, `Ry=[[c,0,-s],[0,1,0],[s,0,c]]`, `Rz=[[c,s,0],[-s,c,0],[0,0,1]]`.
//!
//! `R` maps a model-frame point `X` (x towards the subject's left, y up, z towards the camera, mm)
//! into the camera frame; see [`super::projection`] for the step to image pixels. Estimators work
//! on rotation matrices and convert to angles only at the edge, through [`EulerAngles`].
//!
//! The other conventions a caller can ask for (issue 39, docs/API.md "Conventions") live in the
//! submodules, so that no other module converts between angles and matrices:
//! - [`euler`]: Euler angles in any named order, kind, units, axes and matrix sense;
//! - [`camera`]: where the face is ([`Placement`]), the camera a convention refers to, and the
//!   camera's orientation in the world ([`CameraOrientation`]);
//! - [`peers`]: OpenCV's `rvec`/`tvec` and MediaPipe's facial transformation matrix;
//! - [`request`]: the request option `conventions` parsed from plain values, with typed errors,
//!   and [`answer`], a pose to one answer per requested name.

use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result, ensure_finite};

pub mod camera;
#[cfg(test)]
mod conventions_tests;
pub mod euler;
pub mod peers;
pub mod request;

pub use camera::{CameraOrientation, CameraPose, ImageSize, Placement, assumed_camera, image_size};
pub use euler::{Axes, EulerSpec, Kind, Matrices, Order, Units};
pub use peers::{MEDIAPIPE_CAMERA, MediaPipeAnswer, MeshFrame, ObjectFrame, OpenCvAnswer};
pub use request::{
    ConventionAnswer, ConventionAnswers, ConventionError, ConventionRequest, ConventionWarning,
    EulerAnswer, PoseInput, QuaternionAnswer, Refit, answer,
};

/// Head pose angles in degrees, `Pose_Para` convention (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EulerAngles {
    /// Rotation about the x axis; > 0 chin up.
    pub pitch: f64,
    /// Rotation about the y axis; > 0 the nose turns towards image-left.
    pub yaw: f64,
    /// Rotation about the z axis; > 0 clockwise on screen.
    pub roll: f64,
}

/// Below this value of `cos(yaw)` the decomposition is at gimbal lock: pitch and roll are no
/// longer separable and roll is set to 0 (the matrix is still reproduced exactly).
const GIMBAL_COS: f64 = 1e-9;

impl EulerAngles {
    /// Angles in degrees. Fails on NaN or infinity.
    pub fn new(yaw: f64, pitch: f64, roll: f64) -> Result<Self> {
        ensure_finite("angles", [&yaw, &pitch, &roll])?;
        Ok(EulerAngles { pitch, yaw, roll })
    }

    /// `R = Rx(pitch) · Ry(yaw) · Rz(roll)`.
    pub fn to_rotation(self) -> Rotation3<f64> {
        Rotation3::from_matrix_unchecked(rx(self.pitch) * ry(self.yaw) * rz(self.roll))
    }

    /// The angles of a rotation matrix: yaw in [-90, 90], pitch and roll in (-180, 180].
    /// At gimbal lock (|yaw| = 90) roll is 0 and pitch carries the remaining rotation.
    pub fn from_rotation(r: &Rotation3<f64>) -> Self {
        let m = r.matrix();
        // R[0] = [cy cr, cy sr, -sy], R[1][2] = sp cy, R[2][2] = cp cy.
        let cy = m[(0, 0)].hypot(m[(0, 1)]);
        let yaw = (-m[(0, 2)]).atan2(cy);
        let (pitch, roll) = if cy > GIMBAL_COS {
            (m[(1, 2)].atan2(m[(2, 2)]), m[(0, 1)].atan2(m[(0, 0)]))
        } else {
            // cos(yaw) = 0, roll := 0: R[1] = [sp sy, cp, 0], R[2] = [cp sy, -sp, 0].
            ((-m[(2, 1)]).atan2(m[(1, 1)]), 0.0)
        };
        EulerAngles {
            pitch: pitch.to_degrees(),
            yaw: yaw.to_degrees(),
            roll: roll.to_degrees(),
        }
    }
}

/// The convention's rotation about x by `deg` degrees (pitch).
pub fn rx(deg: f64) -> Matrix3<f64> {
    let (s, c) = deg.to_radians().sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c)
}

/// The convention's rotation about y by `deg` degrees (yaw).
pub fn ry(deg: f64) -> Matrix3<f64> {
    let (s, c) = deg.to_radians().sin_cos();
    Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c)
}

/// The convention's rotation about z by `deg` degrees (roll).
pub fn rz(deg: f64) -> Matrix3<f64> {
    let (s, c) = deg.to_radians().sin_cos();
    Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0)
}

/// An angle difference in degrees brought into (-180, 180].
pub fn wrap_deg(d: f64) -> f64 {
    let r = (d + 180.0).rem_euclid(360.0) - 180.0;
    if r == -180.0 { 180.0 } else { r }
}

/// The rotation whose first two rows are `r1` and `r2` made orthonormal (Gram-Schmidt, `r1`
/// kept), the third their cross product: the rotation of a scaled orthographic camera.
pub fn rotation_from_two_rows(r1: &Vector3<f64>, r2: &Vector3<f64>) -> Rotation3<f64> {
    let r1 = r1.normalize();
    let r2 = (r2 - r1 * r1.dot(r2)).normalize();
    Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        r1.transpose(),
        r2.transpose(),
        r1.cross(&r2).transpose(),
    ]))
}

/// A 3x3 matrix given row-major (as in JSON `rotation` fields) as a rotation, after checking that
/// it is orthonormal with determinant +1 to within `tol`.
pub fn rotation_from_rows(rows: [[f64; 3]; 3], tol: f64) -> Result<Rotation3<f64>> {
    ensure_finite("rotation matrix", rows.iter().flatten())?;
    let m = Matrix3::from_fn(|i, j| rows[i][j]);
    let err = (m.transpose() * m - Matrix3::identity()).abs().max();
    if err > tol || (m.determinant() - 1.0).abs() > tol {
        return Err(Error::param(
            "rotation",
            format!(
                "not a proper rotation (orthonormality error {err:.2e}, det {:.6})",
                m.determinant()
            ),
        ));
    }
    Ok(Rotation3::from_matrix_unchecked(m))
}

/// The rotation as row-major nested arrays, the form used in every response.
pub fn rotation_rows(r: &Rotation3<f64>) -> [[f64; 3]; 3] {
    let m = r.matrix();
    [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]])
}

/// The rotation as a unit quaternion (w, x, y, z), acting on model-frame points like `R`.
pub fn to_quaternion(r: &Rotation3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(r)
}

/// The rotation as a unit axis and an angle in degrees (angle in [0, 180]); the identity gives
/// the z axis and 0.
pub fn to_axis_angle(r: &Rotation3<f64>) -> (Unit<Vector3<f64>>, f64) {
    match r.axis_angle() {
        Some((axis, angle)) => (axis, angle.to_degrees()),
        None => (Vector3::z_axis(), 0.0),
    }
}

/// The rotation of `angle_deg` degrees about `axis` (need not be unit length, must be non-zero).
pub fn from_axis_angle(axis: Vector3<f64>, angle_deg: f64) -> Result<Rotation3<f64>> {
    ensure_finite("axis-angle", axis.iter().chain([&angle_deg]))?;
    let axis = Unit::try_new(axis, 1e-12)
        .ok_or_else(|| Error::param("axis", "the rotation axis has zero length"))?;
    Ok(Rotation3::from_axis_angle(&axis, angle_deg.to_radians()))
}

/// The geodesic distance between two rotations in degrees (the angle of `aᵀ b`), computed as
/// `atan2(‖skew part‖, symmetric part)` so that it stays exact near 0 and 180.
pub fn geodesic_deg(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    let m = a.matrix().transpose() * b.matrix();
    let skew = Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    );
    (0.5 * skew.norm())
        .atan2(0.5 * (m.trace() - 1.0))
        .to_degrees()
}

// How the angles move with the rotation: what propagates a rotation's uncertainty to them.

/// `d(atan2(a, b))` for the changes `da`, `db`, degrees.
fn datan2(a: f64, b: f64, da: f64, db: f64) -> f64 {
    (b * da - a * db) / (a * a + b * b) * 180.0 / std::f64::consts::PI
}

/// The gradient of yaw (degrees) with respect to the small turn `δ` (radians):
/// yaw = atan2(−R₀₂, hypot(R₀₀, R₀₁)) ([`EulerAngles::from_rotation`]), `dR = [δ]ₓ R`.
pub fn yaw_turn_gradient(r: &Rotation3<f64>) -> Vector3<f64> {
    let m = r.matrix();
    let cy = m[(0, 0)].hypot(m[(0, 1)]);
    Vector3::from_fn(|k, _| {
        let d = turn_derivative(m, k);
        let dcy = if cy > 0.0 {
            (m[(0, 0)] * d[(0, 0)] + m[(0, 1)] * d[(0, 1)]) / cy
        } else {
            0.0
        };
        datan2(-m[(0, 2)], cy, -d[(0, 2)], dcy)
    })
}

/// `[e_k]ₓ R`: the derivative of `exp([δ]ₓ) R` along `δ = e_k`.
fn turn_derivative(m: &Matrix3<f64>, k: usize) -> Matrix3<f64> {
    let mut e = Vector3::zeros();
    e[k] = 1.0;
    e.cross_matrix() * m
}

/// The derivative of (pitch, yaw, roll) in degrees with respect to a small turn `δ` (radians)
/// applied as `exp([δ]ₓ) R`, differentiating [`EulerAngles::from_rotation`]'s formulas;
/// `None` at gimbal lock (|yaw| = 90°), where pitch and roll are not separable.
pub fn angle_turn_jacobian(r: &Rotation3<f64>) -> Option<Matrix3<f64>> {
    let m = r.matrix();
    let cy = m[(0, 0)].hypot(m[(0, 1)]);
    if cy < 1e-9 {
        return None;
    }
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let d = turn_derivative(m, k);
        let dcy = (m[(0, 0)] * d[(0, 0)] + m[(0, 1)] * d[(0, 1)]) / cy;
        j[(0, k)] = datan2(m[(1, 2)], m[(2, 2)], d[(1, 2)], d[(2, 2)]);
        j[(1, k)] = datan2(-m[(0, 2)], cy, -d[(0, 2)], dcy);
        j[(2, k)] = datan2(m[(0, 1)], m[(0, 0)], d[(0, 1)], d[(0, 0)]);
    }
    Some(j)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The analytic derivative of the angles matches central differences of the decomposition.
    #[test]
    fn angle_jacobian_matches_finite_differences() {
        for (y, p, r) in [
            (20.0, -10.0, 5.0),
            (-75.0, 30.0, -40.0),
            (5.0, 170.0, 100.0),
        ] {
            let rot = EulerAngles::new(y, p, r).unwrap().to_rotation();
            let j = angle_turn_jacobian(&rot).unwrap();
            let angles = |r: &Rotation3<f64>| {
                let a = EulerAngles::from_rotation(r);
                Vector3::new(a.pitch, a.yaw, a.roll)
            };
            for k in 0..3 {
                let mut axis = Vector3::zeros();
                axis[k] = 1e-6;
                let (plus, minus) = (
                    angles(&(Rotation3::new(axis) * rot)),
                    angles(&(Rotation3::new(-axis) * rot)),
                );
                for a in 0..3 {
                    let num = wrap_deg(plus[a] - minus[a]) / 2e-6;
                    assert!(
                        (j[(a, k)] - num).abs() < 1e-4 * (1.0 + num.abs()),
                        "{a} {k}: {} vs {num}",
                        j[(a, k)]
                    );
                }
                assert!((yaw_turn_gradient(&rot)[k] - j[(1, k)]).abs() < 1e-9);
            }
        }
        let lock = EulerAngles::new(90.0, 10.0, 0.0).unwrap().to_rotation();
        assert!(angle_turn_jacobian(&lock).is_none());
    }

    use approx::assert_relative_eq;
    use proptest::prelude::*;

    #[test]
    fn elementary_rotations_match_the_written_convention() {
        // Yaw 90: Ry = [[0,0,-1],[0,1,0],[1,0,0]]; the nose (+z) goes to -x (image-left).
        let r = EulerAngles::new(90.0, 0.0, 0.0).unwrap().to_rotation();
        let nose = r * Vector3::z();
        assert_relative_eq!(nose, Vector3::new(-1.0, 0.0, 0.0), epsilon = 1e-12);
        // Pitch 90 (chin up): the nose (+z) goes up (+y); Rx = [[1,0,0],[0,0,1],[0,-1,0]].
        let r = EulerAngles::new(0.0, 90.0, 0.0).unwrap().to_rotation();
        assert_relative_eq!(r * Vector3::z(), Vector3::y(), epsilon = 1e-12);
        // Roll 90 clockwise on screen: the top of the head (+y) goes to image-right (+x).
        let r = EulerAngles::new(0.0, 0.0, 90.0).unwrap().to_rotation();
        assert_relative_eq!(r * Vector3::y(), Vector3::x(), epsilon = 1e-12);
    }

    #[test]
    fn geodesic_distance_is_the_rotation_angle() {
        let a = EulerAngles::new(10.0, 20.0, 30.0).unwrap().to_rotation();
        assert_eq!(geodesic_deg(&a, &a), 0.0);
        let b = from_axis_angle(Vector3::new(1.0, 2.0, 2.0), 37.0).unwrap() * a;
        assert_relative_eq!(geodesic_deg(&a, &b), 37.0, epsilon = 1e-9);
        let c = from_axis_angle(Vector3::new(0.0, 1.0, 0.0), 180.0).unwrap() * a;
        assert_relative_eq!(geodesic_deg(&a, &c), 180.0, epsilon = 1e-9);
    }

    #[test]
    fn rejects_non_finite_angles() {
        assert!(EulerAngles::new(f64::NAN, 0.0, 0.0).is_err());
        assert!(EulerAngles::new(0.0, f64::INFINITY, 0.0).is_err());
    }

    #[test]
    fn gimbal_lock_reproduces_the_matrix() {
        for yaw in [90.0, -90.0] {
            let a = EulerAngles::new(yaw, 30.0, 20.0).unwrap();
            let r = a.to_rotation();
            let b = EulerAngles::from_rotation(&r);
            assert!(b.pitch.is_finite() && b.yaw.is_finite() && b.roll.is_finite());
            assert_relative_eq!(b.to_rotation().matrix(), r.matrix(), epsilon = 1e-9);
        }
    }

    #[test]
    fn quaternion_and_axis_angle_agree_with_the_matrix() {
        let r = EulerAngles::new(25.0, -10.0, 5.0).unwrap().to_rotation();
        let q = to_quaternion(&r);
        let v = Vector3::new(1.0, 2.0, 3.0);
        assert_relative_eq!(q * v, r * v, epsilon = 1e-12);
        let (axis, angle) = to_axis_angle(&r);
        let back = from_axis_angle(axis.into_inner(), angle).unwrap();
        assert_relative_eq!(back.matrix(), r.matrix(), epsilon = 1e-12);
        assert!(from_axis_angle(Vector3::zeros(), 10.0).is_err());
    }

    #[test]
    fn rows_round_trip_and_reject_non_rotations() {
        let r = EulerAngles::new(10.0, 20.0, 30.0).unwrap().to_rotation();
        let back = rotation_from_rows(rotation_rows(&r), 1e-9).unwrap();
        assert_relative_eq!(back.matrix(), r.matrix(), epsilon = 1e-15);
        let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(rotation_from_rows(mirror, 1e-6).is_err());
    }

    proptest! {
        #[test]
        fn angles_round_trip(yaw in -89.9f64..89.9, pitch in -179.9f64..179.9, roll in -179.9f64..179.9) {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let b = EulerAngles::from_rotation(&a.to_rotation());
            prop_assert!((a.yaw - b.yaw).abs() < 1e-7);
            prop_assert!((a.pitch - b.pitch).abs() < 1e-7);
            prop_assert!((a.roll - b.roll).abs() < 1e-7);
        }

        #[test]
        fn matrices_round_trip_over_the_whole_range(
            yaw in -90.0f64..=90.0, pitch in -180.0f64..=180.0, roll in -180.0f64..=180.0,
            near_lock in proptest::bool::ANY, tiny in -1e-6f64..1e-6,
        ) {
            // Half of the cases sit within a micro-degree of gimbal lock.
            let yaw = if near_lock { 90.0f64.copysign(yaw) - tiny.abs() * yaw.signum() } else { yaw };
            let r = EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation();
            let b = EulerAngles::from_rotation(&r);
            prop_assert!(b.yaw.is_finite() && b.pitch.is_finite() && b.roll.is_finite());
            prop_assert!(b.yaw.abs() <= 90.0);
            let err = (b.to_rotation().matrix() - r.matrix()).abs().max();
            prop_assert!(err < 1e-6, "matrix error {err}");
        }
    }
}
