//! Readers for the data files the project develops and tests with (`../shared/data/`): the
//! bfm68 populations and morphable model, MediaPipe's canonical mesh and the AFLW2000-3D JSON
//! Lines. This module does I/O; the numeric core never calls it.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;

/// A data file that could not be read or parsed.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Parse { path: PathBuf, reason: String },
}

fn read(path: &Path) -> Result<String, DataError> {
    std::fs::read_to_string(path).map_err(|source| DataError::Io {
        path: path.into(),
        source,
    })
}

fn parse<T: for<'de> Deserialize<'de>>(path: &Path, text: &str) -> Result<T, DataError> {
    serde_json::from_str(text).map_err(|e| DataError::Parse {
        path: path.into(),
        reason: e.to_string(),
    })
}

/// Where the shared data lives: `$FACEPOSE_DATA`, else `../shared/data` next to the crate.
pub fn data_dir() -> PathBuf {
    match std::env::var_os("FACEPOSE_DATA") {
        Some(p) => PathBuf::from(p),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
    }
}

fn to_vectors(points: &[[f64; 3]]) -> Vec<Vector3<f64>> {
    points.iter().map(|p| Vector3::from(*p)).collect()
}

/// A set of 3D shapes in one scheme (`population_*.json`).
#[derive(Debug, Clone)]
pub struct Population {
    pub scheme: String,
    pub shapes: Vec<Vec<Vector3<f64>>>,
}

/// Reads a population file: `{"scheme": ..., "shapes": [[[x, y, z], ...], ...]}`.
pub fn load_population(path: &Path) -> Result<Population, DataError> {
    #[derive(Deserialize)]
    struct Raw {
        scheme: String,
        shapes: Vec<Vec<[f64; 3]>>,
    }
    let raw: Raw = parse(path, &read(path)?)?;
    Ok(Population {
        scheme: raw.scheme,
        shapes: raw.shapes.iter().map(|s| to_vectors(s)).collect(),
    })
}

pub use crate::model::basis::MorphableModel;

/// Reads the morphable model file.
pub fn load_morphable_model(path: &Path) -> Result<MorphableModel, DataError> {
    #[derive(Deserialize)]
    struct Raw {
        mean: Vec<[f64; 3]>,
        shape_basis: Vec<Vec<[f64; 3]>>,
        shape_coef_mean: Vec<f64>,
        expression_basis: Vec<Vec<[f64; 3]>>,
        expression_coef_mean: Vec<f64>,
    }
    let raw: Raw = parse(path, &read(path)?)?;
    Ok(MorphableModel {
        mean: to_vectors(&raw.mean),
        shape_basis: raw.shape_basis.iter().map(|b| to_vectors(b)).collect(),
        shape_coef_mean: raw.shape_coef_mean,
        expression_basis: raw.expression_basis.iter().map(|b| to_vectors(b)).collect(),
        expression_coef_mean: raw.expression_coef_mean,
    })
}

/// MediaPipe's canonical face mesh with the ibug68 mapping.
#[derive(Debug, Clone)]
pub struct CanonicalMesh {
    pub vertices: Vec<Vector3<f64>>,
    pub triangles: Vec<[usize; 3]>,
    /// ibug68 point i = mean of these mesh vertices.
    pub ibug68: Vec<Vec<usize>>,
}

/// Reads `canonical_face_468.json`.
pub fn load_canonical_mesh(path: &Path) -> Result<CanonicalMesh, DataError> {
    #[derive(Deserialize)]
    struct Mapping {
        indices: Vec<Vec<usize>>,
    }
    #[derive(Deserialize)]
    struct Raw {
        vertices: Vec<[f64; 3]>,
        triangles: Vec<[usize; 3]>,
        ibug68_from_mediapipe: Mapping,
    }
    let raw: Raw = parse(path, &read(path)?)?;
    Ok(CanonicalMesh {
        vertices: to_vectors(&raw.vertices),
        triangles: raw.triangles,
        ibug68: raw.ibug68_from_mediapipe.indices,
    })
}

/// One face of the AFLW2000-3D JSON Lines.
#[derive(Debug, Clone, Deserialize)]
pub struct AflwFace {
    pub image: String,
    pub pitch: f64,
    pub yaw: f64,
    pub roll: f64,
    pub rotation: [[f64; 3]; 3],
    pub within_99: bool,
    pub landmarks_fitted: Vec<[f64; 2]>,
    pub landmarks_reannotated: Vec<[f64; 2]>,
}

/// Reads a JSON Lines file of faces (blank lines skipped); errors name the line.
pub fn load_aflw(path: &Path) -> Result<Vec<AflwFace>, DataError> {
    let text = read(path)?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l).map_err(|e| DataError::Parse {
                path: path.into(),
                reason: format!("line {}: {e}", i + 1),
            })
        })
        .collect()
}

/// One subject's views in a multi-view file.
#[derive(Debug, Clone, Deserialize)]
pub struct SubjectViews {
    /// Echoed in the output.
    #[serde(default)]
    pub id: Option<serde_json::Value>,
    /// Each view: one `[x, y]` (image pixels, y down) or `null` per point of the scheme.
    pub views: Vec<Vec<Option<[f64; 2]>>>,
}

/// A multi-view file: `{"scheme": "ibug68", "views": [...]}` for one subject, or
/// `{"scheme": "ibug68", "subjects": [{"id": ..., "views": [...]}, ...]}` for several.
#[derive(Debug, Clone)]
pub struct MultiViewSet {
    pub scheme: String,
    pub subjects: Vec<SubjectViews>,
}

/// Parses a multi-view file's text (`path` is only used in messages).
pub fn parse_multi_view(path: &Path, text: &str) -> Result<MultiViewSet, DataError> {
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Raw {
        #[serde(default = "default_scheme")]
        scheme: String,
        #[serde(default)]
        views: Option<Vec<Vec<Option<[f64; 2]>>>>,
        #[serde(default)]
        subjects: Option<Vec<SubjectViews>>,
    }
    fn default_scheme() -> String {
        "ibug68".into()
    }
    let raw: Raw = parse(path, text)?;
    let subjects = match (raw.views, raw.subjects) {
        (Some(views), None) => vec![SubjectViews { id: None, views }],
        (None, Some(s)) => s,
        _ => {
            return Err(DataError::Parse {
                path: path.into(),
                reason: "give exactly one of \"views\" (one subject) or \"subjects\"".into(),
            });
        }
    };
    Ok(MultiViewSet {
        scheme: raw.scheme,
        subjects,
    })
}

/// Reads a multi-view file.
pub fn load_multi_view(path: &Path) -> Result<MultiViewSet, DataError> {
    parse_multi_view(path, &read(path)?)
}
