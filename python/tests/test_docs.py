"""The Python examples of docs/PYTHON.md run, in order, in one namespace, against fakes of the
detectors they call (mediapipe, dlib, OpenCV's VideoCapture) that hand over real landmarks:
MediaPipe's canonical face mesh turned by a known pose, AFLW2000-3D faces."""

import contextlib
import io
import json
import re
import sys
import types

import numpy as np
import pytest

from conftest import REPO, rotation

DOC = REPO / "docs" / "PYTHON.md"


def blocks():
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)


class _P:
    def __init__(self, x, y):
        self.x, self.y = x, y


def fake_mediapipe(data, yaw, pitch, roll):
    with open(data / "mediapipe" / "canonical_face_468.json") as f:
        v = np.array(json.load(f)["vertices"])
    mp = types.ModuleType("mediapipe")

    class FaceMesh:
        def __init__(self, static_image_mode=False, refine_landmarks=False):
            self.refine = refine_landmarks

        def __enter__(self):
            return self

        def __exit__(self, *a):
            return False

        def process(self, rgb):
            h, w = rgb.shape[:2]
            p = (v @ rotation(yaw, pitch, roll).T)[:, :2] * [2.5, -2.5] + [w / 2, h / 2]
            if self.refine:  # ten iris points: the eyes' centres
                eyes = [p[[33, 133]].mean(0)] * 5 + [p[[362, 263]].mean(0)] * 5
                p = np.vstack([p, eyes])
            face = types.SimpleNamespace(landmark=[_P(x / w, y / h) for x, y in p])
            return types.SimpleNamespace(multi_face_landmarks=[face])

    mp.solutions = types.SimpleNamespace(face_mesh=types.SimpleNamespace(FaceMesh=FaceMesh))
    return mp


def fake_dlib(points):
    dlib = types.ModuleType("dlib")
    dlib.get_frontal_face_detector = lambda: (lambda img, up: ["rect"])
    parts = [_P(int(round(x)), int(round(y))) for x, y in points]
    dlib.shape_predictor = lambda path: (lambda img, rect: types.SimpleNamespace(parts=lambda: parts))
    dlib.load_rgb_image = lambda path: np.zeros((450, 450, 3), np.uint8)
    return dlib


def fake_cv2(frames):
    cv2 = types.ModuleType("cv2")
    cv2.CAP_PROP_POS_MSEC = 0

    class VideoCapture:
        def __init__(self, path):
            self.k = -1

        def read(self):
            self.k += 1
            return (self.k < frames, self.k)

        def get(self, prop):
            return self.k * 1000 / 30

    cv2.VideoCapture = VideoCapture
    return cv2


def test_every_python_example_runs(aflw, data, tmp_path, monkeypatch):
    code = blocks()
    assert len(code) >= 8, "docs/PYTHON.md lost its examples"
    rng = np.random.default_rng(5)
    base = np.array(aflw[4]["landmarks_fitted"])
    monkeypatch.setitem(sys.modules, "mediapipe", fake_mediapipe(data, 25.0, -10.0, 5.0))
    monkeypatch.setitem(sys.modules, "dlib", fake_dlib(aflw[4]["landmarks_reannotated"]))
    monkeypatch.setitem(sys.modules, "cv2", fake_cv2(45))
    monkeypatch.chdir(REPO)  # the examples' paths are the repository's
    ns = {
        "face": aflw[0],
        "faces": aflw[:50],
        "data": data,
        "tmp": tmp_path,
        "rgb": np.zeros((720, 1280, 3), np.uint8),
        # Two faces a frame, with pixel jitter; the second is lost for a frame now and then.
        "find_landmarks": lambda frame: [base + rng.normal(0, 1, base.shape)]
        + ([] if frame % 7 == 3 else [base[:, ::-1] * 0 + base + 40]),
    }
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        for i, c in enumerate(code):
            try:
                exec(compile(c, f"docs/PYTHON.md python block {i + 1}", "exec"), ns)
            except Exception as e:
                pytest.fail(f"docs/PYTHON.md python block {i + 1} raised {e!r}:\n{c}")
    text = out.getvalue()
    # The MediaPipe example finds the pose the fake mesh was turned to.
    m = re.search(r"mediapipe478 (\S+) (\S+) (\S+)", text)
    assert m, text
    yaw, pitch, roll = map(float, m.groups())
    assert abs(yaw - 25) < 1.5 and abs(pitch + 10) < 1.5 and abs(roll - 5) < 1.5, m.group(0)
    assert "[ True False  True]" in text
    assert "invalid landmark scheme" in text
    assert text.count("face 0: yaw") == 45 and "face 1: yaw" in text
    assert (tmp_path / "mine" / "model.json").is_file()
