//! Landmark schemes and 2D/3D shapes.

pub mod builtin;
pub mod pixels;
pub mod scheme;
pub mod shapes;

pub use builtin::{BUILTIN_NAMES, BUILTIN_SCHEMES, BuiltinScheme, PointClass, inner51};
pub use scheme::{Anchors, DLIB5_IN_IBUG68, MAX_POINTS, Scheme, dlib5, five, ibug68};
pub use shapes::{Shape2, Shape3, normalized_vector};

/// A 3D point of a shape: model frame, mm.
pub type Point3 = nalgebra::Vector3<f64>;
