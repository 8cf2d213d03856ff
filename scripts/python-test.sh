#!/usr/bin/env bash
# The Python package in a venv of its own, then pytest on python/tests. Extra arguments go to
# pytest.
#
#   scripts/python-test.sh [PYTEST ARGS...]   # as a user gets it: `pip install ./python`
#   scripts/python-test.sh --build-only       # the venv and that build, no tests
#   scripts/python-test.sh --no-build [ARGS]  # pytest on what --build-only installed
#   scripts/python-test.sh --test-build [ARGS]  # pytest on the workspace's test build (CI)
#   scripts/python-test.sh --setup-only       # only the venv (CI, early)
#
# - `pip install ./python` is the documented build: maturin from PyPI in pip's isolated build
#   environment, the workspace's release profile, the crates as Cargo.lock pins them.
# - --test-build builds the extension in the test profile as CI's build does (`cargo build
#   --profile test --all-targets`: after CI's build, nothing is new; `-p facepose-python` alone
#   would resolve the dependencies' features for that crate only, and build serde, nalgebra and
#   the core a second time), the same sources on the crates the workspace's tests already use,
#   instead of a second, release build of the core (about 150 s of CPU). The package's Python files and ${CARGO_TARGET_DIR:-target}/debug/
#   lib_facepose.so are laid out in target/python-test-build/facepose, which goes first on
#   PYTHONPATH. CI runs this (.ci/run); a release build's tests are this script without an
#   option.
# - The venv: target/python-venv, made once (numpy and pytest from PyPI).
# - The release build's cargo folder: target/python (CARGO_TARGET_DIR, when set, is kept).
# - The tests that compare with the CLI and the service take the binary from FACEPOSE_BIN,
#   else target/{release,debug}/facepose, else build it.
# - pytest's exit status is this script's: "no tests collected" is 5, a failure like any other;
#   3 means the venv could not be made (no Python venv module, or PyPI unreachable).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=target/python-venv
PIP=("$VENV/bin/pip" --quiet --disable-pip-version-check)
build=1 test=1 test_build=0 setup=0
case "${1:-}" in
--setup-only) build=0 test=0 setup=1; shift ;;
--build-only) test=0; shift ;;
--no-build) build=0; shift ;;
--test-build) build=0 test_build=1; shift ;;
esac
if [ "$build" = 1 ] || [ "$test_build" = 1 ] || [ "$setup" = 1 ]; then
    . scripts/lib/venv.sh
    venv_ensure --check 'import numpy, pytest' "$VENV" 'numpy>=1.21' 'pytest>=7' || {
        echo "cannot make $VENV (python3 -m venv, numpy and pytest from PyPI)" >&2
        exit 3
    }
fi
if [ "$test_build" = 1 ]; then
    # `cargo test` builds the library only as a test harness; the extension is a target of the
    # workspace's build of every target (CI's build: with its clippy-driver, when it set one).
    echo "== cargo build --profile test --all-targets (the extension among them)" >&2
    cargo build --locked --quiet --profile test --all-targets
    so=${CARGO_TARGET_DIR:-target}/debug/lib_facepose.so
    pkg=target/python-test-build
    rm -rf "$pkg"
    mkdir -p "$pkg/facepose"
    cp python/facepose/__init__.py python/facepose/_facepose.pyi python/facepose/py.typed "$pkg/facepose/"
    cp "$so" "$pkg/facepose/_facepose.abi3.so"
    export PYTHONPATH=$PWD/$pkg${PYTHONPATH:+:$PYTHONPATH}
    echo "== the package from the test build ($so), in $pkg" >&2
fi
if [ "$build" = 1 ]; then
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
