//! The model bundle format (`models/<name>/model.json`): a readable JSON document with the
//! scheme, the frontal mean shape and its triangulation, the HPR visibility computed at training
//! (schema 2), the training parameters, the regression matrices per subset and view bin, the
//! optional shape basis, the geometric constants, version, creation time, provenance and a
//! checksum. Text in, text out: the file I/O is in `store.rs`.
//!
//! Schema 2 stores what training computed by hidden-point removal (the visibility map and the
//! training views' visibility) so that loading runs none: it was 85-90% of a start-up. Schema 1
//! bundles, which lack it, still load, with HPR recomputing it.
//!
//! The checksum is `sha256:` + the SHA-256 of the compact JSON of the document with an empty
//! `checksum` field, so it covers every value and no formatting.

use nalgebra::{DMatrix, Vector3};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::mesh::{FaceMesh, MeshSource};
use super::packed_bits;
use super::train::{
    TrainOptions, bins_with_visibility, geometry_of, map_bins, subset_of, synthesize_bins,
};
use super::{PoseModel, Subset};
use crate::error::Error;
use crate::estimate::detector::DetectorRegression;
use crate::estimate::geometric::GeometryConstants;
use crate::estimate::morph_fit::MorphableBasis;
use crate::estimate::regression::RegressionModel;
use crate::estimate::visibility_map::VisibilityMap;
use crate::hpr::{PaperHpr, Triangulation};
use crate::shape::Scheme;
use crate::synth::AngleRange;
use crate::uncertainty::Calibration;

/// The `format` field of every bundle.
pub const FORMAT: &str = "facepose-model";
/// The schema version this build writes.
pub const SCHEMA_VERSION: u32 = 2;
/// The oldest schema version this build reads (1: no stored visibility).
pub const OLDEST_SCHEMA_VERSION: u32 = 1;

/// A bundle that could not be read: the message names the field and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    /// The text is not a bundle's JSON.
    #[error("not valid JSON for a model bundle at {field}: {reason}")]
    Parse {
        /// Where in the bundle.
        field: String,
        /// The parser's complaint.
        reason: String,
    },
    /// A field's value is invalid.
    #[error("{field}: {reason}")]
    Invalid {
        /// The invalid field.
        field: String,
        /// Why it is invalid.
        reason: String,
    },
    /// The content does not hash to the stated checksum.
    #[error(
        "checksum mismatch: the file says {expected}, its content hashes to {actual} (edited or truncated)"
    )]
    Checksum {
        /// The checksum the file states.
        expected: String,
        /// The checksum of its content.
        actual: String,
    },
    /// A field fails the core's checks.
    #[error("{field}: {source}")]
    Core {
        /// The field that failed.
        field: String,
        /// The core's error.
        source: Error,
    },
}

fn invalid(field: impl Into<String>, reason: impl Into<String>) -> BundleError {
    BundleError::Invalid {
        field: field.into(),
        reason: reason.into(),
    }
}

fn core(field: &str) -> impl FnOnce(Error) -> BundleError + '_ {
    move |source| BundleError::Core {
        field: field.into(),
        source,
    }
}

/// Where a model came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The source files with their SHA-256.
    pub sources: Vec<SourceFile>,
    /// The command that built the model.
    pub command: String,
    /// Free text: licences, protocol.
    pub notes: String,
}

/// One source file of a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceFile {
    /// The file's path, as given to training.
    pub path: String,
    /// SHA-256 of the file's content, hex.
    pub sha256: String,
    /// Shapes read from it.
    pub shapes: usize,
}

/// The regression of one subset: `ε` and one `3 x (2n + 1)` matrix per view bin (bin 0 coarse).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegressionEntry {
    /// The subset's scheme name.
    pub scheme: String,
    /// Ridge regularization `ε` chosen for the subset.
    pub epsilon: f64,
    /// One `3 x (2n + 1)` matrix per view bin, row-major (bin 0 coarse).
    pub matrices: Vec<Vec<Vec<f64>>>,
}

/// What HPR found visible when the model was trained, as rows of flags in the hex text of
/// [`packed_bits`] (one row per pose, `⌈n / 4⌉` digits for `n` points, point 0 the high bit of
/// the first digit).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisibilityEntry {
    /// The visibility map's yaw directions (degrees).
    pub map_yaw: AngleRange,
    /// The visibility map's pitch directions (degrees).
    pub map_pitch: AngleRange,
    /// One row per map direction at roll 0, yaw outermost.
    pub map: String,
    /// One text per regression grid (the coarse one first, then the fine bins), one row per
    /// view in grid order (yaw outermost).
    pub views: Vec<String>,
}

