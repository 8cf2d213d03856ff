//! The request option `conventions` and its answers: the names and parameters a client sends,
//! parsed from plain strings (every transport maps its own form onto [`ConventionRequest::parse`]),
//! and [`answer`], which turns a pose into one answer per requested name.

use std::fmt;

use nalgebra::{Rotation3, UnitQuaternion};

use crate::estimate::Intrinsics;
use thiserror::Error;

use super::camera::{
    CameraOrientation, CameraPose, ImageSize, Placement, assumed_camera, check_intrinsics,
    image_size,
};
use super::euler::{Axes, EulerSpec, Kind, Matrices, Order, PRESETS, Units};
use super::peers::{
    MEDIAPIPE_CAMERA, MediaPipeAnswer, MeshFrame, ObjectFrame, OpenCvAnswer, rows3,
};

/// What a client got wrong in the `conventions` option or the camera orientation, or what the
/// answer lacks. Messages say what to fix. All but [`ConventionError::NoPlacement`] and
/// [`ConventionError::NoMesh`] are the client's (HTTP 400, gRPC INVALID_ARGUMENT); those two are
/// 422 / FAILED_PRECONDITION (the model or the method cannot give what was asked).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ConventionError {
    #[error("unknown convention {name:?}; the conventions are {}", ConventionRequest::NAMES.join(", "))]
    /// No convention has this name.
    UnknownName {
        /// The name requested.
        name: String,
    },

    #[error("convention {convention} has no parameter {param:?}; its parameters are {known}")]
    /// The convention has no such parameter.
    UnknownParameter {
        /// The convention's name.
        convention: String,
        /// The parameter given.
        param: String,
        /// The convention's parameters, listed.
        known: String,
    },

    #[error("convention {convention}: {param} {value:?} is not one; expected {expected}")]
    /// A parameter's value is not one it takes.
    BadValue {
        /// The convention's name.
        convention: String,
        /// The parameter's name.
        param: String,
        /// The value given.
        value: String,
        /// What the parameter takes.
        expected: String,
    },

    #[error("convention euler: order {order:?} is not an Euler order: {reason}")]
    /// The Euler order is not three axes of an Euler order.
    BadOrder {
        /// The order given.
        order: String,
        /// Why it is not one.
        reason: String,
    },

    #[error(
        "convention euler: order {order:?} is {case_kind} (upper case intrinsic, lower case \
         extrinsic, as in scipy) but kind is {kind}; write the order as {fixed:?} or drop kind"
    )]
    /// The order's case says one kind and the `kind` parameter another.
    KindConflict {
        /// The order given.
        order: String,
        /// The kind its case says.
        case_kind: &'static str,
        /// The kind parameter.
        kind: &'static str,
        /// The order rewritten for `kind`.
        fixed: String,
    },

    #[error("convention euler needs an order (e.g. \"XYZ\", \"zyx\") or a preset ({presets})")]
    /// `euler` without an order or a preset.
    MissingOrder {
        /// The presets, listed.
        presets: String,
    },

    #[error("convention {0} is requested twice; the answer has one object per name")]
    /// A convention named twice in one request (its name).
    Duplicate(String),

    #[error(
        "convention list item {0:?} is empty or malformed; write name[:param=value...], e.g. euler:order=zyx:units=radians"
    )]
    /// A list item not of the form `name[:param=value...]` (the item).
    Malformed(String),

    #[error("camera intrinsics: {0}")]
    /// The camera intrinsics are invalid (why).
    BadIntrinsics(String),

    #[error("image size must be positive pixels, got {width} x {height}")]
    /// The image size is not positive and finite.
    BadImageSize {
        /// Width given, pixels.
        width: f64,
        /// Height given, pixels.
        height: f64,
    },

    #[error("{0}")]
    /// The rotation is not a proper rotation (why).
    NotARotation(String),

    #[error(
        "convention {0} needs the face's position in a camera: send camera {{fx, fy, cx, cy}} \
         (or, with MediaPipe's normalized landmarks, image_size [width, height], from which \
         a camera is assumed)"
    )]
    /// The convention (named) needs the face's position and the image size or intrinsics.
    NeedsImageSize(&'static str),

    #[error("the estimate has no position for convention {0} (use a fit method)")]
    /// The convention (named) needs a position the estimate lacks.
    NoPlacement(&'static str),

    #[error("convention mediapipe needs the model's MediaPipe face mesh: {0}")]
    /// `mediapipe` with a model without MediaPipe's face mesh (why).
    NoMesh(String),

    #[error("the face's placement: {0}")]
    /// The face's placement is unusable (why).
    BadPlacement(String),
}

impl ConventionError {
    /// Whether the client can fix it by changing the request (400 / INVALID_ARGUMENT), rather
    /// than the model or method lacking something (422 / FAILED_PRECONDITION).
    pub fn is_invalid_argument(&self) -> bool {
        !matches!(
            self,
            ConventionError::NoPlacement(_)
                | ConventionError::NoMesh(_)
                | ConventionError::BadPlacement(_)
        )
    }
}

/// One requested convention with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ConventionRequest {
    /// The rotation as a unit quaternion (Hamilton, w ≥ 0).
    Quaternion,
    /// Euler angles in a named convention.
    Euler(EulerSpec),
    /// OpenCV's `rvec`, `tvec`.
    OpenCv(ObjectFrame),
    /// MediaPipe's facial transformation matrix.
    MediaPipe,
}

