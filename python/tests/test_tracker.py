"""Tracker: Kalman and One Euro, frame by frame, one state per track."""

import numpy as np
import pytest

import facepose


@pytest.fixture(scope="module")
def still(fitted):
    """One face's landmarks with 60 frames of pixel jitter."""
    rng = np.random.default_rng(7)
    base = fitted[3]
    return [base + rng.normal(0, 1.5, base.shape) for _ in range(60)]


@pytest.mark.parametrize("kind", ["kalman", "one-euro"])
def test_jitter_shrinks(kind, still):
    tr = facepose.Tracker(kind)
    raw, smooth = [], []
    for k, lm in enumerate(still):
        p = facepose.estimate(lm)
        s = tr.update(p, timestamp=k / 30)
        assert s.smoothed and not p.smoothed
        assert s.method == p.method and s.residual == p.residual
        np.testing.assert_array_equal(s.visible, p.visible)
        raw.append(p.angles)
        smooth.append(s.angles)
    raw, smooth = np.array(raw[10:]), np.array(smooth[10:])
    assert (np.std(smooth, 0) < 0.8 * np.std(raw, 0)).all(), (np.std(raw, 0), np.std(smooth, 0))
    assert tr.tracks == ["0"] and tr.kind == kind


def test_first_frame_passes_through(face68):
    p = facepose.estimate(face68)
    s = facepose.Tracker().update(p)
    np.testing.assert_allclose(s.rotation, p.rotation, atol=1e-12)
    assert abs(s.yaw - p.yaw) < 1e-9


def test_each_track_steps_by_its_own_time(fitted, still):
    """A track's filter sees the time since its own last update, whatever other tracks do in
    between (the service's stream steps every track by the stream's frame interval)."""
    a, b = facepose.estimate(fitted[3]), facepose.estimate(fitted[10])
    a2 = facepose.estimate(still[1])
    alone = facepose.Tracker("one-euro")
    alone.update(a, 0.0, "x")
    want = alone.update(a2, 0.5, "x")
    busy = facepose.Tracker("one-euro")
    busy.update(a, 0.0, "x")
    for k in range(1, 15):  # another face every frame in between
        busy.update(b, k / 30, "y")
    got = busy.update(a2, 0.5, "x")
    np.testing.assert_array_equal(got.rotation, want.rotation)
    assert sorted(busy.tracks) == ["x", "y"]


def test_a_long_gap_restarts_the_track(fitted):
    p, q = facepose.estimate(fitted[3]), facepose.estimate(fitted[10])
    tr = facepose.Tracker("kalman", max_gap=0.5)
    tr.update(p, 0.0)
    s = tr.update(q, 2.0)  # 2 s later: a new start at q
    np.testing.assert_allclose(s.rotation, q.rotation, atol=1e-12)


def test_kalman_gates_a_wild_frame(still, fitted):
    tr = facepose.Tracker("kalman")
    for k, lm in enumerate(still[:20]):
        tr.update(facepose.estimate(lm), k / 30)
    wild = facepose.estimate(fitted[1])  # another face, 60 degrees of yaw away
    s = tr.update(wild, 20 / 30)
    assert s.gated and abs(s.yaw - wild.yaw) > 20


def test_batch_frames_and_forgetting(fitted):
    tr = facepose.Tracker("one-euro", beta=0.1)
    b = facepose.estimate(fitted[:3])
    out = tr.update_batch(b, 0.0, tracks=["a", "b", "c"])
    assert [p.smoothed for p in out] == [True] * 3
    assert tr.forget("b") and not tr.forget("b")
    assert tr.tracks == ["a", "c"]
    tr.reset()
    assert tr.tracks == []
