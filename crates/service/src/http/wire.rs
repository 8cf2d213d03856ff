//! The JSON of the HTTP API: requests and responses of the pose routes and of the model
//! listings (the OpenAPI document is derived from these types), and their conversions from the
//! application's views. The upload's types are beside its route (`retrain.rs`).

use facepose_app::views::{ModelView, ModelsView, SchemeDetail, VersionView, VersionsView};
use facepose_core::estimate::Intrinsics;
use facepose_core::model::bundle::Provenance;
use facepose_core::pose::{LandmarkStyle, Method};
use facepose_core::shape::MAX_POINTS;
use facepose_core::shape::pixels::{ImageSize, MAX_COORDINATE, MAX_IMAGE_SIDE};
use facepose_records::{Landmarks, PoseRecord, push_str};
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use utoipa::ToSchema;
use utoipa::openapi::RefOr;
use utoipa::openapi::schema::{
    ArrayBuilder, ObjectBuilder, OneOfBuilder, Schema, SchemaType, Type,
};

use super::conventions::{Conventions, Orientation};
use super::error::ErrorObject;

/// Pinhole camera intrinsics in pixels (image x right, y down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    #[schema(exclusive_minimum = 0.0)]
    /// Focal length along x, pixels.
    pub fx: f64,
    #[schema(exclusive_minimum = 0.0)]
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels (y down).
    pub cy: f64,
}

impl From<Camera> for Intrinsics {
    fn from(c: Camera) -> Self {
        Intrinsics {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
        }
    }
}

/// A client's identifier for a face (a string or a number), echoed in its result as it was
/// sent: a number keeps its digits (`18446744073709551616` comes back as that, not as a
/// float), a string its characters.
#[derive(Debug, Clone)]
pub enum FaceId {
    /// A string id, as sent.
    Text(String),
    /// The number's JSON text.
    Number(Box<RawValue>),
}

impl PartialEq for FaceId {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (FaceId::Text(a), FaceId::Text(b)) => a == b,
            (FaceId::Number(a), FaceId::Number(b)) => a.get() == b.get(),
            _ => false,
        }
    }
}

impl Serialize for FaceId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            FaceId::Text(t) => s.serialize_str(t),
            FaceId::Number(n) => n.serialize(s),
        }
    }
}

impl<'de> Deserialize<'de> for FaceId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::{Error, Unexpected};
        let raw = Box::<RawValue>::deserialize(d)?;
        match raw.get().as_bytes().first() {
            Some(b'"') => serde_json::from_str(raw.get())
                .map(FaceId::Text)
                .map_err(D::Error::custom),
            Some(b'-' | b'0'..=b'9') => Ok(FaceId::Number(raw)),
            _ => Err(D::Error::invalid_type(
                Unexpected::Other(raw.get().get(..16).unwrap_or(raw.get())),
                &"id as a string or a number",
            )),
        }
    }
}

impl utoipa::PartialSchema for FaceId {
    fn schema() -> RefOr<Schema> {
        OneOfBuilder::new()
            .item(ObjectBuilder::new().schema_type(Type::String))
            .item(ObjectBuilder::new().schema_type(Type::Number))
            .description(Some(
                "A string or a number, echoed as sent (a number keeps its digits).",
            ))
            .into()
    }
}

impl ToSchema for FaceId {}

/// The schema of a landmark list: at most [`MAX_POINTS`] entries, each `[x, y]` (pixels,
/// within ±1e9) or `null`.
fn landmarks_schema() -> ArrayBuilder {
    let coordinate = ObjectBuilder::new()
        .schema_type(Type::Number)
        .minimum(Some(-MAX_COORDINATE))
        .maximum(Some(MAX_COORDINATE));
    let point = ArrayBuilder::new()
        .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
        .items(coordinate)
        .min_items(Some(2))
        .max_items(Some(2));
    ArrayBuilder::new().items(point).max_items(Some(MAX_POINTS))
}

/// A name among `names`, or empty or absent for the default (`default`).
fn names_schema(names: &[&str], default: &str, what: &str) -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(SchemaType::from_iter([Type::String, Type::Null]))
        .enum_values(Some(
            [serde_json::Value::Null, "".into()]
                .into_iter()
                .chain(names.iter().map(|&n| n.into())),
        ))
        .description(Some(format!("{what}; empty or absent: `{default}`")))
}