const EULER_PARAMS: &str = "preset, order, kind, units, axes, matrices";

impl ConventionRequest {
    /// Every name, in the order of the docs.
    pub const NAMES: [&'static str; 4] = ["quaternion", "euler", "opencv", "mediapipe"];

    /// The name on every interface (the answer's key).
    pub fn name(&self) -> &'static str {
        match self {
            ConventionRequest::Quaternion => "quaternion",
            ConventionRequest::Euler(_) => "euler",
            ConventionRequest::OpenCv(_) => "opencv",
            ConventionRequest::MediaPipe => "mediapipe",
        }
    }

    /// A convention from its name and `(parameter, value)` pairs (JSON object members, gRPC
    /// fields, CLI `name:param=value`). Names and values are case-sensitive except the Euler
    /// order, whose case is its kind.
    ///
    /// - `quaternion`, `mediapipe`: no parameters.
    /// - `euler`: `preset` (`pose-para` = `6drepnet` = `hopenet`, `openface`, `three`, `unity`)
    ///   and/or `order` (three letters of `xyz`, upper case intrinsic, lower case extrinsic),
    ///   `kind` (`intrinsic`/`extrinsic`, only to confirm the case or turn a preset's order),
    ///   `units` (`degrees`/`radians`), `axes` (`RUB`, `RDF`, `RUF`, ... or `facepose`,
    ///   `opengl`, `three`, `opencv`, `unity`), `matrices` (`standard`/`pose-para`); given
    ///   parameters override the preset's, and without a preset the defaults are degrees,
    ///   `RUB`, `standard`.
    /// - `opencv`: `object_frame` (`opencv`, the default, or `model`).
    pub fn parse(name: &str, params: &[(&str, &str)]) -> Result<Self, ConventionError> {
        let unknown =
            |convention: &str, param: &str, known: &str| ConventionError::UnknownParameter {
                convention: convention.into(),
                param: param.into(),
                known: known.into(),
            };
        match name {
            "quaternion" | "mediapipe" => {
                if let Some((p, _)) = params.first() {
                    return Err(unknown(name, p, "none"));
                }
                Ok(if name == "quaternion" {
                    ConventionRequest::Quaternion
                } else {
                    ConventionRequest::MediaPipe
                })
            }
            "opencv" => {
                let mut frame = ObjectFrame::default();
                for (p, v) in params {
                    match *p {
                        "object_frame" => {
                            frame = match *v {
                                "opencv" => ObjectFrame::OpenCv,
                                "model" => ObjectFrame::Model,
                                _ => {
                                    return Err(ConventionError::BadValue {
                                        convention: "opencv".into(),
                                        param: "object_frame".into(),
                                        value: v.to_string(),
                                        expected: "opencv (the model's points in OpenCV's axes, \
                                                   a frontal face is rvec 0) or model (facepose's \
                                                   model frame, y up)"
                                            .into(),
                                    });
                                }
                            }
                        }
                        _ => return Err(unknown("opencv", p, "object_frame")),
                    }
                }
                Ok(ConventionRequest::OpenCv(frame))
            }
            "euler" => parse_euler(params).map(ConventionRequest::Euler),
            _ => Err(ConventionError::UnknownName { name: name.into() }),
        }
    }

