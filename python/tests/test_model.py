"""Models: the embedded default, a bundle folder, save, and train from shape arrays."""

import json

import numpy as np
import pytest

import facepose
from conftest import REPO


def test_default_model():
    m = facepose.Model.default()
    assert m.name == "default" and m.version
    assert [s for s, _ in m.schemes][:4] == ["ibug68", "inner51", "five", "dlib5"]
    assert m.has_shape_basis and m.has_calibration
    assert m.scheme_points("five") == ["eye_left", "eye_right", "nose_tip", "mouth_left", "mouth_right"]
    assert "Model(" in repr(m)


def test_the_bundle_folder_is_the_embedded_model(face68):
    m = facepose.Model.load(REPO / "models" / "default")
    assert m.to_json() == facepose.Model.default().to_json()
    assert facepose.estimate(face68, model=m).to_dict() == facepose.estimate(face68).to_dict()


def test_save_and_load(tmp_path, face68):
    out = tmp_path / "copy"
    facepose.Model.default().save(out)
    assert (out / "model.json").is_file()
    m = facepose.Model.load(out)
    assert facepose.estimate(face68, model=m).yaw == facepose.estimate(face68).yaw
    with pytest.raises(facepose.ModelError, match="already exists"):
        facepose.Model.default().save(out)


@pytest.fixture(scope="module")
def population(data):
    with open(data / "bfm68" / "population_249.json") as f:
        return np.array(json.load(f)["shapes"], dtype=np.float64)


def test_train_from_shapes(population, tmp_path, fitted, aflw):
    m = facepose.train(population[:60], components=10, grid="paper", name="py", version="7")
    assert m.name == "py" and m.version == "7"
    assert [s for s, _ in m.schemes] == ["ibug68", "inner51", "five", "dlib5"]
    assert m.has_shape_basis and not m.has_calibration
    b = facepose.estimate(fitted[:50], model=m, errors="keep")
    truth = np.array([[f["yaw"], f["pitch"], f["roll"]] for f in aflw[:50]])
    small = (np.abs(truth) < 40).all(1)  # the paper grid's range
    assert np.nanmean(np.abs(b.angles - truth)[small]) < 8
    assert b[0].uncertainty is None and b.model == "py"
    m.save(tmp_path / "py")
    again = facepose.Model.load(tmp_path / "py")
    assert again.to_json() == m.to_json()
    rigid = facepose.train(population[:20], components=0, grid="paper", subsets=["five"])
    assert not rigid.has_shape_basis and [s for s, _ in rigid.schemes] == ["ibug68", "five"]
    with pytest.raises(facepose.InvalidParameterError, match="fit-shape"):
        facepose.estimate(fitted[0], model=rigid, method="fit-shape")
