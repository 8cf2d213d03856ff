#!/usr/bin/env bash
# Runs two real landmark detectors, dlib (68 and 5 points) and MediaPipe's Face Mesh (478
# points), on real photographs and on transformed copies whose true pose change is known, and
# writes what they found to tests/fixtures/detectors/{dlib,mediapipe}.json: the fixtures of
# tests/integration/detectors.rs (which `cargo test` checks without Python) and of the report
# of scripts/detector-report.sh. What runs and how: scripts/detector_landmarks.py.
#
#   scripts/detector-landmarks.sh [OUT_DIR]
#
# Makes (once) a venv in target/detector-venv from PyPI: mediapipe 0.10.14 (its face models are
# in the wheel), dlib-bin and face-recognition-models (dlib and its predictors' weights),
# scikit-image (the photographs). Offline after that. Needs CPython 3.8-3.12 (mediapipe
# 0.10.14's wheels) and the shared data (FACEPOSE_DATA, else ../shared/data) for the canonical
# face mesh of MediaPipe's face geometry.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${FACEPOSE_DATA:-../shared/data}
VENV=target/detector-venv
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# mediapipe 0.10.14 has wheels for CPython 3.8-3.12 only (PYTHON: another interpreter).
# numpy < 2: mediapipe 0.10.14 is built against numpy 1; opencv-contrib-python (which
# mediapipe requires) pinned to a release that still supports it, so pip need not search.
venv_ensure --python "${PYTHON:-python3}" --requires-python 3.8-3.12 \
    --check 'import dlib, face_recognition_models, mediapipe, skimage' "$VENV" \
    'mediapipe==0.10.14' 'numpy==1.26.4' 'opencv-contrib-python==4.11.0.86' \
    'dlib-bin==20.0.1.post1' 'face-recognition-models==0.3.0' 'scikit-image>=0.24,<0.27' \
    setuptools
"$VENV/bin/python" scripts/detector_landmarks.py "${1:-tests/fixtures/detectors}" \
    "$DATA/mediapipe/canonical_face_468.json"
