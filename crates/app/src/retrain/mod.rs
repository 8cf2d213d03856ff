//! Retraining: an upload (HTTP JSON or gRPC chunks, both turned into one [`RawUpload`]), the
//! checks answered at once ([`prepare`]), and the background job ([`job::run`]): structure
//! from motion for multi-view sets, training on the blocking pool, the new version written
//! atomically, loaded back and activated.
//!
//! What is checked before the job is accepted (4xx at once): the model name, the scheme, the
//! options ([`options`]), that exactly one of `shapes` / `subjects` is given, and the shapes
//! themselves (`model::validate`: counts, finite values, degenerate and mirrored shapes,
//! outliers by Procrustes distance; for multi-view sets the per-subject view checks). Too few
//! usable shapes is 422 with the report. Structure from motion and training run in the job;
//! their failures are the job's `error`. The transports turn their uploads into a
//! [`RawUpload`] (an HTTP JSON body, or a gRPC `Retrain` stream of chunks).

pub mod job;
pub mod options;

use facepose_core::shape::Point3;

use crate::error::ServiceError;
use crate::registry::{DEFAULT_MODEL, version_error, versions::check_name};
use facepose_core::model::validate::{
    Dropped, ValidatedShapes, ValidationReport, subject_views, validate_shapes,
};
use facepose_core::shape::{Scheme, Shape2};
pub use options::{RawGrid, RawOptions, UploadOptions, check_options};

/// The longest `notes` recorded in a version's provenance, bytes.
pub const MAX_NOTES: usize = 4096;

/// The most points of an uploaded scheme definition: a scheme's limit.
pub use facepose_core::shape::MAX_POINTS as MAX_SCHEME_POINTS;

/// The scheme of an upload: a built-in name or a definition.
#[derive(Debug, Clone)]
pub enum SchemeSpec {
    /// A built-in scheme's name.
    Name(String),
    /// A scheme defined in the upload.
    Definition(Box<Scheme>),
}

/// The shapes of an upload.
#[derive(Debug, Clone)]
pub enum UploadData {
    /// 3D shapes, model frame, mm.
    Shapes(Vec<Vec<Point3>>),
    /// Per subject, its views (image pixels), rebuilt by structure from motion.
    Subjects(Vec<Vec<Vec<Option<[f64; 2]>>>>),
}

/// An upload as either transport hands it over.
#[derive(Debug, Clone)]
pub struct RawUpload {
    /// The model to retrain; `None` or empty: `default`.
    pub model: Option<String>,
    /// `None`: ibug68.
    pub scheme: Option<SchemeSpec>,
    /// `None`: neither shapes nor subjects were given.
    pub data: Option<UploadData>,
    /// Both `shapes` and `subjects` were given.
    pub both: bool,
    /// The training options.
    pub options: RawOptions,
    /// `None`: activate.
    pub activate: Option<bool>,
    /// Recorded in the version's provenance.
    pub notes: Option<String>,
    /// SHA-256 of the upload as received (provenance).
    pub sha256: String,
    /// `POST /v1/models` or `gRPC Retrain` (provenance).
    pub origin: &'static str,
}

/// What the job works on.
#[derive(Debug)]
pub enum Work {
    /// 3D shapes, validated.
    Shapes(ValidatedShapes),
    /// Subjects whose views passed the cheap checks (input index, views), and those dropped.
    Subjects {
        /// Per subject, its input index and views.
        views: Vec<(usize, Vec<Shape2>)>,
        /// The subjects dropped.
        dropped: Vec<Dropped>,
    },
}

/// What a job needs besides its shapes.
#[derive(Debug)]
pub struct JobSpec {
    /// The model folder's name.
    pub model: String,
    /// The scheme of the shapes.
    pub scheme: Scheme,
    /// The checked training options.
    pub options: UploadOptions,
    /// Activate the version once written.
    pub activate: bool,
    /// Recorded in the version's provenance.
    pub notes: String,
    /// SHA-256 of the upload (provenance).
    pub sha256: String,
    /// The route or RPC it came through (provenance).
    pub origin: &'static str,
    /// `shapes` or `subjects`.
    pub kind: &'static str,
    /// Shapes or subjects uploaded.
    pub uploaded: usize,
}

/// An accepted upload.
#[derive(Debug)]
pub struct Prepared {
    /// The job.
    pub spec: JobSpec,
    /// What it works on.
    pub work: Work,
}

impl Prepared {
    /// The validation report known when the job is accepted (3D shapes).
    pub fn report(&self) -> Option<ValidationReport> {
        match &self.work {
            Work::Shapes(v) => Some(v.report.clone()),
            Work::Subjects { .. } => None,
        }
    }
}

fn resolve_scheme(spec: Option<SchemeSpec>) -> Result<Scheme, ServiceError> {
    let scheme = named_or_defined_scheme(spec)?;
    scheme
        .check_model_scheme()
        .map_err(|e| ServiceError::invalid(format!("scheme: {e}")))?;
    Ok(scheme)
}

fn named_or_defined_scheme(spec: Option<SchemeSpec>) -> Result<Scheme, ServiceError> {
    match spec {
        None => Ok(facepose_core::shape::ibug68()),
        Some(SchemeSpec::Name(n)) if n.is_empty() => Ok(facepose_core::shape::ibug68()),
        Some(SchemeSpec::Name(n)) => Scheme::builtin(&n).ok_or_else(|| {
            ServiceError::invalid(format!(
                "scheme {n:?} is not built in ({}); send a scheme definition instead",
                Scheme::builtin_names().join(", ")
            ))
        }),
        Some(SchemeSpec::Definition(s)) => {
            if s.len() > MAX_SCHEME_POINTS {
                return Err(ServiceError::invalid(format!(
                    "scheme: {} points; the limit is {MAX_SCHEME_POINTS}",
                    s.len()
                )));
            }
            s.validate()
                .map_err(|e| ServiceError::invalid(format!("scheme: {e}")))?;
            Ok(*s)
        }
    }
}

