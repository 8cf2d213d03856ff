#!/usr/bin/env bash
# Tests deploy/compose/ (three facepose replicas behind HAProxy, one models volume) through the
# balancer, under load and failures, and prints the figures (docs/DEPLOY.md, "What the failure
# tests showed"):
#
#   scripts/compose-test.sh      # as root, or a user of the docker group; about 3 minutes
#
# Phases, each bounded by `timeout` (the whole under 8 minutes once the images exist):
#  1. the images, made if missing (scripts/images.sh, scripts/lb-image.sh), a venv with requests
#     and grpcio (scripts/lib/venv.sh), and Python stubs of proto/facepose/v1/pose.proto;
#  2. `docker-compose up` on its own project, ports and admin token (a file in a private
#     folder), all set in an env file given with --env-file (nothing exported: the same
#     `docker-compose --env-file` line works by hand while it runs), and HAProxy showing the
#     three replicas UP;
#  3. every replica runs read-only as uid 10001 (docker inspect, docker top);
#  4. gRPC calls from one channel spread over the three replicas (each replica's /metrics,
#     scraped at its address on the compose network);
#  5. a retrain uploaded through the balancer reaches every replica; its job answers from each;
#  6. under steady HTTP and gRPC load: a rolling restart of every replica, stop (the drain's
#     exit status 0) then start (0 failures expected);
#  7. under load: `docker kill` of one replica (failures counted, the others carry on);
#  8. under load: `docker network disconnect` of one replica (the time until HAProxy marks it
#     DOWN, then reconnected and UP again);
#  9. WebSocket streams through the balancer (scripts/compose_ws.py): a stream silent for 15 s
#     stays open (HAProxy's `timeout tunnel`); 6 streams of a rendered head trajectory at 30
#     frames a second, smoothed, while one replica is killed (`docker kill`), then again while
#     one is restarted (`docker-compose restart`: SIGTERM, the drain, start): the closes the
#     clients see, their reconnection through the balancer to a live replica, the fresh track;
# 10. under load: connection ageing (every replica asks the connections HAProxy keeps to it to
#     close, again and again, within a bound derived from the configured age and grace).
# Every request and every failure is counted and printed with its reason. Cleanup (trap): the
# load driver stopped, `docker-compose down -v`, the token removed. Exit 0 with a SKIP line
# when no Docker engine answers or docker-compose is missing. A passing run writes its figures
# into the generated block "compose-test" of docs/DEPLOY.md (COMPOSE_TEST_DOC=0: not).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
compose_file=$repo/deploy/compose/compose.yaml
project=${COMPOSE_TEST_PROJECT:-faceposetest}
# Not the compose file's defaults (8080, 8404), so that a running setup is left alone.
lb_port=${COMPOSE_TEST_PORT:-18080}
stats_port=${COMPOSE_TEST_STATS_PORT:-18404}
http_rate=${COMPOSE_TEST_HTTP_RATE:-150}
grpc_rate=${COMPOSE_TEST_GRPC_RATE:-150}
population=${FACEPOSE_DATA:-../shared/data}/bfm68/population_249.json
venv=target/compose-venv
out=target/compose-test
t_all=$(date +%s)
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# shellcheck source=scripts/lib/docblock.sh
. scripts/lib/docblock.sh

say() { echo "compose-test: $*"; }
fail() {
  echo "compose-test: FAIL: $*" >&2
  failed=1
}
failed=0

if ! timeout 10 docker info >/dev/null 2>&1; then
  say "SKIP: no Docker engine answers (docker info)"
  exit 0
fi
if ! command -v docker-compose >/dev/null; then
  say "SKIP: no docker-compose command"
  exit 0
fi

# ---- cleanup: whatever runs is stopped, the project removed with its volume, the token gone.
tokdir=
load_pid=
dc=()
cleanup() {
  if [ -n "$load_pid" ]; then kill "$load_pid" 2>/dev/null || true; fi
  if [ -n "$tokdir" ]; then
    timeout 60 "${dc[@]}" down -v --remove-orphans >/dev/null 2>&1 || true
    rm -rf "$tokdir"
  fi
}
trap cleanup EXIT

# ---- 1. images, venv, stubs.
say "phase 1: images, venv"
if ! docker image inspect facepose:dev >/dev/null 2>&1; then
  # A cold build: 15 minutes on 2 free cores, over 30 on 2 cores shared with other builds (the
  # 30-minute bound this had cut a first run short at the last crate: docs/DEPLOY.md).
  say "facepose:dev missing: scripts/images.sh (15 to 40 minutes the first time)"
  timeout "${COMPOSE_TEST_IMAGES_TIMEOUT:-3600}" scripts/images.sh
