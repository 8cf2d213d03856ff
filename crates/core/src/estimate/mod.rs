//! Pose estimators: landmarks (some may be missing) -> rotation, angles, visibility, residual.
//!
//! [`pipeline::estimate`] is the one entry point; the modules hold the methods: the paper's
//! [`geometric`] five-point method and [`regression`], and beyond the paper the rigid
//! [`fit`] and the morphable [`morph_fit`].

pub mod fit;
pub mod geometric;
pub mod morph_fit;
pub mod perspective;
pub mod pipeline;
pub mod regression;
pub mod visibility_map;

pub use fit::{FitOptions, Hidden, RigidFit, fit_rigid};
pub use perspective::Intrinsics;
pub use pipeline::{Estimate, EstimateOptions, LandmarkStyle, Method, estimate, estimate_with};
pub use visibility_map::VisibilityMap;
