//! The estimators, in one table: each method's name, what it needs of a model, whether it
//! takes a camera, where its misfit comes from and how it runs. Dispatch, the name lists of
//! messages, `--help`, the OpenAPI enum and the metrics' labels are read off [`METHODS`]; the
//! docs that cannot be are checked against it by a test (`tests/integration/registries.rs`).
//!
//! Adding a method: a variant of [`Method`], its row in [`METHODS`], and its runner (a function
//! from a [`SubsetInput`] to a [`Ran`]).

use std::borrow::Cow;
use std::fmt;
use std::str::FromStr;

use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::estimate::detector::DetectorRegression;
use crate::estimate::fit::{FitOptions, RigidFit, fit_rigid};
use crate::estimate::geometric::estimate_geometric;
use crate::estimate::morph_fit::{MorphOptions, fit_morphable};
use crate::estimate::perspective::Intrinsics;
use crate::model::{PoseModel, Subset, SubsetMap};
use crate::shape::Shape2;

use super::MIN_SHAPE_FIT_POINTS;

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
    /// The ridge regression trained on a landmark detector's own output.
    Detector,
}

/// What a method needs of a model beyond its mean shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Needs {
    /// Nothing more: every model runs it.
    Nothing,
    /// A morphable shape basis (`PoseModel::morph`).
    ShapeBasis,
    /// A detector regression (`PoseModel::detectors`), for the scheme of the input.
    DetectorRegression,
}

impl Needs {
    /// Whether `model` has it.
    pub fn met_by(self, model: &PoseModel) -> bool {
        match self {
            Needs::Nothing => true,
            Needs::ShapeBasis => model.morph.is_some(),
            Needs::DetectorRegression => !model.detectors.is_empty(),
        }
    }

    /// What it is, for messages ("method fit-shape needs a model with a shape basis").
    pub fn what(self) -> &'static str {
        match self {
            Needs::Nothing => "nothing",
            Needs::ShapeBasis => "a model with a shape basis",
            Needs::DetectorRegression => "a model with a detector regression",
        }
    }
}

/// Where an estimate's misfit ([`super::Estimate::misfit`]) comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Misfit {
    /// The method's own pose: it fits the landmarks.
    OfOwnPose,
    /// A rigid fit of the same landmarks: the method's pose can be poor where the landmarks
    /// are fine (the paper's methods), so its own misfit would blame the landmarks.
    OfRigidFit,
}

/// What a method's runner gets: the landmarks in a scheme of the model's points.
pub struct SubsetInput<'a> {
    /// The model.
    pub model: &'a PoseModel,
    /// The subset of the model's points the landmarks are in.
    pub subset: &'a Subset,
    /// The scheme's name as the caller gave it, for messages.
    pub scheme: &'a str,
    /// The landmarks, image pixels (y down).
    pub landmarks: &'a Shape2,
    /// Options of the rigid fit.
    pub fit_options: FitOptions,
}

/// What a runner returns: the rotation and, for the fit methods, the shape they fitted (in the
/// subset's points) with the fit's camera, which the perspective refinement and the raw spread
/// start from.
pub struct Ran<'a> {
    /// Rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// The fitted shape and its camera, for the fit methods.
    pub fitted: Option<(Cow<'a, [Vector3<f64>]>, RigidFit)>,
    /// The rotation of the mean shape's rigid fit, when the method ran that fit without
    /// answering with it (the detector regression's reference): what the misfit of
    /// [`Misfit::OfRigidFit`] is measured on, rather than fitting again.
    pub rigid: Option<Rotation3<f64>>,
}

/// A method's runner.
pub type Runner = for<'a> fn(&SubsetInput<'a>) -> Result<Ran<'a>>;

