#!/usr/bin/env bash
# Tests deploy/compose/ (three facepose replicas behind HAProxy, one models volume) through the
# balancer, under load and failures, and prints the figures (docs/DEPLOY.md, "What the failure
# tests showed"):
#
#   scripts/compose-test.sh      # as root, or a user of the docker group; about 1 minute
#
# Phases, each bounded by `timeout` (the whole under 8 minutes):
#  1. the images, made if missing (scripts/images.sh, scripts/lb-image.sh), a venv with requests
#     and grpcio, and Python stubs of proto/facepose/v1/pose.proto;
#  2. `docker-compose up` on its own project, ports and admin token (a file in a private
#     folder), and HAProxy showing the three replicas UP;
#  3. every replica runs read-only as uid 10001 (docker inspect, docker top);
#  4. gRPC calls from one channel spread over the three replicas (each replica's /metrics,
#     scraped at its address on the compose network);
#  5. a retrain uploaded through the balancer reaches every replica; its job answers from each;
#  6. under steady HTTP and gRPC load: a rolling restart of every replica, stop (the drain's
#     exit status 0) then start (0 failures expected);
#  7. under load: `docker kill` of one replica (failures counted, the others carry on);
#  8. under load: `docker network disconnect` of one replica (the time until HAProxy marks it
#     DOWN, then reconnected and UP again).
# Every request and every failure is counted and printed with its reason. Cleanup (trap): the
# load driver stopped, `docker-compose down -v`, the token removed. Exit 0 with a SKIP line
# when no Docker engine answers or docker-compose is missing.
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
cleanup() {
  [ -n "$load_pid" ] && kill "$load_pid" 2>/dev/null || true
  if [ -n "$tokdir" ]; then
    timeout 60 docker-compose -p "$project" -f "$compose_file" down -v --remove-orphans \
      >/dev/null 2>&1 || true
    rm -rf "$tokdir"
  fi
}
trap cleanup EXIT

# ---- 1. images, venv, stubs.
say "phase 1: images, venv"
if ! docker image inspect facepose:dev >/dev/null 2>&1; then
  say "facepose:dev missing: scripts/images.sh (several minutes)"
  timeout 1800 scripts/images.sh
fi
timeout 600 scripts/lb-image.sh
mkdir -p "$out"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import grpc, grpc_tools, requests' 2>/dev/null; then
  timeout 300 python3 -m venv "$venv"
  timeout 300 "$venv/bin/pip" install -q requests grpcio grpcio-tools
fi
rm -rf "$venv/stubs" && mkdir -p "$venv/stubs"
"$venv/bin/python" -m grpc_tools.protoc -Iproto --python_out="$venv/stubs" \
  --grpc_python_out="$venv/stubs" proto/facepose/v1/pose.proto
export FACEPOSE_STUBS=$repo/$venv/stubs FACEPOSE_LB=127.0.0.1:$lb_port \
  FACEPOSE_LB_STATS=127.0.0.1:$stats_port
py=("$venv/bin/python" scripts/compose_load.py)

# ---- 2. up. The token: a private folder (0700), the file readable by the container's uid.
say "phase 2: docker-compose up (project $project, 127.0.0.1:$lb_port, stats :$stats_port)"
tokdir=$(mktemp -d)
(umask 022 && openssl rand -hex 32 >"$tokdir/token")
export FACEPOSE_ADMIN_TOKEN_FILE=$tokdir/token FACEPOSE_PUBLISH=127.0.0.1:$lb_port \
  FACEPOSE_LB_STATS=127.0.0.1:$stats_port
# Connection ageing short enough to happen several times during the test (phase 9).
export FACEPOSE_MAX_CONNECTION_AGE=${FACEPOSE_MAX_CONNECTION_AGE:-8s} \
  FACEPOSE_MAX_CONNECTION_AGE_GRACE=${FACEPOSE_MAX_CONNECTION_AGE_GRACE:-4s}
dc=(docker-compose -p "$project" -f "$compose_file")
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
say "all 3 replicas UP in HAProxy $(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s after up -d"
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

