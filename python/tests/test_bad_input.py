"""Bad input raises (FaceposeError, a ValueError, with the service's message; TypeError for
what is not numbers) and never crashes the interpreter. Each case also runs in a child
interpreter, so that a crash (a segfault, an abort) fails the test instead of the run."""

import subprocess
import sys

import numpy as np
import pytest

import facepose

F68 = None


@pytest.fixture(autouse=True)
def _face(face68):
    global F68
    F68 = face68


def nan_at(i, j):
    x = F68.copy()
    x[i, j] = np.nan
    return x


def val_at(i, j, v):
    x = F68.copy()
    x[i, j] = v
    return x


# (id, call, exception, message part)
CASES = [
    ("shape-1d", lambda: facepose.estimate(np.zeros(136)), facepose.InvalidParameterError, "(N, 2)"),
    ("shape-n3", lambda: facepose.estimate(np.zeros((68, 3))), facepose.InvalidParameterError, "got shape (68, 3)"),
    ("shape-4d", lambda: facepose.estimate(np.zeros((2, 2, 68, 2))), facepose.InvalidParameterError, "(B, N, 2)"),
    ("shape-scalar", lambda: facepose.estimate(3.0), facepose.InvalidParameterError, "got shape ()"),
    ("shape-b-n3", lambda: facepose.estimate(np.zeros((2, 68, 3))), facepose.InvalidParameterError, "got shape (68, 3)"),
    ("empty", lambda: facepose.estimate(np.zeros((0, 2))), facepose.InvalidParameterError, "0 landmarks"),
    ("empty-batch", lambda: facepose.estimate(np.zeros((0, 68, 2))), None, None),
    ("too-many", lambda: facepose.estimate(np.ones((1001, 2))), facepose.InvalidParameterError, "more than 1000 landmarks"),
    ("dtype-str", lambda: facepose.estimate(np.array([["a", "b"]] * 68)), TypeError, "real numbers"),
    ("dtype-object", lambda: facepose.estimate(np.array([[1, None]] * 68, dtype=object)), TypeError, "dtype object"),
    ("dtype-complex", lambda: facepose.estimate(F68 + 1j), TypeError, "complex"),
    ("dtype-bool", lambda: facepose.estimate(F68 > 100), TypeError, "dtype bool"),
    ("ragged", lambda: facepose.estimate([[1.0, 2.0], [3.0]]), (ValueError, TypeError), None),
    ("list-bad-item", lambda: facepose.estimate([F68, np.zeros((5, 3))]), facepose.InvalidParameterError, "faces[1]"),
    ("list-str-item", lambda: facepose.estimate([F68, np.array([["a", "b"]])]), TypeError, "faces[1]"),
    ("half-nan", lambda: facepose.estimate(nan_at(3, 1)), facepose.NonFiniteError, "landmark 3 y is not a finite number"),
    ("inf", lambda: facepose.estimate(val_at(7, 0, np.inf)), facepose.NonFiniteError, "landmark 7 x is not a finite number"),
    ("neg-inf-batch", lambda: facepose.estimate(np.stack([F68, val_at(2, 1, -np.inf)])), facepose.NonFiniteError, "faces[1]: landmark 2 y"),
    ("huge", lambda: facepose.estimate(val_at(0, 0, 1e12)), facepose.InvalidParameterError, "out of range"),
    ("all-nan", lambda: facepose.estimate(np.full((68, 2), np.nan)), facepose.FaceposeError, None),
    ("all-same", lambda: facepose.estimate(np.full((68, 2), 5.0)), facepose.DegenerateError, "degenerate input"),
    ("collinear", lambda: facepose.estimate(np.stack([np.arange(68.0), np.arange(68.0)], 1) * 3), facepose.FaceposeError, None),
    ("normalized-no-size", lambda: facepose.estimate(F68 / 1000), facepose.InvalidParameterError, "normalized coordinates"),
    ("pixels-with-size", lambda: facepose.estimate(F68, image_size=(640, 480)), facepose.InvalidParameterError, "not a normalized coordinate"),
    ("bad-size", lambda: facepose.estimate(F68 / 1000, image_size=(0, 480)), facepose.InvalidParameterError, "image_size"),
    ("size-shape", lambda: facepose.estimate(F68, image_size=(1, 2, 3)), facepose.InvalidParameterError, "image_size"),
    ("unknown-scheme", lambda: facepose.estimate(F68, scheme="mediapipe"), facepose.InvalidSchemeError, 'invalid landmark scheme "mediapipe": this model serves ibug68'),
    ("scheme-count", lambda: facepose.estimate(F68, scheme="five"), facepose.PointCountError, "expected 5 points, got 68"),
    ("count-fits-none", lambda: facepose.estimate(F68[:7]), facepose.InvalidParameterError, "7 landmarks, and no scheme"),
    ("five-unnamed", lambda: facepose.estimate(F68[:5]), facepose.InvalidParameterError, "fit more than one scheme"),
    ("unknown-method", lambda: facepose.estimate(F68, method="fast"), facepose.InvalidParameterError, 'unknown method "fast"'),
    ("unknown-style", lambda: facepose.estimate(F68, landmark_style="3d"), facepose.InvalidParameterError, "unknown landmark style"),
    ("long-name", lambda: facepose.estimate(F68, scheme="x" * 65), facepose.InvalidParameterError, "at most 64 characters"),
    ("scheme-type", lambda: facepose.estimate(F68, scheme=68), TypeError, "scheme"),
    ("camera-negative", lambda: facepose.estimate(F68, camera=(-1, 900, 320, 240)), facepose.FaceposeError, "camera"),
    ("camera-nan", lambda: facepose.estimate(F68, camera=(np.nan, 900, 320, 240)), facepose.FaceposeError, None),
    ("camera-shape", lambda: facepose.estimate(F68, camera=(900, 900)), facepose.InvalidParameterError, "camera"),
    ("camera-dict", lambda: facepose.estimate(F68, camera={"f": 1}), facepose.InvalidParameterError, "fx, fy, cx, cy"),
    ("camera-regression", lambda: facepose.estimate(F68, method="regression", camera=(900, 900, 320, 240)), facepose.InvalidParameterError, "weak-perspective only"),
    ("convention-name", lambda: facepose.estimate(F68, conventions="quaternions"), facepose.ConventionError, "quaternions"),
    ("convention-type", lambda: facepose.estimate(F68, conventions=5), TypeError, "conventions"),
    ("not-a-face", lambda: facepose.estimate(np.random.default_rng(1).uniform(100, 400, (68, 2))), facepose.NotAFaceError, "do not look like a face"),
    ("errors-arg", lambda: facepose.estimate(F68[None], errors="ignore"), ValueError, "errors"),
    ("threads-arg", lambda: facepose.estimate(F68[None], threads=0), ValueError, "threads"),
    ("model-arg", lambda: facepose.estimate(F68, model="default"), TypeError, "Model"),
    ("tracker-kind", lambda: facepose.Tracker("median"), facepose.InvalidParameterError, "unknown filter"),
    ("tracker-param", lambda: facepose.Tracker("kalman", beta=1.0), facepose.InvalidParameterError, 'no parameter "beta"'),
    ("tracker-value", lambda: facepose.Tracker("one-euro", min_cutoff_hz=0), facepose.InvalidParameterError, "cutoff"),
    ("tracker-gap", lambda: facepose.Tracker(max_gap=-1), facepose.InvalidParameterError, "max_gap"),
    ("tracker-pose", lambda: facepose.Tracker().update(F68), TypeError, "Pose"),
    ("tracker-time", lambda: facepose.Tracker().update(facepose.estimate(F68), timestamp=float("nan")), facepose.InvalidParameterError, "timestamp"),
    ("load-missing", lambda: facepose.Model.load("/nonexistent/model"), facepose.ModelError, "/nonexistent/model"),
    ("train-shape", lambda: facepose.train(np.zeros((3, 68, 2))), facepose.InvalidParameterError, "(S, 68, 3)"),
    ("train-scheme", lambda: facepose.train(np.zeros((3, 68, 3)), scheme="nope"), facepose.InvalidSchemeError, "built-in schemes"),
    ("train-nan", lambda: facepose.train(np.full((3, 68, 3), np.nan)), facepose.NonFiniteError, "shape 0 point 0"),
    ("train-grid", lambda: facepose.train(np.zeros((3, 68, 3)), grid="fine"), facepose.InvalidParameterError, "unknown grid"),
    ("train-few", lambda: facepose.train(np.zeros((1, 68, 3))), facepose.FaceposeError, "training shapes"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_raises(case):
    _, call, exc, part = case
    if exc is None:
        call()  # accepted
        return
    with pytest.raises(exc) as info:
        call()
    if part is not None:
        assert part in str(info.value)


def test_errors_are_value_errors():
    assert issubclass(facepose.FaceposeError, ValueError)
    for name in ("NonFiniteError", "PointCountError", "NotAFaceError", "ModelError"):
        assert issubclass(getattr(facepose, name), facepose.FaceposeError)


def test_no_case_crashes_the_interpreter():
    """Every case in one child interpreter: it must exit normally."""
    code = (
        "import sys; sys.path.insert(0, %r)\n"
        "import conftest, test_bad_input as t, numpy as np, json\n"
        "faces = [json.loads(l) for l in open(conftest.data_dir() / 'aflw2000/aflw2000_dev.jsonl')]\n"
        "t.F68 = np.array(faces[0]['landmarks_fitted'], dtype=float)\n"
        "for name, call, exc, part in t.CASES:\n"
        "    try:\n"
        "        call()\n"
        "    except Exception:\n"
        "        pass\n"
        "print('survived', len(t.CASES))\n"
    ) % str(__import__("pathlib").Path(__file__).parent)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "survived" in r.stdout
