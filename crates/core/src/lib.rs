//! facepose: head pose (yaw, pitch, roll and the rotation matrix) from 2D facial landmarks,
//! after Heo & Savvides, "Generic 3D Face Pose Estimation using Facial Shapes" (IJCB 2011).
//!
//! This crate is the numeric core: pure, no I/O and no async (its dependencies have no runtime
//! and `clippy.toml` refuses file, network and process calls). Conventions (frames, units,
//! angles) live in [`geometry::convention`]. Files are read and written by `facepose-files`;
//! the service is `facepose-service`.

pub mod data;
pub mod error;
pub mod estimate;
pub mod geometry;
pub mod hpr;
pub mod model;
pub mod parallel;
pub mod pose;
pub mod sfm;
pub mod shape;
pub mod synth;
pub mod uncertainty;

pub use error::{Error, Result};

/// Small synthetic faces for the unit tests of several modules.
#[cfg(test)]
pub(crate) mod test_faces {
    use nalgebra::Vector3;

    /// The first `n` (at most 10) points of a small non-planar face, model frame, mm: eye
    /// centres, nose tip, mouth corners, ears, chin, forehead, brow.
    pub fn face(n: usize) -> Vec<Vector3<f64>> {
        let all = [
            Vector3::new(-32.0, 35.0, 0.0),
            Vector3::new(32.0, 35.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 8.0),
            Vector3::new(25.0, -30.0, 8.0),
            Vector3::new(-60.0, 10.0, -60.0),
            Vector3::new(60.0, 10.0, -60.0),
            Vector3::new(0.0, -70.0, 10.0),
            Vector3::new(0.0, 40.0, 20.0),
            Vector3::new(-15.0, 50.0, 10.0),
        ];
        all[..n].to_vec()
    }
}
