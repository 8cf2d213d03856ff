#!/usr/bin/env bash
# Load benchmark of `facepose serve` on this machine; writes docs/PERFORMANCE.md.
#
#   scripts/loadtest.sh                 # 10 s per run
#   DURATION=20 scripts/loadtest.sh     # longer runs
#
# Installs wrk and h2load (Debian nghttp2-client) if missing, builds the release binary and our
# gRPC stream load generator (crates/service/examples/loadgen.rs), starts the server on a free loopback port,
# and measures: time to ready, resident memory, /healthz, then for each workload (scheme:method)
# one pose (HTTP), a batch (HTTP) and its ceiling (the same work in one process, no network),
# gRPC unary (h2load with a pre-encoded frame) and gRPC streams
# (loadgen), and for the default method issue 38's ratio: RATIO_ROUNDS rounds of RATIO_SECONDS
# of /healthz then the pose, their server CPU compared, the median reported. Load generators run
# on the same machine and share its cores with the server.
# Faces: the AFLW2000-3D dev split's re-annotated landmarks (FACES=dev, needs the shared data:
# FACEPOSE_DATA, else ../shared/data), or FACES=synthetic (the default model's mean shape at
# random poses). The method `default` sends none: the server's default, `auto`.
# docs/performance-notes.md, if present, is appended (the analysis). Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

DURATION=${DURATION:-10}
CONNS=${CONNS:-16}
# Issue 38's ratio, a single default-method pose's server CPU against a /healthz request's:
# RATIO_ROUNDS rounds of RATIO_SECONDS of each in turn (the host's load drifts over a run; the
# median of rounds taken side by side moves less than one long run of each).
RATIO_ROUNDS=${RATIO_ROUNDS:-5}
RATIO_SECONDS=${RATIO_SECONDS:-4}
[[ $RATIO_ROUNDS =~ ^[0-9]+$ && $RATIO_SECONDS =~ ^[1-9][0-9]*$ ]] ||
    { echo "RATIO_ROUNDS (0: none) and RATIO_SECONDS are whole numbers" >&2; exit 2; }
# ibug68 is the main scheme (68 points, 2.5 kB of JSON a face) and the default method what a
# client gets without asking, so it goes first; then the rigid fit. five (what face detectors,
# RetinaFace or SCRFD, give) is one more workload away: WORKLOADS="ibug68:default ibug68:fit five:fit".
WORKLOADS=${WORKLOADS:-"ibug68:default ibug68:fit"}
FACES=${FACES:-dev}
BATCH=${BATCH:-1000}
OUT=${OUT:-docs/PERFORMANCE.md}
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/server.sh
. scripts/lib/server.sh
WORK=$(mktemp -d)
trap 'server_stop; rm -rf "$WORK"' EXIT

need() { command -v "$1" >/dev/null 2>&1; }
if ! need wrk || ! need h2load; then
    echo "== installing wrk and nghttp2-client (h2load)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
    $SUDO apt-get install -y wrk nghttp2-client >/dev/null 2>&1 ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y wrk nghttp2-client >/dev/null; }
fi

release_build --example loadgen
LOADGEN=$EXAMPLES/loadgen
for w in $WORKLOADS; do
    "$LOADGEN" bodies "$WORK/$w" --scheme "${w%%:*}" --method "${w##*:}" --batch "$BATCH" \
        --faces-from "$FACES" >/dev/null
done

LOAD_START=$(cut -d' ' -f1-3 /proc/loadavg)
# Polled every 2 ms: the time to ready is one of the figures.
SERVER_POLL=0.002 server_start - --log warn
RSS_IDLE_KB=$(awk '/^VmRSS/ {print $2}' "/proc/$PID/status")
echo "ready after ${READY_MS} ms, RSS ${RSS_IDLE_KB} kB"

# One body a request, cycling through the file's lines (one JSON body a line).
cat >"$WORK/post.lua" <<'LUA'
wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
local bodies = {}
for line in io.lines(os.getenv("BODY")) do
    if #line > 0 then bodies[#bodies + 1] = line end
end
local i = 0
request = function()
    i = i % #bodies + 1
    return wrk.format(nil, nil, nil, bodies[i])
end
LUA