/// `[width, height]` in pixels.
fn image_size_schema() -> ArrayBuilder {
    let side = ObjectBuilder::new()
        .schema_type(Type::Number)
        .exclusive_minimum(Some(0.0))
        .maximum(Some(MAX_IMAGE_SIDE));
    ArrayBuilder::new()
        .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
        .items(side)
        .min_items(Some(2))
        .max_items(Some(2))
        .description(Some(
            "The image's [width, height] in pixels: the landmarks are then normalized \
             coordinates, fractions of the width and height within [0, 1] (MediaPipe's x, y; a \
             face running off the frame may reach -0.25 to 1.25). Absent: the landmarks are \
             pixels.",
        ))
}

/// The image size of a request, if it gave one.
pub fn image_size(v: Option<[f64; 2]>) -> Option<ImageSize> {
    v.map(|[width, height]| ImageSize { width, height })
}

fn method_schema() -> ObjectBuilder {
    names_schema(&Method::NAMES, "auto", "The estimation method")
}

fn style_schema() -> ObjectBuilder {
    names_schema(
        &LandmarkStyle::NAMES,
        "projected",
        "How the landmarks were made",
    )
}

/// `POST /v1/pose`: one face.
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({
    "landmarks": [[301, 240], [341, 240], [321, 265], [305, 290], [337, 290]],
    "scheme": "five",
    "id": "face-17"
}))]
pub struct PoseRequest {
    /// Image pixels (origin top-left, x right, y down), in the scheme's order; `null` for a
    /// point that could not be found.
    #[schema(schema_with = landmarks_schema)]
    pub landmarks: Landmarks,
    /// The landmark scheme (`ibug68`, `inner51`, `five`, `dlib5`, `mediapipe468`,
    /// `mediapipe478`, ...); default: the one scheme with that many points (5 points must name
    /// `five` or `dlib5`).
    #[serde(default)]
    #[schema(max_length = 64)]
    pub scheme: Option<String>,
    /// `auto` (default), `fit`, `fit-shape`, `regression` or `geometry`.
    #[serde(default)]
    #[schema(schema_with = method_schema)]
    pub method: Option<String>,
    /// The model by name; default: `default`.
    #[serde(default)]
    #[schema(max_length = 64)]
    pub model: Option<String>,
    /// Camera intrinsics: the fit methods then refine the pose under full perspective.
    #[serde(default)]
    pub camera: Option<Camera>,
    /// How the landmarks were made: `projected` (default: every landmark is its 3D point's
    /// projection, as 3D-style annotations and 3DMM fitters give) or `contour` (2D-style, as
    /// 300-W / dlib: hidden jaw points sit on the visible outline and the fit leaves them out).
    #[serde(default)]
    #[schema(schema_with = style_schema)]
    pub landmark_style: Option<String>,
    /// `[width, height]`: the landmarks are normalized to this image size (MediaPipe's x, y).
    #[serde(default)]
    #[schema(schema_with = image_size_schema)]
    pub image_size: Option<[f64; 2]>,
    /// Echoed in the response.
    #[serde(default)]
    pub id: Option<FaceId>,
    /// The conventions to answer in besides facepose's own (docs/API.md, "Answers in your
    /// convention"); absent or empty: none, at no cost.
    #[serde(default)]
    pub conventions: Option<Conventions>,
    /// The camera's orientation in the world: the conventions' answers then refer to it.
    #[serde(default)]
    pub camera_orientation: Option<Orientation>,
}

/// A pose with its scheme and model.
#[derive(Debug, Serialize, ToSchema)]
pub struct PoseResponse {
    #[serde(flatten)]
    /// The pose.
    pub pose: PoseRecord,
    /// The scheme of the input landmarks.
    pub scheme: String,
    /// The model's name and version.
    pub model: String,
    /// The version that answered.
    pub model_version: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    /// The request's `id`, echoed.
    pub id: Option<FaceId>,
}

