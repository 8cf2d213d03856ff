#!/usr/bin/env bash
# Soak test of `facepose serve` (scripts/soak.py): real faces over HTTP (wrk) and gRPC for
# DURATION seconds, with a retraining upload and an activation every CYCLE seconds; reports the
# requests, the failed ones and the server's RSS growth, and exits non-zero when a target
# (0 failed, RSS growth <= 10%) is missed.
#
#   scripts/soak.sh                     # 600 s (after a 20 s warm-up)
#   DURATION=60 scripts/soak.sh         # a short run
#   DURATION=600 HTTP_CONNS=8 GRPC_CALLERS=2 CYCLE=60 WARMUP=20 scripts/soak.sh
#
# Installs wrk if missing, builds the release binary and makes a venv under target/abuse-venv
# with the h2 package (HTTP/2 framing of the gRPC calls; the messages are built by hand). Reads
# real faces and 3D shapes from ../shared/data. Starts and stops its own server. Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v wrk >/dev/null 2>&1; then
    echo "== installing wrk"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y wrk >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y wrk >/dev/null; }
fi

# The release binary (exported as FACEPOSE_BIN, which the Python side runs) and the venv
# with the h2 package, which frames the gRPC calls.
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
release_build
VENV=target/abuse-venv
venv_ensure --check 'import h2' "$VENV" 'h2>=4,<5'
exec "$VENV/bin/python" scripts/soak.py "$@"