/// MediaPipe's face mesh in the model's frame ([`super::mesh`]): what serves `mediapipe468` and
/// `mediapipe478`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshEntry {
    /// The 468 vertices, model frame, mm.
    pub vertices: Vec<[f64; 3]>,
    /// The mesh's triangles (HPR).
    pub triangles: Vec<[usize; 3]>,
    /// Model point `k` = the mean of vertices `to_model[k]`.
    pub to_model: Vec<Vec<usize>>,
    /// The visibility map's yaw directions (degrees).
    pub map_yaw: AngleRange,
    /// The visibility map's pitch directions (degrees).
    pub map_pitch: AngleRange,
    /// HPR's visibility of the vertices over the map's directions, as [`VisibilityEntry::map`].
    pub map: String,
}

/// A shape basis: `shape = mean + Σ c_k components_k`, `c ~ N(prior_mean, I)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BasisEntry {
    /// Mean shape, model frame, mm.
    pub mean: Vec<[f64; 3]>,
    /// Components, one shape offset each (mm per unit coefficient).
    pub components: Vec<Vec<[f64; 3]>>,
    /// Prior mean of the coefficients.
    pub prior_mean: Vec<f64>,
}

/// The bundle document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bundle {
    /// The file format's name.
    pub format: String,
    /// The bundle schema's version.
    pub schema_version: u32,
    /// The model's name.
    pub name: String,
    /// The model's version.
    pub version: String,
    /// RFC 3339.
    pub created: String,
    /// Where the model came from.
    pub provenance: Provenance,
    /// The model's own landmark scheme.
    pub scheme: Scheme,
    /// Frontal mean shape, model frame, mm.
    pub mean: Vec<[f64; 3]>,
    /// Delaunay triangulation of the frontal mean (HPR).
    pub triangles: Vec<[usize; 3]>,
    /// HPR's results at training; required from schema 2 on. Absent in schema 1, and then
    /// left out of the JSON, so that schema 1 bundles' checksums still verify.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub visibility: Option<VisibilityEntry>,
    /// Geometric constants of the model.
    pub geometry: GeometryConstants,
    /// The options it was trained with.
    pub training: TrainOptions,
    /// One regression per served subset.
    pub regressions: Vec<RegressionEntry>,
    /// The shape basis, if the model has one.
    pub shape_basis: Option<BasisEntry>,
    /// MediaPipe's face mesh; absent in bundles without one (and then left out of the JSON, so
    /// that their checksums still verify).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<MeshEntry>,
    /// The uncertainty's calibration ([`crate::uncertainty::calibration`]); absent in bundles
    /// without one (left out of the JSON, so their checksums stay as they were).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<Calibration>,
    /// Regressions trained on landmark detectors' output ([`crate::estimate::detector`]);
    /// absent in bundles without them (left out of the JSON, so their checksums stay as they
    /// were).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub detector_regressions: Vec<DetectorRegression>,
    /// `sha256:<hex>` of the compact JSON with an empty checksum field.
    pub checksum: String,
}

fn to_arrays(v: &[Vector3<f64>]) -> Vec<[f64; 3]> {
    v.iter().map(|p| [p.x, p.y, p.z]).collect()
}

fn to_vectors(v: &[[f64; 3]]) -> Vec<Vector3<f64>> {
    v.iter().map(|p| Vector3::from(*p)).collect()
}