cat >"$WORK/wrk.py" <<'PY'
import re, sys
t = open(sys.argv[1]).read()
def ms(label):
    m = re.search(r"^\s*%s\s+([\d.]+)(us|ms|s)\b" % label, t, re.M)
    v, u = float(m.group(1)), m.group(2)
    return v / 1000 if u == "us" else v * 1000 if u == "s" else v
rps = float(re.search(r"Requests/sec:\s+([\d.]+)", t).group(1))
bad = re.search(r"Non-2xx or 3xx responses: (\d+)", t)
print(f"{rps:.0f} {ms('50%'):.3f} {ms('99%'):.3f} {int(bad.group(1)) if bad else 0}")
PY

cat >"$WORK/h2.py" <<'PY'
import sys
d = sorted(int(l.split()[2]) for l in open(sys.argv[1]) if l.strip())
n = len(d)
print(f"{n / float(sys.argv[2]):.0f} {d[n // 2] / 1000:.3f} {d[int(n * 0.99)] / 1000:.3f} {n}")
PY

# The server's CPU time so far (user + system), in clock ticks.
server_ticks() { awk '{print $14 + $15}' "/proc/$PID/stat"; }

# wrk: prints "<req/s> <p50 ms> <p99 ms> <non-2xx> <server CPU µs per request> <wrk's CPU µs
# per request>" (wrk's user + system time, from bash's `time`).
run_wrk() { # conns path [body]; WRK_SECONDS (default DURATION) long
    local conns=$1 path=$2 body=${3:-} t0 t1 client seconds=${WRK_SECONDS:-$DURATION}
    local args=(-t1 -c"$conns" -d"${seconds}s" --latency)
    [ -n "$body" ] && args+=(-s "$WORK/post.lua")
    t0=$(server_ticks)
    client=$( { TIMEFORMAT='%U %S'; time BODY="$body" wrk "${args[@]}" "$BASE$path" >"$WORK/wrk.txt" 2>"$WORK/wrk.err"; } 2>&1 ) ||
        { cat "$WORK/wrk.err" >&2; exit 1; }
    t1=$(server_ticks)
    echo "$(python3 "$WORK/wrk.py" "$WORK/wrk.txt") $(python3 -c "
import re
rps = float(re.search(r'Requests/sec:\s+([\d.]+)', open('$WORK/wrk.txt').read()).group(1))
n = rps * $seconds
user, system = map(float, '$client'.split())
print(f'{($t1 - $t0) / $(getconf CLK_TCK) / n * 1e6:.1f} {(user + system) / n * 1e6:.1f}')")"
}

pass() { python3 -c "print('met' if $1 else 'NOT met')"; }

grpc_ok() {
    curl -s "$BASE/metrics" | awk '/^facepose_grpc_requests_total\{rpc="Estimate",code="OK"\}/ {print $2}' | head -1
}

