//! Hidden-point removal: which landmarks of a posed 3D shape the camera sees.
//!
//! [`PaperHpr`] is the paper's method (the one the pipeline uses), [`KatzHpr`] the
//! spherical-flipping baseline, and [`MeshVisibility`] the ground truth from a dense mesh that
//! both are scored against ([`Confusion`]).

pub mod convex_hull;
pub mod katz;
pub mod mesh;
pub mod paper;
pub mod score;
pub mod triangulation;

pub use katz::KatzHpr;
pub use mesh::{MeshVisibility, SurfacePoint};
pub use paper::{DepthTest, HprScratch, PaperHpr};
pub use score::Confusion;
pub use triangulation::Triangulation;