impl PoseResponse {
    /// The answer as JSON: serde_json's bytes for it (a test holds them equal), written by
    /// hand ([`PoseRecord::write_json_members`]) in a buffer with room for one pose.
    pub fn to_json(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(super::body::ONE_POSE_JSON);
        out.push(b'{');
        self.pose.write_json_members(&mut out);
        out.extend_from_slice(b",\"scheme\":");
        push_str(&mut out, &self.scheme);
        out.extend_from_slice(b",\"model\":");
        push_str(&mut out, &self.model);
        out.extend_from_slice(b",\"model_version\":");
        push_str(&mut out, &self.model_version);
        if let Some(id) = &self.id {
            out.extend_from_slice(b",\"id\":");
            match id {
                FaceId::Text(t) => push_str(&mut out, t),
                // serde_json writes a raw value's text as it is.
                FaceId::Number(n) => out.extend_from_slice(n.get().as_bytes()),
            }
        }
        out.push(b'}');
        out
    }
}

/// One face of a batch; `scheme`, `method` and `camera` default to the batch's.
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BatchFace {
    #[schema(schema_with = landmarks_schema)]
    /// Image pixels (origin top-left, x right, y down), in the scheme's order; `null` for a point that could not be found.
    pub landmarks: Landmarks,
    #[serde(default)]
    #[schema(max_length = 64)]
    /// The landmark scheme; default: the batch's.
    pub scheme: Option<String>,
    #[serde(default)]
    #[schema(schema_with = method_schema)]
    /// The estimation method; default: the batch's.
    pub method: Option<String>,
    #[serde(default)]
    /// Camera intrinsics; default: the batch's.
    pub camera: Option<Camera>,
    #[serde(default)]
    #[schema(schema_with = style_schema)]
    /// How the landmarks were made (`projected` or `contour`); default: the batch's.
    pub landmark_style: Option<String>,
    #[serde(default)]
    #[schema(schema_with = image_size_schema)]
    /// `[width, height]`: the landmarks are normalized to this image size; default: the batch's.
    pub image_size: Option<[f64; 2]>,
    #[serde(default)]
    /// Echoed in the face's result.
    pub id: Option<FaceId>,
    /// The conventions to answer in besides facepose's own (docs/API.md, "Answers in your
    /// convention"); absent or empty: none, at no cost.
    #[serde(default)]
    pub conventions: Option<Conventions>,
    /// The camera's orientation in the world: the conventions' answers then refer to it.
    #[serde(default)]
    pub camera_orientation: Option<Orientation>,
}

/// `POST /v1/pose:batch`: many faces, at most `--max-batch` (1000 by default).
#[derive(Debug, Default, PartialEq, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({
    "scheme": "five",
    "faces": [
        {"landmarks": [[301, 240], [341, 240], [321, 265], [305, 290], [337, 290]], "id": 1},
        {"landmarks": [[290, 238], [333, 242], [309, 266], [296, 289], [329, 292]], "id": 2}
    ]
}))]
pub struct BatchRequest {
    /// The faces, at most `--max-batch`.
    pub faces: Vec<BatchFace>,
    /// Defaults for every face.
    #[serde(default)]
    #[schema(max_length = 64)]
    pub scheme: Option<String>,
    #[serde(default)]
    #[schema(schema_with = method_schema)]
    /// The estimation method (`auto` by default).
    pub method: Option<String>,
    #[serde(default)]
    /// Camera intrinsics: the fit methods then refine the pose under full perspective.
    pub camera: Option<Camera>,
    #[serde(default)]
    #[schema(schema_with = style_schema)]
    /// How the landmarks were made: `projected` (default) or `contour`.
    pub landmark_style: Option<String>,
    #[serde(default)]
    #[schema(schema_with = image_size_schema)]
    /// `[width, height]`: the landmarks are normalized to this image size (MediaPipe's x, y).
    pub image_size: Option<[f64; 2]>,
    /// One model for the whole batch; default: `default`.
    #[serde(default)]
    #[schema(max_length = 64)]
    pub model: Option<String>,
    /// The conventions to answer in besides facepose's own (docs/API.md, "Answers in your
    /// convention"); absent or empty: none, at no cost.
    #[serde(default)]
    pub conventions: Option<Conventions>,
    /// The camera's orientation in the world: the conventions' answers then refer to it.
    #[serde(default)]
    pub camera_orientation: Option<Orientation>,
}

