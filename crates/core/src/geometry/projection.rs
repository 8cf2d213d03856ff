//! Weak-perspective (scaled orthographic) projection with the image y flip:
//! `[u, -v] = s · (R X)[0:2] + t`, where `(u, v)` are image pixels (origin top-left, x right,
//! y down) and `X` is a model-frame point (x towards the subject's left, y up, z towards the
//! camera). `t` is expressed in the y-up plane, so `v = -(s (R X)_y + t_y)`.

use nalgebra::{Rotation3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result, ensure_finite};

/// A weak-perspective camera: rotation, isotropic scale (pixels per model unit) and 2D
/// translation in the y-up image plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WeakPerspective {
    /// Rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// Scale `s`, pixels per model unit (mm).
    pub scale: f64,
    /// Translation `t`, pixels in the y-up image plane.
    pub translation: Vector2<f64>,
}

impl WeakPerspective {
    /// Fails on a non-finite or non-positive scale, or a non-finite translation.
    pub fn new(rotation: Rotation3<f64>, scale: f64, translation: Vector2<f64>) -> Result<Self> {
        ensure_finite(
            "projection",
            rotation.matrix().iter().chain(translation.iter()),
        )?;
        if !(scale.is_finite() && scale > 0.0) {
            return Err(Error::param(
                "scale",
                format!("must be positive and finite, got {scale}"),
            ));
        }
        Ok(WeakPerspective {
            rotation,
            scale,
            translation,
        })
    }

    /// Image pixel coordinates (y down) of a model-frame point.
    pub fn project(&self, x: &Vector3<f64>) -> Vector2<f64> {
        let r = self.rotation * x;
        Vector2::new(
            self.scale * r.x + self.translation.x,
            -(self.scale * r.y + self.translation.y),
        )
    }
}

/// Image pixels (y down) to the y-up plane in which the projection is linear: `(u, v) -> (u, -v)`.
pub fn image_to_plane(p: &Vector2<f64>) -> Vector2<f64> {
    Vector2::new(p.x, -p.y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;
    use approx::assert_relative_eq;

    #[test]
    fn frontal_projection_flips_y() {
        let cam =
            WeakPerspective::new(Rotation3::identity(), 2.0, Vector2::new(100.0, -200.0)).unwrap();
        // A point above the centre (y up in the model) lands above it in the image (smaller v).
        let centre = cam.project(&Vector3::zeros());
        let above = cam.project(&Vector3::new(0.0, 10.0, 0.0));
        assert_relative_eq!(centre, Vector2::new(100.0, 200.0));
        assert_relative_eq!(above, Vector2::new(100.0, 180.0));
        // The subject's left (+x) is image-right.
        assert!(cam.project(&Vector3::new(10.0, 0.0, 0.0)).x > centre.x);
    }

    #[test]
    fn positive_yaw_moves_the_nose_to_image_left() {
        let r = EulerAngles::new(30.0, 0.0, 0.0).unwrap().to_rotation();
        let cam = WeakPerspective::new(r, 1.0, Vector2::zeros()).unwrap();
        let nose = cam.project(&Vector3::new(0.0, 0.0, 40.0));
        assert!(nose.x < -19.0);
    }

    #[test]
    fn rejects_bad_scale() {
        for s in [0.0, -1.0, f64::NAN] {
            assert!(WeakPerspective::new(Rotation3::identity(), s, Vector2::zeros()).is_err());
        }
    }
}
