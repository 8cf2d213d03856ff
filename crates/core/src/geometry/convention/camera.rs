//! Where the face is and which camera sees it: what the `opencv` and `mediapipe` conventions
//! need beyond the rotation, and the camera's orientation in the world.
//!
//! A pose is carried over from the camera facepose fitted in to a convention's camera (the
//! request's intrinsics, an assumed camera, MediaPipe's virtual camera) through the *view*: the
//! pixel where the model origin lands, the image scale there (pixels per millimetre) and the
//! rotation relative to the line of sight. Each camera then places the face on its own ray
//! through that pixel at the depth `f / scale` and turns the view rotation by the ray's
//! direction (`R_cam = R_ray R_view`, `R_ray` the shortest turn of the optical axis onto the
//! ray). For a perspective pose under the same camera this gives the pose back exactly; for a
//! weak-perspective fit, which sees the face as if along the optical axis, it is the first-order
//! perspective pose (measured against `cv2.solvePnP` in the conventions' tests).

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};

use super::euler::{Axes, EulerSpec};
use super::request::ConventionError;
use crate::estimate::Intrinsics;
use crate::geometry::moments::Moments;
use crate::shape::Shape2;

pub use crate::shape::pixels::ImageSize;

/// The image size `width` x `height` (pixels) a camera is assumed from; fails unless both are
/// finite and positive.
pub fn image_size(width: f64, height: f64) -> Result<ImageSize, ConventionError> {
    if !(width.is_finite() && height.is_finite() && width > 0.0 && height > 0.0) {
        return Err(ConventionError::BadImageSize { width, height });
    }
    Ok(ImageSize { width, height })
}

/// Where the face is, as the estimate knows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Placement {
    /// A weak-perspective fit `[u, -v] = s (R X)[0:2] + t`: the scale `s` (pixels per mm) and
    /// the translation `t` (pixels, y-up plane: the model origin is at pixel `(t.x, -t.y)`).
    Weak {
        /// Image scale `s`, pixels per mm.
        scale: f64,
        /// Translation `t`, pixels in the y-up image plane.
        translation: Vector2<f64>,
    },
    /// A perspective pose under `camera`: the model origin in the camera frame (mm; x right,
    /// y up, z towards the viewer, the face at negative z).
    Perspective {
        /// Model origin in the camera frame, mm.
        translation: Vector3<f64>,
        /// The camera the pose was refined under.
        camera: Intrinsics,
    },
}

/// What any camera needs to place the face: the origin's pixel, the image scale there (pixels
/// per mm) and the rotation relative to the line of sight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// The model origin's pixel (image x right, y down).
    pub origin_px: Vector2<f64>,
    /// Image scale at the origin, pixels per mm.
    pub scale: f64,
    /// Rotation relative to the line of sight (model frame to camera axes).
    pub rotation: Rotation3<f64>,
}

/// A pose in a camera: rotation and the model origin (mm), facepose's camera axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// Rotation, model frame to facepose's camera axes (x right, y up, z back).
    pub rotation: Rotation3<f64>,
    /// Model origin in the camera frame, mm.
    pub translation: Vector3<f64>,
}

/// The shortest turn of the optical axis (`-z`) onto the direction `d`.
fn ray_turn(d: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::rotation_between(&-Vector3::z(), d).unwrap_or_else(Rotation3::identity)
}

impl Placement {
    /// Fails on non-finite values, a non-positive scale, bad intrinsics or a face behind the
    /// camera.
    pub fn validate(&self) -> Result<(), ConventionError> {
        match self {
            Placement::Weak { scale, translation } => {
                if !(scale.is_finite() && *scale > 0.0 && translation.iter().all(|v| v.is_finite()))
                {
                    return Err(ConventionError::BadPlacement(format!(
                        "the weak-perspective scale must be positive and the translation finite, \
                         got {scale} and ({}, {})",
                        translation.x, translation.y
                    )));
                }
            }
            Placement::Perspective {
                translation,
                camera,
            } => {
                check_intrinsics(camera)?;
                if !translation.iter().all(|v| v.is_finite()) || translation.z >= 0.0 {
                    return Err(ConventionError::BadPlacement(format!(
                        "the face must be in front of the camera (z < 0), got {translation}"
                    )));
                }
            }
        }
        Ok(())
    }

