//! facepose: head pose (yaw, pitch, roll and the rotation matrix) from 2D facial landmarks,
//! after Heo & Savvides, "Generic 3D Face Pose Estimation using Facial Shapes" (IJCB 2011).
//!
//! The numeric core ([`geometry`], [`shape`], [`hpr`], [`sfm`], [`synth`]) is pure: no I/O, no
//! async. Conventions (frames, units, angles) live in [`geometry::convention`].

pub mod data;
pub mod error;
pub mod estimate;
pub mod eval;
pub mod geometry;
pub mod hpr;
pub mod model;
pub mod record;
pub mod service;
pub mod sfm;
pub mod shape;
pub mod synth;

pub use error::{Error, Result};
