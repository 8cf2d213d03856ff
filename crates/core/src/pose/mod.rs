//! One interface over every estimator: landmarks in a scheme the model serves -> rotation,
//! angles, per-point visibility at the estimated pose, a fit residual and the method used.

mod conventions;
mod method;

pub use conventions::{ConventionOptions, conventions_of};
pub use method::{
    DETECTOR_FILTER_TRUST, DETECTOR_MISFIT, METHODS, Method, MethodSpec, Misfit, Needs, Ran,
    Runner, SubsetInput,
};

use std::fmt;
use std::str::FromStr;

use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::estimate::fit::{FitOptions, Hidden, fit_rigid};
use crate::estimate::perspective::{Intrinsics, refine_perspective};
use crate::geometry::EulerAngles;
use crate::geometry::moments::Moments;
use crate::model::{FaceMesh, MeshScheme, PoseModel, SubsetMap};
use crate::shape::{Scheme, Shape2};
use crate::uncertainty::{PointClass, RawSpread, Uncertainty, raw_spread};

/// Fewest present points for `auto` to choose the shape fit: below, the prior decides most of
/// the shape and the rigid fit is as good.
pub const MIN_SHAPE_FIT_POINTS: usize = 12;

/// A pose estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Rotation, model frame to camera axes.
    pub rotation: Rotation3<f64>,
    /// The rotation's angles, degrees (Pose_Para).
    pub angles: EulerAngles,
    /// Per input point: visible at the estimated pose (HPR on the mean shape).
    pub visible: Vec<bool>,
    /// RMS reprojection error of the mean shape at the estimate over the present points,
    /// divided by the projected inter-ocular distance (eye centres): unitless.
    pub residual: f64,
    /// The share of the landmarks' spread that the mean shape at the estimate leaves
    /// unexplained: `sqrt(SSE / Σ|y - ȳ|²)` at the best scale and translation (0 a perfect fit,
    /// 1 nothing explained). Scale-free and, unlike the residual, not inflated where the eyes
    /// close up in profile: what says whether the landmarks look like a face in their scheme.
    ///
    /// For the paper's methods, whose pose can be poor where the landmarks are fine, it is the
    /// rigid fit's (NaN when the rigid fit cannot answer, and then nothing is checked).
    pub misfit: f64,
    /// What the caller should know about this answer.
    pub warnings: Vec<Warning>,
    /// The raw spread of the angles from the fit's covariance at the estimate (`None` with
    /// fewer than four usable points): what the calibration maps to [`Estimate::uncertainty`].
    pub spread: Option<RawSpread>,
    /// Calibrated standard deviation and 90% interval per angle, when the model has a
    /// calibration for the method and the spread exists.
    pub uncertainty: Option<Uncertainty>,
    /// The method that produced it (never `Auto`).
    pub method: Method,
    /// With camera intrinsics: the model origin in the camera frame, mm (x right, y up, z
    /// towards the viewer; the face is at negative z).
    pub translation: Option<Vector3<f64>>,
}

impl Estimate {
    /// The covariance of the rotation's small turn (radians²) a filter on rotations should
    /// weigh this answer by: the calibrated one ([`Uncertainty::turn_cov`]) divided by the
    /// method's [`MethodSpec::filter_trust`]. `None` without an uncertainty.
    pub fn filter_cov(&self) -> Option<nalgebra::Matrix3<f64>> {
        let trust = self.method.spec().filter_trust;
        self.uncertainty.map(|u| u.turn_cov / trust)
    }
}

/// Misfit ([`Estimate::misfit`]) above which an answer carries a [`Warning::PoorFit`]. On the
/// AFLW2000-3D dev faces (every landmark set, `auto` and `fit`) the largest is 0.25
/// (`facepose eval --protocol real`); the first 68 MediaPipe points sent as ibug68 give 0.93.
pub const MISFIT_WARN: f64 = 0.35;

/// Misfit above which the landmarks are refused ([`Error::NotAFace`]): more than twice the
/// worst real face's.
pub const MISFIT_REFUSE: f64 = 0.6;