    /// A comma-separated list as the CLI takes it: `quaternion,euler:order=zyx:units=radians,
    /// opencv:object_frame=model,mediapipe`. Fails on a repeated name.
    pub fn parse_list(spec: &str) -> Result<Vec<Self>, ConventionError> {
        let mut out: Vec<ConventionRequest> = Vec::new();
        for item in spec.split(',').map(str::trim) {
            let mut parts = item.split(':');
            let name = parts.next().unwrap_or_default().trim();
            if name.is_empty() {
                return Err(ConventionError::Malformed(item.into()));
            }
            let mut params = Vec::new();
            for p in parts {
                let (k, v) = p
                    .split_once('=')
                    .ok_or_else(|| ConventionError::Malformed(item.into()))?;
                params.push((k.trim(), v.trim()));
            }
            out.push(ConventionRequest::parse(name, &params)?);
        }
        check_unique(&out)?;
        Ok(out)
    }
}

impl EulerSpec {
    /// An Euler convention from `(parameter, value)` pairs, as `euler` takes them
    /// ([`ConventionRequest::parse`]): for a camera orientation given as angles.
    pub fn from_params(params: &[(&str, &str)]) -> Result<EulerSpec, ConventionError> {
        parse_euler(params)
    }
}

/// Fails when a name is requested twice.
pub fn check_unique(requests: &[ConventionRequest]) -> Result<(), ConventionError> {
    for (k, r) in requests.iter().enumerate() {
        if requests[..k].iter().any(|o| o.name() == r.name()) {
            return Err(ConventionError::Duplicate(r.name().into()));
        }
    }
    Ok(())
}

fn bad_value(param: &str, value: &str, expected: &str) -> ConventionError {
    ConventionError::BadValue {
        convention: "euler".into(),
        param: param.into(),
        value: value.into(),
        expected: expected.into(),
    }
}

fn preset_names() -> String {
    PRESETS.map(|(n, _)| n).join(", ")
}

fn parse_euler(params: &[(&str, &str)]) -> Result<EulerSpec, ConventionError> {
    let get = |name: &str| params.iter().find(|(p, _)| *p == name).map(|(_, v)| *v);
    if let Some((p, _)) = params
        .iter()
        .find(|(p, _)| !EULER_PARAMS.split(", ").any(|k| k == *p))
    {
        return Err(ConventionError::UnknownParameter {
            convention: "euler".into(),
            param: p.to_string(),
            known: EULER_PARAMS.into(),
        });
    }
    let mut spec = match get("preset") {
        Some(p) => PRESETS
            .iter()
            .find(|(n, _)| *n == p)
            .map(|(_, s)| *s)
            .ok_or_else(|| bad_value("preset", p, &preset_names()))?,
        None => {
            if get("order").is_none() {
                return Err(ConventionError::MissingOrder {
                    presets: preset_names(),
                });
            }
            EulerSpec {
                matrices: Matrices::Standard,
                ..EulerSpec::THREE
            }
        }
    };
    if get("preset").is_none() {
        spec.units = Units::Degrees;
    }
    let kind = match get("kind") {
        None => None,
        Some("intrinsic") => Some(Kind::Intrinsic),
        Some("extrinsic") => Some(Kind::Extrinsic),
        Some(v) => return Err(bad_value("kind", v, "intrinsic or extrinsic")),
    };
    match get("order") {
        Some(o) => {
            let (order, case_kind) = Order::parse(o)?;
            if let Some(k) = kind
                && k != case_kind
            {
                return Err(ConventionError::KindConflict {
                    order: o.into(),
                    case_kind: case_kind.name(),
                    kind: k.name(),
                    fixed: order.written(k),
                });
            }
            spec.order = order;
            spec.kind = case_kind;
        }
        None => {
            if let Some(k) = kind {
                spec.kind = k;
            }
        }
    }
    if let Some(u) = get("units") {
        spec.units = u
            .parse()
            .map_err(|_| bad_value("units", u, "degrees or radians"))?;
    }
    if let Some(a) = get("axes") {
        spec.axes = Axes::parse(a)?;
    }
    if let Some(m) = get("matrices") {
        spec.matrices = match m {
            "standard" => Matrices::Standard,
            "pose-para" => Matrices::PosePara,
            _ => {
                return Err(bad_value(
                    "matrices",
                    m,
                    "standard (Rx = [[1,0,0],[0,c,-s],[0,s,c]]: scipy, three.js, Unity, OpenCV) \
                     or pose-para (the transposes, as 300W-LP's Pose_Para)",
                ));
            }
        };
    }
    Ok(spec)
}

