//! Perspective refinement of a weak-perspective fit, for requests that give camera intrinsics.
//!
//! Camera frame: x right, y up, z towards the viewer (the model frame's axes after rotation);
//! the camera sits at the origin and looks along -z. A model point `X` (mm) lands at
//! `p = R X + T` and is seen at pixel
//! `u = cx + fx · p_x / d`, `v = cy - fy · p_y / d` with depth `d = -p_z > 0`.
//! The weak-perspective estimate `[u, -v] = s (R X)[0:2] + t` gives the start: the face's depth
//! is `fx / s` and `T` follows from `t`. Levenberg-Marquardt then refines `R` and `T` on the
//! reprojection error in pixels, with the weak fit's weights (missing, hidden and rejected
//! points stay out).

use nalgebra::{Matrix6, Rotation3, Vector2, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::shape::Shape2;

/// Pinhole intrinsics in pixels (focal lengths and principal point; image x right, y down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels (y down).
    pub cy: f64,
}

impl Intrinsics {
    /// Fails unless the focal lengths are positive and every value is finite.
    pub fn validate(&self) -> Result<()> {
        let v = [self.fx, self.fy, self.cx, self.cy];
        if !v.iter().all(|x| x.is_finite()) {
            return Err(Error::non_finite("camera intrinsics"));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(Error::param(
                "camera",
                format!(
                    "focal lengths must be positive pixels, got fx {} fy {}",
                    self.fx, self.fy
                ),
            ));
        }
        Ok(())
    }

    /// The pixel of a camera-frame point (mm), or `None` behind the camera.
    pub fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        let d = -p.z;
        (d > 0.0).then(|| Vector2::new(self.cx + self.fx * p.x / d, self.cy - self.fy * p.y / d))
    }
}

/// A perspective pose: rotation and the model origin's position in the camera frame (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerspectivePose {
    /// Rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// Model origin in the camera frame, mm.
    pub translation: Vector3<f64>,
    /// Weighted RMS reprojection error in pixels.
    pub rms_px: f64,
}

/// Refines a weak-perspective fit `(r, s, t)` of `shape` to `landmarks` under the pinhole camera
/// `k`. `weights` are per point (0 leaves a point out); at least four must be positive.
pub fn refine_perspective(
    shape: &[Vector3<f64>],
    landmarks: &Shape2,
    weights: &[f64],
    k: &Intrinsics,
    start: (Rotation3<f64>, f64, Vector2<f64>),
) -> Result<PerspectivePose> {
    k.validate()?;
    let n = shape.len();
    if landmarks.len() != n || weights.len() != n {
        return Err(Error::PointCount {
            what: "landmarks and weights for the perspective refinement".into(),
            expected: n,
            got: landmarks.len().min(weights.len()),
        });
    }
    let used = weights
        .iter()
        .zip(landmarks.present())
        .filter(|(w, p)| **w > 0.0 && **p)
        .count();
    if used < 4 {
        return Err(Error::too_few("perspective refinement", 4, used));
    }
    let (r0, s, t) = start;
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::param(
            "scale",
            "the weak-perspective start has no scale",
        ));
    }
    let depth = k.fx / s;
    let mut pose = (
        r0,
        Vector3::new(
            (t.x - k.cx) * depth / k.fx,
            (t.y + k.cy) * depth / k.fy,
            -depth,
        ),
    );
    let y = landmarks.points();
    let w: Vec<f64> = weights
        .iter()
        .zip(landmarks.present())
        .map(|(&w, &p)| if p { w } else { 0.0 })
        .collect();
    let mut lambda = 1e-4;
    let (mut cost, mut jtj, mut jtr) = normal_equations(shape, y, &w, k, &pose.0, &pose.1)
        .ok_or_else(|| Error::Degenerate("the face is behind the camera".into()))?;
    for _ in 0..30 {
        let mut a = jtj;
        for i in 0..6 {
            a[(i, i)] *= 1.0 + lambda;
        }
        let Some(delta) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
            lambda *= 10.0;
            continue;
        };
        let r = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])) * pose.0;
        let tt = pose.1 + Vector3::new(delta[3], delta[4], delta[5]);
        match normal_equations(shape, y, &w, k, &r, &tt) {
            Some((c, j, g)) if c <= cost => {
                let small = delta.fixed_rows::<3>(0).norm() < 1e-9
                    && delta.fixed_rows::<3>(3).norm() < 1e-7 * depth;
                (pose, cost, jtj, jtr) = ((r, tt), c, j, g);
                lambda = (lambda * 0.1).max(1e-12);
                if small {
                    break;
                }
            }
            _ => {
                lambda *= 10.0;
                if lambda > 1e8 {
                    break;
                }
            }
        }
    }
    let sw: f64 = w.iter().sum();
    let rms_px = (cost / sw).sqrt();
    if !rms_px.is_finite() || -pose.1.z <= 0.0 {
        return Err(Error::Numerical(
            "the perspective refinement diverged".into(),
        ));
    }
    Ok(PerspectivePose {
        rotation: Rotation3::from_matrix(pose.0.matrix()),
        translation: pose.1,
        rms_px,
    })
}

