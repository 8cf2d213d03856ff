//! The formats of the data files the project develops and tests with (`../shared/data/`): the
//! bfm68 populations and morphable model, MediaPipe's canonical mesh, the AFLW2000-3D JSON
//! Lines, and the multi-view sets of `facepose reconstruct`. Text in, values out: reading the
//! files is `facepose_files::data`'s.

use nalgebra::Vector3;
use serde::Deserialize;

pub use crate::model::basis::MorphableModel;

fn parse<T: for<'de> Deserialize<'de>>(text: &str) -> Result<T, String> {
    serde_json::from_str(text).map_err(|e| e.to_string())
}

fn to_vectors(points: &[[f64; 3]]) -> Vec<Vector3<f64>> {
    points.iter().map(|p| Vector3::from(*p)).collect()
}

/// A set of 3D shapes in one scheme (`population_*.json`).
#[derive(Debug, Clone)]
pub struct Population {
    /// The landmark scheme's name.
    pub scheme: String,
    /// The shapes: one point per scheme point, model frame, mm.
    pub shapes: Vec<Vec<Vector3<f64>>>,
}

/// A population file's text: `{"scheme": ..., "shapes": [[[x, y, z], ...], ...]}`.
pub fn parse_population(text: &str) -> Result<Population, String> {
    #[derive(Deserialize)]
    struct Raw {
        scheme: String,
        shapes: Vec<Vec<[f64; 3]>>,
    }
    let raw: Raw = parse(text)?;
    Ok(Population {
        scheme: raw.scheme,
        shapes: raw.shapes.iter().map(|s| to_vectors(s)).collect(),
    })
}

/// The morphable model file's text (`bfm68/morphable_model.json`).
pub fn parse_morphable_model(text: &str) -> Result<MorphableModel, String> {
    #[derive(Deserialize)]
    struct Raw {
        mean: Vec<[f64; 3]>,
        shape_basis: Vec<Vec<[f64; 3]>>,
        shape_coef_mean: Vec<f64>,
        expression_basis: Vec<Vec<[f64; 3]>>,
        expression_coef_mean: Vec<f64>,
    }
    let raw: Raw = parse(text)?;
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
    /// Mesh vertices, model frame.
    pub vertices: Vec<Vector3<f64>>,
    /// Triangles, as vertex indices.
    pub triangles: Vec<[usize; 3]>,
    /// ibug68 point i = mean of these mesh vertices.
    pub ibug68: Vec<Vec<usize>>,
}

/// The text of `canonical_face_468.json`.
pub fn parse_canonical_mesh(text: &str) -> Result<CanonicalMesh, String> {
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
    let raw: Raw = parse(text)?;
    Ok(CanonicalMesh {
        vertices: to_vectors(&raw.vertices),
        triangles: raw.triangles,
        ibug68: raw.ibug68_from_mediapipe.indices,
    })
}

/// One face of the AFLW2000-3D JSON Lines.
#[derive(Debug, Clone, Deserialize)]
pub struct AflwFace {
    /// The image's file name.
    pub image: String,
    /// True pitch, degrees (Pose_Para).
    pub pitch: f64,
    /// True yaw, degrees (Pose_Para).
    pub yaw: f64,
    /// True roll, degrees (Pose_Para).
    pub roll: f64,
    /// True rotation matrix, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Whether every |angle| is at most 99° (the faces the evaluations use).
    pub within_99: bool,
    /// The 68 fitted landmarks, image pixels (y down).
    pub landmarks_fitted: Vec<[f64; 2]>,
    /// The 68 re-annotated landmarks, image pixels (y down).
    pub landmarks_reannotated: Vec<[f64; 2]>,
}

/// JSON Lines of faces (blank lines skipped); errors name the line.
pub fn parse_aflw(text: &str) -> Result<Vec<AflwFace>, String> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| serde_json::from_str(l).map_err(|e| format!("line {}: {e}", i + 1)))
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
    /// The landmark scheme's name.
    pub scheme: String,
    /// The subjects, each with its views.
    pub subjects: Vec<SubjectViews>,
}

/// A multi-view file's text.
pub fn parse_multi_view(text: &str) -> Result<MultiViewSet, String> {
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
    let raw: Raw = parse(text)?;
    let subjects = match (raw.views, raw.subjects) {
        (Some(views), None) => vec![SubjectViews { id: None, views }],
        (None, Some(s)) => s,
        _ => return Err("give exactly one of \"views\" (one subject) or \"subjects\"".into()),
    };
    Ok(MultiViewSet {
        scheme: raw.scheme,
        subjects,
    })
}