/// A perspective pose of the request's landmarks under a given camera: facepose's perspective
/// refinement run again with those intrinsics (`estimate_with` with `camera`), `None` when it
/// cannot answer.
pub type Refit<'a> = &'a dyn Fn(&Intrinsics) -> Option<CameraPose>;

/// What the conventions are computed from.
#[derive(Clone, Copy)]
pub struct PoseInput<'a> {
    /// The estimate's rotation (model frame to camera frame).
    pub rotation: Rotation3<f64>,
    /// Where the face is: the perspective pose when the request had intrinsics, else the
    /// weak-perspective fit's scale and translation. `opencv` and `mediapipe` need it.
    pub placement: Option<Placement>,
    /// The image's size: for the assumed camera of `opencv` without intrinsics and for
    /// MediaPipe's virtual camera.
    pub image_size: Option<ImageSize>,
    /// The camera's orientation in the world: every answer then refers to the world.
    pub orientation: Option<CameraOrientation>,
    /// The model's MediaPipe mesh frame, for `mediapipe`.
    pub mesh: Option<&'a MeshFrame>,
    /// For `opencv` without intrinsics (the assumed camera) and `mediapipe` (its virtual
    /// camera), whose camera is not the one the estimate was made in: the pose refitted under
    /// that camera. Without it, the estimate's pose is carried over through its view
    /// ([`Placement::in_camera`]), a first-order answer (within 1-3° of the refitted one on the
    /// conventions' fixtures); with it, `cv2.solvePnP`'s and MediaPipe's answers on synthetic
    /// faces to 1e-4°. Costs one perspective refinement per such convention.
    pub refit: Option<Refit<'a>>,
}

impl PoseInput<'_> {
    /// The pose in the camera `k`: the estimate's own when it was made in `k`, else the refit,
    /// else carried over.
    fn pose_in(&self, placement: &Placement, k: &Intrinsics) -> CameraPose {
        if let Placement::Perspective { camera, .. } = placement
            && camera == k
        {
            return placement.in_camera(&self.rotation, k);
        }
        self.refit
            .and_then(|f| f(k))
            .filter(|p| p.translation.iter().all(|v| v.is_finite()) && p.translation.z < 0.0)
            .unwrap_or_else(|| placement.in_camera(&self.rotation, k))
    }
}

/// A unit quaternion, Hamilton, `w ≥ 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuaternionAnswer {
    /// Scalar part, `w ≥ 0`.
    pub w: f64,
    /// Vector part, x.
    pub x: f64,
    /// Vector part, y.
    pub y: f64,
    /// Vector part, z.
    pub z: f64,
}

