#!/usr/bin/env bash
# Instructions the release server executes per request, under callgrind: the whole path in user
# space (hyper, axum, the middleware, the body reader, the estimate, the answer), a figure that
# moves far less with the machine's load than the load test's CPU times. The kernel's part (the
# loopback exchange) is not counted. What runs on a clock rather than per request (jemalloc's
# thread-cache sweeps, at most every 10 ms; the metrics' upkeep) is counted at callgrind's
# pace, about 50 times slower than native: a change to such work must be measured natively.
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

# count healthz|pose: sets COUNT, the instructions per request (run in this shell, not in a
# command substitution, so that the EXIT trap sees the server's PID).
count() {
    local port out deadline args path=/healthz
    port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    out="$WORK/callgrind.$1"
    valgrind --tool=callgrind --callgrind-out-file="$out" "$BIN" serve \
        --addr "127.0.0.1:$port" --log warn >"$WORK/server.log" 2>&1 &
    VPID=$!
    deadline=$((SECONDS + ${SERVER_READY_TIMEOUT:-120}))
    until curl -sf -o /dev/null "http://127.0.0.1:$port/readyz"; do
        kill -0 "$VPID" 2>/dev/null || { cat "$WORK/server.log" >&2; exit 1; }
        [ "$SECONDS" -lt "$deadline" ] || { echo "$1: the server was not ready in time" >&2; exit 1; }
        sleep 0.3
    done
    args=(--h1 -n "$N" -c 1)
    if [ "$1" = pose ]; then
        args+=(-d "$WORK/pose.json" -H 'content-type: application/json')
        path=/v1/pose
    fi
    h2load "${args[@]}" "http://127.0.0.1:$port$path" >"$WORK/h2load.txt"
    grep -q "status codes: $N 2xx" "$WORK/h2load.txt" ||
        { cat "$WORK/h2load.txt" >&2; echo "$1: not every request answered 2xx" >&2; exit 1; }
    kill -TERM "$VPID"; wait "$VPID" || true; VPID=""
    callgrind_annotate --inclusive=yes --threshold=99.99 "$out" >"$WORK/annotate.txt" 2>/dev/null
    COUNT=$(awk -v n="$N" '/multi_thread::worker::run \[/ && !done {gsub(",", "", $1); printf "%.0f\n", $1 / n; done = 1}' "$WORK/annotate.txt")
    [[ $COUNT =~ ^[0-9]+$ ]] || { echo "$1: no count for the runtime's worker loop in callgrind's output" >&2; exit 1; }
}

count healthz; H=$COUNT
count pose; P=$COUNT
printf '| request | instructions per request |\n|---|---|\n'
printf '| `GET /healthz` | %s |\n' "$H"
printf '| `POST /v1/pose` (68 points, `auto`) | %s |\n' "$P"
printf '| ratio | %s |\n' "$(python3 -c "print(f'{$P / $H:.2f}x')")"