/// One estimator: everything the code and the docs say of it.
pub struct MethodSpec {
    /// The method.
    pub method: Method,
    /// The name on every interface (kebab-case, as serde writes it).
    pub name: &'static str,
    /// One line for listings and `--help`.
    pub summary: &'static str,
    /// What the model needs to run it.
    pub needs: Needs,
    /// Refines its pose under full perspective when the request has camera intrinsics; the
    /// others are weak-perspective by construction and refuse a camera.
    pub perspective: bool,
    /// Which pose the misfit is measured on.
    pub misfit: Misfit,
    /// How much more a filter on rotations trusts its answers than their calibrated turn
    /// covariance says ([`super::Estimate::filter_cov`] divides the covariance by it): one
    /// where the uncertainty is mostly frame-to-frame scatter; above one where it is mostly a
    /// bias that consecutive frames share, which weighing by it would only make the filter lag.
    /// Chosen on the rendered benchmark's training trajectories (docs/RESULTS.md).
    pub filter_trust: f64,
    /// How it runs on a subset of the model's points (`None`: `auto`, which resolves first).
    run: Option<Runner>,
}

/// [`MethodSpec::filter_trust`] of the detector regression.
pub const DETECTOR_FILTER_TRUST: f64 = 4.0;

/// Every method, in the order of the docs and of listings ([`Method::ALL`] follows it).
pub const METHODS: [MethodSpec; 6] = [
    MethodSpec {
        method: Method::Auto,
        name: "auto",
        summary: "the most accurate method for the input: detector for dlib's 68 points (all of \
                  them in ibug68, landmark_style contour, no camera), fit-shape for 12 or more \
                  other points of ibug68 or inner51; on a MediaPipe mesh, detector for a \
                  detector's points (all of them, no camera) and fit for the mesh's own \
                  projection; fit otherwise",
        needs: Needs::Nothing,
        perspective: true,
        misfit: Misfit::OfOwnPose,
        filter_trust: 1.0,
        run: None,
    },
    MethodSpec {
        method: Method::Fit,
        name: "fit",
        summary: "a robust rigid weak-perspective fit of the mean 3D shape",
        needs: Needs::Nothing,
        perspective: true,
        misfit: Misfit::OfOwnPose,
        filter_trust: 1.0,
        run: Some(run_fit),
    },
    MethodSpec {
        method: Method::FitShape,
        name: "fit-shape",
        summary: "the MAP fit of the morphable shape basis (identity and expression) and the \
                  pose",
        needs: Needs::ShapeBasis,
        perspective: true,
        misfit: Misfit::OfOwnPose,
        filter_trust: 1.0,
        run: Some(run_fit_shape),
    },
    MethodSpec {
        method: Method::Regression,
        name: "regression",
        summary: "the paper's ridge regression from the normalized 2D shape (§4.2)",
        needs: Needs::Nothing,
        perspective: false,
        misfit: Misfit::OfRigidFit,
        filter_trust: 1.0,
        run: Some(run_regression),
    },
    MethodSpec {
        method: Method::Geometry,
        name: "geometry",
        summary: "the paper's modified five-point geometric method (§4.1)",
        needs: Needs::Nothing,
        perspective: false,
        misfit: Misfit::OfRigidFit,
        filter_trust: 1.0,
        run: Some(run_geometry),
    },
    MethodSpec {
        method: Method::Detector,
        name: "detector",
        summary: "the ridge regression trained on a detector's own points over rendered heads at \
                  known poses (mediapipe478 and ibug68 in the default model; every point needed)",
        needs: Needs::DetectorRegression,
        perspective: false,
        misfit: Misfit::OfRigidFit,
        // Its 90% intervals (about 15°) hold the under-reading a detector's points share from
        // frame to frame; its answers scatter by far less.
        filter_trust: DETECTOR_FILTER_TRUST,
        run: Some(run_detector),
    },
];

impl Method {
    /// Every method, in the order of [`METHODS`].
    pub const ALL: [Method; METHODS.len()] = {
        let mut all = [Method::Auto; METHODS.len()];
        let mut i = 0;
        while i < all.len() {
            all[i] = METHODS[i].method;
            i += 1;
        }
        all
    };

    /// Every method name, for messages and enums.
    pub const NAMES: [&'static str; METHODS.len()] = {
        let mut names = [""; METHODS.len()];
        let mut i = 0;
        while i < names.len() {
            names[i] = METHODS[i].name;
            i += 1;
        }
        names
    };

