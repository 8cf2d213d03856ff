//! One interface over every estimator: landmarks in a scheme the model serves -> rotation,
//! angles, per-point visibility at the estimated pose, a fit residual and the method used.

use std::fmt;
use std::str::FromStr;

use nalgebra::{Rotation3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::fit::{FitOptions, fit_rigid};
use super::geometric::estimate_geometric;
use super::morph_fit::{MorphOptions, fit_morphable};
use super::perspective::{Intrinsics, refine_perspective};
use crate::error::{Error, Result};
use crate::geometry::EulerAngles;
use crate::model::{PoseModel, SubsetMap};
use crate::shape::Shape2;

/// The estimators.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The most accurate method for the input (see [`Method::resolve`]).
    #[default]
    Auto,
    /// Rigid weak-perspective fit of the mean shape.
    Fit,
    /// Fit with identity and expression coefficients of the morphable model.
    FitShape,
    /// The paper's ridge regression.
    Regression,
    /// The paper's modified five-point geometric method.
    Geometry,
}

impl Method {
    /// Every method name, for messages.
    pub const NAMES: [&'static str; 5] = ["auto", "fit", "fit-shape", "regression", "geometry"];

    /// The method `auto` stands for, given the model, the input scheme and how many points are
    /// present. Measured on AFLW2000-3D (docs/RESULTS.md): the shape fit is the most accurate with
    /// many points, the rigid fit with five.
    pub fn resolve(self, model: &PoseModel, scheme: &str, present: usize) -> Method {
        match self {
            Method::Auto
                if model.morph.is_some() && scheme == model.scheme.name && present >= 20 =>
            {
                Method::FitShape
            }
            Method::Auto => Method::Fit,
            m => m,
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let i = [
            Method::Auto,
            Method::Fit,
            Method::FitShape,
            Method::Regression,
            Method::Geometry,
        ]
        .iter()
        .position(|m| m == self)
        .unwrap_or(0);
        f.write_str(Method::NAMES[i])
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Method::Auto),
            "fit" => Ok(Method::Fit),
            "fit-shape" => Ok(Method::FitShape),
            "regression" => Ok(Method::Regression),
            "geometry" => Ok(Method::Geometry),
            _ => Err(Error::param(
                "method",
                format!("unknown method {s:?} (known: {})", Method::NAMES.join(", ")),
            )),
        }
    }
}

/// A pose estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    pub rotation: Rotation3<f64>,
    pub angles: EulerAngles,
    /// Per input point: visible at the estimated pose (HPR on the mean shape).
    pub visible: Vec<bool>,
    /// RMS reprojection error of the mean shape at the estimate over the present points,
    /// divided by the projected inter-ocular distance (eye centres): unitless.
    pub residual: f64,
    /// The method that produced it (never `Auto`).
    pub method: Method,
    /// With camera intrinsics: the model origin in the camera frame, mm (x right, y up, z
    /// towards the viewer; the face is at negative z).
    pub translation: Option<Vector3<f64>>,
}

/// How to estimate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EstimateOptions {
    pub method: Method,
    /// Pinhole intrinsics: the fit methods then refine the pose under full perspective.
    pub camera: Option<Intrinsics>,
}

/// Estimates the pose of `landmarks` (image pixels) given in `scheme` with `method`.
pub fn estimate(
    model: &PoseModel,
    scheme: &str,
    landmarks: &Shape2,
    method: Method,
) -> Result<Estimate> {
    estimate_with(
        model,
        scheme,
        landmarks,
        &EstimateOptions {
            method,
            camera: None,
        },
    )
}

