#!/usr/bin/env bash
# CPU time per call of the per-face work (crates/service/examples/instructions.rs), to compare two
# builds on this shared machine: each figure is (task-clock of CALLS calls - task-clock of no call)
# / CALLS under `perf stat`, the median of ROUNDS runs. CPU time, not wall time, so waiting for
# the CPU does not count (other tenants' cache and frequency effects still do: compare builds in
# turn, in one session).
#
#   scripts/cputime.sh estimate-auto-dev-fitted estimate-auto-dev-reannotated
#   BIN=/tmp/old-instructions scripts/cputime.sh estimate-auto-dev-reannotated   # another build
#
# Installs perf (linux-perf) if missing. The `…-dev-…` entries estimate the 491 AFLW2000-3D dev
# faces in turn: give them a multiple of 491 calls. Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."
CALLS=${CALLS:-19640}
ROUNDS=${ROUNDS:-5}
ENTRIES=("$@")
[ ${#ENTRIES[@]} -eq 0 ] && ENTRIES=(estimate-auto-dev-fitted estimate-auto-dev-reannotated)
if ! command -v perf >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y linux-perf >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y linux-perf >/dev/null; }
fi
if [ -z "${BIN:-}" ]; then
    # shellcheck source=scripts/lib/release.sh
    . scripts/lib/release.sh
    release_build --no-bin --example instructions
    BIN=$EXAMPLES/instructions
fi
# Milliseconds of task-clock for one run.
ms() { perf stat -x, -e task-clock "$BIN" "$1" "$2" 2>&1 >/dev/null | awk -F, '/task-clock/ {print $1}'; }
printf '| entry | ns of CPU per call (median of %s) |\n|---|---|\n' "$ROUNDS"
for e in "${ENTRIES[@]}"; do
    med=$(for _ in $(seq "$ROUNDS"); do
        base=$(ms "$e" 0)
        total=$(ms "$e" "$CALLS")
        awk -v t="$total" -v b="$base" -v n="$CALLS" 'BEGIN {printf "%d\n", (t - b) * 1e6 / n}'
    done | sort -n | awk '{v[NR] = $1} END {print v[int((NR + 1) / 2)]}')
    printf '| `%s` | %s |\n' "$e" "$med"
done
