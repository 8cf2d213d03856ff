//! Pose estimators: landmarks (some may be missing) -> rotation, angles, visibility, residual.

pub mod fit;
pub mod morph_fit;
pub mod regression;
pub mod visibility_map;

pub use fit::{FitOptions, RigidFit, fit_rigid};
pub use visibility_map::VisibilityMap;