impl Bundle {
    /// The bundle of a trained model, checksummed.
    pub fn from_model(
        model: &PoseModel,
        training: &TrainOptions,
        name: &str,
        version: &str,
        created: &str,
        provenance: Provenance,
    ) -> Result<Bundle, BundleError> {
        let regressions = model
            .subsets
            .iter()
            .map(|s| {
                let m = s
                    .regression
                    .full_pattern_matrices()
                    .map_err(core("regressions"))?;
                Ok(RegressionEntry {
                    scheme: s.scheme.name.clone(),
                    epsilon: s.regression.epsilon(),
                    matrices: m
                        .iter()
                        .map(|w| w.row_iter().map(|r| r.iter().copied().collect()).collect())
                        .collect(),
                })
            })
            .collect::<Result<Vec<_>, BundleError>>()?;
        let n = model.scheme.len();
        let (map_yaw, map_pitch) = model.visibility.grid();
        let own = model
            .subsets
            .first()
            .filter(|s| s.map == super::SubsetMap::Own)
            .ok_or_else(|| invalid("regressions", "the first subset must be the model's own"))?;
        let visibility = VisibilityEntry {
            map_yaw,
            map_pitch,
            map: packed_bits::encode(model.visibility.bits().chunks(n), n),
            views: own
                .regression
                .bins()
                .iter()
                .map(|b| packed_bits::encode(b.views.iter().map(|v| &v.visible[..]), n))
                .collect(),
        };
        let shape_basis = model.morph.as_ref().map(|b| BasisEntry {
            mean: to_arrays(b.mean()),
            components: b.components().iter().map(|c| to_arrays(c)).collect(),
            prior_mean: b.prior_mean().to_vec(),
        });
        let mesh = model.mesh.as_ref().map(|m| {
            let src = m.source();
            let (map_yaw, map_pitch) = m.visibility().grid();
            MeshEntry {
                vertices: to_arrays(&src.vertices),
                triangles: src.triangles.clone(),
                to_model: src.to_model.clone(),
                map_yaw,
                map_pitch,
                map: packed_bits::encode(
                    m.visibility().bits().chunks(src.vertices.len()),
                    src.vertices.len(),
                ),
            }
        });
        let mut bundle = Bundle {
            format: FORMAT.into(),
            schema_version: SCHEMA_VERSION,
            name: name.into(),
            version: version.into(),
            created: created.into(),
            provenance,
            scheme: model.scheme.clone(),
            mean: to_arrays(&model.mean),
            triangles: model.hpr.triangulation().triangles().to_vec(),
            visibility: Some(visibility),
            geometry: model.geometry,
            training: training.clone(),
            regressions,
            shape_basis,
            mesh,
            calibration: model.calibration.clone(),
            detector_regressions: model.detectors.clone(),
            checksum: String::new(),
        };
        bundle.checksum = bundle.compute_checksum()?;
        Ok(bundle)
    }

    /// `sha256:<hex>` of the compact JSON with an empty checksum field.
    pub fn compute_checksum(&self) -> Result<String, BundleError> {
        let mut copy = self.clone();
        copy.checksum.clear();
        let text = serde_json::to_string(&copy).map_err(|e| invalid("checksum", e.to_string()))?;
        let digest = Sha256::digest(text.as_bytes());
        Ok(format!("sha256:{}", hex(&digest)))
    }