/// Euler angles and what they mean.
#[derive(Debug, Clone, PartialEq)]
pub struct EulerAnswer {
    /// In the order's letters, in `units`.
    pub angles: [f64; 3],
    /// As written back: upper case intrinsic, lower case extrinsic.
    pub order: String,
    /// `intrinsic` or `extrinsic`.
    pub kind: &'static str,
    /// `degrees` or `radians`.
    pub units: &'static str,
    /// Three letters (`RUB`, ...).
    pub axes: String,
    /// `standard` or `pose-para`.
    pub matrices: &'static str,
    /// The matrix the angles rebuild, in `axes`, row-major.
    pub matrix: [[f64; 3]; 3],
    /// Within 1° of gimbal lock: the first and third angles are ill-conditioned there.
    pub near_gimbal_lock: bool,
}

/// One answer.
#[derive(Debug, Clone, PartialEq)]
pub enum ConventionAnswer {
    /// A unit quaternion.
    Quaternion(QuaternionAnswer),
    /// Euler angles in the requested convention.
    Euler(EulerAnswer),
    /// OpenCV's `rvec`, `tvec` and camera matrix.
    OpenCv(OpenCvAnswer),
    /// MediaPipe's facial transformation matrix.
    MediaPipe(MediaPipeAnswer),
}

impl ConventionAnswer {
    /// The answer's key: the convention's name.
    pub fn name(&self) -> &'static str {
        match self {
            ConventionAnswer::Quaternion(_) => "quaternion",
            ConventionAnswer::Euler(_) => "euler",
            ConventionAnswer::OpenCv(_) => "opencv",
            ConventionAnswer::MediaPipe(_) => "mediapipe",
        }
    }
}

/// Something the caller should know about the answers.
#[derive(Debug, Clone, PartialEq)]
pub enum ConventionWarning {
    /// `opencv` without intrinsics: the camera was assumed.
    AssumedCamera {
        /// Focal length assumed, pixels (both axes).
        fx: f64,
        /// Principal point x assumed, pixels.
        cx: f64,
        /// Principal point y assumed, pixels (y down).
        cy: f64,
    },
    /// `mediapipe` without the image size: taken from the intrinsics' principal point.
    ImageSizeFromPrincipalPoint {
        /// Width taken, pixels.
        width: f64,
        /// Height taken, pixels.
        height: f64,
    },
    /// Euler angles within 1° of gimbal lock.
    NearGimbalLock {
        /// The middle angle, in `units`.
        middle: f64,
        /// `degrees` or `radians`.
        units: &'static str,
    },
}

impl fmt::Display for ConventionWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConventionWarning::AssumedCamera { fx, cx, cy } => write!(
                f,
                "opencv: no camera intrinsics were sent, so rvec and tvec assume fx = fy = \
                 {fx} (the image width), cx = {cx}, cy = {cy}; tvec's depth scales with that \
                 guess; send camera {{fx, fy, cx, cy}} for a true position"
            ),
            ConventionWarning::ImageSizeFromPrincipalPoint { width, height } => write!(
                f,
                "mediapipe: no image size was sent; MediaPipe's virtual camera was set on a \
                 {width} x {height} image (twice the principal point); send image_size"
            ),
            ConventionWarning::NearGimbalLock { middle, units } => write!(
                f,
                "euler: the middle angle ({middle:.3} {units}) is within 1 degree of gimbal \
                 lock, where the first and third angles are ill-conditioned; the matrix and \
                 the quaternion are not"
            ),
        }
    }
}

/// The answers to a request's conventions, in the request's order, and the warnings.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ConventionAnswers {
    /// One answer per requested convention, in the request's order.
    pub answers: Vec<ConventionAnswer>,
    /// What the caller should know about the answers.
    pub warnings: Vec<ConventionWarning>,
}