fi
timeout 600 scripts/lb-image.sh
t_images=$(($(date +%s) - t_all))
mkdir -p "$out"
: >"$out/figures.tsv"
figure() { printf '%s\t%s\n' "$1" "$2" >>"$out/figures.tsv"; }
VENV_TIMEOUT=300 venv_ensure --check 'import grpc, grpc_tools, requests, websockets' "$venv" \
  requests grpcio grpcio-tools 'websockets==15.0.1'
rm -rf "$venv/stubs" && mkdir -p "$venv/stubs"
"$venv/bin/python" -m grpc_tools.protoc -Iproto --python_out="$venv/stubs" \
  --grpc_python_out="$venv/stubs" proto/facepose/v1/pose.proto
export FACEPOSE_STUBS=$repo/$venv/stubs FACEPOSE_LB=127.0.0.1:$lb_port \
  FACEPOSE_LB_STATS=127.0.0.1:$stats_port
py=("$venv/bin/python" scripts/compose_load.py)
wspy=("$venv/bin/python" scripts/compose_ws.py)

# ---- 2. up. The token: a private folder (0700), the file readable by the container's uid.
# The compose file's variables go into an env file beside it, given with --env-file: nothing
# is exported, and variables of the caller's environment that would override the file are
# unset for docker-compose (a deployment's own FACEPOSE_PUBLISH must not leak into the test).
say "phase 2: docker-compose up (project $project, 127.0.0.1:$lb_port, stats :$stats_port)"
tokdir=$(mktemp -d)
(umask 022 && openssl rand -hex 32 >"$tokdir/token")
# Phases 2-9 run with the compose file's connection ages (5m, grace 30s). Phase 10 recreates
# the replicas with ages short enough to happen several times in it. Not the short ages from
# the start: at 8 s with a 4 s grace, a call held by the network cut of phase 8 outlived its
# connection's age and grace, and the replica cut the connection under the answer it had just
# begun (HAProxy's log: SD--, a 200 already forwarded, so not retryable; the gRPC client:
# "Stream removed"): the cut's failures were the ageing's, not the cut's.
max_age=${FACEPOSE_MAX_CONNECTION_AGE:-8s}
age_grace=${FACEPOSE_MAX_CONNECTION_AGE_GRACE:-4s}
cat >"$tokdir/compose.env" <<ENV
FACEPOSE_ADMIN_TOKEN_FILE=$tokdir/token
FACEPOSE_PUBLISH=127.0.0.1:$lb_port
FACEPOSE_LB_STATS=127.0.0.1:$stats_port
ENV
dc=(env -u FACEPOSE_ADMIN_TOKEN_FILE -u FACEPOSE_PUBLISH -u FACEPOSE_LB_STATS
  -u FACEPOSE_MAX_CONNECTION_AGE -u FACEPOSE_MAX_CONNECTION_AGE_GRACE
  docker-compose --env-file "$tokdir/compose.env" -p "$project" -f "$compose_file")
say "  (by hand meanwhile: docker-compose --env-file $tokdir/compose.env -p $project -f $compose_file ps)"
t=$(date +%s.%N)
timeout 120 "${dc[@]}" up -d 2>&1 | grep -v '\.\.\. *$' | sed 's/^/  /'
net=${project}_backend
cid_of() { "${dc[@]}" ps -q "$1"; }
replicas=(facepose-1 facepose-2 facepose-3)
wait_up() { # every replica UP in HAProxy, within $1 s
  local deadline=$(($(date +%s) + $1)) s
  while :; do
    s=$(curl -s --max-time 2 "http://127.0.0.1:$stats_port/stats;csv" |
      awk -F, '$1 == "replicas" && $2 ~ /^facepose-/ && $18 ~ /^UP/' | wc -l)
    [ "$s" = 3 ] && return 0
    [ "$(date +%s)" -ge "$deadline" ] && return 1
    sleep 0.2
  done
}
wait_up 60 || { fail "the replicas are not all UP in HAProxy after 60 s"; exit 1; }
t_up=$(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
say "all 3 replicas UP in HAProxy $t_up s after up -d"
figure '`docker-compose up -d` to every replica UP in HAProxy' "$t_up s"
addrs=
for r in "${replicas[@]}"; do
  ip=$(docker inspect -f "{{(index .NetworkSettings.Networks \"$net\").IPAddress}}" "$(cid_of "$r")")
  addrs="${addrs:+$addrs,}$r=$ip"
done
say "replicas on $net: $addrs"

# ---- 3. read-only, non-root.
say "phase 3: docker inspect"
for r in "${replicas[@]}"; do
  c=$(cid_of "$r")
  got=$(docker inspect -f '{{.Config.User}} ro={{.HostConfig.ReadonlyRootfs}} caps={{.HostConfig.CapDrop}}' "$c")
  uids=$(docker top "$c" -o pid,uid | awk 'NR > 1 { print $2 }' | sort -u | paste -sd ' ')
  say "  $r: user $got, process uids $uids"
  case "$got $uids" in
    "10001:10001 ro=true "*" 10001") ;;
    *) fail "$r is not read-only as 10001: $got, uids $uids" ;;
  esac
