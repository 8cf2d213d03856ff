#!/usr/bin/env bash
# Rendered ground-truth benchmark (issue 37, item 1): textured 3D heads made from real photos
# shipped inside packages (scikit-image's astronaut; insightface's t1.jpg, one identity per
# face, and Tom_Hanks_54745.png), rendered at known poses by a numpy software renderer, with
# MediaPipe FaceMesh (478) and dlib (68, 5) run on every render. Writes the fixtures
# tests/fixtures/rendered/*.jsonl.gz + identities.json (landmarks, truth, detection failures; no
# images; format in tests/fixtures/rendered/README.md) and the contact sheet
# docs/rendered-benchmark.png, prints sanity checks (non-zero exit if one fails) and a report.
#
#   scripts/rendered-benchmark.sh [--quick] [--seed N] [other options of rendered_benchmark.py]
#   scripts/rendered-benchmark.sh --report-only     # the report again from the fixtures
#
# The full run takes about 10 minutes on 2 cores (one process, one thread per library).
#
# Makes (once) a venv in target/render-venv from PyPI: the pins of scripts/detector-landmarks.sh
# (mediapipe 0.10.14, numpy 1.26.4, opencv-contrib-python, dlib-bin, face-recognition-models,
# scikit-image). insightface is only downloaded (pip download --no-deps, a pure-Python wheel),
# never installed: its images are read out of the archive. Needs CPython 3.8-3.12 and the shared
# data (FACEPOSE_DATA, else ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${FACEPOSE_DATA:-../shared/data}
VENV=target/render-venv
. scripts/lib/venv.sh
venv_ensure --python "${PYTHON:-python3}" --requires-python 3.8-3.12 \
    --check 'import dlib, face_recognition_models, mediapipe, skimage' "$VENV" \
    'mediapipe==0.10.14' 'numpy==1.26.4' 'opencv-contrib-python==4.11.0.86' \
    'dlib-bin==20.0.1.post1' 'face-recognition-models==0.3.0' 'scikit-image>=0.24,<0.27' \
    setuptools
WHEELS=target/render-wheels
WHEEL=$(ls "$WHEELS"/insightface-*.whl 2>/dev/null | head -n1 || true)
if [ -z "$WHEEL" ]; then
    mkdir -p "$WHEELS"
    # 2.1 is the release this benchmark was made with (a wheel; its images are the same in
    # 0.7.x's sdist).
    "$VENV/bin/pip" download --quiet --disable-pip-version-check --no-deps --only-binary :all: \
        -d "$WHEELS" 'insightface==2.1'
    WHEEL=$(ls "$WHEELS"/insightface-*.whl | head -n1)
fi
# One thread per library: the machine is shared, and the run is sequential anyway.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONDONTWRITEBYTECODE=1
exec "$VENV/bin/python" scripts/rendered_benchmark.py --wheel "$WHEEL" --data "$DATA" "$@"