    /// The weak-perspective placement of `shape` (model frame, mm) turned by `r` that best fits
    /// the present `landmarks` (pixels): the least-squares scale and translation at that
    /// rotation. What a caller without the fit's own scale and translation (the paper's
    /// methods keep none) can pass; `None` without a positive scale.
    pub fn fit_weak(
        shape: &[Vector3<f64>],
        landmarks: &Shape2,
        r: &Rotation3<f64>,
    ) -> Option<Placement> {
        let m = Moments::of_landmarks(shape, landmarks, None);
        let (scale, _) = m.best_scale(r)?;
        if !(scale.is_finite() && scale > 0.0) {
            return None;
        }
        Some(Placement::Weak {
            scale,
            translation: m.cy - scale * (r * m.cx).xy(),
        })
    }

    /// The view of a face turned by `r` placed here.
    pub fn view(&self, r: &Rotation3<f64>) -> View {
        match *self {
            Placement::Weak { scale, translation } => View {
                origin_px: Vector2::new(translation.x, -translation.y),
                scale,
                rotation: *r,
            },
            Placement::Perspective {
                translation,
                camera,
            } => {
                let d = -translation.z;
                View {
                    origin_px: Vector2::new(
                        camera.cx + camera.fx * translation.x / d,
                        camera.cy - camera.fy * translation.y / d,
                    ),
                    scale: camera.fx / d,
                    rotation: ray_turn(&translation).inverse() * r,
                }
            }
        }
    }

    /// The pose of a face turned by `r` placed here, in the camera `k`: exactly the estimate's
    /// own for a perspective placement under `k`.
    pub fn in_camera(&self, r: &Rotation3<f64>, k: &Intrinsics) -> CameraPose {
        if let Placement::Perspective {
            translation,
            camera,
        } = self
            && camera == k
        {
            return CameraPose {
                rotation: *r,
                translation: *translation,
            };
        }
        let v = self.view(r);
        let d = k.fx / v.scale;
        let t = Vector3::new(
            (v.origin_px.x - k.cx) * d / k.fx,
            -(v.origin_px.y - k.cy) * d / k.fy,
            -d,
        );
        CameraPose {
            rotation: ray_turn(&t) * v.rotation,
            translation: t,
        }
    }
}

/// The rotation nearest to `m` (polar factor by SVD, determinant +1). Unlike nalgebra's
/// `Rotation3::from_matrix`, whose iteration starts at the identity, it is right for half
/// turns (a camera mounted upside down).
pub fn nearest_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Rotation3::identity();
    };
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    Rotation3::from_matrix_unchecked(u * d * v_t)
}

/// Fails unless the intrinsics are finite and the focal lengths positive, saying which value.
pub fn check_intrinsics(k: &Intrinsics) -> Result<(), ConventionError> {
    for (name, v) in [("fx", k.fx), ("fy", k.fy), ("cx", k.cx), ("cy", k.cy)] {
        if !v.is_finite() {
            return Err(ConventionError::BadIntrinsics(format!(
                "{name} is {v}; every intrinsic must be a finite number of pixels"
            )));
        }
    }
    if k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(ConventionError::BadIntrinsics(format!(
            "the focal lengths must be positive pixels, got fx {} fy {}",
            k.fx, k.fy
        )));
    }
    Ok(())
}

/// The camera assumed when a request gives no intrinsics, as the OpenCV head-pose tutorials
/// (and, with another factor, OpenFace) guess it: focal length = the image width in pixels
/// (a horizontal field of view of 2·atan(1/2) ≈ 53°), square pixels, the principal point at
/// the image centre.
pub fn assumed_camera(size: ImageSize) -> Intrinsics {
    Intrinsics {
        fx: size.width,
        fy: size.width,
        cx: size.width / 2.0,
        cy: size.height / 2.0,
    }
}

