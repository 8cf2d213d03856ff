#!/usr/bin/env bash
# Computes the answers of the tools that define facepose's conventions (scipy's Euler angles and
# quaternions, OpenCV's solvePnP / Rodrigues / projectPoints, MediaPipe's own face-geometry
# calculator) on synthetic faces and on the detector fixtures' real landmarks, and writes them to
# tests/fixtures/conventions/{scipy,opencv,mediapipe}.json: the fixtures of
# crates/core/tests/conventions.rs, which `cargo test` checks without Python. What runs and how:
# scripts/convention_fixtures.py.
#
#   scripts/convention-fixtures.sh [OUT_DIR]
#
# Makes (once) a venv in target/convention-venv from PyPI: mediapipe 0.10.14 with numpy 1.26.4
# and opencv-contrib-python 4.11.0.86 (mediapipe requires the contrib build, which holds the
# same cv2.solvePnP as opencv-python-headless; installing both would overwrite one cv2 with the
# other), and scipy. Offline after that. Needs CPython 3.8-3.12 (mediapipe 0.10.14's wheels)
# and the shared data (FACEPOSE_DATA, else ../shared/data) for MediaPipe's canonical face mesh.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${FACEPOSE_DATA:-../shared/data}
VENV=target/convention-venv
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# mediapipe 0.10.14 has wheels for CPython 3.8-3.12 only (PYTHON: another interpreter).
venv_ensure --python "${PYTHON:-python3}" --requires-python 3.8-3.12 \
    --check 'import cv2, mediapipe, scipy' "$VENV" \
    'mediapipe==0.10.14' 'numpy==1.26.4' 'opencv-contrib-python==4.11.0.86' 'scipy>=1.11,<1.15'
# detector_landmarks.py (imported for MediaPipe's calculator) imports dlib and skimage at the
# top; this venv has neither, so stub them: only its FaceGeometry class is used.
"$VENV/bin/python" - "${1:-tests/fixtures/conventions}" "$DATA/mediapipe/canonical_face_468.json" <<'EOF'
import sys, types
for name in ("dlib", "face_recognition_models", "skimage"):
    stub = types.ModuleType(name)
    stub.data = stub.transform = None
    sys.modules[name] = stub
sys.argv = ["scripts/convention_fixtures.py"] + sys.argv[1:]
sys.path.insert(0, "scripts")
import convention_fixtures
convention_fixtures.main(sys.argv[1], sys.argv[2])
EOF