/// The result for one face of a batch: its pose, or its error.
#[derive(Debug, Serialize, ToSchema)]
#[serde(untagged)]
// Nearly every result is a pose: boxing it would allocate once more per face to save the
// rare errors some bytes.
#[allow(clippy::large_enum_variant)]
pub enum BatchResult {
    /// The face's pose.
    Pose(BatchPose),
    /// The face's error.
    Error(BatchError),
}

/// A face's pose in a batch.
#[derive(Debug, Serialize, ToSchema)]
pub struct BatchPose {
    #[serde(flatten)]
    /// The pose.
    pub pose: PoseRecord,
    /// The scheme of the input landmarks.
    pub scheme: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    /// The face's `id`, echoed.
    pub id: Option<FaceId>,
}

/// A face's error in a batch.
#[derive(Debug, Serialize, ToSchema)]
pub struct BatchError {
    #[serde(skip_serializing_if = "Option::is_none")]
    /// The face's `id`, echoed.
    pub id: Option<FaceId>,
    /// The error.
    pub error: ErrorObject,
}

/// `POST /v1/pose:batch`'s answer.
#[derive(Debug, Serialize, ToSchema)]
pub struct BatchResponse {
    /// The model's name.
    pub model: String,
    /// The version that answered.
    pub model_version: String,
    /// Faces with a pose.
    pub succeeded: u64,
    /// Faces with an error.
    pub failed: u64,
    /// One per face, in order.
    pub results: Vec<BatchResult>,
}

/// A scheme a model serves.
#[derive(Debug, Serialize, ToSchema)]
pub struct SchemeSummary {
    /// The scheme's name.
    pub name: String,
    /// Number of points.
    pub points: usize,
}

/// A loaded model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelSummary {
    /// The model's name.
    pub name: String,
    /// The version served.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// The model's own scheme (the default scheme of requests).
    pub scheme: String,
    /// Every scheme it serves, its own first.
    pub schemes: Vec<SchemeSummary>,
    /// The methods it supports.
    pub methods: Vec<String>,
    /// `sha256:<hex>` of the bundle.
    pub checksum: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// Whether requests that name no model use it (named as in gRPC's `ModelInfo`).
    pub is_default: bool,
    /// The same as `is_default`, under its first name: kept for clients written before it.
    #[schema(deprecated)]
    pub default: bool,
    /// Its versions in the models folder (empty without one): the folder's active one and the
    /// one this replica serves are marked.
    pub versions: Vec<VersionSummary>,
}

/// One version of a model in the models folder.
#[derive(Debug, Serialize, ToSchema)]
pub struct VersionSummary {
    /// The version's id.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// `sha256:<hex>` of the bundle.
    pub checksum: String,
    /// The model's own scheme in that version.
    pub scheme: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// The folder's active version: what every replica serves once it has followed the
    /// folder.
    pub active: bool,
    /// The version this replica serves.
    pub served: bool,
    /// Deployed with the folder (`DIR/<name>/model.json`) or built in: not deletable through
    /// the API.
    pub fixed: bool,
}

/// One source file of a model.
#[derive(Debug, Serialize, ToSchema)]
pub struct SourceSummary {
    /// The file's path, as given to training.
    pub path: String,
    /// SHA-256 of the file's content, hex.
    pub sha256: String,
    /// Shapes read from it.
    pub shapes: usize,
}

/// Where a model came from.
#[derive(Debug, Serialize, ToSchema)]
pub struct ProvenanceSummary {
    /// The command that built the model.
    pub command: String,
    /// Free text: licences, protocol.
    pub notes: String,
    /// The source files with their SHA-256.
    pub sources: Vec<SourceSummary>,
}

/// `GET /v1/models`: every served model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelsResponse {
    /// The model answering requests that name none.
    pub default_model: String,
    /// The served models.
    pub models: Vec<ModelSummary>,
}

/// A health probe's answer: `{"status": ...}`.
#[derive(Debug, Serialize, ToSchema)]
pub struct Status {
    /// `alive`, `ready` or `draining`.
    pub status: &'static str,
}

