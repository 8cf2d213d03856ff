#!/usr/bin/env bash
# Abuse test of `facepose serve` (scripts/abuse.py: amplification, slowloris, idle connections,
# long strings, over HTTP and gRPC) with /healthz latency and RSS watched; prints a Markdown
# table and exits non-zero when a target is missed.
#
#   scripts/abuse.sh                          # every case, 20 s each (40 s for c and d)
#   ABUSE_CASES="a b1" scripts/abuse.sh       # some cases (baseline a b1 b2 c d d2 e)
#   ABUSE_SECONDS=10 ABUSE_LONG_SECONDS=35 ABUSE_NICE=10 scripts/abuse.sh
#
# Builds the release binary and makes a venv under target/abuse-venv with the h2 package (the
# HTTP/2 framing of the gRPC cases; the gRPC messages themselves are built by hand). Reads real
# faces from ../shared/data (AFLW2000-3D). The script starts and stops its own servers. Not
# part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== building (release)"
cargo build --release --locked --bin facepose 2>&1 | tail -1

VENV=target/abuse-venv
if ! "$VENV/bin/python" -c 'import h2' 2>/dev/null; then
    echo "== making $VENV (h2)"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet 'h2>=4,<5'
fi
# The attackers hold thousands of sockets.
ulimit -n "$(ulimit -Hn)"
exec "$VENV/bin/python" scripts/abuse.py "$@"