/// The answers of `requests` for a pose. An empty list costs nothing.
pub fn answer(
    requests: &[ConventionRequest],
    input: &PoseInput<'_>,
) -> Result<ConventionAnswers, ConventionError> {
    let mut out = ConventionAnswers::default();
    if requests.is_empty() {
        return Ok(out);
    }
    check_unique(requests)?;
    let world = input
        .orientation
        .unwrap_or_else(CameraOrientation::identity);
    let r_world = world.rotation() * input.rotation;
    for req in requests {
        let a = match req {
            ConventionRequest::Quaternion => ConventionAnswer::Quaternion(quaternion(&r_world)),
            ConventionRequest::Euler(spec) => {
                let e = euler(spec, &r_world);
                if e.near_gimbal_lock {
                    out.warnings.push(ConventionWarning::NearGimbalLock {
                        middle: e.angles[1],
                        units: spec.units.name(),
                    });
                }
                ConventionAnswer::Euler(e)
            }
            ConventionRequest::OpenCv(frame) => {
                let placement = input
                    .placement
                    .ok_or(ConventionError::NoPlacement("opencv"))?;
                placement.validate()?;
                let (k, assumed) = match placement {
                    Placement::Perspective { camera, .. } => (camera, false),
                    Placement::Weak { .. } => {
                        let size = input
                            .image_size
                            .ok_or(ConventionError::NeedsImageSize("opencv"))?;
                        let k = assumed_camera(size);
                        out.warnings.push(ConventionWarning::AssumedCamera {
                            fx: k.fx,
                            cx: k.cx,
                            cy: k.cy,
                        });
                        (k, true)
                    }
                };
                check_intrinsics(&k)?;
                let pose = world.apply(&input.pose_in(&placement, &k));
                ConventionAnswer::OpenCv(OpenCvAnswer::new(&pose, &k, assumed, *frame))
            }
            ConventionRequest::MediaPipe => {
                let placement = input
                    .placement
                    .ok_or(ConventionError::NoPlacement("mediapipe"))?;
                placement.validate()?;
                let mesh = input.mesh.ok_or_else(|| {
                    ConventionError::NoMesh("this model serves no MediaPipe mesh".into())
                })?;
                let size = match (input.image_size, placement) {
                    (Some(s), _) => s,
                    (None, Placement::Perspective { camera, .. }) => {
                        let s = image_size(2.0 * camera.cx, 2.0 * camera.cy)?;
                        out.warnings
                            .push(ConventionWarning::ImageSizeFromPrincipalPoint {
                                width: s.width,
                                height: s.height,
                            });
                        s
                    }
                    (None, Placement::Weak { .. }) => {
                        return Err(ConventionError::NeedsImageSize("mediapipe"));
                    }
                };
                let k = MEDIAPIPE_CAMERA.intrinsics(size.width, size.height);
                let pose = world.apply(&input.pose_in(&placement, &k));
                ConventionAnswer::MediaPipe(MediaPipeAnswer::new(&pose, mesh))
            }
        };
        out.answers.push(a);
    }
    Ok(out)
}

/// The quaternion of a rotation, `w ≥ 0` (at `w = 0`, the first non-zero of x, y, z positive).
pub fn quaternion(r: &Rotation3<f64>) -> QuaternionAnswer {
    let q = UnitQuaternion::from_rotation_matrix(r);
    let (mut w, mut x, mut y, mut z) = (q.w, q.i, q.j, q.k);
    let flip = w < 0.0
        || (w == 0.0
            && [x, y, z]
                .iter()
                .find(|c| **c != 0.0)
                .is_some_and(|c| *c < 0.0));
    if flip {
        (w, x, y, z) = (-w, -x, -y, -z);
    }
    QuaternionAnswer {
        w: w + 0.0,
        x: x + 0.0,
        y: y + 0.0,
        z: z + 0.0,
    }
}

/// The Euler answer of a rotation (facepose's axes).
pub fn euler(spec: &EulerSpec, r: &Rotation3<f64>) -> EulerAnswer {
    let angles = spec.angles(r.matrix());
    let middle = match spec.units {
        Units::Degrees => angles[1].to_radians(),
        Units::Radians => angles[1],
    };
    let lock_distance = if spec.order.is_tait_bryan() {
        middle.cos().abs()
    } else {
        middle.sin().abs()
    };
    EulerAnswer {
        angles,
        order: spec.order.written(spec.kind),
        kind: spec.kind.name(),
        units: spec.units.name(),
        axes: spec.axes.letters(),
        matrices: spec.matrices.name(),
        matrix: rows3(&spec.matrix_in_axes(angles)),
        near_gimbal_lock: lock_distance < 1f64.to_radians().sin(),
    }
}
