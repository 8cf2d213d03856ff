"""facepose: head pose (yaw, pitch, roll, rotation) from 2D facial landmarks.

The numeric core of the facepose service, in process, with numpy in and out::

    import facepose
    pose = facepose.estimate(landmarks)          # (N, 2) pixels: one Pose
    batch = facepose.estimate(stack)             # (B, N, 2) or a list: a PoseBatch
    print(pose.yaw, pose.pitch, pose.roll, pose.rotation)

Conventions are the service's (docs/API.md): landmarks are image pixels (x right, y down) in
a scheme's order, a row of NaN is a missing point; angles are degrees in the 300W-LP /
AFLW2000-3D ``Pose_Para`` convention (pitch > 0 chin up, yaw > 0 the nose turns towards
image-left, roll > 0 clockwise on screen) and ``rotation`` is ``R = Rx(pitch) Ry(yaw) Rz(roll)``.
Errors are :class:`FaceposeError` (a ``ValueError``) with the messages of the service's 422
answers.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _facepose
from ._facepose import (
    ConventionError,
    DegenerateError,
    FaceposeError,
    InvalidParameterError,
    InvalidSchemeError,
    Model,
    ModelError,
    NonFiniteError,
    NotAFaceError,
    NumericalError,
    PointCountError,
    TooFewPointsError,
)

__all__ = [
    "AngleUncertainty",
    "ConventionError",
    "DegenerateError",
    "FaceposeError",
    "InvalidParameterError",
    "InvalidSchemeError",
    "Model",
    "ModelError",
    "NonFiniteError",
    "NotAFaceError",
    "NumericalError",
    "PointCountError",
    "Pose",
    "PoseBatch",
    "TooFewPointsError",
    "Tracker",
    "Uncertainty",
    "default_model",
    "estimate",
    "train",
]

__version__ = "0.1.0"


@dataclass(frozen=True)
class AngleUncertainty:
    """How far to trust one angle, degrees: a standard deviation and the 90% interval
    ``(low, high)`` that holds the true angle for 90% of real faces."""

    sd: float
    interval90: Tuple[float, float]


@dataclass(frozen=True)
class Uncertainty:
    """Per angle, how far to trust it (calibrated on real faces; docs/API.md)."""

    yaw: AngleUncertainty
    pitch: AngleUncertainty
    roll: AngleUncertainty


def _make(cls: Any, fields: Dict[str, Any]) -> Any:
    """An instance of a frozen dataclass from every one of its fields, without the generated
    __init__ (which sets each field through object.__setattr__: most of a single face's cost
    in Python)."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


def _uncertainty(u: Any) -> Optional[Uncertainty]:
    if u is None:
        return None
    sd, iv = u
    a = [_make(AngleUncertainty, {"sd": sd[k], "interval90": iv[k]}) for k in range(3)]
    return _make(Uncertainty, {"yaw": a[0], "pitch": a[1], "roll": a[2]})


