"""The answers of the tools that define facepose's conventions (issue 39), computed by those
tools and written as test fixtures (tests/fixtures/conventions/), which the core's test
crates/core/tests/conventions.rs checks without Python. Run by scripts/convention-fixtures.sh,
which makes the virtual environment.

- scipy.json: scipy's `Rotation.as_euler` for every order (upper case intrinsic, lower case
  extrinsic) and `as_quat` on random rotations and rotations at and near gimbal lock: the
  independent reference for Euler angles and quaternions.
- opencv.json: OpenCV's `solvePnP` (SOLVEPNP_SQPNP, then `solvePnPRefineLM`), `Rodrigues` and
  `projectPoints`
  (i) on synthetic faces, the default model's mean shape placed at known poses before a known
  camera and projected by `projectPoints`, and (ii) on the real dlib landmarks of
  tests/fixtures/detectors/dlib.json with the camera the conventions assume without
  intrinsics (fx = fy = image width, principal point at the centre). Object points: the mean in
  OpenCV's axes (F X, F = diag(1, -1, -1)) and, for the synthetic faces, also as served (X).
- mediapipe.json: MediaPipe's own FaceGeometryPipelineCalculator (as in
  scripts/detector_landmarks.py) (i) on synthetic faces, MediaPipe's canonical mesh placed at
  known poses in its virtual camera (vertical field of view 63 degrees) and projected, with
  `z` the depth relative to the face's mean in the scale of x (as Face Mesh's z); (ii) on the
  real landmarks of tests/fixtures/detectors/mediapipe.json with z = 0 (that fixture keeps no
  z), to measure what z does to MediaPipe's own matrix.
"""

import json
import math
import os
import sys
import warnings

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, os.path.dirname(__file__))
from detector_landmarks import FaceGeometry  # noqa: E402

F = np.diag([1.0, -1.0, -1.0])
ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ"]
SEQS = ORDERS + [o.lower() for o in ORDERS]
DEC = 10


def r(x, d=DEC):
    if isinstance(x, (list, tuple, np.ndarray)):
        return [r(v, d) for v in x]
    return round(float(x), d)


def pose_para(yaw, pitch, roll):
    """R = Rx(pitch) Ry(yaw) Rz(roll) with Pose_Para's matrices (the transposes of scipy's)."""
    return Rotation.from_euler("XYZ", [-pitch, -yaw, -roll], degrees=True).as_matrix()


def scipy_fixture():
    rng = np.random.default_rng(39)
    mats = list(Rotation.random(24, random_state=rng).as_matrix())
    mats.append(np.eye(3))
    # At and near gimbal lock of several orders: the middle angle at +-90 (Tait-Bryan) or
    # 0 / 180 (proper), exactly and within 1e-7 degrees.
    for seq, mids in [
        ("XYZ", [90, -90, 90 - 1e-7, -90 + 1e-7, 89.5]),
        ("zyx", [90, -90, 90 - 1e-7]),
        ("YXZ", [90, -90 + 1e-7]),
        ("ZXZ", [0, 180, 1e-7, 180 - 1e-7]),
        ("xyx", [0, 180]),
    ]:
        for m in mids:
            mats.append(Rotation.from_euler(seq, [37.0, m, -52.0], degrees=True).as_matrix())
    out = []
    for m in mats:
        rot = Rotation.from_matrix(m)
        q = rot.as_quat(canonical=True)  # x, y, z, w with w >= 0
        euler = {}
        for s in SEQS:
            with warnings.catch_warnings(record=True) as w:
                warnings.simplefilter("always")
                a = rot.as_euler(s)
            euler[s] = {"angles": r(a), "gimbal_lock": bool(w)}
        out.append(
            {
                "matrix": r(m, 15),
                "quaternion_wxyz": r([q[3], q[0], q[1], q[2]], 15),
                "euler_radians": euler,
            }
        )
    return {
        "made_by": "scripts/convention-fixtures.sh",
        "tool": "scipy " + __import__("scipy").__version__ + " Rotation.as_euler (upper case"
        " intrinsic, lower case extrinsic, radians) and as_quat(canonical=True)",
        "rotations": out,
    }


def load_model(path):
    with open(path) as f:
        m = json.load(f)
    return np.array(m["mean"], dtype=float), np.array(m["mesh"]["vertices"], dtype=float)


def solve(obj, img, k):
    # SQPnP (globally optimal) then Levenberg-Marquardt on the reprojection error: the default
    # SOLVEPNP_ITERATIVE from no guess lands behind the camera on 3 of the 11 real faces.
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_SQPNP)
    assert ok
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, None, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
    rms = float(np.sqrt(np.mean(np.sum((proj[:, 0, :] - img) ** 2, axis=1))))
    rmat, _ = cv2.Rodrigues(rvec)
    return {
        "rvec": r(rvec.ravel()),
        "tvec": r(tvec.ravel()),
        "rotation": r(rmat),
        "rms_px": r(rms, 6),
    }