/// Cost, `JᵀWJ` and `JᵀWr` over `(ω, T)` with `R ← exp([ω]×) R`; `None` when a weighted point
/// is behind the camera.
fn normal_equations(
    shape: &[Vector3<f64>],
    y: &[Vector2<f64>],
    w: &[f64],
    k: &Intrinsics,
    r: &Rotation3<f64>,
    t: &Vector3<f64>,
) -> Option<(f64, Matrix6<f64>, Vector6<f64>)> {
    let mut cost = 0.0;
    let mut jtj = Matrix6::zeros();
    let mut jtr = Vector6::zeros();
    for ((x, obs), &wi) in shape.iter().zip(y).zip(w) {
        if wi == 0.0 {
            continue;
        }
        let q = r * x;
        let p = q + t;
        let d = -p.z;
        if d <= 1e-9 {
            return None;
        }
        let res = Vector2::new(k.cx + k.fx * p.x / d - obs.x, k.cy - k.fy * p.y / d - obs.y);
        // d(u, v)/dp, then dp/dω = -[q]× and dp/dT = I.
        let du = Vector3::new(k.fx / d, 0.0, k.fx * p.x / (d * d));
        let dv = Vector3::new(0.0, -k.fy / d, -k.fy * p.y / (d * d));
        let rows = [du, dv];
        for (g, e) in rows.iter().zip([res.x, res.y]) {
            // g · (-[q]× δω) = δω · (q × g)... as a row: (q × g)ᵀ.
            let jw = q.cross(g);
            let j = Vector6::new(jw.x, jw.y, jw.z, g.x, g.y, g.z);
            jtj.syger(wi, &j, &j, 1.0);
            jtr.axpy(wi * e, &j, 1.0);
        }
        cost += wi * res.norm_squared();
    }
    jtj.fill_upper_triangle_with_lower_triangle();
    Some((cost, jtj, jtr))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;

    fn face() -> Vec<Vector3<f64>> {
        crate::test_faces::face(8)
    }

    const K: Intrinsics = Intrinsics {
        fx: 800.0,
        fy: 800.0,
        cx: 320.0,
        cy: 240.0,
    };

    /// A face at `a`, `t` (mm) seen by `K`, and the weak-perspective start a fit would give
    /// (scale from the depth, rotation perturbed by a few degrees).
    fn scene(a: EulerAngles, t: Vector3<f64>) -> (Shape2, (Rotation3<f64>, f64, Vector2<f64>)) {
        let r = a.to_rotation();
        let pts = face()
            .iter()
            .map(|x| K.project(&(r * x + t)).unwrap())
            .collect();
        let s = K.fx / -t.z;
        let start_r = EulerAngles::new(a.yaw + 3.0, a.pitch - 2.0, a.roll + 1.0)
            .unwrap()
            .to_rotation();
        let tw = Vector2::new(K.cx + s * t.x, -K.cy + s * t.y);
        (Shape2::full(pts).unwrap(), (start_r, s, tw))
    }

    #[test]
    fn recovers_pose_and_position_of_a_close_face() {
        // 40 cm away, off-centre: weak perspective is visibly wrong here.
        for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (35.0, -12.0, 8.0), (-60.0, 20.0, -15.0)] {
            let a = EulerAngles::new(yaw, pitch, roll).unwrap();
            let t = Vector3::new(60.0, -30.0, -400.0);
            let (lm, start) = scene(a, t);
            let p = refine_perspective(&face(), &lm, &[1.0; 8], &K, start).unwrap();
            let e = EulerAngles::from_rotation(&p.rotation);
            assert!(
                (e.yaw - yaw).abs() < 1e-6 && (e.pitch - pitch).abs() < 1e-6,
                "{a:?} -> {e:?}"
            );
            assert!((e.roll - roll).abs() < 1e-6);
            assert!((p.translation - t).norm() < 1e-6, "{}", p.translation);
            assert!(p.rms_px < 1e-6);
        }
    }

    #[test]
    fn bad_intrinsics_and_too_few_points_are_errors() {
        let a = EulerAngles::new(10.0, 0.0, 0.0).unwrap();
        let (lm, start) = scene(a, Vector3::new(0.0, 0.0, -500.0));
        let bad = Intrinsics { fx: -1.0, ..K };
        assert!(refine_perspective(&face(), &lm, &[1.0; 8], &bad, start).is_err());
        let nan = Intrinsics { cx: f64::NAN, ..K };
        assert!(refine_perspective(&face(), &lm, &[1.0; 8], &nan, start).is_err());
        let w = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!(matches!(
            refine_perspective(&face(), &lm, &w, &K, start),
            Err(Error::TooFewPoints { .. })
        ));
    }
}