/// One render of the rendered ground-truth benchmark (`tests/fixtures/rendered/`, its README
/// describes every field): the truth, the camera, the oracle's exact 68 points and what the
/// detectors found. Fields the evaluation does not use (degradations, texture stretch) are
/// left out.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedRecord {
    /// The render's unique id.
    pub id: String,
    /// `grid`, `random`, `trajectory` or `identity`.
    pub set: String,
    /// The photo's person (`astronaut`, `insightface/t1#0`, ...).
    pub identity: String,
    /// `train` or `test`.
    pub split: String,
    /// `bfm` (absolute truth) or `mediapipe` (truth up to a constant rotation per identity).
    pub geometry: String,
    /// Whether `truth` is in the model frame (`bfm`) rather than up to a constant rotation.
    pub truth_absolute: bool,
    /// `[width, height]`, pixels.
    pub image_size: [f64; 2],
    /// The camera that made the render.
    pub camera: RenderedCamera,
    /// The head's true pose.
    pub truth: RenderedTruth,
    /// Its place in a trajectory (`set` = `trajectory`).
    pub trajectory: Option<RenderedFrame>,
    /// The mesh's own 68 points, projected exactly.
    pub oracle: RenderedOracle,
    /// What dlib found (`None`: no face detected).
    pub dlib: Option<RenderedDlib>,
    /// What MediaPipe found (`None`: no face detected).
    pub mediapipe: Option<RenderedMediaPipe>,
}

/// The render's camera (`ortho` or `perspective`; the intrinsics of a perspective one).
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedCamera {
    /// `ortho` (scaled orthographic) or `perspective` (pinhole).
    pub kind: String,
    /// Focal length along x, pixels (perspective only).
    pub fx: Option<f64>,
    /// Focal length along y, pixels (perspective only).
    pub fy: Option<f64>,
    /// Principal point x, pixels (perspective only).
    pub cx: Option<f64>,
    /// Principal point y, pixels, image y down (perspective only).
    pub cy: Option<f64>,
}

/// The true pose: Pose_Para angles (degrees) and the rotation, row-major.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedTruth {
    /// Degrees, > 0 chin up.
    pub pitch: f64,
    /// Degrees, > 0 the nose turns towards image-left.
    pub yaw: f64,
    /// Degrees, > 0 the eye line turns clockwise on screen.
    pub roll: f64,
    /// `R = Rx(pitch) Ry(yaw) Rz(roll)`, row-major.
    pub rotation: [[f64; 3]; 3],
}

/// A trajectory frame.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedFrame {
    /// The trajectory's id.
    pub id: String,
    /// The frame's index in it, from 0.
    pub frame: usize,
    /// When the frame was taken, µs.
    pub timestamp_us: i64,
    /// The trajectory's frame rate.
    pub fps: f64,
}

/// The exact projection of the rendered mesh's 68 ibug points (continuous pixel coordinates)
/// and which of them the z-buffer sees (`1`/`0` per point).
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedOracle {
    /// The 68 points, pixels (image y down).
    pub ibug68: Vec<[f64; 2]>,
    /// `1` or `0` per point: seen by the z-buffer.
    pub visible: String,
    /// The smallest angle error a weak-perspective estimate could reach on this render,
    /// degrees (0 for orthographic renders).
    pub weak_perspective_deg: f64,
}

/// dlib's detection: integer pixel indices, as dlib gives them.
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedDlib {
    /// The 68-point predictor's points, pixels.
    pub ibug68: Vec<[f64; 2]>,
    /// The 5-point predictor's points, pixels (scheme `dlib5`).
    pub dlib5: Vec<[f64; 2]>,
    /// The face detector's score.
    pub score: f64,
}

/// MediaPipe's detection: 478 points normalized by the image's width and height, and its own
/// facial transformation matrix (row-major 4x4).
#[derive(Debug, Clone, Deserialize)]
pub struct RenderedMediaPipe {
    /// 478 points, x and y as fractions of the image's width and height.
    pub landmarks: Vec<[f64; 2]>,
    /// MediaPipe's own pose of the face, row-major 4x4 (its canonical face, cm).
    pub facial_transformation_matrix: [[f64; 4]; 4],
}

/// The records of one JSON Lines text (blank lines skipped); errors name the line.
pub fn parse_rendered_lines(text: &str) -> Result<Vec<RenderedRecord>, String> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| parse(l).map_err(|e| format!("line {}: {e}", i + 1)))
        .collect()
}