/// `GET /v1/models/{name}/versions`.
#[derive(Debug, Serialize, ToSchema)]
pub struct VersionsResponse {
    /// The model's name.
    pub name: String,
    /// The folder's active version; `null` if none was ever activated.
    pub active: Option<String>,
    /// Its versions in the models folder.
    pub versions: Vec<VersionSummary>,
}

/// The points whose mean gives each semantic anchor ("left" and "right": image-left and
/// image-right of a frontal face). `nose_tip` and the mouth corners are empty together in a
/// scheme without them (`dlib5`).
#[derive(Debug, Serialize, ToSchema)]
pub struct AnchorsSummary {
    /// Points whose mean is the image-left eye centre (the subject's right).
    pub eye_left: Vec<usize>,
    /// Points whose mean is the image-right eye centre (the subject's left).
    pub eye_right: Vec<usize>,
    /// Points whose mean is the nose tip.
    pub nose_tip: Vec<usize>,
    /// Points whose mean is the image-left mouth corner.
    pub mouth_left: Vec<usize>,
    /// Points whose mean is the image-right mouth corner.
    pub mouth_right: Vec<usize>,
}

/// `GET /v1/models/{name}/schemes/{scheme}`: a scheme the model serves, with the model's mean
/// shape in it. Projecting `mean` at a pose gives the landmarks a face of that pose would
/// have: `[u, -v] = s · (R X)[0:2] + t`, with `R` as in the responses.
#[derive(Debug, Serialize, ToSchema)]
#[schema(example = json!({
    "model": "default", "model_version": "1", "scheme": "five",
    "points": ["eye_left", "eye_right", "nose_tip", "mouth_left", "mouth_right"],
    "mean": [[-31.4, 38.2, 4.5], [31.3, 38.2, 4.5], [0.2, 4.1, 42.1], [-26.7, -28.9, 7.0], [26.0, -29.2, 6.9]],
    "anchors": {"eye_left": [0], "eye_right": [1], "nose_tip": [2], "mouth_left": [3], "mouth_right": [4]},
    "mirror": [1, 0, 2, 4, 3],
    "contour": []
}))]
pub struct SchemeResponse {
    /// The model's name.
    pub model: String,
    /// The version that answered.
    pub model_version: String,
    /// The scheme's name, as requests give it.
    pub scheme: String,
    /// One name per point, in the order requests send the landmarks.
    pub points: Vec<String>,
    /// The model's mean shape in this scheme, `[x, y, z]` per point: millimetres, the model
    /// frame (x towards the subject's left, y up, z towards the camera; the nose tip has the
    /// largest z), origin at the centroid of the model's own scheme.
    pub mean: Vec<[f64; 3]>,
    /// The same points in OpenCV's object frame, `(x, -y, -z)`: the object points of
    /// `cv2.solvePnP` and `cv2.projectPoints` for the `opencv` convention's `rvec` and `tvec`
    /// (its default `object_frame`; with `object_frame: "model"`, use `mean`).
    pub mean_opencv: Vec<[f64; 3]>,
    /// The points of each semantic anchor.
    pub anchors: AnchorsSummary,
    /// `mirror[i]` is the point `i` becomes when the face is mirrored left-right; `null` when
    /// the scheme does not say.
    pub mirror: Option<Vec<usize>>,
    /// Points on the face outline (ibug68's jaw), which 2D-style annotations move with the
    /// silhouette.
    pub contour: Vec<usize>,
}

impl From<SchemeDetail> for SchemeResponse {
    fn from(d: SchemeDetail) -> Self {
        let a = d.anchors;
        SchemeResponse {
            model: d.model,
            model_version: d.model_version,
            scheme: d.name,
            points: d.points,
            mean: d.mean,
            mean_opencv: d.mean_opencv,
            anchors: AnchorsSummary {
                eye_left: a.eye_left,
                eye_right: a.eye_right,
                nose_tip: a.nose_tip,
                mouth_left: a.mouth_left,
                mouth_right: a.mouth_right,
            },
            mirror: d.mirror,
            contour: d.contour,
        }
    }
}

/// The answer of an activation: the model now served.
#[derive(Debug, Serialize, ToSchema)]
pub struct ActivateResponse {
    #[serde(flatten)]
    /// The model now served.
    pub model: ModelSummary,
}

