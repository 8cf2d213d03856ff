//! Pose estimators: landmarks (some may be missing) -> rotation, angles, visibility, residual.
//!
//! The methods, each over its own parameters: the paper's [`geometric`] five-point method and
//! [`regression`], and beyond the paper the rigid [`fit`] and the morphable [`morph_fit`]. A
//! trained model ([`crate::model`]) holds those parameters, and [`crate::pose`] is the one entry
//! point that runs a method with a model: this module knows no model.

pub(crate) mod dense;
pub mod detector;
pub mod fit;
pub mod geometric;
pub mod morph_fit;
pub mod perspective;
pub mod regression;
pub mod visibility_map;

pub use fit::{FitOptions, Hidden, RigidFit, fit_rigid};
pub use perspective::Intrinsics;
pub use visibility_map::VisibilityMap;
