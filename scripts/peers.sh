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
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
VENV=target/peers-venv
venv_ensure --check 'import cv2, numpy' "$VENV" 'opencv-python-headless>=4.10,<6' 'numpy>=1.26,<3'
release_build
"$VENV/bin/python" scripts/peers.py "$BIN" "$DATA/aflw2000/aflw2000_dev.jsonl" \
    models/default/model.json "${1:-docs/results/peers.md}"
