//! The models, their versions and the folder's catalog as the API shows them, whatever the
//! transport: plain data the HTTP and gRPC layers convert into their wire types.

use facepose_core::geometry::convention::ObjectFrame;
use facepose_core::model::bundle::Provenance;
use facepose_core::pose::Method;
use facepose_core::shape::Anchors;

use crate::error::ServiceError;
use crate::registry::{Catalog, ModelSet, ServedModel, StoredVersions};

/// A scheme a model serves.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemeView {
    /// The scheme's name.
    pub name: String,
    /// Number of points.
    pub points: usize,
}

/// A served model.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelView {
    /// The model's name.
    pub name: String,
    /// The version served.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// The model's own scheme (the default scheme of requests).
    pub scheme: String,
    /// Every scheme it serves, its own first.
    pub schemes: Vec<SchemeView>,
    /// The methods it supports.
    pub methods: Vec<Method>,
    /// `sha256:<hex>` of the bundle.
    pub checksum: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// Whether requests that name no model use it.
    pub default: bool,
    /// Its versions in the models folder (empty without one).
    pub versions: Vec<VersionView>,
}

/// A served model with its provenance.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelDetail {
    /// The model.
    pub model: ModelView,
    /// Its provenance: source files, the command that built it, notes.
    pub provenance: Provenance,
}

/// A scheme a served model serves, with what a client needs to synthesize or draw its faces:
/// the points' names, the model's mean shape in that scheme and the semantic anchors.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemeDetail {
    /// The model's name and the version that answered.
    pub model: String,
    /// The version that answered.
    pub model_version: String,
    /// The scheme's name.
    pub name: String,
    /// One name per point, in the scheme's order.
    pub points: Vec<String>,
    /// The model's mean shape in this scheme, one `[x, y, z]` per point: the model frame
    /// (x towards the subject's left, y up, z towards the camera), millimetres, the model's
    /// origin at the centroid of its own scheme's points.
    pub mean: Vec<[f64; 3]>,
    /// The same points in OpenCV's object frame (`(x, -y, -z)`): what `cv2.solvePnP` and
    /// `cv2.projectPoints` take with the `opencv` convention's `rvec` and `tvec`.
    pub mean_opencv: Vec<[f64; 3]>,
    /// The points whose mean gives each semantic anchor (eyes, nose tip, mouth corners).
    pub anchors: Anchors,
    /// `mirror[i]`: the point `i` becomes when the face is mirrored left-right, if known.
    pub mirror: Option<Vec<usize>>,
    /// The points on the face outline (2D-style annotations move them with the silhouette).
    pub contour: Vec<usize>,
}

/// The scheme `scheme` of the served model `m`, or `UnknownScheme` naming the ones it serves.
pub fn scheme_detail(m: &ServedModel, scheme: &str) -> Result<SchemeDetail, ServiceError> {
    ServiceError::check_name_length("scheme", scheme)?;
    // A subset of the model's own points, or a scheme of its face mesh (MediaPipe's).
    let subset = m.model.subsets.iter().find(|s| s.scheme.name == scheme);
    let (s, mean) = match (subset, m.model.mesh_scheme(scheme)) {
        (Some(subset), _) => (&subset.scheme, &subset.mean),
        (None, Some((_, mesh))) => (&mesh.scheme, &mesh.points),
        (None, None) => {
            return Err(ServiceError::UnknownScheme {
                model: m.name.clone(),
                scheme: scheme.to_string(),
                served: m.schemes().map(|(name, _)| name.to_string()).collect(),
            });
        }
    };
    Ok(SchemeDetail {
        model: m.name.clone(),
        model_version: m.version.clone(),
        name: s.name.clone(),
        points: s.points.clone(),
        mean: mean.iter().map(|p| [p.x, p.y, p.z]).collect(),
        mean_opencv: ObjectFrame::OpenCv.object_points(mean),
        anchors: s.anchors.clone(),
        mirror: s.mirror.clone(),
        contour: s.contour.clone(),
    })
}

/// Every served model.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelsView {
    /// The model answering when a request names none.
    pub default_model: String,
    /// The served models.
    pub models: Vec<ModelView>,
}

/// One version of a model in the models folder.
#[derive(Debug, Clone, PartialEq)]
pub struct VersionView {
    /// The version's id.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// The bundle's checksum, `sha256:<hex>`.
    pub checksum: String,
    /// The model's own scheme in that version.
    pub scheme: String,
    /// The bundle file, or `embedded`.
    pub source: String,
    /// The folder's active version: what every replica serves once it has followed the folder.
    pub active: bool,
    /// The version this replica serves.
    pub served: bool,
    /// Deployed with the folder (`DIR/<name>/model.json`) or built in: not deletable through
    /// the API.
    pub fixed: bool,
}

/// A model folder entry's versions.
#[derive(Debug, Clone, PartialEq)]
pub struct VersionsView {
    /// The model folder's name.
    pub name: String,
    /// The folder's active version; `None` if none was ever activated.
    pub active: Option<String>,
    /// Its versions on disk.
    pub versions: Vec<VersionView>,
}

/// The versions of a models folder entry, the active one and the one `served` marked.
pub fn versions_of(
    stored: Option<&StoredVersions>,
    served: Option<&ServedModel>,
) -> Vec<VersionView> {
    let Some(stored) = stored else {
        return vec![];
    };
    stored
        .versions
        .iter()
        .map(|v| VersionView {
            version: v.version.clone(),
            created: v.created.clone(),
            checksum: v.checksum.clone(),
            scheme: v.scheme.clone(),
            source: v.source.clone(),
            active: stored.active.as_deref() == Some(v.version.as_str()),
            served: served.is_some_and(|m| m.version == v.version),
            fixed: v.fixed,
        })
        .collect()
}

/// A served model, with its versions from the catalog.
pub fn model_view(m: &ServedModel, set: &ModelSet, catalog: &Catalog) -> ModelView {
    let stored = m.store.as_ref().and_then(|s| catalog.models.get(s));
    ModelView {
        name: m.name.clone(),
        version: m.version.clone(),
        created: m.created.clone(),
        scheme: m.scheme().to_string(),
        schemes: m
            .schemes()
            .map(|(name, points)| SchemeView {
                name: name.to_string(),
                points,
            })
            .collect(),
        methods: m.methods(),
        checksum: m.checksum.clone(),
        source: m.source.to_string(),
        default: m.name == set.default_name(),
        versions: versions_of(stored, Some(m)),
    }
}
