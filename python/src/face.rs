//! One face through the core, as the service does it (`crates/app/src/pose.rs`,
//! `estimate_face`): name checks, the scheme (named, else by the landmark count), the method and
//! landmark style, normalized coordinates to pixels, the estimate, and the check that the answer
//! is finite. The same order of checks gives the same message for the same bad input.

use facepose_core::estimate::Intrinsics;
use facepose_core::geometry::EulerAngles;
use facepose_core::geometry::convention::ConventionRequest;
use facepose_core::model::PoseModel;
use facepose_core::pose::{
    ConventionOptions, Estimate, EstimateOptions, LandmarkStyle, Method, conventions_of,
    estimate_with,
};
use facepose_core::shape::pixels::{ImageSize, pixel_shape};
use facepose_records::{ConventionsRecord, PoseRecord};

use crate::errors::FaceError;

/// The longest scheme, method or landmark style name (the service's `MAX_NAME`).
pub const MAX_NAME: usize = 64;

/// The options shared by every face of a call, parsed once.
#[derive(Debug, Clone)]
pub struct Options {
    pub scheme: Option<String>,
    pub opts: EstimateOptions,
    pub image_size: Option<ImageSize>,
    /// The conventions to answer in besides facepose's own (docs/API.md, "Answers in your
    /// convention").
    pub conventions: Vec<ConventionRequest>,
}

fn check_name_length(what: &str, name: &str) -> Result<(), FaceError> {
    if name.len() <= MAX_NAME {
        return Ok(());
    }
    Err(FaceError::Invalid(format!(
        "{what} names have at most {MAX_NAME} characters; this one has {}",
        name.len()
    )))
}

fn given(s: Option<&str>) -> Option<&str> {
    s.filter(|s| !s.is_empty())
}

impl Options {
    /// Parses the options as the service does; `model_name` is for the message of a method
    /// the model lacks.
    #[allow(clippy::too_many_arguments)]
    pub fn parse(
        model: &PoseModel,
        model_name: &str,
        scheme: Option<&str>,
        method: Option<&str>,
        style: Option<&str>,
        camera: Option<[f64; 4]>,
        image_size: Option<[f64; 2]>,
        conventions: Option<&str>,
    ) -> Result<Options, FaceError> {
        for (what, name) in [
            ("scheme", scheme),
            ("method", method),
            ("landmark style", style),
        ] {
            check_name_length(what, name.unwrap_or_default())?;
        }
        // A named scheme is checked here, before any face (the service checks it per face;
        // the message is the same).
        let scheme = match given(scheme) {
            Some(s) => Some(model.scheme(s)?.name.clone()),
            None => None,
        };
        let method: Method = match given(method) {
            Some(m) => m.parse()?,
            None => Method::Auto,
        };
        if !method.is_supported_by(model) {
            return Err(FaceError::Invalid(format!(
                "method {method} needs {}; model {model_name:?} has none",
                method.spec().needs.what()
            )));
        }
        let style: LandmarkStyle = match given(style) {
            Some(s) => s.parse()?,
            None => LandmarkStyle::default(),
        };
        let camera = camera.map(|[fx, fy, cx, cy]| Intrinsics { fx, fy, cx, cy });
        if let Some(k) = &camera {
            k.validate()?;
        }
        let image_size = image_size.map(|[width, height]| ImageSize { width, height });
        if let Some(s) = &image_size {
            s.validate()?;
        }
        let conventions = match conventions.filter(|c| !c.trim().is_empty()) {
            Some(c) => ConventionRequest::parse_list(c).map_err(facepose_core::Error::from)?,
            None => Vec::new(),
        };
        Ok(Options {
            conventions,
            scheme,
            opts: EstimateOptions {
                method,
                camera,
                style,
            },
            image_size,
        })
    }
}