    /// The pretty JSON text of the bundle (what is written to disk).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).expect("a bundle always serializes");
        s.push('\n');
        s
    }

    /// Parses a bundle's text, naming the field on error. Does not validate (see [`Bundle::load`]).
    /// A bundle of a schema version this build does not read fails on its version, not on the
    /// fields that version added.
    pub fn parse(text: &str) -> Result<Bundle, BundleError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        serde_path_to_error::deserialize(de).map_err(|e| {
            if let Ok(Header {
                schema_version: Some(v),
            }) = serde_json::from_str::<Header>(text)
                && let Err(unread) = check_schema_version(v)
            {
                return unread;
            }
            BundleError::Parse {
                field: e.path().to_string(),
                reason: e.inner().to_string(),
            }
        })
    }

    /// Validates everything (format, schema version, checksum, dimensions, finite numbers) and
    /// builds the model: HPR over the stored triangulation, the visibility map, and the
    /// regressions with their training views projected from the mean over the stored grids and
    /// the stored matrices as the all-points-present solutions. The visibility of the map and
    /// the views is the stored one (schema 2), or HPR's (schema 1).
    pub fn load(&self) -> Result<PoseModel, BundleError> {
        if self.format != FORMAT {
            return Err(invalid(
                "format",
                format!("expected {FORMAT:?}, found {:?}", self.format),
            ));
        }
        check_schema_version(self.schema_version)?;
        match (self.schema_version, &self.visibility) {
            (1, Some(_)) => {
                return Err(invalid(
                    "visibility",
                    "not a field of schema version 1: set schema_version to 2",
                ));
            }
            (v, None) if v >= 2 => {
                return Err(invalid(
                    "visibility",
                    format!(
                        "missing: schema version {v} bundles store the visibility computed at \
                         training; the file was edited or truncated: rebuild it with the \
                         command in its provenance"
                    ),
                ));
            }
            _ => {}
        }
        let actual = self.compute_checksum()?;
        if actual != self.checksum {
            return Err(BundleError::Checksum {
                expected: self.checksum.clone(),
                actual,
            });
        }
        time::OffsetDateTime::parse(
            &self.created,
            &time::format_description::well_known::Rfc3339,
        )
        .map_err(|e| invalid("created", format!("not an RFC 3339 time: {e}")))?;
        self.scheme.validate().map_err(core("scheme"))?;
        let n = self.scheme.len();
        if self.mean.len() != n {
            return Err(invalid(
                "mean",
                format!("{} points, the scheme has {n}", self.mean.len()),
            ));
        }
        if let Some(i) = self
            .mean
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(invalid(format!("mean[{i}]"), "not a finite number"));
        }
        let mean = to_vectors(&self.mean);
        let tri = Triangulation::new(&mean, self.triangles.clone()).map_err(core("triangles"))?;
        let hpr = PaperHpr::new(tri);
        self.training
            .regression
            .validate()
            .map_err(core("training.regression"))?;
        let (visibility, stored_views) = match &self.visibility {
            Some(v) => {
                let (map, views) = v.decode(n, &self.training)?;
                (map, Some(views))
            }
            None => (
                VisibilityMap::build_default(&mean, &hpr).map_err(core("triangles"))?,
                None,
            ),
        };
        // Stored for readers of the file; what is served is recomputed and must agree.
        let g = geometry_of(&self.scheme, &mean).map_err(core("mean"))?;
        for (field, stored, derived) in [
            ("lf", self.geometry.lf, g.lf),
            ("ln", self.geometry.ln, g.ln),
            ("axis_tilt", self.geometry.axis_tilt, g.axis_tilt),
        ] {
            // Bundles written before axis_tilt existed read it as exactly 0.
            let legacy = field == "axis_tilt" && stored == 0.0;
            let agrees = (stored - derived).abs() <= 1e-9 * derived.abs().max(1.0);
            if !legacy && !agrees {
                return Err(invalid(
                    format!("geometry.{field}"),
                    format!("{stored} does not match the mean shape's {derived}"),
                ));
            }
        }
        let mut subsets = Vec::new();
        let own_bins = match stored_views {
            Some(views) => bins_with_visibility(&mean, &self.training.regression, &views),
            None => synthesize_bins(&mean, &hpr, &self.training.regression),
        }
        .map_err(core("training.regression"))?;
        for (k, entry) in self.regressions.iter().enumerate() {
            let field = format!("regressions[{k}]");
            let (scheme, map) = subset_of(&self.scheme, &entry.scheme).map_err(core(&field))?;
            let bins = map_bins(&own_bins, &self.scheme, &map);
            if entry.matrices.len() != bins.len() {
                return Err(invalid(
                    format!("{field}.matrices"),
                    format!(
                        "{} matrices for {} view bins of the training grids",
                        entry.matrices.len(),
                        bins.len()
                    ),
                ));
            }
            let d = 2 * scheme.len() + 1;
            let mut matrices = Vec::new();
            for (b, m) in entry.matrices.iter().enumerate() {
                if m.len() != 3 || m.iter().any(|r| r.len() != d) {
                    return Err(invalid(
                        format!("{field}.matrices[{b}]"),
                        format!("expected 3 rows of {d} numbers"),
                    ));
                }
                if m.iter().flatten().any(|v| !v.is_finite()) {
                    return Err(invalid(
                        format!("{field}.matrices[{b}]"),
                        "not a finite number",
                    ));
                }
                matrices.push(DMatrix::from_fn(3, d, |i, j| m[i][j]));
            }
            let eyes = (
                scheme.anchors.eye_left.clone(),
                scheme.anchors.eye_right.clone(),
            );
            let regression =
                RegressionModel::new(scheme.len(), eyes.0, eyes.1, bins, entry.epsilon)
                    .map_err(core(&field))?;
            regression
                .seed_full_pattern(matrices)
                .map_err(core(&field))?;
            let sub_mean = map.map_points(&self.scheme, &mean);
            subsets.push(Subset {
                scheme,
                map,
                mean: sub_mean,
                regression,
            });
        }
        if subsets
            .first()
            .map(|s| s.scheme.name != self.scheme.name)
            .unwrap_or(true)
        {
            return Err(invalid(
                "regressions",
                format!(
                    "the first entry must be the model's own scheme {:?}",
                    self.scheme.name
                ),
            ));
        }
        let morph = match &self.shape_basis {
            Some(b) => {
                if b.mean.len() != n || b.components.iter().any(|c| c.len() != n) {
                    return Err(invalid(
                        "shape_basis",
                        format!("every shape must have {n} points"),
                    ));
                }
                Some(
                    MorphableBasis::new(
                        to_vectors(&b.mean),
                        b.components.iter().map(|c| to_vectors(c)).collect(),
                        b.prior_mean.clone(),
                    )
                    .map_err(core("shape_basis"))?,
                )
            }
            None => None,
        };
        let mesh = match &self.mesh {
            Some(m) => Some(m.decode(&self.scheme)?),
            None => None,
        };
        if let Some(c) = &self.calibration {
            c.validate().map_err(core("calibration"))?;
        }
        for (i, d) in self.detector_regressions.iter().enumerate() {
            d.validate().map_err(core("detector_regressions"))?;
            // The model's own scheme (dlib's 68 points on an ibug68 model) or a mesh scheme.
            let n = if d.scheme == self.scheme.name {
                Some(self.scheme.len())
            } else {
                mesh.as_ref()
                    .and_then(|m| m.scheme(&d.scheme))
                    .map(|s| s.scheme.len())
            };
            if n.map(|n| 2 * n + 1) != Some(d.weights.len()) {
                return Err(invalid(
                    "detector_regressions",
                    format!(
                        "entry {i} ({}) is not for the model's own scheme or a mesh scheme of \
                         it, or has the wrong number of weights",
                        d.scheme
                    ),
                ));
            }
            if self.detector_regressions[..i]
                .iter()
                .any(|e| e.scheme == d.scheme)
            {
                return Err(invalid(
                    "detector_regressions",
                    format!("entry {i} repeats scheme {}", d.scheme),
                ));
            }
        }
        Ok(PoseModel {
            scheme: self.scheme.clone(),
            mean,
            hpr,
            visibility,
            geometry: g,
            subsets,
            morph,
            mesh,
            calibration: self.calibration.clone(),
            detectors: self.detector_regressions.clone(),
        })
    }
}

