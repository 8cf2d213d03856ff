#!/usr/bin/env bash
# Instructions per call of the per-face work (crates/service/examples/instructions.rs) under callgrind: a
# measure that does not move with the machine's load, unlike criterion's times.
#
#   scripts/instructions.sh            # every entry, 1000 calls each
#   CALLS=200 scripts/instructions.sh fit fit-shape
#   CALLS=982 scripts/instructions.sh estimate-auto-dev-fitted estimate-auto-dev-reannotated
#
# Installs valgrind if missing. Each count is (total of CALLS calls - total of no call of the same
# entry) / CALLS, so the model loading and the entry's setup are left out. The `…-dev-…` entries
# estimate the 491 AFLW2000-3D dev faces in turn: give them a multiple of 491 calls. Not part of
# CI.
set -euo pipefail
cd "$(dirname "$0")/.."
CALLS=${CALLS:-1000}
ENTRIES=("$@")
[ ${#ENTRIES[@]} -eq 0 ] && ENTRIES=(fit fit-shape estimate-fit estimate-auto estimate-regression parse-pose-body estimate-face-fit grpc-decode-landmarks grpc-decode-xy)
if ! command -v valgrind >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y valgrind >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y valgrind >/dev/null; }
fi
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
release_build --no-bin --example instructions
BIN=$EXAMPLES/instructions
OUT=$(mktemp)
trap 'rm -f "$OUT"' EXIT
count() {
    valgrind --tool=callgrind --callgrind-out-file="$OUT" "$BIN" "$1" "$2" 2>&1 |
        awk '/Collected/ {print $4}'
}
printf '| entry | instructions per call |\n|---|---|\n'
for e in "${ENTRIES[@]}"; do
    base=$(count "$e" 0)
    total=$(count "$e" "$CALLS")
    printf '| `%s` | %s |\n' "$e" "$(( (total - base) / CALLS ))"
done
