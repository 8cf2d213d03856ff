#!/usr/bin/env bash
# The Python package's speed and accuracy on real faces: µs per face of a batch from Python
# (one thread, and every core) beside the Rust in-process figures (the same loop in Rust,
# python/examples/core_batch.rs, and criterion's real_faces bench: the same faces, the same
# machine, in the same run), and OpenCV's solvePnP (SQPnP, EPnP) called from Python on the same
# faces, with the MAE of each. What is measured: scripts/python_bench.py. Writes the tables to
# docs/results/python.md (scripts/results.sh puts them into docs/RESULTS.md).
#
#   scripts/python-bench.sh [--no-install]
#
# Makes (once) a venv in target/python-bench-venv with numpy and opencv-python-headless from
# PyPI, installs the package into it (`pip install ./python`: a release build; --no-install
# keeps the one there), runs the Rust bench (auto and fit on the three landmark sets), then the
# Python side. A few minutes. Needs the shared data (FACEPOSE_DATA, else ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${FACEPOSE_DATA:-../shared/data}
# Absolute: cargo bench runs in crates/core.
DATA=$(cd "$DATA" && pwd)
export FACEPOSE_DATA=$DATA
VENV=target/python-bench-venv
. scripts/lib/venv.sh
venv_ensure --check 'import cv2, numpy' "$VENV" 'opencv-python-headless>=4.10,<6' 'numpy>=1.26,<3'
# The package's cargo folder is scripts/python-test.sh's (CARGO_TARGET_DIR, if set, is kept).
PY_TARGET=${CARGO_TARGET_DIR:-$PWD/target/python}
if [ "${1:-}" != "--no-install" ] || ! "$VENV/bin/python" -c 'import facepose' 2>/dev/null; then
    echo "== pip install ./python" >&2
    CARGO_TARGET_DIR=$PY_TARGET \
        "$VENV/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps ./python
fi
out=target/python-bench-criterion.txt
echo "== cargo bench --bench real_faces (auto and fit; criterion's lines in $out)" >&2
cargo bench --locked -p facepose-core --bench real_faces -- '^real/(fitted|reannotated|five)/(auto|fit)$' \
    >"$out" 2>&1
core=target/python-bench-core.txt
echo "== the same batch loop in Rust (python/examples/core_batch.rs; in $core)" >&2
(cd python && CARGO_TARGET_DIR=$PY_TARGET PYO3_PYTHON="$PWD/../$VENV/bin/python" \
    cargo run --release --locked --quiet --example core_batch -- \
    "$DATA/aflw2000/aflw2000_dev.jsonl" 30) >"$core"
# The tables, also kept for scripts/results.sh (docs/RESULTS.md).
"$VENV/bin/python" scripts/python_bench.py "$out" "$core" "$DATA/aflw2000/aflw2000_dev.jsonl" |
    tee docs/results/python.md