echo "== wrk /healthz"
read -r H_RPS H_P50 H_P99 _ H_CPU H_WRK < <(run_wrk "$CONNS" /healthz)
TABLES=""
for w in $WORKLOADS; do
    SCHEME=${w%%:*}; METHOD=${w##*:}; D="$WORK/$w"
    # Targets: issue 19's for the default method, the earlier ones for the others.
    if [ "$METHOD" = default ]; then
        T_POSE=0.6; T_BATCH=150000; T_STREAM=120000
        TITLE="Scheme \`$SCHEME\`, the default method (\`auto\`: no method given)"
    else
        T_POSE=0.8; T_BATCH=200000; T_STREAM=100000
        TITLE="Scheme \`$SCHEME\`, method \`$METHOD\`"
    fi
    echo "== $w: wrk POST /v1/pose"
    read -r P_RPS P_P50 P_P99 P_BAD P_CPU P_WRK < <(run_wrk "$CONNS" /v1/pose "$D/poses.jsonl")
    RATIO_ROW=""
    if [ "$METHOD" = default ] && [ "$RATIO_ROUNDS" -gt 0 ]; then
        ROUND_RATIOS=""
        for r in $(seq "$RATIO_ROUNDS"); do
            echo "== $w: server CPU of a pose against /healthz, round $r of $RATIO_ROUNDS"
            # Odd rounds start with /healthz, even ones with the pose: no order favoured.
            for which in $( [ $((r % 2)) = 1 ] && echo "healthz pose" || echo "pose healthz"); do
                if [ "$which" = healthz ]; then
                    read -r _ _ _ _ RH_CPU _ < <(WRK_SECONDS=$RATIO_SECONDS run_wrk "$CONNS" /healthz)
                else
                    read -r _ _ _ R_BAD RP_CPU _ < <(WRK_SECONDS=$RATIO_SECONDS run_wrk "$CONNS" /v1/pose "$D/poses.jsonl")
                    [ "$R_BAD" = 0 ] || { echo "round $r: $R_BAD poses answered other than 2xx" >&2; exit 1; }
                fi
            done
            ROUND_RATIOS+="$(python3 -c "print(f'{$RP_CPU / $RH_CPU:.2f}')") "
        done
        read -r R_MEDIAN R_LIST < <(python3 -c "
import statistics
r = [float(x) for x in '$ROUND_RATIOS'.split()]
print(f'{statistics.median(r):.2f}', ', '.join(f'{x:.2f}' for x in r))")
        RATIO_ROW="| a pose's server CPU against a /healthz request's | wrk, $CONNS connections: /healthz and \`POST /v1/pose\` in turn, ${RATIO_SECONDS} s each, $RATIO_ROUNDS rounds | | **${R_MEDIAN}x**, the median (rounds: $R_LIST; the long runs above: $(python3 -c "print(f'{$P_CPU / $H_CPU:.2f}')")x) | | | | ≤ 2.5x: $(pass "$R_MEDIAN <= 2.5") |
"
    fi
    echo "== $w: wrk POST /v1/pose:batch ($BATCH faces)"
    read -r B_RPS B_P50 B_P99 B_BAD B_CPU _ < <(run_wrk 4 /v1/pose:batch "$D/batch.json")
    B_CPU=$(python3 -c "print(f'{$B_CPU / $BATCH:.2f}')")
    # The same body's work in one process, no network, right after: what bounds the batch.
    echo "== $w: loadgen ceiling ($BATCH faces)"
    CEIL_LINE=$("$LOADGEN" ceiling "$D/batch.json" --threads "$(nproc)" --duration "$DURATION")
    C_FPS=$(echo "$CEIL_LINE" | sed -E 's/.*: ([0-9]+) faces\/s.*/\1/')
    C_US=$(echo "$CEIL_LINE" | sed -E 's/.*, ([0-9.]+) µs.*/\1/')
    echo "== $w: h2load gRPC Estimate"
    OK0=$(grpc_ok); OK0=${OK0:-0}; rm -f "$WORK/h2.log"
    h2load -D "$DURATION" -c 4 -m 16 -t 1 \
        -H 'content-type: application/grpc' -H 'te: trailers' \
        -d "$D/estimate.grpc" --log-file "$WORK/h2.log" \
        "$BASE/facepose.v1.PoseService/Estimate" >"$WORK/h2.txt"
    OK1=$(grpc_ok); OK1=${OK1:-0}
    read -r G_RPS G_P50 G_P99 G_N < <(python3 "$WORK/h2.py" "$WORK/h2.log" "$DURATION")
    G_OK=$(( ${OK1%.*} - ${OK0%.*} ))
    # Streams with each landmark form: Landmark messages, then packed xy.
    STREAM_ROWS=""
    # And the WebSocket stream (GET /v1/pose:stream, JSON): target at least half of the gRPC
    # stream's poses/s (issue 40).
    for FORM in landmarks xy ws; do
        echo "== $w: loadgen stream ($FORM)"
        FLAG=""; [ "$FORM" = xy ] && FLAG=--packed; [ "$FORM" = ws ] && FLAG=--ws
        STREAM_LINE=$("$LOADGEN" stream --addr "$BASE" --streams 8 --faces 4 --window 8 \
            --duration "$DURATION" --scheme "$SCHEME" --method "$METHOD" --faces-from "$FACES" $FLAG)
        S_PPS=$(echo "$STREAM_LINE" | sed -E 's/.*: ([0-9]+) poses\/s.*/\1/')
        S_P50=$(echo "$STREAM_LINE" | sed -E 's/.*p50 ([0-9.]+) ms.*/\1/')
        S_P99=$(echo "$STREAM_LINE" | sed -E 's/.*p99 ([0-9.]+) ms.*/\1/')
        LABEL="\`Landmark\` messages"; [ "$FORM" = xy ] && LABEL="packed \`xy\`"
        if [ "$FORM" = ws ]; then
            HALF=$(( ${G_STREAM:-0} / 2 ))
            STREAM_ROWS+="| WebSocket \`GET /v1/pose:stream\`, JSON text | loadgen --ws, 8 streams, 4 faces/frame, 8 frames in flight | **$S_PPS poses/s** | | | $S_P50 ms / frame | $S_P99 ms / frame | ≥ half the gRPC stream's ($HALF poses/s): $(pass "$S_PPS >= $HALF") |
"
        else
            [ "$FORM" = landmarks ] && G_STREAM=$S_PPS
            STREAM_ROWS+="| gRPC \`EstimateStream\`, $LABEL | loadgen, 8 streams, 4 faces/frame, 8 frames in flight | **$S_PPS poses/s** | | | $S_P50 ms / frame | $S_P99 ms / frame | ≥ $((T_STREAM / 1000))k poses/s: $(pass "$S_PPS >= $T_STREAM") |
"
        fi
    done
    RATIO=$(python3 -c "print(f'{$P_RPS / $H_RPS * 100:.0f}')")
    # What one pose a request could reach at most: the pose run's CPU (server and wrk) spent
    # as if the server did for each request only what it does for /healthz plus the face's
    # own work (parse, estimate, write: the ceiling's time a face); and the face's work that
    # the target would allow on those terms.
    read -r BOUND NEEDED < <(python3 -c "
cpu = $P_RPS * ($P_CPU + $P_WRK)
bound = cpu / ($H_CPU + $C_US + $P_WRK)
print(f'{bound / $H_RPS * 100:.0f} {cpu / ($T_POSE * $H_RPS) - $H_CPU - $P_WRK:.1f}')")
    BATCH_PPS=$(python3 -c "print(f'{$B_RPS * $BATCH:.0f}')")
    TABLES+="
### $TITLE

| what | load | throughput | server CPU | wrk's CPU | p50 | p99 | target |
|---|---|---|---|---|---|---|---|
| \`POST /v1/pose\` | wrk, $CONNS connections | $P_RPS req/s (**${RATIO}%** of /healthz) | $P_CPU µs / request | $P_WRK µs / request | $P_P50 ms | $P_P99 ms | ≥ $(python3 -c "print(round($T_POSE * 100))")% of /healthz: $(pass "$P_RPS >= $T_POSE * $H_RPS") |
| one pose a request at most: the run's CPU if the server did /healthz's work plus the face's (the ceiling's $C_US µs) | computed | ${BOUND}% of /healthz | | | | | the target needs the face's work ≤ $NEEDED µs on these terms |
$RATIO_ROW| \`POST /v1/pose:batch\`, $BATCH faces | wrk, 4 connections | $B_RPS req/s = **$BATCH_PPS poses/s** | $B_CPU µs / pose | | $B_P50 ms | $B_P99 ms | ≥ $((T_BATCH / 1000))k poses/s: $(pass "$BATCH_PPS >= $T_BATCH") |
| the batch's ceiling: its work alone (\`http::answer_batch\`, no network, no server) | loadgen ceiling, $(nproc) threads | $C_FPS faces/s | $C_US µs / face | | | | the batch is at $(python3 -c "print(f'{$BATCH_PPS / $C_FPS * 100:.0f}')")% of it |
| gRPC \`Estimate\` | h2load, 4 connections × 16 streams | $G_RPS req/s ($G_OK OK, $G_N answered) | | | $G_P50 ms | $G_P99 ms | |
$STREAM_ROWS
Non-2xx HTTP responses: /v1/pose $P_BAD, batch $B_BAD.
"
done

if [ "$FACES" = dev ]; then
    FACES_TEXT="Faces: real ones, the AFLW2000-3D dev split's re-annotated 68 landmarks (the 491 faces with every
|angle| ≤ 99°, integer pixel coordinates; \`five\`: their anchors' means): \`POST /v1/pose\` cycles through them one
a request, a batch holds $BATCH of them in turn, each stream cycles through 256 of them; gRPC \`Estimate\` (h2load) sends
one face, the first, over and over."
else
    FACES_TEXT="Faces: the default model's mean shape at random poses (yaw ±60°, pitch ±25°, roll ±20°) with 1 px of
landmark noise, full-precision coordinates."
fi
RSS_KB=$(awk '/^VmRSS/ {print $2}' "/proc/$PID/status")
HWM_KB=$(awk '/^VmHWM/ {print $2}' "/proc/$PID/status")
kill -TERM "$PID"; wait "$PID" || true; PID=""
CPU=$(awk -F: '/model name/ {print $2; exit}' /proc/cpuinfo | sed 's/^ *//')

{
    cat <<DOC
# Performance

Measured by \`scripts/loadtest.sh\` (DURATION=$DURATION) on $(date -u +%Y-%m-%d): $(nproc) cores ($CPU),
$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 )) MiB, $(uname -sr). The load generators run on the same cores as the
server, and the machine is shared with other work that was not stopped (load average before the
server started: $LOAD_START; at the end: $(cut -d' ' -f1-3 /proc/loadavg)): figures move by ±30% between runs. $FACES_TEXT
Release build, default flags (\`facepose serve --log warn\`). "Server CPU" is the server
process's user + system time (\`/proc/PID/stat\`) over the run divided by the requests (or poses)
answered, "wrk's CPU" wrk's (bash's \`time\`); the kernel's work for the loopback connections
counts partly in one, partly in the other.

| what | load | throughput | server CPU | wrk's CPU | p50 | p99 | target |
|---|---|---|---|---|---|---|---|
| ready after start | \`facepose serve\` to the first 200 on /readyz | | | | ${READY_MS} ms | | ≤ 200 ms: $(pass "$READY_MS <= 200") |
| \`GET /healthz\` | wrk, $CONNS connections | $H_RPS req/s | $H_CPU µs / request | $H_WRK µs / request | $H_P50 ms | $H_P99 ms | |
| resident memory | after start / at the end / peak | | | | $((RSS_IDLE_KB / 1024)) MiB / $((RSS_KB / 1024)) MiB / $((HWM_KB / 1024)) MiB | | ≤ 64 MB: $(pass "$HWM_KB * 1024 <= 64000000") |
$TABLES
## Commands

\`\`\`sh
scripts/loadtest.sh      # DURATION=$DURATION CONNS=$CONNS BATCH=$BATCH WORKLOADS="$WORKLOADS" FACES=$FACES RATIO_ROUNDS=$RATIO_ROUNDS RATIO_SECONDS=$RATIO_SECONDS
# which runs, against target/release/facepose serve --addr 127.0.0.1:PORT --log warn:
wrk -t1 -c$CONNS -d${DURATION}s --latency http://127.0.0.1:PORT/healthz
wrk -t1 -c$CONNS -d${DURATION}s --latency -s post.lua http://127.0.0.1:PORT/v1/pose          # BODY=poses.jsonl, one body a request in turn
wrk -t1 -c4 -d${DURATION}s --latency -s post.lua http://127.0.0.1:PORT/v1/pose:batch         # BODY=batch.json
# for a workload of the default method, RATIO_ROUNDS rounds of the two in turn (odd rounds
# /healthz first), server CPU compared:
wrk -t1 -c$CONNS -d${RATIO_SECONDS}s --latency http://127.0.0.1:PORT/healthz
wrk -t1 -c$CONNS -d${RATIO_SECONDS}s --latency -s post.lua http://127.0.0.1:PORT/v1/pose
h2load -D $DURATION -c 4 -m 16 -t 1 -H 'content-type: application/grpc' -H 'te: trailers' \\
  -d estimate.grpc http://127.0.0.1:PORT/facepose.v1.PoseService/Estimate
target/release/examples/loadgen stream --addr http://127.0.0.1:PORT --streams 8 --faces 4 --window 8 \\
  --duration $DURATION --scheme SCHEME --method METHOD --faces-from $FACES [--packed | --ws]
target/release/examples/loadgen ceiling batch.json --threads $(nproc) --duration $DURATION   # right after the batch run
\`\`\`

The bodies come from \`target/release/examples/loadgen bodies DIR --scheme SCHEME --method METHOD --batch $BATCH --faces-from $FACES\`
(METHOD \`default\`: no method in the requests); the streams' faces from the same source.
DOC
    if [ -f docs/performance-notes.md ]; then echo; cat docs/performance-notes.md; fi
} >"$OUT"
echo "== wrote $OUT"
cat "$OUT"