@dataclass(frozen=True)
class Pose:
    """One face's pose: the fields of the service's answer.

    Attributes:
        yaw, pitch, roll: degrees (``Pose_Para`` convention).
        rotation: (3, 3) float64, ``R = Rx(pitch) Ry(yaw) Rz(roll)``, row-major.
        visible: (N,) bool, per input landmark: visible at the estimated pose.
        residual: RMS reprojection error over the present landmarks divided by the projected
            inter-ocular distance (unitless; a good fit is below ~0.05).
        method: the method that produced it (never ``auto``).
        warnings: what to know about this answer (empty when all is well).
        uncertainty: per angle sd and 90% interval, or None (a model without calibration).
        translation: (3,) float64, with a camera only: the model origin in the camera frame,
            mm (x right, y up, z towards the viewer: a face in front has z < 0).
        scheme: the landmark scheme the face was estimated in.
        model, model_version: the model that answered.
        conventions: the answers in the conventions asked for (``conventions=``), as the
            service's ``conventions`` object (docs/API.md, "Answers in your convention"), or
            None.
        turn_cov: (3, 3) covariance of the rotation's small turn, radians², or None: what
            the Kalman tracker weighs the frame by (the calibrated one, divided by the
            method's filter trust: 4 for ``detector``, 1 otherwise; as the stream does).
        smoothed, gated: set by :class:`Tracker`: the angles and rotation are the filter's;
            the Kalman filter left this frame out as an outlier (the pose is its prediction).
    """

    yaw: float
    pitch: float
    roll: float
    rotation: np.ndarray
    visible: np.ndarray = dataclasses.field(repr=False)
    residual: float
    method: str
    warnings: List[str]
    uncertainty: Optional[Uncertainty]
    translation: Optional[np.ndarray]
    scheme: str
    model: str
    model_version: str
    turn_cov: Optional[np.ndarray] = dataclasses.field(default=None, repr=False)
    conventions: Optional[Dict[str, Any]] = None
    smoothed: bool = False
    gated: bool = False

    @property
    def angles(self) -> np.ndarray:
        """(yaw, pitch, roll) in degrees, as a (3,) array."""
        return np.array([self.yaw, self.pitch, self.roll])

    def to_dict(self) -> Dict[str, Any]:
        """The service's JSON answer to ``POST /v1/pose`` for this face (plain Python types)."""
        d: Dict[str, Any] = {
            "yaw": self.yaw,
            "pitch": self.pitch,
            "roll": self.roll,
            "rotation": self.rotation.tolist(),
            "visible": self.visible.tolist(),
            "residual": self.residual,
            "method": self.method,
        }
        if self.translation is not None:
            d["translation"] = self.translation.tolist()
        d["warnings"] = list(self.warnings)
        if self.uncertainty is not None:
            d["uncertainty"] = {
                k: {"sd": a.sd, "interval90": list(a.interval90)}
                for k, a in (
                    ("yaw", self.uncertainty.yaw),
                    ("pitch", self.uncertainty.pitch),
                    ("roll", self.uncertainty.roll),
                )
            }
        if self.conventions is not None:
            d["conventions"] = self.conventions
        d["scheme"] = self.scheme
        d["model"] = self.model
        d["model_version"] = self.model_version
        return d


def _pose(d: Dict[str, Any]) -> Pose:
    """A Pose from the extension's dict (every field but the tracker's flags)."""
    d["uncertainty"] = _uncertainty(d["uncertainty"])
    c = d["conventions"]
    d["conventions"] = None if c is None else json.loads(c)
    d["smoothed"] = False
    d["gated"] = False
    return _make(Pose, d)


@dataclass(frozen=True)
class PoseBatch:
    """The poses of a batch, as columns (one row per face, in input order).

    A face that failed has NaN in the arrays, ``""`` as its method and scheme, and its
    exception in ``errors`` (None for the faces that succeeded); ``ok`` is the mask of the
    faces that succeeded. ``batch[i]`` is face i's :class:`Pose` (or raises its error);
    iterating gives every face's Pose (None for the failed ones).

    Attributes:
        yaw, pitch, roll: (B,) degrees.
        rotation: (B, 3, 3).
        visible: (B, N) bool when every face has N points, else a list of (N_i,) arrays.
        residual: (B,).
        method, scheme: list of B strings.
        warnings: list of B tuples of strings (empty when all is well).
        sd: (B, 3) standard deviations of yaw, pitch, roll (NaN without calibration).
        interval90: (B, 3, 2) 90% intervals of yaw, pitch, roll.
        translation: (B, 3) with a camera, else None.
        turn_cov: (B, 3, 3) covariances for the Kalman tracker (NaN without calibration).
        errors: list of B exceptions or None.
        conventions: list of B JSON texts of the conventions' answers (None without
            ``conventions=``); ``batch[i].conventions`` is face i's as a dict.
        model, model_version: the model that answered.
    """

    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    rotation: np.ndarray
    visible: Union[np.ndarray, List[np.ndarray]]
    residual: np.ndarray
    method: List[str]
    scheme: List[str]
    warnings: List[Tuple[str, ...]]
    sd: np.ndarray
    interval90: np.ndarray
    translation: Optional[np.ndarray]
    turn_cov: np.ndarray = dataclasses.field(repr=False)
    errors: List[Optional[FaceposeError]] = dataclasses.field(repr=False)
    conventions: List[Optional[str]] = dataclasses.field(default_factory=list, repr=False)
    model: str = ""
    model_version: str = ""

    @property
    def ok(self) -> np.ndarray:
        """(B,) bool: the faces that were estimated."""
        return np.array([e is None for e in self.errors], dtype=bool)

    @property
    def angles(self) -> np.ndarray:
        """(B, 3): yaw, pitch, roll in degrees."""
        return np.stack([self.yaw, self.pitch, self.roll], axis=1)

    def __len__(self) -> int:
        return len(self.errors)

    def __getitem__(self, i: int) -> Pose:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"face {i} of a batch of {n}")
        i %= n
        err = self.errors[i]
        if err is not None:
            raise err
        has_u = not math.isnan(self.sd[i, 0])
        unc = None
        if has_u:
            unc = Uncertainty(
                *(
                    AngleUncertainty(
                        float(self.sd[i, k]),
                        (float(self.interval90[i, k, 0]), float(self.interval90[i, k, 1])),
                    )
                    for k in range(3)
                )
            )
        return Pose(
            yaw=float(self.yaw[i]),
            pitch=float(self.pitch[i]),
            roll=float(self.roll[i]),
            rotation=self.rotation[i].copy(),
            visible=np.array(self.visible[i], dtype=bool),
            residual=float(self.residual[i]),
            method=self.method[i],
            warnings=list(self.warnings[i]),
            uncertainty=unc,
            translation=None if self.translation is None else self.translation[i].copy(),
            scheme=self.scheme[i],
            model=self.model,
            model_version=self.model_version,
            turn_cov=self.turn_cov[i].copy() if has_u else None,
            conventions=None if self.conventions[i] is None else json.loads(self.conventions[i]),
        )

    def __iter__(self) -> Iterator[Optional[Pose]]:
        for i in range(len(self)):
            yield None if self.errors[i] is not None else self[i]

    def poses(self) -> List[Optional[Pose]]:
        """Every face's Pose, None for the failed ones."""
        return list(self)


