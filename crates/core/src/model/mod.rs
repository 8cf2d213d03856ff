//! A pose model: everything the estimators need for one landmark scheme, trained from a mean
//! 3D shape or a population (`train.rs`, `basis.rs`), and its bundle format (`bundle.rs`);
//! bundles on disk are `facepose_files::store`'s.
//!
//! A model serves its own scheme and the sub-schemes it was trained for: for `ibug68`, also
//! `inner51` (points 17-67) and `five` (anchor means).

pub mod basis;
pub mod bundle;
pub mod mesh;
pub mod packed_bits;
pub mod train;
pub mod validate;

use std::borrow::Cow;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::estimate::detector::DetectorRegression;
use crate::estimate::geometric::GeometryConstants;
use crate::estimate::morph_fit::MorphableBasis;
use crate::estimate::regression::RegressionModel;
use crate::estimate::visibility_map::VisibilityMap;
use crate::hpr::PaperHpr;
use crate::shape::{Scheme, Shape2};
use crate::uncertainty::Calibration;

pub use mesh::{FaceMesh, MeshScheme, MeshSource};
pub use train::{BasisSource, RegressionParams, TrainOptions, train, train_from_population};

/// How a sub-scheme's points come from the model scheme's points.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SubsetMap {
    /// The model's own scheme: point `k` is point `k`.
    Own,
    /// Point `k` of the subset is point `indices[k]` of the model.
    Indices(Vec<usize>),
    /// The subset is `five`: each point is the mean of one anchor's points.
    Anchors,
}

impl SubsetMap {
    /// The subset's 3D points from the model's.
    pub fn map_points(&self, scheme: &Scheme, pts: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        match self {
            SubsetMap::Own => pts.to_vec(),
            SubsetMap::Indices(idx) => idx.iter().map(|&i| pts[i]).collect(),
            SubsetMap::Anchors => scheme
                .anchors
                .as_array()
                .iter()
                .map(|a| a.iter().map(|&i| pts[i]).sum::<Vector3<f64>>() / a.len() as f64)
                .collect(),
        }
    }

    /// Marks in `out` the subset's points hidden under the model's visibility `vis` (an anchor is
    /// hidden when all its points are); allocation-free.
    pub fn hidden_into(&self, scheme: &Scheme, vis: &[bool], out: &mut [bool]) {
        match self {
            SubsetMap::Own => {
                for (o, &v) in out.iter_mut().zip(vis) {
                    *o = !v;
                }
            }
            SubsetMap::Indices(idx) => {
                for (o, &i) in out.iter_mut().zip(idx) {
                    *o = !vis[i];
                }
            }
            SubsetMap::Anchors => {
                for (o, a) in out.iter_mut().zip(scheme.anchors.as_array()) {
                    *o = !a.iter().any(|&i| vis[i]);
                }
            }
        }
    }

    /// The subset's visibility from the model's: an anchor is visible if any of its points is.
    pub fn map_visibility(&self, scheme: &Scheme, vis: &[bool]) -> Vec<bool> {
        match self {
            SubsetMap::Own => vis.to_vec(),
            SubsetMap::Indices(idx) => idx.iter().map(|&i| vis[i]).collect(),
            SubsetMap::Anchors => scheme
                .anchors
                .as_array()
                .iter()
                .map(|a| a.iter().any(|&i| vis[i]))
                .collect(),
        }
    }
}

/// One scheme the model answers for.
#[derive(Debug)]
pub struct Subset {
    /// The subset's scheme.
    pub scheme: Scheme,
    /// How its points come from the model's.
    pub map: SubsetMap,
    /// The mean shape's points in this scheme.
    pub mean: Vec<Vector3<f64>>,
    /// The subset's pose regression.
    pub regression: RegressionModel,
}

/// A trained pose model.
#[derive(Debug)]
pub struct PoseModel {
    /// The model's own scheme.
    pub scheme: Scheme,
    /// Frontal mean shape, model frame, mm, centred.
    pub mean: Vec<Vector3<f64>>,
    /// Hidden point removal on the mean shape's triangulation (the training views' visibility).
    pub hpr: PaperHpr,
    /// Which points are visible from which directions.
    pub visibility: VisibilityMap,
    /// Geometric constants of the model.
    pub geometry: GeometryConstants,
    /// Subset 0 is the model's own scheme.
    pub subsets: Vec<Subset>,
    /// The morphable shape basis, for the shape-fitting methods.
    pub morph: Option<MorphableBasis>,
    /// MediaPipe's face mesh, aligned to the mean: the `mediapipe468` and `mediapipe478`
    /// schemes ([`mesh`]).
    pub mesh: Option<FaceMesh>,
    /// The map from an estimate's raw spread to calibrated standard deviations and 90%
    /// intervals ([`crate::uncertainty::calibration`]); without it answers carry none.
    pub calibration: Option<Calibration>,
    /// Regressions trained on landmark detectors' own output, one per scheme at most
    /// ([`crate::estimate::detector`]): method `detector`, and `auto` on those schemes.
    pub detectors: Vec<DetectorRegression>,
}