/// [`estimate`] with options: with camera intrinsics, the fit methods (and `auto`) refine the
/// weak-perspective pose under full perspective and report the face's position; the paper's
/// methods are weak-perspective by construction and refuse a camera.
pub fn estimate_with(
    model: &PoseModel,
    scheme: &str,
    landmarks: &Shape2,
    opts: &EstimateOptions,
) -> Result<Estimate> {
    if let Some(k) = &opts.camera {
        k.validate()?;
    }
    let method = opts.method;
    let subset = model.subset(scheme)?;
    if landmarks.len() != subset.scheme.len() {
        return Err(Error::PointCount {
            what: format!("landmarks for scheme {scheme}"),
            expected: subset.scheme.len(),
            got: landmarks.len(),
        });
    }
    let present = landmarks.n_present();
    let method = method.resolve(model, scheme, present);
    let map = &subset.map;
    let contour = &subset.scheme.contour;
    if opts.camera.is_some() && matches!(method, Method::Regression | Method::Geometry) {
        return Err(Error::param(
            "camera",
            format!(
                "method {method} is weak-perspective only; use fit, fit-shape or auto with camera intrinsics"
            ),
        ));
    }
    // The fit methods keep their shape and camera for the perspective refinement.
    let mut fitted: Option<(Vec<Vector3<f64>>, super::fit::RigidFit)> = None;
    let rotation = match method {
        Method::Fit => {
            let f = fit_rigid(
                &subset.mean,
                landmarks,
                contour,
                None,
                FitOptions {
                    hpr_aware: false,
                    ..FitOptions::default()
                },
            )?;
            let r = f.rotation;
            fitted = Some((subset.mean.clone(), f));
            r
        }
        Method::FitShape => {
            let morph = model.morph.as_ref().ok_or_else(|| {
                Error::param("method", "fit-shape needs a model with a morphable basis")
            })?;
            let full = model.expand(subset, landmarks).ok_or_else(|| {
                Error::param("method", format!("fit-shape does not take scheme {scheme}"))
            })?;
            let f = fit_morphable(
                morph,
                &full,
                &model.scheme.contour,
                None,
                MorphOptions::default(),
            )?;
            let r = f.camera.rotation;
            let shape = subset.map.map_points(&model.scheme, &f.shape);
            let weights = match &subset.map {
                SubsetMap::Indices(idx) => idx.iter().map(|&i| f.camera.weights[i]).collect(),
                SubsetMap::Anchors => vec![1.0; subset.scheme.len()],
            };
            fitted = Some((
                shape,
                super::fit::RigidFit {
                    weights,
                    ..f.camera
                },
            ));
            r
        }
        Method::Regression => {
            let hidden = |yaw: f64, pitch: f64, out: &mut [bool]| {
                map.hidden_into(
                    &model.scheme,
                    model.visibility.lookup_yaw_pitch(yaw, pitch),
                    out,
                )
            };
            subset.regression.estimate(landmarks, &hidden)?.rotation
        }
        Method::Geometry => {
            let five = match map {
                SubsetMap::Anchors => landmarks.clone(),
                SubsetMap::Indices(_) => landmarks.to_five(&subset.scheme)?,
            };
            estimate_geometric(&five, &model.geometry)?.to_rotation()
        }
        Method::Auto => unreachable!("resolved above"),
    };
    let (rotation, translation) = match (&opts.camera, fitted) {
        (Some(k), Some((shape, f))) => {
            let p = refine_perspective(
                &shape,
                landmarks,
                &f.weights,
                k,
                (f.rotation, f.scale, f.translation),
            )?;
            (p.rotation, Some(p.translation))
        }
        _ => (rotation, None),
    };
    let visible = map.map_visibility(&model.scheme, model.visibility.lookup(&rotation));
    let residual = residual(
        &subset.mean,
        landmarks,
        &rotation,
        &subset.scheme.anchors.eye_left,
        &subset.scheme.anchors.eye_right,
    );
    Ok(Estimate {
        angles: EulerAngles::from_rotation(&rotation),
        rotation,
        visible,
        residual,
        method,
        translation,
    })
}

/// The RMS reprojection error at the best scale and translation for a fixed rotation, over the
/// projected distance between the eye centres.
fn residual(
    mean: &[Vector3<f64>],
    lm: &Shape2,
    r: &Rotation3<f64>,
    eye_l: &[usize],
    eye_r: &[usize],
) -> f64 {
    let pairs: Vec<(Vector2<f64>, Vector2<f64>)> = lm
        .iter_present()
        .map(|(i, p)| ((r * mean[i]).xy(), Vector2::new(p.x, -p.y)))
        .collect();
    let n = pairs.len() as f64;
    let cq = pairs.iter().map(|(q, _)| q).sum::<Vector2<f64>>() / n;
    let cy = pairs.iter().map(|(_, y)| y).sum::<Vector2<f64>>() / n;
    let (mut num, mut den) = (0.0, 0.0);
    for (q, y) in &pairs {
        num += (q - cq).dot(&(y - cy));
        den += (q - cq).norm_squared();
    }
    let s = if den > 0.0 { num / den } else { 0.0 };
    let sse: f64 = pairs
        .iter()
        .map(|(q, y)| (s * (q - cq) + cy - y).norm_squared())
        .sum();
    let eye = |idx: &[usize]| {
        idx.iter().map(|&i| mean[i]).sum::<Vector3<f64>>() / idx.len().max(1) as f64
    };
    let iod = s.abs() * (r * (eye(eye_r) - eye(eye_l))).xy().norm();
    if iod > 0.0 {
        (sse / n).sqrt() / iod
    } else {
        f64::INFINITY
    }
}
