//! One face through the core, the same for every transport and use case
//! ([`crate::estimate`]): resolve scheme and method against the model, build the shape,
//! estimate, check the output is finite.

use crate::error::ServiceError;
use crate::registry::ServedModel;

use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::convention::{CameraOrientation, ConventionRequest};
use facepose_core::pose::{ConventionOptions, conventions_of};
use facepose_core::pose::{EstimateOptions, LandmarkStyle, Method, estimate_with};
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_records::{ConventionsRecord, PoseRecord};

/// One face as a transport hands it over. Empty strings mean "not given".
#[derive(Debug, Clone, Default)]
pub struct FaceSpec<'a> {
    /// The landmarks, image pixels (y down); `None` for a missing point.
    pub landmarks: &'a [Option<[f64; 2]>],
    /// The scheme's name.
    pub scheme: Option<&'a str>,
    /// The method's name.
    pub method: Option<&'a str>,
    /// Camera intrinsics, for the perspective refinement.
    pub camera: Option<Intrinsics>,
    /// `projected` (default) or `contour`: see [`LandmarkStyle`].
    pub style: Option<&'a str>,
    /// With it, the landmarks are normalized to this image size (MediaPipe's x, y).
    pub image_size: Option<ImageSize>,
    /// The conventions to answer in besides facepose's own (none: nothing more is computed).
    pub conventions: &'a [ConventionRequest],
    /// The camera's orientation in the world: the conventions' answers then refer to it.
    pub orientation: Option<CameraOrientation>,
}

/// An estimate as the transports send it, with the rotation for stream smoothing and the
/// scheme it was made in.
#[derive(Debug, Clone)]
pub struct FacePose {
    /// The record the transports encode.
    pub record: PoseRecord,
    /// The estimated rotation.
    pub rotation: facepose_core::geometry::Rotation,
    /// The covariance of the rotation's small turn (radians²) the stream's Kalman filter weighs
    /// the frame by ([`facepose_core::pose::Estimate::filter_cov`]), when the answer has an
    /// uncertainty.
    pub turn_cov: Option<facepose_core::geometry::TurnCovariance>,
    /// The scheme the estimate was made in.
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
    let opts = EstimateOptions {
        method,
        camera: face.camera,
        style,
    };
    let estimate = estimate_with(&model.model, scheme, &shape, &opts)?;
    let conventions = if face.conventions.is_empty() {
        None
    } else {
        Some(conventions_of(
            &model.model,
            scheme,
            &shape,
            &opts,
            &estimate,
            &ConventionOptions {
                requests: face.conventions,
                orientation: face.orientation,
                image_size: face.image_size,
            },
        )?)
    };
    let rotation = estimate.rotation;
    let turn_cov = estimate.filter_cov();
    let mut record = PoseRecord::from(estimate);
    if let Some(c) = &conventions {
        record
            .warnings
            .extend(c.warnings.iter().map(ToString::to_string));
        record.conventions = Some(Box::new(ConventionsRecord::from(c)));
    }
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
