#!/usr/bin/env bash
# facepose on what real detectors found on real photographs (tests/fixtures/detectors/, made by
# scripts/detector-landmarks.sh): MediaPipe's Face Mesh against dlib on the same faces, the
# consistency of each under transforms of the photograph whose pose change is known, and
# MediaPipe's own facial transformation matrix beside them. Writes docs/results/detectors.md
# (scripts/results.sh puts it into docs/RESULTS.md) and prints it. What is measured and how:
# scripts/detector_report.py. Needs python3 (standard library only); builds the release binary.
#
#   scripts/detector-report.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
release_build
python3 scripts/detector_report.py "$BIN" tests/fixtures/detectors \
    "${1:-docs/results/detectors.md}"
