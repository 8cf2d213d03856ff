# shellcheck shell=bash
# Sourced helper (from the repository's root, as every script `cd`s there first): the release
# build of facepose, done once.
#
#   . scripts/lib/release.sh
#   release_build                          # target/release/facepose; sets BIN
#   release_build --example loadgen        # that example too; sets BIN and EXAMPLES
#   release_build --no-bin --example instructions   # the example alone (BIN left as it was)
#
# - `cargo build --release --locked --bin facepose [--example NAME]...`, its last line (or its
#   errors) on stderr, after "== building (release)": stdout stays the script's own output.
# - FACEPOSE_BIN set: that binary is used as it is (nothing built for it; examples still are).
#   After a build FACEPOSE_BIN is exported with the binary's absolute path, so that the scripts
#   and Python programs this one starts (results.sh -> peers.sh, abuse.sh -> abuse.py) use it
#   and do not build again.
# - CARGO_TARGET_DIR is honoured (default target/).
# Sets BIN (the facepose binary), RELEASE_DIR (<target>/release) and EXAMPLES
# (<target>/release/examples). Safe under `set -euo pipefail`: a failed build exits the script
# with cargo's status (its errors printed).

# release_build [--no-bin] [--example NAME]...
# shellcheck disable=SC2120 # called without arguments too: they are options, not the script's
release_build() {
  local want_bin=1 args=() log rc
  while [ $# -gt 0 ]; do
    case "$1" in
    --no-bin) want_bin=0 ;;
    --example) args+=(--example "${2:?release_build: --example NAME}"); shift ;;
    *) echo "release_build: unknown argument $1" >&2; return 2 ;;
    esac
    shift
  done
  RELEASE_DIR=${CARGO_TARGET_DIR:-target}/release
  # shellcheck disable=SC2034 # for the caller
  EXAMPLES=$RELEASE_DIR/examples
  if [ "$want_bin" = 1 ]; then
    if [ -n "${FACEPOSE_BIN:-}" ]; then
      BIN=$FACEPOSE_BIN
    else
      args=(--bin facepose "${args[@]}")
      BIN=$RELEASE_DIR/facepose
    fi
  fi
  if [ ${#args[@]} -gt 0 ]; then
    echo "== building (release: ${args[*]})" >&2
    log=$(mktemp)
    rc=0
    cargo build --release --locked "${args[@]}" >"$log" 2>&1 || rc=$?
    if [ "$rc" != 0 ]; then
      cat "$log" >&2
      rm -f "$log"
      echo "release_build: cargo build --release failed (exit $rc)" >&2
      exit "$rc"
    fi
    tail -1 "$log" >&2
    rm -f "$log"
  fi
  if [ "$want_bin" = 1 ]; then
    [ -x "$BIN" ] || { echo "release_build: no binary at $BIN" >&2; exit 1; }
    FACEPOSE_BIN=$(cd "$(dirname "$BIN")" && pwd)/$(basename "$BIN")
    export FACEPOSE_BIN
  fi
}