def kmat(fx, fy, cx, cy):
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def opencv_fixture(mean, dlib_path):
    size = (640, 480)
    k = kmat(800.0, 800.0, 320.0, 240.0)
    assumed = kmat(size[0], size[0], size[0] / 2, size[1] / 2)
    obj_cv = mean @ F.T
    synthetic = []
    for yaw, pitch, roll, t in [
        (0, 0, 0, [0, 0, 600]),
        (30, -10, 5, [10, -20, 600]),
        (-45, 20, -15, [-80, 60, 700]),
        (60, 5, 25, [120, -90, 500]),
        (-20, -30, 10, [-150, -100, 900]),
    ]:
        rot = pose_para(yaw, pitch, roll)
        r_cv = F @ rot @ F  # object points in OpenCV's axes
        rvec, _ = cv2.Rodrigues(r_cv)
        tvec = np.array(t, dtype=float)
        px, _ = cv2.projectPoints(obj_cv, rvec, tvec, k, None)
        px = px[:, 0, :]
        synthetic.append(
            {
                "pose_para": [yaw, pitch, roll],
                "image_size": list(size),
                "camera": [800.0, 800.0, 320.0, 240.0],
                "true_rvec": r(rvec.ravel()),
                "true_tvec": r(tvec),
                "landmarks": r(px, 6),
                "solvepnp": solve(obj_cv, px, k),
                "solvepnp_model_frame": solve(mean, px, k),
                "solvepnp_assumed_camera": solve(obj_cv, px, assumed),
            }
        )
    with open(dlib_path) as f:
        dlib = json.load(f)
    real = []
    for face in dlib["faces"]:
        w, h = face["image_size"]
        img = np.array(face["ibug68"], dtype=float)
        ka = kmat(w, w, w / 2, h / 2)
        real.append(
            {
                "image": face["image"],
                "image_size": [w, h],
                "solvepnp_assumed_camera": solve(obj_cv, img, ka),
            }
        )
    return {
        "made_by": "scripts/convention-fixtures.sh",
        "tool": f"OpenCV {cv2.__version__}: solvePnP (SOLVEPNP_SQPNP, no distortion), then"
        " solvePnPRefineLM; Rodrigues, projectPoints",
        "object_points": "the default model's mean shape (models/default/model.json `mean`, ibug68,"
        " mm) in OpenCV's axes, F X with F = diag(1, -1, -1); solvepnp_model_frame: as served, X",
        "camera": "fx, fy, cx, cy; the assumed camera is fx = fy = image width, cx, cy the centre",
        "synthetic": synthetic,
        "real": {"landmarks": "tests/fixtures/detectors/dlib.json ibug68", "faces": real},
    }


def mp_matrix(geometry, size, points):
    """MediaPipe's matrix for normalized [x, y, z] points on an image of `size` (w, h)."""
    img = np.zeros((size[1], size[0], 3), dtype=np.uint8)
    return geometry.matrix(img, points)


def mediapipe_fixture(canonical_path, mp_fixture_path):
    with open(canonical_path) as f:
        canonical = np.array(json.load(f)["vertices"], dtype=float) / 10.0  # cm
    geometry = FaceGeometry(canonical_path)
    synthetic = []
    for (w, h), (yaw, pitch, roll), t in [
        ((640, 480), (0, 0, 0), [0, 0, -60]),
        ((640, 480), (25, -10, 5), [3, -2, -55]),
        ((640, 480), (-40, 15, -10), [-8, 5, -70]),
        ((1280, 720), (10, 25, 20), [12, 6, -80]),
        ((480, 640), (-15, -25, -5), [-4, -9, -45]),
        ((640, 480), (55, 5, 0), [0, 0, -65]),
    ]:
        rot = pose_para(yaw, pitch, roll)
        p = canonical @ rot.T + np.array(t)
        depth = -p[:, 2]
        f = h / (2 * math.tan(math.radians(31.5)))
        u = w / 2 + f * p[:, 0] / depth
        v = h / 2 - f * p[:, 1] / depth
        # z: depth relative to the mean, in the scale of x at the mean depth (normalized by
        # the width), smaller nearer the camera, as Face Mesh's z.
        z = (depth - depth.mean()) * f / depth.mean() / w
        pts = np.stack([u / w, v / h, z], axis=1)
        m = mp_matrix(geometry, (w, h), pts.tolist())
        m_flat = mp_matrix(geometry, (w, h), np.c_[pts[:, :2], np.zeros(len(pts))].tolist())
        true = np.eye(4)
        true[:3, :3] = rot
        true[:3, 3] = t
        synthetic.append(
            {
                "pose_para": [yaw, pitch, roll],
                "image_size": [w, h],
                "true_matrix": r(true),
                "mediapipe_matrix": r(m, 7),
                "mediapipe_matrix_z0": r(m_flat, 7),
                "landmarks": r(pts[:, :2], 8),
                "z": r(z, 8),
            }
        )
    with open(mp_fixture_path) as f:
        faces = json.load(f)["faces"]
    real = []
    for face in faces:
        pts = [[x, y, 0.0] for x, y in face["landmarks"][:468]]
        real.append(
            {
                "image": face["image"],
                "mediapipe_matrix_z0": r(mp_matrix(geometry, face["image_size"], pts), 7),
            }
        )
    geometry.close()
    return {
        "made_by": "scripts/convention-fixtures.sh",
        "tool": "MediaPipe 0.10.14 FaceGeometryPipelineCalculator (FaceLandmarker's default"
        " environment: vertical FOV 63 degrees, near 1, far 10000, origin top-left), canonical"
        " mesh from the shared data's canonical_face_468.json (cm); matrices row-major",
        "synthetic": synthetic,
        "real": {
            "landmarks": "tests/fixtures/detectors/mediapipe.json (its matrices used z)",
            "faces": real,
        },
    }


def write(path, doc):
    with open(path, "w") as f:
        json.dump(doc, f, separators=(",", ":"))
        f.write("\n")
    print(f"wrote {path} ({os.path.getsize(path)} bytes)")


def main(out_dir, canonical_path):
    os.makedirs(out_dir, exist_ok=True)
    mean, _ = load_model("models/default/model.json")
    write(os.path.join(out_dir, "scipy.json"), scipy_fixture())
    write(
        os.path.join(out_dir, "opencv.json"),
        opencv_fixture(mean, "tests/fixtures/detectors/dlib.json"),
    )
    write(
        os.path.join(out_dir, "mediapipe.json"),
        mediapipe_fixture(canonical_path, "tests/fixtures/detectors/mediapipe.json"),
    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