impl From<VersionView> for VersionSummary {
    fn from(v: VersionView) -> Self {
        VersionSummary {
            version: v.version,
            created: v.created,
            checksum: v.checksum,
            scheme: v.scheme,
            source: v.source,
            active: v.active,
            served: v.served,
            fixed: v.fixed,
        }
    }
}

impl From<ModelView> for ModelSummary {
    fn from(m: ModelView) -> Self {
        ModelSummary {
            name: m.name,
            version: m.version,
            created: m.created,
            scheme: m.scheme,
            schemes: m
                .schemes
                .into_iter()
                .map(|s| SchemeSummary {
                    name: s.name,
                    points: s.points,
                })
                .collect(),
            methods: m.methods.iter().map(|x| x.to_string()).collect(),
            checksum: m.checksum,
            source: m.source,
            is_default: m.default,
            default: m.default,
            versions: m.versions.into_iter().map(Into::into).collect(),
        }
    }
}

impl From<Provenance> for ProvenanceSummary {
    fn from(p: Provenance) -> Self {
        ProvenanceSummary {
            command: p.command,
            notes: p.notes,
            sources: p
                .sources
                .into_iter()
                .map(|s| SourceSummary {
                    path: s.path,
                    sha256: s.sha256,
                    shapes: s.shapes,
                })
                .collect(),
        }
    }
}

impl From<ModelsView> for ModelsResponse {
    fn from(v: ModelsView) -> Self {
        ModelsResponse {
            default_model: v.default_model,
            models: v.models.into_iter().map(Into::into).collect(),
        }
    }
}

impl From<VersionsView> for VersionsResponse {
    fn from(v: VersionsView) -> Self {
        VersionsResponse {
            name: v.name,
            active: v.active,
            versions: v.versions.into_iter().map(Into::into).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use facepose_core::pose::Method;

    fn record() -> PoseRecord {
        PoseRecord {
            yaw: -21.370000000000005,
            pitch: 4.5,
            roll: 0.0,
            rotation: [[0.93, 0.0, -0.36], [0.01, 1.0, 0.0], [0.36, 0.0, 0.93]],
            visible: vec![true, false, true, true],
            residual: 0.0421,
            method: Method::FitShape,
            translation: None,
            warnings: vec![],
            uncertainty: None,
            conventions: None,
        }
    }

    /// The hand-written answer is serde_json's, byte for byte, with each kind of id and
    /// names that need escaping.
    #[test]
    fn the_pose_answer_is_serde_jsons_bytes() {
        let ids = [
            None,
            Some(FaceId::Text("frame \"7\"\n".into())),
            Some(FaceId::Number(
                RawValue::from_string("18446744073709551616".into()).unwrap(),
            )),
            Some(FaceId::Number(
                RawValue::from_string("-1.5e3".into()).unwrap(),
            )),
        ];
        let mut full = record();
        full.translation = Some([12.5, -3.0, -640.25]);
        full.warnings = vec!["a \"quoted\"\twarning".into(), "second".into()];
        full.uncertainty = Some(facepose_records::UncertaintyRecord {
            yaw: facepose_records::AngleUncertainty {
                sd: 2.5,
                interval90: [-25.5, -17.2],
            },
            pitch: facepose_records::AngleUncertainty {
                sd: f64::INFINITY,
                interval90: [-180.0, 180.0],
            },
            roll: facepose_records::AngleUncertainty {
                sd: 0.75,
                interval90: [-1.2, 1.2],
            },
        });
        full.conventions = Some(Box::new(facepose_records::ConventionsRecord {
            quaternion: Some(facepose_records::QuaternionRecord {
                w: 0.98,
                x: 0.01,
                y: -0.18,
                z: 0.0,
            }),
            ..Default::default()
        }));
        let poses = [record(), full];
        for (id, pose) in ids.into_iter().zip(poses.iter().cycle()) {
            let answer = PoseResponse {
                pose: pose.clone(),
                scheme: "ibug68".into(),
                model: "default\\x".into(),
                model_version: "v1".into(),
                id,
            };
            assert_eq!(
                String::from_utf8(answer.to_json()).unwrap(),
                serde_json::to_string(&answer).unwrap()
            );
        }
    }
}