    /// Its row of [`METHODS`].
    pub const fn spec(self) -> &'static MethodSpec {
        &METHODS[self as usize]
    }

    /// The name on every interface (kebab-case, as serde writes it).
    pub const fn name(self) -> &'static str {
        self.spec().name
    }

    /// Whether `model` has what the method needs.
    pub fn is_supported_by(self, model: &PoseModel) -> bool {
        self.spec().needs.met_by(model)
    }

    /// The method's place in [`Method::ALL`], for tables indexed by method.
    pub fn index(self) -> usize {
        self as usize
    }

    /// The method `auto` stands for, given the model, the subset the input is in, how many
    /// points are present and whether the input is a detector's that the model has a regression
    /// for (`detector_input`: complete, sent in 2D style (`landmark_style: contour`, as dlib's
    /// 68 points are) and without a camera). Measured on AFLW2000-3D (docs/RESULTS.md): the
    /// shape fit is the most accurate on 68 and 51 points, the rigid fit on five (anchor means,
    /// which the shape fit does not take); on the rendered benchmark's dlib points, the
    /// regression trained on dlib's output (`facepose eval --protocol rendered`).
    pub fn resolve(
        self,
        model: &PoseModel,
        subset: &Subset,
        present: usize,
        detector_input: bool,
    ) -> Method {
        match self {
            Method::Auto if detector_input => Method::Detector,
            Method::Auto
                if Method::FitShape.is_supported_by(model)
                    && subset.map != SubsetMap::Anchors
                    && present >= MIN_SHAPE_FIT_POINTS =>
            {
                Method::FitShape
            }
            Method::Auto => Method::Fit,
            m => m,
        }
    }

    /// The method `auto` stands for on a MediaPipe mesh scheme, given the misfit of the mesh's
    /// rigid fit to the points when the detector regression could read them (`None`: no
    /// camera-free, complete input with a regression for the scheme). A detector's points are
    /// not a rigid mesh: MediaPipe Face Mesh's own output misfits the mesh by 0.057-0.24 on
    /// every render of the rendered benchmark and 0.060-0.116 on the real photographs
    /// (tests/fixtures/detectors), where the regression trained on that output is the more
    /// accurate (`facepose eval --protocol rendered`). Points that fit the mesh to within
    /// [`DETECTOR_MISFIT`] are the mesh's own projection (0.049 at most with noise of 2% of the
    /// eyes' distance), where the rigid fit is exact and the regression far off (17° on average
    /// over `eval --protocol mediapipe`'s poses): those get the rigid fit. The figures:
    /// `cargo run --release -p facepose-eval --example detector_gate`.
    pub fn resolve_on_mesh(self, detector_misfit: Option<f64>) -> Method {
        match (self, detector_misfit) {
            (Method::Auto, Some(m)) if m >= DETECTOR_MISFIT => Method::Detector,
            (Method::Auto, _) => Method::Fit,
            (m, _) => m,
        }
    }
}

/// The misfit ([`super::Estimate::misfit`]) of a MediaPipe mesh's rigid fit from which `auto`
/// reads the points as a detector's output (see [`Method::resolve_on_mesh`]): between the
/// mesh's own projection with noise (at most 0.049) and MediaPipe Face Mesh's output (at least
/// 0.057), nearer the first: taking a detector's points for the mesh's costs the fit's 1-3°,
/// the other mistake about 17°.
pub const DETECTOR_MISFIT: f64 = 0.05;

impl MethodSpec {
    /// Fails when a camera is given to a method that cannot use it, naming those that can.
    pub fn check_camera(&self, camera: Option<&Intrinsics>) -> Result<()> {
        if camera.is_none() || self.perspective {
            return Ok(());
        }
        let can: Vec<&str> = METHODS
            .iter()
            .filter(|m| m.perspective)
            .map(|m| m.name)
            .collect();
        Err(Error::param(
            "camera",
            format!(
                "method {} is weak-perspective only; use {} with camera intrinsics",
                self.name,
                or_list(&can)
            ),
        ))
    }

    /// Runs the method (resolved: not `auto`) on `input`.
    pub fn run<'a>(&self, input: &SubsetInput<'a>) -> Result<Ran<'a>> {
        let run = self.run.ok_or_else(|| {
            Error::param("method", "auto must be resolved before it runs (internal)")
        })?;
        run(input)
    }
}