/// The camera's orientation in the world: `C` maps camera-frame vectors (facepose's camera
/// axes: x right, y up, z towards the viewer) to world vectors, so that the head's rotation in
/// the world is `C R` and its position `C T` (the camera at the world's origin). A webcam
/// tilted down by 20° is `C = Rx(-20°)` (standard matrix): its optical axis `-z` points 20°
/// below the horizon.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraOrientation(Rotation3<f64>);

/// How far from a rotation a given camera orientation may be (orthonormality and determinant).
pub const ORIENTATION_TOL: f64 = 1e-6;

impl CameraOrientation {
    /// The identity: the world is the camera frame.
    pub fn identity() -> Self {
        CameraOrientation(Rotation3::identity())
    }

    /// From a row-major 3x3 matrix written in the axes `axes` (for both the camera's and the
    /// world's frame, see [`Axes`]); fails unless it is a rotation to within
    /// [`ORIENTATION_TOL`].
    pub fn from_rows(rows: [[f64; 3]; 3], axes: Axes) -> Result<Self, ConventionError> {
        let m = Matrix3::from_fn(|i, j| rows[i][j]);
        if !m.iter().all(|v| v.is_finite()) {
            return Err(ConventionError::NotARotation(
                "the camera orientation has a value that is not a finite number".into(),
            ));
        }
        let err = (m.transpose() * m - Matrix3::identity()).abs().max();
        let det = m.determinant();
        if err > ORIENTATION_TOL || (det - 1.0).abs() > ORIENTATION_TOL {
            return Err(ConventionError::NotARotation(format!(
                "the camera orientation must be a rotation matrix (orthonormal rows, \
                 determinant +1, to within {ORIENTATION_TOL:e}); this one's rows are \
                 orthonormal to within {err:.2e} and its determinant is {det:.6}"
            )));
        }
        // Re-orthonormalize the tiny residue away.
        let r = nearest_rotation(&axes.unexpress(&m));
        Ok(CameraOrientation(r))
    }

    /// From a unit quaternion `(w, x, y, z)` (Hamilton) in the axes `axes`; fails unless its
    /// norm is within 1e-6 of 1.
    pub fn from_quaternion(
        w: f64,
        x: f64,
        y: f64,
        z: f64,
        axes: Axes,
    ) -> Result<Self, ConventionError> {
        let n = (w * w + x * x + y * y + z * z).sqrt();
        if !n.is_finite() || (n - 1.0).abs() > ORIENTATION_TOL {
            return Err(ConventionError::NotARotation(format!(
                "the camera orientation quaternion must have norm 1 (to within \
                 {ORIENTATION_TOL:e}), got {n}"
            )));
        }
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        let m = q.to_rotation_matrix().into_inner();
        Ok(CameraOrientation(Rotation3::from_matrix_unchecked(
            axes.unexpress(&m),
        )))
    }

    /// From Euler angles in a named convention.
    pub fn from_euler(spec: &EulerSpec, angles: [f64; 3]) -> Result<Self, ConventionError> {
        if !angles.iter().all(|a| a.is_finite()) {
            return Err(ConventionError::NotARotation(
                "the camera orientation's angles must be finite numbers".into(),
            ));
        }
        Ok(CameraOrientation(Rotation3::from_matrix_unchecked(
            spec.rotation(angles),
        )))
    }

    /// The rotation, facepose's axes.
    pub fn rotation(&self) -> &Rotation3<f64> {
        &self.0
    }

    /// A camera pose in the world.
    pub fn apply(&self, p: &CameraPose) -> CameraPose {
        CameraPose {
            rotation: self.0 * p.rotation,
            translation: self.0 * p.translation,
        }
    }
}