def _batch(d: Dict[str, Any]) -> PoseBatch:
    a = d.pop("angles")
    return PoseBatch(yaw=a[:, 0].copy(), pitch=a[:, 1].copy(), roll=a[:, 2].copy(), **d)


_DEFAULT: Optional[Model] = None


def default_model() -> Model:
    """The embedded default model (ibug68 and its subsets, MediaPipe's meshes, calibrated)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Model.default()
    return _DEFAULT


def _camera(camera: Any) -> Optional[Tuple[float, float, float, float]]:
    if camera is None:
        return None
    if isinstance(camera, Mapping):
        keys = {"fx", "fy", "cx", "cy"}
        if set(camera) != keys:
            raise InvalidParameterError(
                f"invalid parameter camera: expected the keys fx, fy, cx, cy, got {sorted(camera)}"
            )
        return tuple(float(camera[k]) for k in ("fx", "fy", "cx", "cy"))  # type: ignore[return-value]
    a = np.asarray(camera, dtype=np.float64)
    if a.shape == (4,):
        return tuple(float(v) for v in a)  # type: ignore[return-value]
    if a.shape == (3, 3):
        # An OpenCV camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]].
        if a[0, 1] != 0 or a[1, 0] != 0 or a[2, 0] != 0 or a[2, 1] != 0 or a[2, 2] != 1:
            raise InvalidParameterError(
                "invalid parameter camera: a 3 x 3 camera matrix must be "
                "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)"
            )
        return (float(a[0, 0]), float(a[1, 1]), float(a[0, 2]), float(a[1, 2]))
    raise InvalidParameterError(
        "invalid parameter camera: give (fx, fy, cx, cy), a dict with those keys, or a "
        f"3 x 3 camera matrix; got an array of shape {a.shape}"
    )


def _pair(v: Any, what: str) -> Optional[Tuple[float, float]]:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (2,):
        raise InvalidParameterError(
            f"invalid parameter {what}: expected [width, height], got shape {a.shape}"
        )
    return (float(a[0]), float(a[1]))


def _name(v: Any, what: str) -> Optional[str]:
    if v is None or isinstance(v, str):
        return v
    raise TypeError(f"{what} must be a string or None, got {type(v).__name__}")


def _conventions(c: Any) -> Optional[str]:
    if c is None or isinstance(c, str):
        return c
    if isinstance(c, (list, tuple)) and all(isinstance(x, str) for x in c):
        return ",".join(c)
    raise TypeError(f"conventions must be a string or a list of strings, got {type(c).__name__}")


def _as_float(a: Any, what: str) -> np.ndarray:
    """`a` as a float64 array (strided views are read as they are); refuses what is not real
    numbers."""
    if type(a) is np.ndarray and a.dtype == np.float64:
        return a
    arr = np.asarray(a)
    if arr.dtype.kind not in "fiu":
        raise TypeError(
            f"{what} must be real numbers (a float or integer array), got dtype {arr.dtype}"
        )
    return np.asarray(arr, dtype=np.float64)


def estimate(
    landmarks: Any,
    scheme: Optional[str] = None,
    method: str = "auto",
    camera: Any = None,
    *,
    landmark_style: str = "projected",
    image_size: Any = None,
    conventions: Union[None, str, Sequence[str]] = None,
    model: Optional[Model] = None,
    errors: str = "raise",
    threads: Optional[int] = None,
) -> Union[Pose, PoseBatch]:
    """Estimates head pose from 2D landmarks.

    Args:
        landmarks: one face, an (N, 2) array of x, y image pixels (a row of NaN for a missing
            point); or a batch, a (B, N, 2) array or a list of (N_i, 2) arrays.
        scheme: the landmark scheme (``ibug68``, ``inner51``, ``five``, ``dlib5``,
            ``mediapipe468``, ``mediapipe478``, or a trained model's own). None: chosen by the
            number of points where only one scheme has that many (five points must be named).
        method: ``auto`` (the most accurate for the input), ``fit``, ``fit-shape``,
            ``regression`` or ``geometry``.
        camera: pinhole intrinsics, as (fx, fy, cx, cy), a dict with those keys, or a 3 x 3
            camera matrix (pixels): the fit methods then refine the pose under full
            perspective and the answer has a ``translation``.
        landmark_style: ``projected`` (3D-style landmarks: hidden points where they project)
            or ``contour`` (2D-style, as dlib: hidden jaw points on the visible outline).
        image_size: (width, height) in pixels when the landmarks are normalized coordinates
            (MediaPipe's x, y); they are scaled to pixels.
        conventions: answers in other conventions besides facepose's own, as the CLI's
            ``--conventions`` takes them: ``"quaternion,euler:preset=openface"`` or a list of
            such items (``quaternion``, ``euler[:order=..:units=..:preset=..]``, ``opencv``,
            ``mediapipe``; docs/API.md, "Answers in your convention"). The answers are in
            ``Pose.conventions``.
        model: the model (default: the embedded default model).
        errors: for a batch, ``raise`` (the first failed face raises, its message prefixed by
            ``faces[i]:``) or ``keep`` (failed faces are marked in the batch).
        threads: for a batch, the threads to use (default: every core the process may use).

    Returns:
        A :class:`Pose` for one face, a :class:`PoseBatch` for a batch.

    Raises:
        FaceposeError: (a ValueError) with the service's message for the same input.
        TypeError: landmarks that are not real numbers.
    """
    m = model if model is not None else (_DEFAULT or default_model())
    if not isinstance(m, Model):
        raise TypeError(f"model must be a facepose.Model, got {type(m).__name__}")
    if errors not in ("raise", "keep"):
        raise ValueError(f'errors must be "raise" or "keep", got {errors!r}')
    if threads is not None and (not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    kw = dict(
        scheme=_name(scheme, "scheme"),
        method=_name(method, "method"),
        landmark_style=_name(landmark_style, "landmark_style"),
        camera=_camera(camera),
        image_size=_pair(image_size, "image_size"),
        conventions=_conventions(conventions),
    )
    if isinstance(landmarks, (list, tuple)) and landmarks and _is_face_list(landmarks):
        faces = [_as_float(f, f"faces[{i}]") for i, f in enumerate(landmarks)]
        for i, f in enumerate(faces):
            if f.ndim != 2:
                raise InvalidParameterError(
                    f"faces[{i}]: landmarks must be an (N, 2) array of x, y pixels, "
                    f"got shape {f.shape}"
                )
        out = _batch(m._estimate_list(faces, threads=threads, **kw))
    else:
        a = _as_float(landmarks, "landmarks")
        if a.ndim == 2:
            return _pose(m._estimate_one(a, **kw))
        if a.ndim != 3:
            raise InvalidParameterError(
                "landmarks must be an (N, 2) array (one face) or a (B, N, 2) array (a batch), "
                f"got shape {a.shape}"
            )
        out = _batch(m._estimate_array(a, threads=threads, **kw))
    if errors == "raise":
        for i, e in enumerate(out.errors):
            if e is not None:
                raise type(e)(f"faces[{i}]: {e}") from e
    return out


def _is_face_list(x: Sequence[Any]) -> bool:
    """Whether a list is a batch of faces (its items are 2D) rather than one face's points."""
    first = x[0]
    if isinstance(first, np.ndarray):
        return first.ndim == 2
    return isinstance(first, (list, tuple)) and len(first) > 0 and isinstance(
        first[0], (list, tuple, np.ndarray)
    )


class Tracker:
    """Smooths poses over time, frame by frame, one filter state per track (face).

    ``kind`` is ``kalman`` (default: weighs each frame by its uncertainty, leaves wild frames
    out; parameters ``acceleration_deg_s2=150``, ``gate=16.27``, ``max_rejected=5``,
    ``default_sd_deg=3``) or ``one-euro`` (``min_cutoff_hz=1``, ``beta=0.05``,
    ``d_cutoff_hz=1``). A track's time step is the time since its own last update (1/30 s
    without timestamps); a track unseen for more than ``max_gap`` seconds starts again.

    Example::

        tracker = facepose.Tracker("kalman")
        for t, landmarks in frames:
            pose = tracker.update(facepose.estimate(landmarks), timestamp=t)
    """

    def __init__(self, kind: str = "kalman", *, max_gap: float = 1.0, **params: float) -> None:
        self._t = _facepose._Tracker(kind, params, float(max_gap))

    @property
    def kind(self) -> str:
        return self._t.kind

    def update(self, pose: Pose, timestamp: Optional[float] = None, track: Any = 0) -> Pose:
        """The smoothed pose of ``track`` for this frame's ``pose`` taken at ``timestamp``
        (seconds; None: one frame of 1/30 s after the track's last). The angles and rotation
        are the filter's; the rest is the frame's own estimate."""
        if not isinstance(pose, Pose):
            raise TypeError(f"pose must be a facepose.Pose, got {type(pose).__name__}")
        t = None if timestamp is None else float(timestamp)
        rot, yaw, pitch, roll, accepted = self._t.filter(
            str(track), np.ascontiguousarray(pose.rotation, dtype=np.float64), pose.turn_cov, t
        )
        return dataclasses.replace(
            pose, yaw=yaw, pitch=pitch, roll=roll, rotation=rot, smoothed=True, gated=not accepted
        )

    def update_batch(
        self, batch: PoseBatch, timestamp: Optional[float] = None, tracks: Optional[Sequence[Any]] = None
    ) -> List[Optional[Pose]]:
        """One frame of several faces: face i on track ``tracks[i]`` (default: its index).
        Failed faces give None and leave their track as it was."""
        keys = list(range(len(batch))) if tracks is None else list(tracks)
        if len(keys) != len(batch):
            raise ValueError(f"{len(keys)} tracks for {len(batch)} faces")
        return [
            None if p is None else self.update(p, timestamp, k) for p, k in zip(batch, keys)
        ]

    def forget(self, track: Any) -> bool:
        """Drops a track's state (False when there was none)."""
        return self._t.forget(str(track))

    def reset(self) -> None:
        """Drops every track."""
        self._t.reset()

    @property
    def tracks(self) -> List[str]:
        """The tracks held (their keys as strings)."""
        return self._t.tracks()


def train(
    shapes: Any,
    scheme: str = "ibug68",
    *,
    components: int = 40,
    grid: str = "wide",
    subsets: Optional[Sequence[str]] = None,
    seed: int = 2011,
    name: str = "trained",
    version: str = "1",
    created: Optional[str] = None,
) -> Model:
    """Trains a model from 3D face shapes, like ``facepose train --shapes``.

    Args:
        shapes: (S, N, 3) float array, mm, model frame (x towards the subject's left, y up,
            z towards the camera), every point present, N the scheme's points.
        scheme: a built-in scheme to train in (``ibug68``, ``inner51``, ``five``, ``dlib5``).
        components: principal components of the shape basis for ``fit-shape`` (0: none).
        grid: the regression's pose grids: ``wide`` (to profile) or ``paper`` (±40°).
        subsets: sub-schemes to serve besides the model's own (default for ibug68:
            inner51, five, dlib5).
        seed: seed of the validation views.
        name, version: the model's name and version in its bundle.
        created: the bundle's creation time, RFC 3339 (default: now, UTC).

    The model has no MediaPipe mesh and no uncertainty calibration (answers carry none).
    ``Model.save(folder)`` writes its bundle. The GIL is released while it trains.
    """
    a = _as_float(shapes, "shapes")
    if a.ndim != 3:
        raise InvalidParameterError(f"shapes must be an (S, N, 3) array, got shape {a.shape}")
    if created is None:
        import datetime

        created = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return _facepose._train(
        a,
        created,
        scheme=scheme,
        components=int(components),
        grid=grid,
        subsets=None if subsets is None else [str(s) for s in subsets],
        seed=int(seed),
        name=name,
        version=version,
    )
