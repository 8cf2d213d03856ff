"""Runs dlib's two landmark predictors (68 points, ibug68; 5 points, dlib5) on a real photograph
(scikit-image's astronaut) and on copies whose true pose change is known, and writes what they
found as a test fixture (tests/fixtures/detectors/dlib_astronaut.json). Run by
scripts/dlib-landmarks.sh, which makes the virtual environment.

Prints, per copy, how far each of dlib's five points lies from the ibug68 point that scheme
dlib5 maps it to (DLIB5_IN_IBUG68 in crates/core/src/shape/scheme.rs).
"""

import json
import sys

import dlib
import face_recognition_models as models
import numpy as np
from skimage import data, transform

DLIB5_IN_IBUG68 = [45, 42, 36, 39, 33]


def copies(img):
    """(name, image, what the transform does to the pose) for each copy."""
    h, w = img.shape[:2]
    yield "original", img, "none"
    yield "mirrored", img[:, ::-1].copy(), "mirror: yaw and roll change sign"
    for deg in (20, -20):
        # skimage rotates counter-clockwise on screen for a positive angle: the face turns
        # anticlockwise, so roll (clockwise positive) changes by -deg.
        rot = transform.rotate(img, deg, resize=True, preserve_range=True).astype(np.uint8)
        yield f"rotated{deg:+d}", rot, f"roll changes by {-deg}"
    small = transform.rescale(img, 0.6, channel_axis=2, preserve_range=True).astype(np.uint8)
    yield "scaled0.6", small, "none"
    yield "cropped", img[40 : h - 100, 60 : w - 40].copy(), "none"


def main(out):
    detector = dlib.get_frontal_face_detector()
    p68 = dlib.shape_predictor(models.pose_predictor_model_location())
    p5 = dlib.shape_predictor(models.pose_predictor_five_point_model_location())
    faces = []
    for name, img, change in copies(data.astronaut()):
        rects, scores, _ = detector.run(img, 1, 0.0)
        if not rects:
            sys.exit(f"{name}: no face found")
        # The astronaut's face: the detection with the highest score.
        r = rects[int(np.argmax(scores))]
        a = [[p.x, p.y] for p in p68(img, r).parts()]
        b = [[p.x, p.y] for p in p5(img, r).parts()]
        dist = [float(np.hypot(*np.subtract(b[k], a[i]))) for k, i in enumerate(DLIB5_IN_IBUG68)]
        print(f"{name:12s} {img.shape[1]}x{img.shape[0]}  dlib5 point to its ibug68 point, px: "
              + " ".join(f"{d:.1f}" for d in dist))
        faces.append({
            "image": f"astronaut/{name}",
            "transform": change,
            "image_size": [img.shape[1], img.shape[0]],
            "ibug68": a,
            "dlib5": b,
        })
    doc = {
        "source": "scikit-image data.astronaut(); dlib " + dlib.__version__
        + " get_frontal_face_detector, shape_predictor_68_face_landmarks and"
        " shape_predictor_5_face_landmarks (face-recognition-models); made by"
        " scripts/dlib-landmarks.sh",
        "faces": faces,
    }
    with open(out, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tests/fixtures/detectors/dlib_astronaut.json")