/// `a, b or c`.
fn or_list(names: &[&str]) -> String {
    match names {
        [] => String::new(),
        [one] => (*one).to_string(),
        [init @ .., last] => format!("{} or {last}", init.join(", ")),
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                Error::param(
                    "method",
                    format!("unknown method {s:?} (known: {})", Method::NAMES.join(", ")),
                )
            })
    }
}

fn run_fit<'a>(i: &SubsetInput<'a>) -> Result<Ran<'a>> {
    let subset = i.subset;
    // The visibility map is over the model's own points; subsets without contour points have
    // nothing to drop.
    let visibility = (subset.map == SubsetMap::Own).then_some(&i.model.visibility);
    let f = fit_rigid(
        &subset.mean,
        i.landmarks,
        &subset.scheme.contour,
        visibility,
        i.fit_options,
    )?;
    Ok(Ran {
        rotation: f.rotation,
        fitted: Some((Cow::Borrowed(&subset.mean[..]), f)),
        rigid: None,
    })
}

fn run_fit_shape<'a>(i: &SubsetInput<'a>) -> Result<Ran<'a>> {
    let (model, subset) = (i.model, i.subset);
    let morph = model.morph.as_ref().ok_or_else(|| {
        Error::param(
            "method",
            "fit-shape needs a model with a shape basis; this model has none",
        )
    })?;
    let full = model.expand(subset, i.landmarks).ok_or_else(|| {
        Error::param(
            "method",
            format!("fit-shape does not take scheme {}", i.scheme),
        )
    })?;
    let f = fit_morphable(
        morph,
        &full,
        &model.scheme.contour,
        Some(&model.visibility),
        MorphOptions {
            rigid: i.fit_options,
            ..MorphOptions::default()
        },
    )?;
    let rotation = f.camera.rotation;
    // The model's own scheme takes the fit's shape and weights as they are.
    let (shape, weights) = match &subset.map {
        SubsetMap::Own => (f.shape, f.camera.weights),
        map => {
            let shape = map.map_points(&model.scheme, &f.shape);
            let weights = match map {
                SubsetMap::Indices(idx) => idx.iter().map(|&k| f.camera.weights[k]).collect(),
                _ => vec![1.0; subset.scheme.len()],
            };
            (shape, weights)
        }
    };
    Ok(Ran {
        rotation,
        fitted: Some((
            Cow::Owned(shape),
            RigidFit {
                weights,
                ..f.camera
            },
        )),
        rigid: None,
    })
}

fn run_regression<'a>(i: &SubsetInput<'a>) -> Result<Ran<'a>> {
    let (model, map) = (i.model, &i.subset.map);
    let hidden = |yaw: f64, pitch: f64, out: &mut [bool]| {
        map.hidden_into(
            &model.scheme,
            model.visibility.lookup_yaw_pitch(yaw, pitch),
            out,
        )
    };
    Ok(Ran {
        rotation: i.subset.regression.estimate(i.landmarks, &hidden)?.rotation,
        fitted: None,
        rigid: None,
    })
}

fn run_geometry<'a>(i: &SubsetInput<'a>) -> Result<Ran<'a>> {
    let five = match &i.subset.map {
        SubsetMap::Anchors => i.landmarks.clone(),
        SubsetMap::Own | SubsetMap::Indices(_) => i.landmarks.to_five(&i.subset.scheme)?,
    };
    Ok(Ran {
        rotation: estimate_geometric(&five, &i.model.geometry)?,
        fitted: None,
        rigid: None,
    })
}

fn run_detector<'a>(i: &SubsetInput<'a>) -> Result<Ran<'a>> {
    let regression = detector_of(i.model, i.scheme)?;
    // The rigid fit is the reference the regression de-rolls by.
    let reference = run_fit(i)?.rotation;
    Ok(Ran {
        rotation: regression.estimate(i.landmarks, &reference)?,
        fitted: None,
        rigid: Some(reference),
    })
}

