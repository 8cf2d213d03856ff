#!/usr/bin/env bash
# Interleaved A/B of two `facepose` binaries on this machine: for ROUNDS rounds, each binary in
# turn serves on a free loopback port while h2load sends gRPC `Estimate` calls, wrk 1000-face
# batches and wrk single poses (the bodies of `loadgen bodies`, ibug68:fit), DURATION seconds
# each; then the server's peak resident size (VmHWM) and its resident size 2 s after the load
# (VmRSS: what the allocator gave back). Interleaving is what makes the comparison mean
# something on a machine whose speed moves by ±30% from minute to minute: compare within a round.
#
#   scripts/ab.sh OLD_BINARY NEW_BINARY        # e.g. a worktree's target/release/facepose
#   ROUNDS=3 DURATION=10 scripts/ab.sh A B
#
# Needs wrk and h2load (scripts/loadtest.sh installs them) and the release loadgen example
# (built here). Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -eq 2 ] || { echo "usage: scripts/ab.sh OLD_BINARY NEW_BINARY" >&2; exit 2; }
ROUNDS=${ROUNDS:-2}
DURATION=${DURATION:-8}
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/server.sh
. scripts/lib/server.sh
WORK=$(mktemp -d)
trap 'server_stop; rm -rf "$WORK"' EXIT
release_build --no-bin --example loadgen
"$EXAMPLES/loadgen" bodies "$WORK" --scheme ibug68 --method fit --batch 1000 >/dev/null
# One face a request: the first of loadgen's one-face bodies.
head -n 1 "$WORK/poses.jsonl" >"$WORK/pose.json"
cat >"$WORK/post.lua" <<'LUA'
wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
local f = io.open(os.getenv("BODY"), "rb"); wrk.body = f:read("*a"); f:close()
LUA
printf '| round | binary | gRPC Estimate req/s | batch req/s (x1000 poses) | pose req/s | peak RSS | RSS 2 s after |\n|---|---|---|---|---|---|---|\n'
for round in $(seq 1 "$ROUNDS"); do
    for which in 1 2; do
        BIN=$1; [ "$which" = 2 ] && BIN=$2
        server_start - --log warn
        G=$(h2load -D "$DURATION" -c 4 -m 16 -t 1 -H 'content-type: application/grpc' \
            -H 'te: trailers' -d "$WORK/estimate.grpc" \
            "http://127.0.0.1:$PORT/facepose.v1.PoseService/Estimate" | awk '/^finished in/ {print $4}')
        B=$(BODY="$WORK/batch.json" wrk -t1 -c4 -d"${DURATION}s" -s "$WORK/post.lua" \
            "http://127.0.0.1:$PORT/v1/pose:batch" | awk '/Requests\/sec/ {print $2}')
        P=$(BODY="$WORK/pose.json" wrk -t1 -c16 -d"${DURATION}s" -s "$WORK/post.lua" \
            "http://127.0.0.1:$PORT/v1/pose" | awk '/Requests\/sec/ {print $2}')
        sleep 2
        HWM=$(awk '/^VmHWM/ {printf "%.1f MiB", $2 / 1024}' "/proc/$PID/status")
        RSS=$(awk '/^VmRSS/ {printf "%.1f MiB", $2 / 1024}' "/proc/$PID/status")
        printf '| %s | `%s` | %s | %s | %s | %s | %s |\n' "$round" "$BIN" "$G" "$B" "$P" "$HWM" "$RSS"
        server_stop
    done
done
