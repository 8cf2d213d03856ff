//! How far to trust an estimate: a standard deviation and a 90% interval per angle.
//!
//! Two steps: [`covariance`] gives every estimate a raw spread from the covariance of a
//! weak-perspective fit at its pose (what the landmarks' residual and layout say), and
//! [`calibration`] maps it, with the yaw, to figures that hold on real faces, per method and
//! point class, learned on faces with ground truth.

pub mod calibration;
pub mod covariance;

pub use calibration::{Calibration, PointClass, Uncertainty, Z90};
pub use covariance::{RawSpread, raw_spread};
