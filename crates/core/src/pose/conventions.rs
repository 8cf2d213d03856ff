//! An estimate in the caller's conventions (`geometry::convention`): what the estimate knows of
//! where the face is, the model's MediaPipe mesh frame, and the refit under another camera,
//! gathered for [`convention::answer`]. Runs only for a request that names conventions.

use crate::error::Result;
use crate::geometry::convention::{
    self, CameraOrientation, CameraPose, ConventionAnswers, ConventionRequest, MeshFrame, Placement,
};
use crate::model::PoseModel;
use crate::shape::Shape2;
use crate::shape::pixels::ImageSize;

use super::{Estimate, EstimateOptions, estimate_with};

/// What a request asks of its answer's conventions.
#[derive(Debug, Clone, Copy, Default)]
pub struct ConventionOptions<'a> {
    /// The conventions asked for, in the request's order.
    pub requests: &'a [ConventionRequest],
    /// The camera's orientation in the world: the answers then refer to the world.
    pub orientation: Option<CameraOrientation>,
    /// The image's size, pixels (the assumed camera of `opencv`, MediaPipe's virtual camera).
    pub image_size: Option<ImageSize>,
}

/// The answers in `conv`'s conventions for `estimate`, which `estimate_with(model, scheme,
/// landmarks, opts)` returned. `opencv` without intrinsics and `mediapipe` refit the landmarks
/// under their camera (one more perspective refinement each).
pub fn conventions_of(
    model: &PoseModel,
    scheme: &str,
    landmarks: &Shape2,
    opts: &EstimateOptions,
    estimate: &Estimate,
    conv: &ConventionOptions<'_>,
) -> Result<ConventionAnswers> {
    if conv.requests.is_empty() {
        return Ok(ConventionAnswers::default());
    }
    let rotation = estimate.rotation;
    let placement = match (opts.camera, estimate.translation) {
        (Some(camera), Some(translation)) => Some(Placement::Perspective {
            translation,
            camera,
        }),
        _ => match model.mesh_scheme(scheme) {
            Some((_, ms)) => {
                Placement::fit_weak(&ms.points, &ms.pose_landmarks(landmarks), &rotation)
            }
            None => Placement::fit_weak(&model.subset(scheme)?.mean, landmarks, &rotation),
        },
    };
    let wants_mesh = conv
        .requests
        .iter()
        .any(|r| matches!(r, ConventionRequest::MediaPipe));
    let mesh = match (&model.mesh, wants_mesh) {
        (Some(m), true) => Some(MeshFrame::of_served_mesh(&m.source().vertices)?),
        _ => None,
    };
    // The refit runs the method that answered (`auto` resolved): a camera would otherwise make
    // `auto` pick a fit where it answered with the detector regression. A method without a
    // perspective refinement refuses the camera, and its own rotation is carried over.
    let refit = |k: &crate::estimate::Intrinsics| {
        let o = EstimateOptions {
            method: estimate.method,
            camera: Some(*k),
            ..*opts
        };
        let e = estimate_with(model, scheme, landmarks, &o).ok()?;
        Some(CameraPose {
            rotation: e.rotation,
            translation: e.translation?,
        })
    };
    let size = match conv.image_size {
        Some(s) => Some(convention::image_size(s.width, s.height)?),
        None => None,
    };
    Ok(convention::answer(
        conv.requests,
        &convention::PoseInput {
            rotation,
            placement,
            image_size: size,
            orientation: conv.orientation,
            mesh: mesh.as_ref(),
            refit: Some(&refit),
        },
    )?)
}