/// The one field of a bundle read before the rest: its schema version.
#[derive(Deserialize)]
struct Header {
    schema_version: Option<u32>,
}

/// Whether this build reads bundles of schema version `v`, with what to do when it does not.
fn check_schema_version(v: u32) -> Result<(), BundleError> {
    if (OLDEST_SCHEMA_VERSION..=SCHEMA_VERSION).contains(&v) {
        return Ok(());
    }
    let todo = if v > SCHEMA_VERSION {
        "a newer build of facepose wrote it: serve it with that build or later"
    } else {
        "rebuild it with the command in its provenance"
    };
    Err(invalid(
        "schema_version",
        format!(
            "this build reads versions {OLDEST_SCHEMA_VERSION} to {SCHEMA_VERSION}, the file is \
             version {v}: {todo}"
        ),
    ))
}

impl VisibilityEntry {
    /// The map and, per regression grid, the views' flags, checked against `n` points and the
    /// grids of `training`.
    fn decode(
        &self,
        n: usize,
        training: &TrainOptions,
    ) -> Result<(VisibilityMap, Vec<Vec<bool>>), BundleError> {
        let cells = self.map_yaw.len() * self.map_pitch.len();
        let bits = packed_bits::decode(&self.map, n, cells)
            .map_err(|reason| invalid("visibility.map", reason))?;
        let map = VisibilityMap::from_bits(self.map_yaw, self.map_pitch, n, bits)
            .map_err(core("visibility.map"))?;
        let grids: Vec<_> = training.regression.grids().collect();
        if self.views.len() != grids.len() {
            return Err(invalid(
                "visibility.views",
                format!(
                    "{} entries for {} regression grids (training.regression)",
                    self.views.len(),
                    grids.len()
                ),
            ));
        }
        let views = self
            .views
            .iter()
            .zip(grids)
            .enumerate()
            .map(|(k, (text, grid))| {
                packed_bits::decode(text, n, grid.len())
                    .map_err(|reason| invalid(format!("visibility.views[{k}]"), reason))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok((map, views))
    }
}

impl MeshEntry {
    /// The served mesh, checked against the model's scheme.
    fn decode(&self, scheme: &Scheme) -> Result<FaceMesh, BundleError> {
        if let Some(i) = self
            .vertices
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(invalid(
                format!("mesh.vertices[{i}]"),
                "not a finite number",
            ));
        }
        let n = self.vertices.len();
        let source = MeshSource {
            vertices: to_vectors(&self.vertices),
            triangles: self.triangles.clone(),
            to_model: self.to_model.clone(),
        };
        source.validate(scheme.len()).map_err(core("mesh"))?;
        Triangulation::new(&source.vertices, source.triangles.clone())
            .map_err(core("mesh.triangles"))?;
        let cells = self.map_yaw.len() * self.map_pitch.len();
        let bits = packed_bits::decode(&self.map, n, cells)
            .map_err(|reason| invalid("mesh.map", reason))?;
        let map = VisibilityMap::from_bits(self.map_yaw, self.map_pitch, n, bits)
            .map_err(core("mesh.map"))?;
        FaceMesh::new(source, scheme, Some(map)).map_err(core("mesh"))
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of some bytes as lower-case hex (for provenance).
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}
