#!/usr/bin/env bash
# The Python package as a user gets it, in a venv of its own: `pip install ./python` (the
# documented build: maturin from PyPI in pip's isolated build environment, the crates from
# crates.io as python/Cargo.lock pins them), then pytest on python/tests. CI runs it
# (.ci/run). Extra arguments go to pytest.
#
#   scripts/python-test.sh [PYTEST ARGS...]
#   scripts/python-test.sh --build-only       # the venv and the build, no tests
#   scripts/python-test.sh --no-build [ARGS]  # pytest on what --build-only installed
#
# CI starts `--build-only` in the background at its start, at the lowest priority, so that the
# build uses the cores the Rust build and tests leave idle, and runs `--no-build` at its end.
# - The venv: target/python-venv, made once (numpy and pytest from PyPI).
# - The build's cargo folder: target/python (CARGO_TARGET_DIR, when set, is kept).
# - The tests that compare with the CLI and the service take the binary from FACEPOSE_BIN,
#   else target/{release,debug}/facepose, else build it.
# - pytest's exit status is this script's: "no tests collected" is 5, a failure like any other;
#   3 means the venv could not be made (no Python venv module, or PyPI unreachable).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=target/python-venv
PIP=("$VENV/bin/pip" --quiet --disable-pip-version-check)
build=1 test=1
case "${1:-}" in
--build-only) test=0; shift ;;
--no-build) build=0; shift ;;
esac
if [ "$build" = 1 ]; then
    . scripts/lib/venv.sh
    venv_ensure --check 'import numpy, pytest' "$VENV" 'numpy>=1.21' 'pytest>=7' || {
        echo "cannot make $VENV (python3 -m venv, numpy and pytest from PyPI)" >&2
        exit 3
    }
    export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target/python}
    # .ci/run makes clippy-driver the compiler of the root workspace's crates; not of this build.
    unset RUSTC_WORKSPACE_WRAPPER CLIPPY_ARGS
    start=$(date +%s)
    echo "== pip install ./python (release build, cargo folder $CARGO_TARGET_DIR)" >&2
    "${PIP[@]}" install --force-reinstall --no-deps ./python
    echo "== built and installed in $(($(date +%s) - start)) s" >&2
fi
[ "$test" = 1 ] || exit 0
[ -x "$VENV/bin/python" ] || { echo "no $VENV: run scripts/python-test.sh --build-only" >&2; exit 3; }
echo "== pytest python/tests" >&2
rc=0
"$VENV/bin/python" -m pytest -q -p no:cacheprovider python/tests "$@" || rc=$?
# pytest's own 3 (an internal error) is a failure, not "could not run".
[ "$rc" = 3 ] && rc=1
exit "$rc"
