#!/usr/bin/env bash
# Runs dlib's 68- and 5-point predictors on a real photograph and on transformed copies of it,
# and writes the landmarks they found to tests/fixtures/detectors/dlib_astronaut.json (the
# fixture of tests/integration/detectors.rs, which `cargo test` checks without Python).
#
#   scripts/dlib-landmarks.sh [OUT]
#
# Makes (once) a venv in target/dlib-venv with dlib-bin (dlib's wheels), face-recognition-models
# (the predictors' weights, in the package) and scikit-image (the photograph). Offline after that.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=target/dlib-venv
if ! "$VENV/bin/python" -c 'import dlib, face_recognition_models, skimage' 2>/dev/null; then
    echo "== making $VENV (dlib-bin, face-recognition-models, scikit-image)"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet --disable-pip-version-check \
        'dlib-bin==20.0.1.post1' 'face-recognition-models==0.3.0' 'scikit-image>=0.24,<0.27' setuptools
fi
"$VENV/bin/python" scripts/dlib_landmarks.py "${1:-tests/fixtures/detectors/dlib_astronaut.json}"