impl PoseModel {
    /// The detector regression that reads scheme `name`, when the model has one.
    pub fn detector(&self, name: &str) -> Option<&DetectorRegression> {
        self.detectors.iter().find(|d| d.scheme == name)
    }

    /// Every scheme the model serves: its subsets' (its own first), then its mesh's.
    pub fn schemes(&self) -> impl Iterator<Item = &Scheme> {
        self.subsets.iter().map(|s| &s.scheme).chain(
            self.mesh
                .iter()
                .flat_map(|m| m.schemes().iter().map(|s| &s.scheme)),
        )
    }

    /// The mesh scheme called `name`, when the model has a mesh that serves it.
    pub fn mesh_scheme(&self, name: &str) -> Option<(&FaceMesh, &MeshScheme)> {
        let mesh = self.mesh.as_ref()?;
        mesh.scheme(name).map(|s| (mesh, s))
    }

    /// The scheme called `name`, with a message listing the served ones.
    pub fn scheme(&self, name: &str) -> Result<&Scheme> {
        self.schemes()
            .find(|s| s.name == name)
            .ok_or_else(|| self.unknown_scheme(name))
    }

    fn unknown_scheme(&self, name: &str) -> Error {
        Error::InvalidScheme {
            scheme: name.into(),
            reason: format!(
                "this model serves {}",
                self.schemes()
                    .map(|s| s.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }

    /// The subset serving `scheme_name` (the schemes of the model's points, not its mesh's),
    /// with a message listing the known ones.
    pub fn subset(&self, scheme_name: &str) -> Result<&Subset> {
        self.subsets
            .iter()
            .find(|s| s.scheme.name == scheme_name)
            .ok_or_else(|| self.unknown_scheme(scheme_name))
    }

    /// The scheme this model serves with `n` points, when only one has that many (68: `ibug68`,
    /// 51: `inner51`, 468: `mediapipe468`, 478: `mediapipe478` for the default model). Fails,
    /// naming the candidates and their points, when several have that many (5: `five` and
    /// `dlib5`, two different point sets) or none does.
    pub fn scheme_for_count(&self, n: usize) -> Result<&Scheme> {
        let fits: Vec<&Scheme> = self.schemes().filter(|s| s.len() == n).collect();
        match fits[..] {
            [one] => Ok(one),
            [] => Err(Error::param(
                "scheme",
                format!(
                    "{n} landmarks, and no scheme of this model has that many ({})",
                    self.schemes()
                        .map(|s| format!("{}: {}", s.name, s.len()))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )),
            _ => Err(Error::param(
                "scheme",
                format!(
                    "{n} landmarks fit more than one scheme, so name it: {}",
                    describe_schemes(&fits)
                ),
            )),
        }
    }

    /// For a landmark count that does not match `scheme`: which served schemes have that many
    /// points ("" when none does), to append to the error.
    pub fn count_hint(&self, n: usize) -> String {
        let fits: Vec<&Scheme> = self.schemes().filter(|s| s.len() == n).collect();
        if fits.is_empty() {
            String::new()
        } else {
            format!(" ({n} points is {})", describe_schemes(&fits))
        }
    }

    /// Serves MediaPipe's face mesh: `source` (vertices with model-frame axes, in mm, and the
    /// correspondence to this model's scheme) is aligned to the mean and its visibility computed
    /// by HPR over its triangles.
    pub fn attach_mesh(&mut self, source: &MeshSource) -> Result<()> {
        let aligned = source.aligned_to(&self.scheme, &self.mean)?;
        self.mesh = Some(FaceMesh::new(aligned, &self.scheme, None)?);
        Ok(())
    }

    /// The model's landmarks expanded from a subset's (missing where the subset has no point).
    pub fn expand<'a>(&self, subset: &Subset, shape: &'a Shape2) -> Option<Cow<'a, Shape2>> {
        match &subset.map {
            SubsetMap::Own => Some(Cow::Borrowed(shape)),
            SubsetMap::Indices(idx) => {
                let mut pts = vec![None; self.scheme.len()];
                for (k, &i) in idx.iter().enumerate() {
                    pts[i] = shape.get(k).map(|p| [p.x, p.y]);
                }
                Shape2::from_options(&pts).ok().map(Cow::Owned)
            }
            SubsetMap::Anchors => None,
        }
    }
}

/// `five [eye_left, eye_right, ...] or dlib5 [...]`: the schemes with their points in order.
fn describe_schemes(schemes: &[&Scheme]) -> String {
    schemes
        .iter()
        .map(|s| {
            if s.len() <= 10 {
                format!("{} [{}]", s.name, s.points.join(", "))
            } else {
                s.name.clone()
            }
        })
        .collect::<Vec<_>>()
        .join(" or ")
}

/// The default model's bundle text (built by `facepose train` from ../shared/data/bfm68; see
/// models/README.md), embedded so that the binary runs without the models folder.
pub const DEFAULT_BUNDLE: &str = include_str!("../../../../models/default/model.json");

/// Parses, validates and builds the embedded default model.
pub fn default_model() -> std::result::Result<(bundle::Bundle, PoseModel), bundle::BundleError> {
    let b = bundle::Bundle::parse(DEFAULT_BUNDLE)?;
    let m = b.load()?;
    Ok((b, m))
}
