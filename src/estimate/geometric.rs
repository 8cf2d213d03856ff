//! The paper's modified Gee-Cipolla five-point method (§4.1).
//!
//! From eye centres, nose tip and mouth corners (scheme `five`, image pixels):
//! 1. roll from the eye line; the points are de-rolled so that it is horizontal;
//! 2. the face axis runs from `fa` (eye midpoint) to `fd` (mouth midpoint); `fb`, the foot of the
//!    face normal, sits on it at `fb = fd + L_f (fa - fd)`;
//! 3. the nose tip's offset from `fb`, normalized by `|fa - fd|`, splits into `dx` across the axis
//!    and `dy` along it; with the relative nose length `l_n`,
//!    `yaw = asin(-dx / l_n)`, `pitch = asin(dy / l_n)` (eq. 15, in our sign convention);
//! 4. the rotation is `Rz(roll) · Rx(pitch) · Ry(yaw)` (the eye line turns in the image plane,
//!    on the camera side), converted to angles at the edge.
//!
//! `L_f` and `l_n` come from a mean 3D shape ([`GeometryConstants::from_mean`]); the paper reports
//! 0.45 and 0.50 for its database.

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::shape::Shape2;

/// The two ratios of the method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeometryConstants {
    /// `|fb - fd| / |fa - fd|`: where the face normal meets the face axis, from the mouth.
    pub lf: f64,
    /// Nose length (nose tip to `fb`) over the face-axis length `|fa - fd|`.
    pub ln: f64,
}

impl GeometryConstants {
    /// The ratios of a frontal mean shape given as its five points (model frame: x towards the
    /// subject's left, y up, z towards the camera), in `five` order.
    pub fn from_mean(five: &[Vector3<f64>; 5]) -> Result<Self> {
        if five.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite("five-point mean shape"));
        }
        let fa = 0.5 * (five[0] + five[1]);
        let fd = 0.5 * (five[3] + five[4]);
        let axis = fa - fd;
        let axis2 = axis.xy();
        if axis2.norm() < 1e-9 {
            return Err(Error::Degenerate(
                "the eye and mouth midpoints coincide".into(),
            ));
        }
        // fb: the nose tip's frontal projection dropped onto the face axis.
        let t = (five[2].xy() - fd.xy()).dot(&axis2) / axis2.norm_squared();
        let fb = fd + t * axis;
        let ln = (five[2] - fb).norm() / axis.norm();
        if !(0.0..=1.5).contains(&t) || ln <= 1e-6 {
            return Err(Error::Degenerate(format!(
                "implausible face geometry (L_f {t:.3}, l_n {ln:.3})"
            )));
        }
        Ok(GeometryConstants { lf: t, ln })
    }
}

/// The pose from five points (image pixels, all present) with the given constants.
pub fn estimate_geometric(five: &Shape2, c: &GeometryConstants) -> Result<EulerAngles> {
    if five.len() != 5 {
        return Err(Error::PointCount {
            what: "five-point landmarks".into(),
            expected: 5,
            got: five.len(),
        });
    }
    if five.n_present() != 5 {
        return Err(Error::too_few(
            "the geometric method (eyes, nose tip, mouth corners)",
            5,
            five.n_present(),
        ));
    }
    let p = five.points();
    let eye = p[1] - p[0];
    if eye.norm() < 1e-9 {
        return Err(Error::Degenerate("the two eye centres coincide".into()));
    }
    let phi = eye.y.atan2(eye.x);
    let (s, co) = phi.sin_cos();
    // De-roll in image coordinates, then flip to the y-up plane.
    let q: Vec<Vector2<f64>> = p
        .iter()
        .map(|v| Vector2::new(co * v.x + s * v.y, -(-s * v.x + co * v.y)))
        .collect();
    let fa = 0.5 * (q[0] + q[1]);
    let fd = 0.5 * (q[3] + q[4]);
    let axis = fa - fd;
    let len = axis.norm();
    if len < 1e-9 {
        return Err(Error::Degenerate(
            "the eye and mouth midpoints coincide".into(),
        ));
    }
    let up = axis / len;
    let right = Vector2::new(up.y, -up.x);
    let fb = fd + c.lf * axis;
    let d = q[2] - fb;
    let dx = d.dot(&right) / len;
    let dy = d.dot(&up) / len;
    let yaw = (-dx / c.ln).clamp(-1.0, 1.0).asin().to_degrees();
    let pitch = (dy / c.ln).clamp(-1.0, 1.0).asin().to_degrees();
    let roll_free = EulerAngles {
        yaw,
        pitch,
        roll: 0.0,
    }
    .to_rotation();
    let in_plane = EulerAngles {
        yaw: 0.0,
        pitch: 0.0,
        roll: phi.to_degrees(),
    }
    .to_rotation();
    Ok(EulerAngles::from_rotation(&(in_plane * roll_free)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::WeakPerspective;

    fn five3() -> [Vector3<f64>; 5] {
        [
            Vector3::new(-31.0, 36.0, 2.0),
            Vector3::new(31.0, 36.0, 2.0),
            Vector3::new(0.0, 2.0, 42.0),
            Vector3::new(-24.0, -28.0, 10.0),
            Vector3::new(24.0, -28.0, 10.0),
        ]
    }

    fn view(a: EulerAngles) -> Shape2 {
        let cam = WeakPerspective::new(a.to_rotation(), 2.5, Vector2::new(225.0, -225.0)).unwrap();
        Shape2::full(five3().iter().map(|x| cam.project(x)).collect()).unwrap()
    }

    #[test]
    fn constants_of_a_known_face() {
        let c = GeometryConstants::from_mean(&five3()).unwrap();
        // fd = (0,-28,10), fa = (0,36,2): the nose (y = 2) sits at t = 30/64 along the axis.
        assert!((c.lf - 30.0 / 64.0).abs() < 1e-12);
        let fb = Vector3::new(0.0, -28.0, 10.0) + c.lf * Vector3::new(0.0, 64.0, -8.0);
        assert!(
            (c.ln - (Vector3::new(0.0, 2.0, 42.0) - fb).norm() / 64f64.hypot(8.0)).abs() < 1e-12
        );
    }

    #[test]
    fn frontal_is_zero_and_signs_follow_the_convention() {
        let c = GeometryConstants::from_mean(&five3()).unwrap();
        let a = estimate_geometric(&view(EulerAngles::new(0.0, 0.0, 0.0).unwrap()), &c).unwrap();
        assert!(
            a.yaw.abs() < 1.5 && a.pitch.abs() < 1.5 && a.roll.abs() < 1e-9,
            "{a:?}"
        );
        for (yaw, pitch, roll) in [(20.0, 0.0, 0.0), (0.0, 15.0, 0.0), (-25.0, -10.0, 12.0)] {
            let e =
                estimate_geometric(&view(EulerAngles::new(yaw, pitch, roll).unwrap()), &c).unwrap();
            assert!((e.yaw - yaw).abs() < 4.0, "{yaw} {pitch} {roll} -> {e:?}");
            assert!(
                (e.pitch - pitch).abs() < 4.0,
                "{yaw} {pitch} {roll} -> {e:?}"
            );
            assert!((e.roll - roll).abs() < 4.0, "{yaw} {pitch} {roll} -> {e:?}");
        }
    }

    #[test]
    fn needs_all_five_points() {
        let c = GeometryConstants::from_mean(&five3()).unwrap();
        let v = view(EulerAngles::new(0.0, 0.0, 0.0).unwrap()).with_missing([2]);
        assert!(matches!(
            estimate_geometric(&v, &c),
            Err(Error::TooFewPoints { .. })
        ));
    }
}