done

# ---- 4. gRPC spread from one channel.
say "phase 4: 300 gRPC calls on one channel"
spread=$(timeout 60 "${py[@]}" spread --replicas "$addrs" --calls 300)
say "  $spread"
echo "$spread" | jq -e .ok >/dev/null || fail "gRPC calls of one channel not spread over 3 replicas"
figure '300 gRPC calls on one channel, per replica (`/metrics`)' \
  "$(echo "$spread" | jq -r '[.metrics_delta[] | tostring] | join(", ")'), $(echo "$spread" | jq .failed) failed"

# ---- 5. retrain through the balancer.
if [ -f "$population" ]; then
  say "phase 5: retrain through the balancer (40 shapes of $(basename "$population"))"
  rt=$(timeout 120 "${py[@]}" retrain --replicas "$addrs" --token-file "$tokdir/token" \
    --population "$population")
  say "  $rt"
  echo "$rt" | jq -e .ok >/dev/null || fail "the retrained version did not reach every replica"
  figure 'retrain through the balancer (40 shapes, coarse grid): upload to job `succeeded`' \
    "$(echo "$rt" | jq .upload_to_succeeded_s) s"
  figure 'retrain: the new version served by each replica, after the job' \
    "$(echo "$rt" | jq -r '[.served_after_s | to_entries[] | "\(.key) \(.value) s"] | join(", ")')"
else
  say "phase 5: SKIP ($population absent: no shapes to upload)"
fi

# ---- load in the background until a stop file appears.
load_start() {
  rm -f "$out/stop"
  "${py[@]}" load --stop-file "$out/stop" --http-rate "$http_rate" --grpc-rate "$grpc_rate" \
    --max-seconds 200 >"$out/$1.json" &
  load_pid=$!
  sleep 3 # steady before the event
}
lb_retries() { # HAProxy's retry and redispatch counters of the backend, since it started
  curl -s --max-time 2 "http://127.0.0.1:$stats_port/stats;csv" |
    awk -F, '$1 == "replicas" && $2 == "BACKEND" { printf "retries %s, redispatches %s", $16, $17 }'
}
load_stop() { # prints the summary, fails the test when $2 (the most failures allowed) is passed
  sleep "${3:-3}"
  touch "$out/stop"
  if ! timeout 60 tail --pid="$load_pid" -f /dev/null; then
    kill "$load_pid" 2>/dev/null || true # stuck: it must not go on loading after the phase
    wait "$load_pid" 2>/dev/null || true
  fi
  load_pid=
  local j=$out/$1.json
  say "  load: $(jq -c '{seconds, rate_per_s, http: (.http | del(.fail_times)), grpc: (.grpc | del(.fail_times))}' "$j")"
  local start nf
  start=$(jq .start "$j")
  nf=$(jq '.http.failed + .grpc.failed' "$j")
  if [ "$nf" -gt 0 ]; then
    say "  failures at (s after the load started): $(jq -c --argjson s "$start" \
      '[.http.fail_times[], .grpc.fail_times[]] | map(. - $s | . * 10 | round / 10) | sort' "$j")"
  fi
  say "  HAProxy so far: $(lb_retries)"
  [ "$nf" -le "$2" ] || fail "$1: $nf failed requests (at most $2 expected)"
}
load_text() { # one line for docs/DEPLOY.md: requests, failures with their reasons, slowness
  jq -r '"\(.http.sent + .grpc.sent) requests (\(.http.sent) HTTP, \(.grpc.sent) gRPC) in \(.seconds) s, **\(.http.failed + .grpc.failed) failed**" +
    (if .http.failed + .grpc.failed > 0 then " (" + ([(.http.reasons | to_entries[] | "HTTP \(.key) ×\(.value)"), (.grpc.reasons | to_entries[] | "gRPC \(.key) ×\(.value)")] | join(", ")) + ")" else "" end) +
    "; slowest \([.http.slowest_s, .grpc.slowest_s] | max) s, \(.http.over_1s + .grpc.over_1s) over 1 s"' "$out/$1.json"
}