# ---- 5. retrain through the balancer.
if [ -f "$population" ]; then
  say "phase 5: retrain through the balancer (40 shapes of $(basename "$population"))"
  rt=$(timeout 120 "${py[@]}" retrain --replicas "$addrs" --token-file "$tokdir/token" \
    --population "$population")
  say "  $rt"
  echo "$rt" | jq -e .ok >/dev/null || fail "the retrained version did not reach every replica"
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

# ---- 6. rolling restart under load.
say "phase 6: rolling restart under load ($http_rate HTTP + $grpc_rate gRPC req/s)"
load_start rolling
health() { docker inspect -f '{{.State.Health.Status}}' "$(cid_of "$1")"; }
t0=$(date +%s.%N)
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
  say "  $r: docker-compose stop $d s (exit $code, drain $dms ms), start; healthy and UP in HAProxy $(awk -v a="$t" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s after it began"
done
say "  rolling restart of 3 replicas: $(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s"
load_stop rolling 0

# ---- 7. docker kill under load.
say "phase 7: docker kill facepose-2 under load"
load_start kill
k=$(timeout 30 "${py[@]}" watch --server facepose-2 --state DOWN --timeout 20 -- docker kill "$(cid_of facepose-2)")
say "  $k"
load_stop kill 8 5
# The others carried on: each answered after the kill.
jq -e '.http.servers["facepose-1"] > 0 and .http.servers["facepose-3"] > 0' "$out/kill.json" >/dev/null ||
  fail "the other replicas did not carry on"
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

# ---- 9. connection ageing under load: the replicas ask HAProxy's connections to close after
# about FACEPOSE_MAX_CONNECTION_AGE (GOAWAY); HAProxy opens new ones; no request may fail.
lb_connects() { # HAProxy's connection attempts to the replicas so far (the "connect" column)
  curl -s --max-time 2 "http://127.0.0.1:$stats_port/stats;csv" | awk -F, '
    NR == 1 { for (i = 1; i <= NF; i++) if ($i == "connect") c = i; next }
    $1 == "replicas" && $2 == "BACKEND" { print $c }'
}
say "phase 9: connection ageing under load (age $FACEPOSE_MAX_CONNECTION_AGE, grace $FACEPOSE_MAX_CONNECTION_AGE_GRACE)"
aged_total() { # facepose_connections_aged_total of each replica, scraped at its own address
  # (looked up again: a replica reconnected in phase 8 may have another)
  local r ip out=
  for r in "${replicas[@]}"; do
    ip=$(docker inspect -f "{{(index .NetworkSettings.Networks \"$net\").IPAddress}}" "$(cid_of "$r")")
    out="$out $r=$(curl -s --max-time 2 "http://$ip:8080/metrics" |
      awk '$1 == "facepose_connections_aged_total" { n = $2 } END { print n + 0 }')"
  done
  echo "${out# }"
}
# Counted from once the load is steady (load_start waits 3 s). 20 s at an age of 8 s (±10%):
# every replica asks each connection HAProxy keeps to it to close at least twice; HAProxy's
# own count of the connections it opened shows them replaced.
load_start ageing
a_before=$(aged_total)
c_before=$(lb_connects)
sleep 20
a_after=$(aged_total)
c_after=$(lb_connects)
load_stop ageing 0 0
say "  connections aged by each replica (facepose_connections_aged_total): $a_before when the load was steady, $a_after 20 s later"
say "  HAProxy's connections to the replicas: $c_before, then $c_after"
for r in "${replicas[@]}"; do
  b=$(echo "$a_before" | tr ' ' '\n' | sed -n "s/^$r=//p")
  a=$(echo "$a_after" | tr ' ' '\n' | sed -n "s/^$r=//p")
  [ -n "$a" ] && [ -n "$b" ] && [ "$((a - b))" -ge 2 ] ||
    fail "$r aged ${b:-?} -> ${a:-?} connections in 20 s (at least 2 expected at an age of $FACEPOSE_MAX_CONNECTION_AGE)"
done

say "the balancer's log (server state changes, requests not ended normally; last 40 lines):"
"${dc[@]}" logs --no-color lb 2>/dev/null | grep -v '\[WARNING\]' | sed 's/^lb_1 *| /  /' | tail -40 || true
say "done in $(($(date +%s) - t_all)) s"
if [ "$failed" != 0 ]; then
  say "FAIL"
  exit 1
fi
say "OK"
