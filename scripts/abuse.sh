#!/usr/bin/env bash
# Abuse test of `facepose serve` (scripts/abuse.py: amplification, slowloris, idle connections,
# long strings, over HTTP and gRPC; huge frames, thousands of streams, slow readers and frames
# after close over the WebSocket) with /healthz latency and RSS watched; prints a Markdown
# table and exits non-zero when a target is missed.
#
#   scripts/abuse.sh                          # every case, 20 s each (40 s for c and d)
#   ABUSE_CASES="a b1" scripts/abuse.sh       # some cases (baseline a b1 b2 c d d2 e w1 w2 w3 w4)
#   ABUSE_SECONDS=10 ABUSE_LONG_SECONDS=35 ABUSE_NICE=10 scripts/abuse.sh
#
# Builds the release binary and makes a venv under target/abuse-venv with the h2 package (the
# HTTP/2 framing of the gRPC cases; the gRPC messages themselves are built by hand). Reads real
# faces from ../shared/data (AFLW2000-3D). The script starts and stops its own servers. Not
# part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

# The release binary (exported as FACEPOSE_BIN, which the Python side runs) and the venv
# with the h2 package, which frames the gRPC calls.
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
release_build
VENV=target/abuse-venv
venv_ensure --check 'import h2' "$VENV" 'h2>=4,<5'
# The attackers hold thousands of sockets.
ulimit -n "$(ulimit -Hn)"
exec "$VENV/bin/python" scripts/abuse.py "$@"
