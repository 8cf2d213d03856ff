//! One face through the core, the same for both transports: resolve scheme and method against
//! the model, build the shape, estimate, check the output is finite. Batches run here too, off
//! the async reactor when they are big, with the request's deadline checked as they go.

use std::time::Instant;

use crate::error::ServiceError;
use crate::registry::ServedModel;

use facepose_core::estimate::Intrinsics;
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_records::PoseRecord;

/// One face as a transport hands it over. Empty strings mean "not given".
#[derive(Debug, Clone, Default)]
pub struct FaceSpec<'a> {
    pub landmarks: &'a [Option<[f64; 2]>],
    pub scheme: Option<&'a str>,
    pub method: Option<&'a str>,
    pub camera: Option<Intrinsics>,
    /// `projected` (default) or `contour`: see [`LandmarkStyle`].
    pub style: Option<&'a str>,
    /// With it, the landmarks are normalized to this image size (MediaPipe's x, y).
    pub image_size: Option<ImageSize>,
}

/// An estimate as the transports send it, with the rotation for stream smoothing and the
/// scheme it was made in.
#[derive(Debug, Clone)]
pub struct FacePose {
    pub record: PoseRecord,
    pub rotation: facepose_core::geometry::Rotation,
    /// The covariance of the rotation's small turn (radians²), when the answer has an
    /// uncertainty: what the stream's Kalman filter weighs the frame by.
    pub turn_cov: Option<nalgebra::Matrix3<f64>>,
    pub scheme: String,
}

fn given(s: Option<&str>) -> Option<&str> {
    s.filter(|s| !s.is_empty())
}

/// Estimates one face with `model`. Every failure is a client error with a message.
pub fn estimate_face(model: &ServedModel, face: &FaceSpec<'_>) -> Result<FacePose, ServiceError> {
    for (what, name) in [
        ("scheme", face.scheme),
        ("method", face.method),
        ("landmark style", face.style),
    ] {
        ServiceError::check_name_length(what, name.unwrap_or_default())?;
    }
    // The scheme first: the landmark count is checked against it. Unnamed, the count chooses
    // it where only one scheme has that many points.
    let scheme = match given(face.scheme) {
        Some(s) => model.model.scheme(s)?.name.as_str(),
        None => model
            .model
            .scheme_for_count(face.landmarks.len())?
            .name
            .as_str(),
    };
    let method: Method = match given(face.method) {
        Some(m) => m.parse()?,
        None => Method::Auto,
    };
    if !method.is_supported_by(&model.model) {
        return Err(ServiceError::invalid(format!(
            "method {method} needs {}; model {:?} has none",
            method.spec().needs.what(),
            model.name
        )));
    }
    let style: LandmarkStyle = match given(face.style) {
        Some(s) => s.parse()?,
        None => LandmarkStyle::default(),
    };
    let shape = pixel_shape(face.landmarks, face.image_size)?;
    let estimate = estimate_with(
        &model.model,
        scheme,
        &shape,
        &EstimateOptions {
            method,
            camera: face.camera,
            style,
        },
    )?;
    let rotation = estimate.rotation;
    let turn_cov = estimate.uncertainty.map(|u| u.turn_cov);
    let record = PoseRecord::from(estimate);
    if !record.is_finite() {
        return Err(ServiceError::invalid(
            "could not estimate a pose from these landmarks: the result is not finite; \
             check that they are the pixel coordinates of one face",
        ));
    }
    Ok(FacePose {
        record,
        rotation,
        turn_cov,
        scheme: scheme.to_string(),
    })
}

/// Batches with more faces than this run on the blocking pool, not on the async workers.
pub const INLINE_FACES: usize = 8;

/// Maps `f` over a batch's faces, each independently. Stops early once `deadline` has passed
/// (checked every few faces), so that a timed-out batch does not keep a core busy.
pub fn for_each_face<T, R>(
    faces: impl IntoIterator<Item = T>,
    deadline: Option<Instant>,
    mut f: impl FnMut(T) -> R,
) -> Result<Vec<R>, DeadlinePassed> {
    let faces = faces.into_iter();
    let mut out = Vec::with_capacity(faces.size_hint().0);
    for (i, face) in faces.enumerate() {
        if i % 16 == 15 && deadline.is_some_and(|d| Instant::now() > d) {
            return Err(DeadlinePassed);
        }
        out.push(f(face));
    }
    Ok(out)
}

/// The deadline passed during a batch.
#[derive(Debug, Clone, Copy)]
pub struct DeadlinePassed;