/// Something the caller should know about an answer.
#[derive(Debug, Clone, PartialEq)]
pub enum Warning {
    /// The landmarks fit the face in their scheme poorly (misfit between [`MISFIT_WARN`] and
    /// [`MISFIT_REFUSE`]).
    PoorFit {
        /// The landmarks' scheme.
        scheme: String,
        /// The misfit (share of the spread unexplained).
        misfit: f64,
    },
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::PoorFit { scheme, misfit } => write!(
                f,
                "the landmarks fit a face in scheme {scheme} poorly: the best fit leaves {:.0}% \
                 of their spread unexplained (real faces stay below 25%); check the scheme, the \
                 order of the points and that x, y are pixels",
                misfit * 100.0
            ),
        }
    }
}

/// The warnings of a misfit, or the refusal past [`MISFIT_REFUSE`].
fn check_misfit(scheme: &str, misfit: f64) -> Result<Vec<Warning>> {
    if misfit > MISFIT_REFUSE {
        return Err(Error::NotAFace {
            scheme: scheme.into(),
            misfit,
            limit: MISFIT_REFUSE,
        });
    }
    Ok(if misfit > MISFIT_WARN {
        vec![Warning::PoorFit {
            scheme: scheme.into(),
            misfit,
        }]
    } else {
        vec![]
    })
}

/// How the landmarks were made, which decides what hidden points mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LandmarkStyle {
    /// Every landmark is the projection of its 3D point, seen or not (3D-style: 3DMM fits,
    /// AFLW2000-3D, 3DDFA, FAN-3D). Hidden points still pull.
    #[default]
    Projected,
    /// 2D-style (300-W, dlib, FAN-2D): contour points (the jaw) hidden at the pose sit on the
    /// visible outline, so the fit methods leave them out (HPR at the estimate). A complete
    /// face in a scheme the model has a detector regression for (dlib's 68 in `ibug68`) is
    /// read as that detector's output: `auto` answers it with the regression.
    Contour,
}

impl LandmarkStyle {
    /// Every style name, for messages.
    pub const NAMES: [&'static str; 2] = ["projected", "contour"];

    /// Every style, in the order of [`LandmarkStyle::NAMES`].
    pub const ALL: [LandmarkStyle; 2] = [LandmarkStyle::Projected, LandmarkStyle::Contour];

    /// One line for listings and `--help`.
    pub fn summary(self) -> &'static str {
        match self {
            LandmarkStyle::Projected => {
                "3D-style: every landmark is its 3D point's projection, hidden or not (3DMM \
                 fits, AFLW2000-3D)"
            }
            LandmarkStyle::Contour => {
                "2D-style: hidden jaw points sit on the visible outline (300-W, dlib), so the \
                 fit leaves them out; all 68 ibug68 points are read as dlib's (auto: detector)"
            }
        }
    }
}

impl FromStr for LandmarkStyle {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "projected" => Ok(LandmarkStyle::Projected),
            "contour" => Ok(LandmarkStyle::Contour),
            _ => Err(Error::param(
                "landmark_style",
                format!(
                    "unknown landmark style {s:?} (known: {})",
                    LandmarkStyle::NAMES.join(", ")
                ),
            )),
        }
    }
}

/// How to estimate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EstimateOptions {
    /// The estimator.
    pub method: Method,
    /// Pinhole intrinsics: the fit methods then refine the pose under full perspective.
    pub camera: Option<Intrinsics>,
    /// How the landmarks were made (the fit methods' use of hidden contour points).
    pub style: LandmarkStyle,
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
            ..EstimateOptions::default()
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
    let mut e = match model.mesh_scheme(scheme) {
        Some((mesh, ms)) => estimate_mesh(model, mesh, ms, landmarks, opts)?,
        None => estimate_in_subset(model, scheme, landmarks, opts)?,
    };
    e.warnings = check_misfit(scheme, e.misfit)?;
    Ok(e)
}

