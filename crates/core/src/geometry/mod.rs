//! Rotations, the angle convention, projection, the moments of a weak-perspective fit,
//! Procrustes alignment and temporal smoothing of rotations.

pub mod convention;
pub mod moments;
pub mod procrustes;
pub mod projection;
pub mod rotation_kalman;
pub mod smoothing;

pub use convention::{
    EulerAngles, geodesic_deg, rotation_from_rows, rotation_from_two_rows, rotation_rows, wrap_deg,
};
pub use procrustes::{Scaling, Similarity2, Similarity3, align2, align3, generalized_procrustes};
pub use projection::{WeakPerspective, image_to_plane};

/// A rotation of the model frame into the camera frame (what estimators return).
pub type Rotation = nalgebra::Rotation3<f64>;

/// The covariance of a rotation's small turn `δ` (`R ← exp([δ]ₓ) R`), radians²: what a
/// calibrated uncertainty carries and the stream's Kalman filter weighs a frame by.
pub type TurnCovariance = nalgebra::Matrix3<f64>;
