#!/usr/bin/env bash
# Instructions the release server executes per request, under callgrind: the whole path in user
# space (hyper, axum, the middleware, the body reader, the estimate, the answer), a figure that
# does not move with the machine's load, unlike the load test's CPU times. The kernel's part
# (the loopback exchange) is not counted.
#
#   scripts/server-instructions.sh                 # /healthz and a default-method pose, 2000 each
#   N=4000 scripts/server-instructions.sh
#   FACEPOSE_BIN=/tmp/old/facepose scripts/server-instructions.sh    # another build
#
# For each workload: `facepose serve` under `valgrind --tool=callgrind`, N requests one at a
# time on one keep-alive connection (h2load --h1 -c 1), then the server stopped; the figure is
# the inclusive count of the runtime's worker loop (`tokio::...::worker::run`, where every
# request is served; the start-up runs on the main thread and the blocking pool) divided by N.
# The pose body is the load test's first: AFLW2000-3D dev face 0, 68 re-annotated points, no
# method (`auto`). Installs valgrind and h2load if missing. Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."
N=${N:-2000}
FACES=${FACES:-dev}
need() { command -v "$1" >/dev/null 2>&1; }
if ! need valgrind || ! need h2load; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y valgrind nghttp2-client >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y valgrind nghttp2-client >/dev/null; }
fi
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
release_build --example loadgen
WORK=$(mktemp -d)
VPID=""
trap '[ -n "$VPID" ] && kill "$VPID" 2>/dev/null; rm -rf "$WORK"' EXIT
"$EXAMPLES/loadgen" bodies "$WORK/bodies" --scheme ibug68 --method default --batch 1 \
    --faces-from "$FACES" >/dev/null
head -n 1 "$WORK/bodies/poses.jsonl" >"$WORK/pose.json"

count() { # healthz | pose
    local port out
    port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    out="$WORK/callgrind.$1"
    valgrind --tool=callgrind --callgrind-out-file="$out" "$BIN" serve \
        --addr "127.0.0.1:$port" --log warn >"$WORK/server.log" 2>&1 &
    VPID=$!
    until curl -sf -o /dev/null "http://127.0.0.1:$port/readyz"; do
        kill -0 "$VPID" 2>/dev/null || { cat "$WORK/server.log" >&2; exit 1; }
        sleep 0.3
    done
    local args=(--h1 -n "$N" -c 1)
    [ "$1" = pose ] && args+=(-d "$WORK/pose.json" -H 'content-type: application/json')
    local path=/healthz
    [ "$1" = pose ] && path=/v1/pose
    h2load "${args[@]}" "http://127.0.0.1:$port$path" | grep -q "status codes: $N 2xx" ||
        { echo "$1: not every request answered 2xx" >&2; exit 1; }
    kill -INT "$VPID"; wait "$VPID" || true; VPID=""
    callgrind_annotate --inclusive=yes --threshold=99.99 "$out" 2>/dev/null |
        awk -v n="$N" '/multi_thread::worker::run \[/ && !done {gsub(",", "", $1); printf "%.0f\n", $1 / n; done = 1}'
}

H=$(count healthz)
P=$(count pose)
printf '| request | instructions per request |\n|---|---|\n'
printf '| `GET /healthz` | %s |\n' "$H"
printf '| `POST /v1/pose` (68 points, `auto`) | %s |\n' "$P"
printf '| ratio | %s |\n' "$(python3 -c "print(f'{$P / $H:.2f}x')")"
