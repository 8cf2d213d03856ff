"""estimate(): one face, batches, the fields of the answer, threads, missing points, options."""

import numpy as np
import pytest

import facepose
from conftest import rotation


def test_one_face_has_the_service_fields(face68):
    p = facepose.estimate(face68)
    assert isinstance(p, facepose.Pose)
    assert p.method == "fit-shape" and p.scheme == "ibug68" and p.model == "default"
    assert p.rotation.shape == (3, 3) and p.rotation.dtype == np.float64
    np.testing.assert_allclose(p.rotation @ p.rotation.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(p.rotation, rotation(p.yaw, p.pitch, p.roll), atol=1e-12)
    assert p.visible.shape == (68,) and p.visible.dtype == np.bool_
    assert 0 <= p.residual < 0.2 and p.warnings == []
    u = p.uncertainty
    assert u is not None and u.yaw.sd > 0
    lo, hi = u.yaw.interval90
    assert lo < p.yaw < hi
    assert p.translation is None and p.turn_cov.shape == (3, 3)
    d = p.to_dict()
    assert list(d) == [
        "yaw", "pitch", "roll", "rotation", "visible", "residual", "method", "warnings",
        "uncertainty", "scheme", "model", "model_version",
    ]


def test_angles_are_near_the_truth(aflw, fitted):
    b = facepose.estimate(fitted)
    truth = np.array([[f["yaw"], f["pitch"], f["roll"]] for f in aflw])
    keep = np.array([f["within_99"] for f in aflw])
    mae = np.abs(b.angles - truth)[keep].mean()
    assert mae < 5, mae


def test_a_batch_is_its_faces_one_by_one(fitted):
    faces = fitted[:40]
    b = facepose.estimate(faces)
    assert isinstance(b, facepose.PoseBatch) and len(b) == 40 and b.ok.all()
    assert b.rotation.shape == (40, 3, 3) and b.visible.shape == (40, 68)
    for i in (0, 17, 39):
        one = facepose.estimate(faces[i])
        got = b[i]
        assert got.to_dict() == one.to_dict()
        assert got.uncertainty == one.uncertainty and got.scheme == one.scheme
        np.testing.assert_array_equal(got.turn_cov, one.turn_cov)


def test_threads_do_not_change_answers(fitted):
    one = facepose.estimate(fitted, threads=1)
    two = facepose.estimate(fitted, threads=2)
    eight = facepose.estimate(fitted, threads=8)
    for b in (two, eight):
        np.testing.assert_array_equal(one.rotation, b.rotation)
        np.testing.assert_array_equal(one.sd, b.sd)
        assert one.method == b.method


def test_lists_may_mix_schemes(face68):
    five = face68[[36, 45, 30, 48, 54]]
    eyes5 = np.array([face68[36:42].mean(0), face68[42:48].mean(0), face68[30], face68[48], face68[54]])
    b = facepose.estimate([face68, face68[17:], face68.tolist()], errors="keep")
    assert b.scheme == ["ibug68", "inner51", "ibug68"] and b.ok.all()
    assert isinstance(b.visible, list) and [len(v) for v in b.visible] == [68, 51, 68]
    assert b[0].to_dict() == b[2].to_dict()
    p = facepose.estimate(eyes5, scheme="five")
    assert p.method == "fit" and abs(p.yaw - b.yaw[0]) < 10
    assert facepose.estimate([five, eyes5], scheme="five").ok.all()


def test_integers_and_float32_are_taken(face68):
    a = facepose.estimate(face68.astype(np.float32))
    b = facepose.estimate(np.round(face68).astype(np.int64))
    c = facepose.estimate(face68)
    assert abs(a.yaw - c.yaw) < 0.1 and abs(b.yaw - c.yaw) < 1
    # A transposed (non-contiguous) view is the same face.
    t = np.ascontiguousarray(face68.T).T
    assert facepose.estimate(t).to_dict() == c.to_dict()


def test_nan_rows_are_missing_points(face68):
    x = face68.copy()
    x[[0, 1, 2, 3, 4, 5]] = np.nan
    p = facepose.estimate(x)
    q = facepose.estimate(face68)
    assert p.visible.shape == (68,) and abs(p.yaw - q.yaw) < 5


def test_every_method(face68):
    for m in ("auto", "fit", "fit-shape", "regression", "geometry"):
        p = facepose.estimate(face68, method=m)
        assert p.method == ("fit-shape" if m == "auto" else m)


def test_camera_gives_translation(face68):
    k = (900.0, 900.0, 320.0, 240.0)
    p = facepose.estimate(face68, camera=k)
    assert p.translation.shape == (3,) and p.translation[2] < 0
    # The same camera as a dict or an OpenCV matrix.
    kd = dict(fx=900, fy=900, cx=320, cy=240)
    km = np.array([[900, 0, 320], [0, 900, 240], [0, 0, 1.0]])
    assert facepose.estimate(face68, camera=kd).to_dict() == p.to_dict()
    assert facepose.estimate(face68, camera=km).to_dict() == p.to_dict()
    b = facepose.estimate(face68[None], camera=k)
    np.testing.assert_array_equal(b.translation[0], p.translation)
    assert "translation" in p.to_dict()


def test_normalized_coordinates_with_image_size(face68):
    w, h = 1280.0, 720.0
    n = face68 / [w, h]
    p = facepose.estimate(n, image_size=(w, h))
    q = facepose.estimate(n * [w, h])
    assert p.to_dict() == q.to_dict()


def test_keep_marks_failed_faces(fitted):
    faces = fitted[:3].copy()
    faces[1] = 5.0  # every point at one place
    with pytest.raises(facepose.DegenerateError, match=r"^faces\[1\]: degenerate input"):
        facepose.estimate(faces)
    b = facepose.estimate(faces, errors="keep")
    assert b.ok.tolist() == [True, False, True]
    assert np.isnan(b.yaw[1]) and b.method[1] == "" and not b.visible[1].any()
    assert isinstance(b.errors[1], facepose.DegenerateError)
    assert str(b.errors[1]).startswith("degenerate input")
    with pytest.raises(facepose.DegenerateError):
        b[1]
    assert b.poses()[1] is None and b.poses()[0].yaw == b.yaw[0]


def test_model_argument(face68):
    m = facepose.default_model()
    assert m is not None and m.name == "default"
    assert dict(m.schemes)["mediapipe478"] == 478
    assert facepose.estimate(face68, model=m).to_dict() == facepose.estimate(face68).to_dict()


def test_batch_releases_the_gil(fitted):
    """Another Python thread runs while a batch estimates."""
    import threading
    import time

    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    faces = np.concatenate([fitted] * 20)
    t = threading.Thread(target=tick)
    t.start()
    time.sleep(0.01)
    n0 = len(ticks)
    t0 = time.perf_counter()
    facepose.estimate(faces, threads=1)
    elapsed = time.perf_counter() - t0
    n1 = len(ticks)
    stop.set()
    t.join()
    # Held GIL: no tick at all during the batch (Rust code holding it is never preempted by
    # the interpreter's switch interval). Released: up to one a millisecond, fewer on a loaded
    # machine.
    assert elapsed > 0.05
    assert n1 - n0 >= 10, (n1 - n0, elapsed)


def test_answers_are_immutable(face68):
    import dataclasses

    p = facepose.estimate(face68)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.yaw = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.uncertainty.yaw.sd = 0.0
    assert isinstance(p.uncertainty.roll.interval90, tuple)
    assert dataclasses.replace(p, yaw=1.0).yaw == 1.0


def test_conventions(face68):
    p = facepose.estimate(face68, conventions="quaternion,euler:preset=openface")
    assert set(p.conventions) == {"quaternion", "euler"}, p.conventions
    assert p.to_dict()["conventions"] == p.conventions
    b = facepose.estimate(face68[None], conventions=["quaternion", "euler:preset=openface"])
    assert b[0].conventions == p.conventions
    assert facepose.estimate(face68).conventions is None