# ---- 6. rolling restart under load.
say "phase 6: rolling restart under load ($http_rate HTTP + $grpc_rate gRPC req/s)"
load_start rolling
health() { docker inspect -f '{{.State.Health.Status}}' "$(cid_of "$1")"; }
t0=$(date +%s.%N)
stops='' codes='' backs=''
drain_ms() { # from "signal received" to "stopped" in the replica's last log lines (JSON)
  docker logs --tail 20 "$1" 2>&1 | "$venv/bin/python" -c '
import json, sys, datetime
t = {}
for line in sys.stdin:
    try:
        j = json.loads(line)
    except ValueError:
        continue
    m = j.get("fields", {}).get("message")
    if m in ("signal received", "stopped"):
        t[m] = datetime.datetime.fromisoformat(j["timestamp"][:26].rstrip("Z"))
print("%.1f" % ((t["stopped"] - t["signal received"]).total_seconds() * 1000)
      if len(t) == 2 else "?")'
}
for r in "${replicas[@]}"; do
  # docker-compose stop (SIGTERM: readiness 503, the listener closed, the drain; exit 0 when
  # the drain completed, 3 when its cap cut it), then start; the next replica only once this
  # one is healthy again (Docker's check of /readyz) and UP in HAProxy.
  t=$(date +%s.%N)
  c=$(cid_of "$r")
  timeout 60 "${dc[@]}" stop -t 20 "$r" >/dev/null 2>&1
  d=$(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  code=$(docker inspect -f '{{.State.ExitCode}}' "$c")
  [ "$code" = 0 ] || fail "$r exited $code after docker-compose stop (0: a complete drain)"
  dms=$(drain_ms "$c")
  timeout 60 "${dc[@]}" start "$r" >/dev/null 2>&1
  deadline=$(($(date +%s) + 60))
  until [ "$(health "$r")" = healthy ]; do
    [ "$(date +%s)" -ge "$deadline" ] && { fail "$r not healthy within 60 s"; break; }
    sleep 0.2
  done
  wait_up 60 || fail "$r not UP again within 60 s"
  back=$(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  say "  $r: docker-compose stop $d s (exit $code, drain $dms ms), start; healthy and UP in HAProxy $back s after it began"
  stops="$stops $d" codes="$codes $code" backs="$backs $back"
done
say "  rolling restart of 3 replicas: $(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s"
load_stop rolling 0
figure 'rolling restart under load (stop, start, healthy and UP, each replica in turn)' \
  "$(load_text rolling); stops ${stops# } s, exit statuses ${codes# }, back UP ${backs# } s after each stop began"

# ---- 7. docker kill under load.
say "phase 7: docker kill facepose-2 under load"
load_start kill
k=$(timeout 30 "${py[@]}" watch --server facepose-2 --state DOWN --timeout 20 -- docker kill "$(cid_of facepose-2)")
say "  $k"
load_stop kill 8 5
# The others carried on: each answered after the kill.
jq -e '.http.servers["facepose-1"] > 0 and .http.servers["facepose-3"] > 0' "$out/kill.json" >/dev/null ||
  fail "the other replicas did not carry on"
figure '`docker kill` of one replica under load' \
  "$(load_text kill); DOWN in HAProxy $(echo "$k" | jq .after_s) s after the kill"
state=$(docker inspect -f '{{.State.Status}} restarts={{.RestartCount}}' "$(cid_of facepose-2)")
say "  facepose-2 after the kill: $state"
timeout 60 "${dc[@]}" start facepose-2 >/dev/null 2>&1
wait_up 60 || fail "facepose-2 not UP again within 60 s of docker-compose start"

# ---- 8. network cut under load.
say "phase 8: docker network disconnect facepose-3 under load"
load_start netcut
c3=$(cid_of facepose-3)
n=$(timeout 30 "${py[@]}" watch --server facepose-3 --state DOWN --timeout 20 -- docker network disconnect "$net" "$c3")
say "  cut: $n"
echo "$n" | jq -e .ok >/dev/null || fail "HAProxy did not mark facepose-3 DOWN within 20 s"
sleep 3
u=$(timeout 40 "${py[@]}" watch --server facepose-3 --state UP --timeout 30 -- docker network connect --alias facepose-3 "$net" "$c3")
say "  reconnected: $u"
echo "$u" | jq -e .ok >/dev/null || fail "facepose-3 not UP within 30 s of its reconnection"
load_stop netcut 8
figure '`docker network disconnect` of one replica under load, then `connect`' \
  "$(load_text netcut); DOWN in HAProxy $(echo "$n" | jq .after_s) s after the cut, UP $(echo "$u" | jq .after_s) s after the reconnection"

# ---- 9. WebSocket streams through the balancer (HAProxy's backend `streams`: HTTP/1.1 to the
# replicas, `timeout tunnel`, leastconn). Before the ageing phase: its short ages would cut
# the streams under the test.
say "phase 9: WebSocket streams through the balancer"
q=$(timeout 60 "${wspy[@]}" quiet --seconds 15) || true
[ -n "$q" ] || q='{"ok": false, "problems": ["compose_ws.py quiet printed nothing"]}'
say "  silent stream: $q"
echo "$q" | jq -e .ok >/dev/null ||
  fail "a WebSocket stream silent for 15 s was cut by the balancer: $(echo "$q" | jq -r '.problems | join("; ")')"
figure 'a WebSocket stream silent for 15 s (past `timeout server`, 12 s) through the balancer' \
  "$(echo "$q" | jq -r 'if .ok then "still open: the frame after the silence answered on the same connection (\(.served_by))" else "cut: \(.problems | join("; "))" end')"
ws_streams() { # NAME VICTIM CODE COMMAND...: 6 streams while COMMAND hits VICTIM; the figure
  local name=$1 victim=$2 code=$3 w
  shift 3
  w=$(timeout 120 "${wspy[@]}" streams --victim "$victim" --expect-code "$code" -- "$@") || true
  [ -n "$w" ] || w='{"ok": false, "problems": ["compose_ws.py printed nothing"]}'
  echo "$w" >"$out/ws-$name.json"
  say "  $(echo "$w" | jq -c 'del(.per_stream, .problems, .ok)')"
  echo "$w" | jq -c '.per_stream[]? | select(.close)' | sed 's/^/    reconnected: /'
  if ! echo "$w" | jq -e .ok >/dev/null; then
    fail "WebSocket streams across $name of $victim: $(echo "$w" | jq -r '.problems | join("; ")')"
    return 0
  fi
  figure "WebSocket streams across \`$name\` of one replica (6 streams, 30 frames/s each, Kalman smoothing)" \
    "$(echo "$w" | jq -r 'def r(x): if x.min == x.max then "\(x.min)" else "\(x.min)–\(x.max)" end;
      [.per_stream[] | select(.close)] as $re |
      "\(.streams) streams (\([.spread[] | tostring] | join("/")) over the replicas; \(.connections) connections opened in all), \(.on_victim) on \(.victim); before: \(.before.sent) frames sent, \(.before.answered) answered, all smoothed; " +
      "those \(.on_victim) saw \([.close_codes | to_entries[] | "\(.key) ×\(.value)"] | join(", ")) (\(.close_reasons | join("; "))) \(r(.close_after_action_s)) s after the command began, the others nothing; " +
      "reconnected through the balancer to \([$re[] | .served_by[-1]] | unique | join(", ")) \(r(.reconnect_s)) s after the close (first answer \(r(.first_answer_after_close_s)) s; \(.failed_handshakes) handshakes refused); " +
      "lost: \(.unanswered_on_closed) frames unanswered on the closed connections, \(.skipped_while_reconnecting) not sent while reconnecting; " +
      "\(.answers_after_reconnect) answers after, on a fresh track (its first answer is the raw estimate: Δ \([$re[] | .first_answer_vs_raw_deg] | max)°; the old track gave answers up to \([$re[] | .old_answers_vs_raw_max_deg] | min)–\([$re[] | .old_answers_vs_raw_max_deg] | max)° from theirs)"')"
}
say "  docker kill facepose-1 with 6 streams open"
ws_streams 'docker kill' facepose-1 1006 docker kill "$(cid_of facepose-1)"
timeout 60 "${dc[@]}" start facepose-1 >/dev/null 2>&1
wait_up 60 || fail "facepose-1 not UP again within 60 s of docker-compose start"
say "  docker-compose restart facepose-2 with 6 streams open"
ws_streams 'docker-compose restart' facepose-2 1001 "${dc[@]}" restart -t 20 facepose-2
wait_up 60 || fail "facepose-2 not UP again within 60 s of docker-compose restart"

# ---- 10. connection ageing under load: the replicas ask HAProxy's connections to close after
# about FACEPOSE_MAX_CONNECTION_AGE (GOAWAY); HAProxy opens new ones; no request may fail.
say "phase 10: connection ageing under load (age $max_age, grace $age_grace)"
printf 'FACEPOSE_MAX_CONNECTION_AGE=%s\nFACEPOSE_MAX_CONNECTION_AGE_GRACE=%s\n' "$max_age" "$age_grace" \
  >>"$tokdir/compose.env"
t=$(date +%s.%N)
timeout 120 "${dc[@]}" up -d "${replicas[@]}" 2>&1 | grep -v '\.\.\. *$' | sed 's/^/  /'
# Reached at their new addresses: until HAProxy's DNS resolution follows (hold valid 1s), the
# old containers' entries may still show UP. So wait for UP, then until requests through the
# balancer (12 at a time) are answered by each of the three (x-served-by), 60 s at most.
wait_served() { # every replica answers through the balancer within $1 s
  local deadline=$(($(date +%s) + $1)) seen
  while :; do
    seen=$(for _ in $(seq 12); do
      curl -s --max-time 2 -o /dev/null -D - "http://127.0.0.1:$lb_port/readyz" |
        tr -d '\r' | awk -F': ' 'tolower($1) == "x-served-by" { print $2 }'
    done | sort -u | paste -sd ' ')
    [ "$seen" = "${replicas[*]}" ] && return 0
    [ "$(date +%s)" -ge "$deadline" ] && return 1
    sleep 0.2
  done
}
if ! wait_up 60 || ! wait_served 60; then
  fail "the replicas recreated with the short ages do not all answer through the balancer within 60 s"
fi
say "  replicas recreated with the short ages; all UP in HAProxy $(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s after up -d"
seconds_of() { # a duration as the service reads it (500ms, 8s, 5m, 1h) in seconds
  python3 -c 'import re, sys
m = re.fullmatch(r"\s*([0-9.]+)\s*(ms|s|m|h)?\s*", sys.argv[1])
print(float(m.group(1)) * {"ms": 0.001, "s": 1, None: 1, "m": 60, "h": 3600}[m.group(2)])' "$1"
}
# What the test waits for, from the configuration rather than a fixed window. A replica asks a
# connection to close (GOAWAY; facepose_connections_aged_total counts it) once the connection
# is past its own age: the configured age spread by ±10% with the client's port, checked once
# a second. Its calls then get the grace; HAProxy opens the next connection at the latest when
# the replica cuts the old one (at once if it stops using the old one on the GOAWAY). So a
# replica under load ages one of HAProxy's connections at least every
#   period = 1.1 × age + 1 s (the check's tick) + grace + 1 s (HAProxy connecting anew)
# and, from any moment, twice within 2 × period. The old check counted a fixed 20 s at an age of
# 8 s and wanted 2: up to 2 × 14.8 s may be needed, so it failed whenever a replica's
# connection had been opened shortly before the window (a race, 1 run of 2).
age_s=$(seconds_of "$max_age")
grace_s=$(seconds_of "$age_grace")
period=$(awk -v a="$age_s" -v g="$grace_s" 'BEGIN { printf "%.1f", 1.1 * a + 1 + g + 1 }')
bound=$(awk -v p="$period" 'BEGIN { printf "%.1f", 2 * p }')
lb_connects() { # HAProxy's connection attempts to the replicas so far (the "connect" column)
  curl -s --max-time 2 "http://127.0.0.1:$stats_port/stats;csv" | awk -F, '
    NR == 1 { for (i = 1; i <= NF; i++) if ($i == "connect") c = i; next }
    $1 == "replicas" && $2 == "BACKEND" { print $c }'
}
# Each replica's address, looked up again (one reconnected in phase 8 or restarted in phase 9
# may have another).
declare -A ip_of
for r in "${replicas[@]}"; do
  ip_of[$r]=$(docker inspect -f "{{(index .NetworkSettings.Networks \"$net\").IPAddress}}" "$(cid_of "$r")")
done
aged_of() { # facepose_connections_aged_total of replica $1, scraped at its own address
  curl -s --max-time 2 "http://${ip_of[$1]}:8080/metrics" |
    awk '$1 == "facepose_connections_aged_total" { n = $2 } END { print n + 0 }'
}
load_start ageing
# A WebSocket stream through the ageing, past one age and grace (period + 5 s): once upgraded,
# the connection is the stream's and the replica no longer ages it (only the drain and the
# stream's own bounds end it).
long_s=$(awk -v p="$period" 'BEGIN { printf "%d", p + 5 }')
timeout $((long_s + 30)) "${wspy[@]}" long --seconds "$long_s" >"$out/ws-long.json" &
ws_pid=$!
declare -A a_before a_now times
c_before=$(lb_connects)
for r in "${replicas[@]}"; do a_before[$r]=$(aged_of "$r"); a_now[$r]=${a_before[$r]}; times[$r]=; done
t_age=$(date +%s.%N)
# Polled every second until each replica has aged 2 connections since the load was steady, or
# the bound has passed; each increase is stamped (to the second) for the intervals below.
while :; do
  sleep 1
  t=$(awk -v a="$t_age" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  done_all=1
  for r in "${replicas[@]}"; do
    n=$(aged_of "$r")
    if [ "$n" -gt "${a_now[$r]}" ]; then times[$r]="${times[$r]} $t"; a_now[$r]=$n; fi
    [ "$((a_now[$r] - a_before[$r]))" -ge 2 ] || done_all=0
  done
  [ "$done_all" = 1 ] && break
  awk -v t="$t" -v b="$bound" 'BEGIN { exit !(t > b) }' && break
done
c_after=$(lb_connects)
load_stop ageing 0 0
say "  bound: 2 ageings per replica within 2 × (1.1 × $age_s + 1 + $grace_s + 1) = $bound s"
ageing_text=
for r in "${replicas[@]}"; do
  d=$((a_now[$r] - a_before[$r]))
  say "  $r: ${a_before[$r]} -> ${a_now[$r]} connections aged; increases seen at${times[$r]:- (none)} s"
  [ "$d" -ge 2 ] ||
    fail "$r aged ${a_before[$r]} -> ${a_now[$r]} connections in $t s (at least 2 expected within $bound s at an age of $max_age, grace $age_grace)"
  ageing_text="$ageing_text, $r at${times[$r]} s"
done
say "  HAProxy's connections to the replicas: $c_before, then $c_after"
wait "$ws_pid" || true
l=$(cat "$out/ws-long.json")
[ -n "$l" ] || l='{"ok": false, "problems": ["compose_ws.py long printed nothing"]}'
say "  WebSocket stream meanwhile: $l"
echo "$l" | jq -e .ok >/dev/null ||
  fail "a WebSocket stream through the connection ageing: $(echo "$l" | jq -r '.problems | join("; ")')"
figure "connection ageing under load (age $max_age, grace $age_grace): every replica ages 2 of HAProxy's connections" \
  "$(load_text ageing); done $t s after the load was steady (bound $bound s); ageings seen${ageing_text#,}; HAProxy opened $((c_after - c_before)) connections; $(echo "$l" | jq -r '"a WebSocket stream meanwhile: \(.seconds) s, \(.answered) of \(.sent) frames answered on one connection, closed \(.close[0]) by the client"')"

say "the balancer's log (server state changes, requests not ended normally; last 40 lines):"
"${dc[@]}" logs --no-color lb 2>/dev/null | grep -v '\[WARNING\]' | sed 's/^lb_1 *| /  /' | tail -40 || true
t_total=$(($(date +%s) - t_all))
say "done in $t_total s"
if [ "$failed" != 0 ]; then
  say "FAIL"
  exit 1
fi
if [ "$t_images" -gt 30 ]; then
  figure '`scripts/compose-test.sh`, whole run' "$t_total s, of which $t_images s making the images"
else
  figure '`scripts/compose-test.sh`, whole run (images already built)' "$t_total s"
fi
if [ "${COMPOSE_TEST_DOC:-1}" != 0 ]; then
  doc_rows docs/DEPLOY.md compose-test scripts/compose-test.sh <"$out/figures.tsv"
fi
say "OK"
