"""Shared fixtures: the repository, the shared data (FACEPOSE_DATA, else ../shared/data beside
the repository), and the AFLW2000-3D dev faces."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def data_dir() -> Path:
    d = os.environ.get("FACEPOSE_DATA")
    return Path(d) if d else REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def data() -> Path:
    d = data_dir()
    if not (d / "aflw2000" / "aflw2000_dev.jsonl").is_file():
        pytest.fail(f"the shared data is not at {d} (set FACEPOSE_DATA)")
    return d


@pytest.fixture(scope="session")
def aflw(data):
    """The dev faces: a list of dicts (landmarks_fitted, landmarks_reannotated, yaw, pitch, roll)."""
    with open(data / "aflw2000" / "aflw2000_dev.jsonl") as f:
        return [json.loads(line) for line in f if line.strip()]


@pytest.fixture(scope="session")
def fitted(aflw):
    """(B, 68, 2) float64: the fitted landmarks of every dev face."""
    return np.array([f["landmarks_fitted"] for f in aflw], dtype=np.float64)


@pytest.fixture(scope="session")
def face68(fitted):
    return fitted[0].copy()


def rotation(yaw, pitch, roll):
    """R = Rx(pitch) Ry(yaw) Rz(roll), degrees, with the convention's matrices
    (crates/core/src/geometry/convention.rs: Pose_Para's, transposed from the textbook ones)."""
    p, y, r = np.radians([pitch, yaw, roll])
    rx = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])
    ry = np.array([[np.cos(y), 0, -np.sin(y)], [0, 1, 0], [np.sin(y), 0, np.cos(y)]])
    rz = np.array([[np.cos(r), np.sin(r), 0], [-np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return rx @ ry @ rz