/// One face's answer; `scheme` is the model's name of it.
#[derive(Debug, Clone)]
pub struct FacePose<'m> {
    pub estimate: Estimate,
    pub scheme: &'m str,
    /// The answers in the conventions asked for, as the service's JSON (`conventions` of a
    /// pose); their warnings are in the estimate's warnings' wake, in `extra_warnings`.
    pub conventions: Option<String>,
    pub extra_warnings: Vec<String>,
}

/// Estimates one face: `points` as the caller gave them (`None`: missing).
pub fn estimate_face<'m>(
    model: &'m PoseModel,
    o: &Options,
    points: &[Option<[f64; 2]>],
) -> Result<FacePose<'m>, FaceError> {
    let scheme = match &o.scheme {
        Some(s) => model.scheme(s)?.name.as_str(),
        None => model.scheme_for_count(points.len())?.name.as_str(),
    };
    let shape = pixel_shape(points, o.image_size)?;
    let estimate = estimate_with(model, scheme, &shape, &o.opts)?;
    let not_finite = || {
        FaceError::Invalid(
            "could not estimate a pose from these landmarks: the result is not finite; \
             check that they are the pixel coordinates of one face"
                .into(),
        )
    };
    if o.conventions.is_empty() {
        if !is_finite(&estimate) {
            return Err(not_finite());
        }
        return Ok(FacePose {
            estimate,
            scheme,
            conventions: None,
            extra_warnings: Vec::new(),
        });
    }
    let c = conventions_of(
        model,
        scheme,
        &shape,
        &o.opts,
        &estimate,
        &ConventionOptions {
            requests: &o.conventions,
            orientation: None,
            image_size: o.image_size,
        },
    )?;
    // The service's record, for its finite check over the conventions' numbers too.
    let mut record = PoseRecord::from(&estimate);
    record.conventions = Some(Box::new(ConventionsRecord::from(&c)));
    if !record.is_finite() {
        return Err(not_finite());
    }
    let json = serde_json::to_string(&record.conventions)
        .map_err(|e| FaceError::Invalid(format!("conventions: {e}")))?;
    Ok(FacePose {
        estimate,
        scheme,
        conventions: Some(json),
        extra_warnings: c.warnings.iter().map(ToString::to_string).collect(),
    })
}

/// What the service's `PoseRecord::is_finite` checks: angles, rotation, residual, translation
/// and uncertainty.
fn is_finite(e: &Estimate) -> bool {
    let EulerAngles { yaw, pitch, roll } = e.angles;
    [yaw, pitch, roll, e.residual]
        .iter()
        .chain(e.rotation.matrix().iter())
        .chain(e.translation.iter().flat_map(|t| t.iter()))
        .copied()
        .chain(
            e.uncertainty
                .iter()
                .flat_map(|u| u.sd.into_iter().chain(u.interval90.into_iter().flatten())),
        )
        .all(f64::is_finite)
}

/// Every face of a batch, on up to `threads` threads (contiguous chunks, results in order).
pub fn estimate_all<'m>(
    model: &'m PoseModel,
    o: &Options,
    faces: &[Vec<Option<[f64; 2]>>],
    threads: usize,
) -> Vec<Result<FacePose<'m>, FaceError>> {
    let one = |f: &Vec<Option<[f64; 2]>>| estimate_face(model, o, f);
    // Below this many faces a thread costs more than it saves (~20 us per thread start).
    const MIN_CHUNK: usize = 8;
    let threads = threads.min(faces.len() / MIN_CHUNK).max(1);
    if threads == 1 {
        return faces.iter().map(one).collect();
    }
    let chunk = faces.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let mut parts = faces.chunks(chunk);
        let first = parts.next().unwrap_or_default();
        let handles: Vec<_> = parts
            .map(|part| scope.spawn(move || part.iter().map(one).collect::<Vec<_>>()))
            .collect();
        let mut out: Vec<_> = first.iter().map(one).collect();
        for h in handles {
            match h.join() {
                Ok(v) => out.extend(v),
                Err(p) => std::panic::resume_unwind(p),
            }
        }
        out
    })
}