/// [`estimate_with`] in a scheme of the model's points, without the misfit's check.
fn estimate_in_subset(
    model: &PoseModel,
    scheme: &str,
    landmarks: &Shape2,
    opts: &EstimateOptions,
) -> Result<Estimate> {
    let method = opts.method;
    let subset = model.subset(scheme)?;
    check_count(model, &subset.scheme, landmarks)?;
    let present = landmarks.n_present();
    // A detector's complete 2D-style points with no camera, which a regression was trained on
    // (dlib's 68 in the default model).
    let detector_input = opts.style == LandmarkStyle::Contour
        && opts.camera.is_none()
        && present == subset.scheme.len()
        && model.detector(scheme).is_some();
    let method = method.resolve(model, subset, present, detector_input);
    let map = &subset.map;
    let contour = &subset.scheme.contour;
    let spec = method.spec();
    spec.check_camera(opts.camera.as_ref())?;
    let fit_options = fit_options(opts.style);
    let input = SubsetInput {
        model,
        subset,
        scheme,
        landmarks,
        fit_options,
    };
    // The fit methods keep their shape and camera for the perspective refinement.
    let Ran {
        rotation,
        fitted,
        rigid,
    } = spec.run(&input)?;
    // The raw spread at the answer's rotation, of the shape the method stands on.
    let spread = match &fitted {
        Some((shape, f)) => raw_spread(shape, landmarks, Some(&f.weights), &rotation),
        None => raw_spread(&subset.mean, landmarks, None, &rotation),
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
    let eyes = (
        &subset.scheme.anchors.eye_left[..],
        &subset.scheme.anchors.eye_right[..],
    );
    let (residual, mut misfit) = residual(&subset.mean, landmarks, &rotation, eyes.0, eyes.1);
    if spec.misfit == Misfit::OfRigidFit {
        // Where the rigid fit cannot answer (too few points for it), there is no misfit to
        // check: NaN passes the check.
        // The detector regression ran that fit already, as its reference.
        let visibility = (subset.map == SubsetMap::Own).then_some(&model.visibility);
        let rigid = match rigid {
            Some(r) => Some(r),
            None => fit_rigid(&subset.mean, landmarks, contour, visibility, fit_options)
                .ok()
                .map(|f| f.rotation),
        };
        misfit = rigid.map_or(f64::NAN, |r| {
            self::residual(&subset.mean, landmarks, &r, eyes.0, eyes.1).1
        });
    }
    let angles = EulerAngles::from_rotation(&rotation);
    let spread = spread.map(|s| RawSpread { misfit, ..s });
    Ok(Estimate {
        uncertainty: calibrated(
            model,
            method,
            PointClass::of_scheme(&subset.scheme.name, subset.scheme.len()),
            spread.as_ref(),
            &angles,
        ),
        angles,
        rotation,
        visible,
        residual,
        misfit,
        warnings: vec![],
        spread,
        method,
        translation,
    })
}

/// The calibrated uncertainty of an estimate, when the model has a calibration for it.
fn calibrated(
    model: &PoseModel,
    method: Method,
    points: PointClass,
    spread: Option<&RawSpread>,
    a: &EulerAngles,
) -> Option<Uncertainty> {
    model
        .calibration
        .as_ref()?
        .uncertainty(method, points, spread?, [a.pitch, a.yaw, a.roll])
}

/// Fails unless `landmarks` has `scheme`'s number of points, saying which schemes have the
/// number it has.
fn check_count(model: &PoseModel, scheme: &Scheme, landmarks: &Shape2) -> Result<()> {
    if landmarks.len() == scheme.len() {
        return Ok(());
    }
    Err(Error::PointCount {
        what: format!(
            "landmarks for scheme {}{}",
            scheme.name,
            model.count_hint(landmarks.len())
        ),
        expected: scheme.len(),
        got: landmarks.len(),
    })
}

/// The fit methods' options for a landmark style.
fn fit_options(style: LandmarkStyle) -> FitOptions {
    FitOptions {
        hidden: match style {
            LandmarkStyle::Projected => Hidden::Keep,
            LandmarkStyle::Contour => Hidden::DropContour,
        },
        ..FitOptions::default()
    }
}

/// A MediaPipe face ([`crate::model::mesh`]): the rigid fit fits the mesh; every other method
/// runs on the model's own scheme, each model point the mean of its mesh landmarks. The
/// visibility and the residual are the mesh's.
fn estimate_mesh(
    model: &PoseModel,
    mesh: &FaceMesh,
    ms: &MeshScheme,
    landmarks: &Shape2,
    opts: &EstimateOptions,
) -> Result<Estimate> {
    check_count(model, &ms.scheme, landmarks)?;
    let pose_lm = ms.pose_landmarks(landmarks);
    let a = &ms.scheme.anchors;
    // The rigid fit of the mesh: the answer of `fit`, the reference `detector` de-rolls by,
    // the misfit of the methods measured on it, and what `auto` reads the points by.
    let rigid = || fit_rigid(&ms.points, &pose_lm, &[], None, fit_options(opts.style));
    let mut fitted = None;
    // The rigid fit's misfit, once known.
    let mut rigid_misfit = None;
    let method = match opts.method {
        Method::Auto => {
            let f = rigid()?;
            let misfit = residual(&ms.points, &pose_lm, &f.rotation, &a.eye_left, &a.eye_right).1;
            let detector_can = opts.camera.is_none()
                && landmarks.n_present() == landmarks.len()
                && model.detector(&ms.scheme.name).is_some();
            fitted = Some(f);
            rigid_misfit = Some(misfit);
            Method::Auto.resolve_on_mesh(detector_can.then_some(misfit))
        }
        m => m,
    };
    let spec = method.spec();
    spec.check_camera(opts.camera.as_ref())?;
    // Every method's spread is taken on the model's own points (the mesh landmarks' means),
    // where the calibration was learned: the mesh's 468 points are not 468 independent
    // measurements.
    let proxy = mesh.to_model(&pose_lm, &model.scheme)?;
    let (rotation, translation) = match method {
        Method::Fit => {
            let f = fitted.take().map_or_else(rigid, Ok)?;
            let answer = match &opts.camera {
                Some(k) => {
                    let p = refine_perspective(
                        &ms.points,
                        &pose_lm,
                        &f.weights,
                        k,
                        (f.rotation, f.scale, f.translation),
                    )?;
                    (p.rotation, Some(p.translation))
                }
                None => (f.rotation, None),
            };
            fitted = Some(f);
            answer
        }
        // The regression reads the detector's own points, all of them.
        Method::Detector => {
            let f = fitted.take().map_or_else(rigid, Ok)?;
            let r =
                method::detector_of(model, &ms.scheme.name)?.estimate(landmarks, &f.rotation)?;
            fitted = Some(f);
            (r, None)
        }
        _ => {
            let e = estimate_in_subset(
                model,
                &model.scheme.name,
                &proxy,
                &EstimateOptions { method, ..*opts },
            )?;
            (e.rotation, e.translation)
        }
    };
    let (residual, own_misfit) =
        residual(&ms.points, &pose_lm, &rotation, &a.eye_left, &a.eye_right);
    let mut misfit = own_misfit;
    if spec.misfit == Misfit::OfRigidFit {
        misfit = match rigid_misfit {
            Some(m) => m,
            None => fitted.map_or_else(rigid, Ok).map_or(f64::NAN, |f| {
                self::residual(&ms.points, &pose_lm, &f.rotation, &a.eye_left, &a.eye_right).1
            }),
        };
    }
    // The detector regression's answer departs from the mesh's best fit by design, and how far
    // it departs is what its calibration reads: points it was not trained on (a projection of
    // the mesh itself, fitted exactly) get a wide interval, not the fit's tiny one. The rigid
    // fit's misfit still says whether the points are a face.
    let spread_misfit = if method == Method::Detector {
        own_misfit
    } else {
        misfit
    };
    let spread = raw_spread(&model.mean, &proxy, None, &rotation).map(|s| RawSpread {
        misfit: spread_misfit,
        ..s
    });
    let angles = EulerAngles::from_rotation(&rotation);
    Ok(Estimate {
        uncertainty: calibrated(model, method, PointClass::Dense, spread.as_ref(), &angles),
        angles,
        visible: ms.visible(mesh, &rotation),
        residual,
        misfit,
        warnings: vec![],
        spread,
        rotation,
        method,
        translation,
    })
}

/// The RMS reprojection error at the best scale and translation for a fixed rotation, over the
/// projected distance between the eye centres, and the misfit ([`Estimate::misfit`]), from the
/// moments of the present points (one pass, no allocation): at the best scale `s` the residual
/// energy is `Σ|y - ȳ|² - s Σ (q - q̄)·(y - ȳ)`, `q = (R X)ₓᵧ`.
fn residual(
    mean: &[Vector3<f64>],
    lm: &Shape2,
    r: &Rotation3<f64>,
    eye_l: &[usize],
    eye_r: &[usize],
) -> (f64, f64) {
    let m = Moments::of_landmarks(mean, lm, None);
    if m.n == 0 {
        return (f64::INFINITY, f64::INFINITY);
    }
    let var_y = m.yy;
    // No spread of the rotated points in the image: no scale, the whole spread is residual.
    let (s, sse) = m.best_scale(r).unwrap_or((0.0, var_y));
    let eye = |idx: &[usize]| {
        idx.iter().map(|&i| mean[i]).sum::<Vector3<f64>>() / idx.len().max(1) as f64
    };
    let iod = s.abs() * (r * (eye(eye_r) - eye(eye_l))).xy().norm();
    let residual = if iod > 0.0 {
        (sse / m.n as f64).sqrt() / iod
    } else {
        f64::INFINITY
    };
    let misfit = if var_y > 0.0 {
        (sse / var_y).sqrt()
    } else {
        f64::INFINITY
    };
    (residual, misfit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{WeakPerspective, image_to_plane};
    use nalgebra::Vector2;

    fn face() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(-32.0, 35.0, 0.0),
            Vector3::new(32.0, 35.0, 0.0),
            Vector3::new(0.0, 0.0, 40.0),
            Vector3::new(-25.0, -30.0, 8.0),
            Vector3::new(25.0, -30.0, 8.0),
            Vector3::new(0.0, -70.0, 10.0),
        ]
    }

    #[test]
    fn residual_is_rms_error_over_eye_distance() {
        let r = EulerAngles::new(20.0, -10.0, 5.0).unwrap().to_rotation();
        let cam = WeakPerspective::new(r, 2.0, Vector2::new(300.0, -200.0)).unwrap();
        let exact = Shape2::full(face().iter().map(|x| cam.project(x)).collect()).unwrap();
        assert!(residual(&face(), &exact, &r, &[0], &[1]).0 < 1e-9);
        assert!(residual(&face(), &exact, &r, &[0], &[1]).1 < 1e-9);
        // Move the chin 3 px down: the best scale and shift spread it, so compare with a
        // direct least-squares fit of scale and translation.
        let mut pts: Vec<Vector2<f64>> = exact.points().to_vec();
        pts[5].y += 3.0;
        let moved = Shape2::full(pts.clone()).unwrap();
        let q: Vec<Vector2<f64>> = face().iter().map(|x| (r * x).xy()).collect();
        let y: Vec<Vector2<f64>> = pts.iter().map(image_to_plane).collect();
        let (qm, ym) = (
            q.iter().sum::<Vector2<f64>>() / 6.0,
            y.iter().sum::<Vector2<f64>>() / 6.0,
        );
        let s = q
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - qm).dot(&(b - ym)))
            .sum::<f64>()
            / q.iter().map(|a| (a - qm).norm_squared()).sum::<f64>();
        let rms = (q
            .iter()
            .zip(&y)
            .map(|(a, b)| (s * (a - qm) + ym - b).norm_squared())
            .sum::<f64>()
            / 6.0)
            .sqrt();
        let iod = s * (q[1] - q[0]).norm();
        let (got, misfit) = residual(&face(), &moved, &r, &[0], &[1]);
        assert!((got - rms / iod).abs() < 1e-12, "{got} vs {}", rms / iod);
        let spread = y.iter().map(|b| (b - ym).norm_squared()).sum::<f64>();
        let want = (rms * rms * 6.0 / spread).sqrt();
        assert!((misfit - want).abs() < 1e-12, "{misfit} vs {want}");
        assert!(got > 0.0);
    }
}