/// The model's detector regression for `scheme`, or a message naming the schemes it has.
pub fn detector_of<'m>(model: &'m PoseModel, scheme: &str) -> Result<&'m DetectorRegression> {
    model.detector(scheme).ok_or_else(|| {
        let have: Vec<&str> = model.detectors.iter().map(|d| d.scheme.as_str()).collect();
        Error::param(
            "method",
            format!(
                "method detector has no regression for scheme {scheme} in this model (it has \
                 one for: {}); use auto or fit",
                if have.is_empty() {
                    "none".to_string()
                } else {
                    have.join(", ")
                }
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A filter trusts every method's answers at least as stated, and only the detector
    /// regression's more; an estimate's filter covariance is its turn covariance divided by
    /// its method's trust.
    #[test]
    fn filters_trust_only_the_detector_regression_more_than_stated() {
        use crate::geometry::EulerAngles;
        use crate::pose::Estimate;
        use crate::uncertainty::Uncertainty;
        use nalgebra::Matrix3;
        for spec in &METHODS {
            let want = if spec.method == Method::Detector {
                DETECTOR_FILTER_TRUST
            } else {
                1.0
            };
            assert_eq!(spec.filter_trust, want, "{}", spec.name);
        }
        assert!(DETECTOR_FILTER_TRUST.is_finite() && DETECTOR_FILTER_TRUST > 1.0);
        let turn_cov = Matrix3::new(4.0, 1.0, 0.0, 1.0, 9.0, 0.5, 0.0, 0.5, 1.0) * 1e-4;
        let estimate = |method| Estimate {
            rotation: nalgebra::Rotation3::identity(),
            angles: EulerAngles::new(0.0, 0.0, 0.0).unwrap(),
            visible: vec![],
            residual: 0.0,
            misfit: 0.1,
            warnings: vec![],
            spread: None,
            uncertainty: Some(Uncertainty {
                sd: [1.0; 3],
                interval90: [[-1.0, 1.0]; 3],
                turn_cov,
            }),
            method,
            translation: None,
        };
        assert_eq!(estimate(Method::Fit).filter_cov(), Some(turn_cov));
        assert_eq!(
            estimate(Method::Detector).filter_cov(),
            Some(turn_cov / DETECTOR_FILTER_TRUST)
        );
        let none = Estimate {
            uncertainty: None,
            ..estimate(Method::Detector)
        };
        assert_eq!(none.filter_cov(), None);
    }

    #[test]
    fn auto_on_a_mesh_reads_a_detector_only_from_the_cut() {
        let on = |m| Method::Auto.resolve_on_mesh(m);
        assert_eq!(on(None), Method::Fit);
        assert_eq!(on(Some(0.0)), Method::Fit);
        assert_eq!(on(Some(DETECTOR_MISFIT - 1e-9)), Method::Fit);
        assert_eq!(on(Some(DETECTOR_MISFIT)), Method::Detector);
        assert_eq!(on(Some(0.2)), Method::Detector);
        assert_eq!(on(Some(f64::NAN)), Method::Fit);
        for m in Method::ALL.into_iter().filter(|&m| m != Method::Auto) {
            assert_eq!(m.resolve_on_mesh(Some(0.2)), m);
            assert_eq!(m.resolve_on_mesh(None), m);
        }
    }

    #[test]
    fn the_table_is_in_the_enum_order() {
        for (i, spec) in METHODS.iter().enumerate() {
            assert_eq!(spec.method as usize, i, "{}", spec.name);
            assert_eq!(spec.method.name(), spec.name);
            assert_eq!(spec.name.parse::<Method>().unwrap(), spec.method);
            // serde's kebab-case name is the table's.
            assert_eq!(
                serde_json::to_string(&spec.method).unwrap(),
                format!("{:?}", spec.name)
            );
            // Only auto resolves instead of running.
            assert_eq!(spec.run.is_none(), spec.method == Method::Auto);
        }
    }

    #[test]
    fn a_camera_is_refused_by_name_with_the_methods_that_take_one() {
        let k = Intrinsics {
            fx: 500.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
        };
        let e = Method::Geometry
            .spec()
            .check_camera(Some(&k))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("method geometry is weak-perspective only; use auto, fit or fit-shape"),
            "{e}"
        );
        assert!(Method::Fit.spec().check_camera(Some(&k)).is_ok());
        assert!(Method::Regression.spec().check_camera(None).is_ok());
    }
}
