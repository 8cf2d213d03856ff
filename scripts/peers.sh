#!/usr/bin/env bash
# facepose beside OpenCV's solvePnP (SQPnP, EPnP, ITERATIVE) with a generic 3D face (the served
# model's mean shape) on the AFLW2000-3D dev faces, in one run: µs per estimate and MAE per
# angle, with the camera as tutorials set it up (focal length = image width) and with a long
# focal length (near orthographic). Writes docs/results/peers.md (scripts/results.sh puts it
# into docs/RESULTS.md) and prints it. What is measured and how: scripts/peers.py.
#
#   scripts/peers.sh [OUT]
#
# Makes (once) a venv in target/peers-venv with opencv-python-headless and numpy from PyPI;
# builds the release binary. About a minute. Needs the shared data (FACEPOSE_DATA, else
# ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${FACEPOSE_DATA:-../shared/data}
VENV=target/peers-venv
if ! "$VENV/bin/python" -c 'import cv2, numpy' 2>/dev/null; then
    echo "== making $VENV (opencv-python-headless, numpy)" >&2
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet --disable-pip-version-check \
        'opencv-python-headless>=4.10,<6' 'numpy>=1.26,<3'
fi
echo "== building (release)" >&2
cargo build --release --locked --quiet --bin facepose
"$VENV/bin/python" scripts/peers.py target/release/facepose "$DATA/aflw2000/aflw2000_dev.jsonl" \
    models/default/model.json "${1:-docs/results/peers.md}"