/// "only 3 of 12 shapes are usable ..." with the first reasons, and the report as details.
pub(crate) fn too_few(report: &ValidationReport, what: &str, min: usize) -> ServiceError {
    let mut reasons: Vec<String> = report
        .dropped
        .iter()
        .take(5)
        .map(|d| format!("{what} {}: {}: {}", d.index, d.reason.name(), d.detail))
        .collect();
    if report.dropped.len() > 5 {
        reasons.push(format!("and {} more", report.dropped.len() - 5));
    }
    let mut message = format!(
        "only {} of {} {what}s are usable; at least {min} are needed (options.min_shapes)",
        report.kept, report.total
    );
    if !reasons.is_empty() {
        message.push_str(&format!(": {}", reasons.join("; ")));
    }
    ServiceError::TooFewShapes {
        message,
        report: Box::new(report.clone()),
    }
}

/// The checks answered at once (see the module docs). CPU work (Procrustes analysis of the
/// whole set): run it on the blocking pool.
pub fn prepare(raw: RawUpload) -> Result<Prepared, ServiceError> {
    let model = raw
        .model
        .filter(|m| !m.is_empty())
        .unwrap_or_else(|| DEFAULT_MODEL.into());
    check_name(&model).map_err(version_error)?;
    let notes = raw.notes.unwrap_or_default();
    if notes.len() > MAX_NOTES {
        return Err(ServiceError::invalid(format!(
            "notes: {} bytes; at most {MAX_NOTES}",
            notes.len()
        )));
    }
    let scheme = resolve_scheme(raw.scheme)?;
    let options = check_options(&raw.options, &scheme)?;
    if raw.both {
        return Err(ServiceError::invalid(
            "give either \"shapes\" (3D shapes) or \"subjects\" (2D views per subject), not both",
        ));
    }
    let data = raw.data.ok_or_else(|| {
        ServiceError::invalid(
            "no shapes: give \"shapes\" (3D shapes, model frame, mm) or \"subjects\" (2D views \
             per subject, rebuilt by structure from motion)",
        )
    })?;
    let (kind, what, uploaded) = match &data {
        UploadData::Shapes(s) => ("shapes", "shape", s.len()),
        UploadData::Subjects(s) => ("subjects", "subject", s.len()),
    };
    if uploaded < options.min_shapes {
        return Err(ServiceError::invalid(format!(
            "{uploaded} {what}s; at least {} are needed (options.min_shapes)",
            options.min_shapes
        )));
    }
    let work = match data {
        UploadData::Shapes(shapes) => {
            let v = validate_shapes(&scheme, &shapes, &options.validation)?;
            if v.report.kept < options.min_shapes {
                return Err(too_few(&v.report, what, options.min_shapes));
            }
            Work::Shapes(v)
        }
        UploadData::Subjects(subjects) => {
            let mut views = Vec::new();
            let mut dropped = Vec::new();
            for (k, s) in subjects.iter().enumerate() {
                match subject_views(&scheme, s) {
                    Ok(v) => views.push((k, v)),
                    Err((reason, detail)) => dropped.push(Dropped {
                        index: k,
                        reason,
                        detail,
                    }),
                }
            }
            if views.len() < options.min_shapes {
                let report = ValidationReport {
                    total: uploaded,
                    kept: views.len(),
                    dropped,
                    median_distance: None,
                    outlier_threshold: None,
                };
                return Err(too_few(&report, what, options.min_shapes));
            }
            Work::Subjects { views, dropped }
        }
    };
    Ok(Prepared {
        spec: JobSpec {
            model,
            scheme,
            options,
            activate: raw.activate.unwrap_or(true),
            notes,
            sha256: raw.sha256,
            origin: raw.origin,
            kind,
            uploaded,
        },
        work,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_uploaded_scheme_has_at_most_1000_points() {
        let mut s = facepose_core::shape::ibug68();
        s.name = "huge".into();
        s.points = (0..=MAX_SCHEME_POINTS).map(|k| format!("p{k}")).collect();
        let e = resolve_scheme(Some(SchemeSpec::Definition(Box::new(s)))).unwrap_err();
        assert_eq!(e.kind(), crate::error::ErrorKind::InvalidArgument);
        assert_eq!(e.to_string(), "scheme: 1001 points; the limit is 1000");
        assert!(resolve_scheme(Some(SchemeSpec::Name("five".into()))).is_ok());
    }

    #[test]
    fn a_scheme_without_nose_and_mouth_cannot_be_a_model_s_own() {
        let e = resolve_scheme(Some(SchemeSpec::Name("dlib5".into()))).unwrap_err();
        assert_eq!(e.kind(), crate::error::ErrorKind::InvalidArgument);
        assert!(e.to_string().contains("serve this one as a subset"), "{e}");
        let e = resolve_scheme(Some(SchemeSpec::Definition(Box::new(
            facepose_core::shape::dlib5(),
        ))))
        .unwrap_err();
        assert!(e.to_string().contains("nose tip and mouth corners"), "{e}");
    }
}
