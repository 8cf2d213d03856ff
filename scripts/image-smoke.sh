#!/usr/bin/env bash
# Smoke test of a facepose image (default facepose:dev, built by scripts/images.sh or
# `docker build -t facepose:dev .`), as a locked-down deployment runs it:
#
#   scripts/image-smoke.sh [IMAGE]
#
# - runs it with a read-only root, as uid 10001, with a tmpfs on the models folder (the only
#   place it writes: retrained versions and job records), its port published on 127.0.0.1 only;
# - waits for Docker's health status (the image's HEALTHCHECK, `facepose healthcheck`) to be
#   `healthy`;
# - sends one pose request over HTTP: the README's five-point face, symmetric about x = 321, so
#   yaw and roll near 0 (within 3 degrees: the model's mean shape is not exactly symmetric); and, if the shared data is here, one AFLW2000-3D face against its ground
#   truth;
# - checks that every process of the container runs as uid 10001;
# - stops it with `docker stop` (SIGTERM) and checks that it exited 0 within the grace period.
# Bounded: 60 s for health, 5 s per request, 20 s grace. Exit 0 (with a SKIP line) when no Docker
# engine answers.
set -euo pipefail
cd "$(dirname "$0")/.."
image=${1:-facepose:dev}
grace=20
health_limit=60
data=${FACEPOSE_DATA:-../shared/data}/aflw2000/aflw2000_dev.jsonl

if ! timeout 10 docker info >/dev/null 2>&1; then
  echo "image-smoke: SKIP: no Docker engine answers (docker info)"
  exit 0
fi
docker image inspect "$image" >/dev/null 2>&1 || {
  echo "image-smoke: FAIL: no image $image (scripts/images.sh builds facepose:dev)" >&2
  exit 1
}

fail() {
  echo "image-smoke: FAIL: $*" >&2
  echo "--- container logs (last 30 lines)" >&2
  docker logs --tail 30 "$cid" >&2 2>&1 || true
  exit 1
}
# A name of its own, so that the trap removes the container even when `docker run` created it
# but could not start it (and printed no id).
name=facepose-smoke-$$
cid=
cleanup() { docker rm -f "$name" >/dev/null 2>&1 || true; }
trap cleanup EXIT

t0=$(date +%s.%N)
cid=$(docker run -d --name "$name" --read-only --user 10001 \
  --tmpfs /var/lib/facepose/models:rw,uid=10001,gid=10001,mode=0755,size=64m \
  --stop-timeout "$grace" -p 127.0.0.1::8080 "$image")
port=$(docker port "$cid" 8080/tcp | sed -n 's/^127\.0\.0\.1:\([0-9]*\)$/\1/p' | head -1)
[ -n "$port" ] || fail "no port published on 127.0.0.1"
echo "image-smoke: $image as ${cid:0:12} on 127.0.0.1:$port (--read-only --user 10001," \
  "tmpfs on the models folder)"

# Health: starting -> healthy (the first check runs one interval after the start).
status=
while :; do
  status=$(docker inspect -f '{{.State.Status}} {{if .State.Health}}{{.State.Health.Status}}{{else}}none{{end}}' "$cid")
  case "$status" in
    "running healthy") break ;;
    "running starting") ;;
    *) fail "state: $status" ;;
  esac
  awk -v a="$t0" -v b="$(date +%s.%N)" -v l="$health_limit" 'BEGIN { exit !(b - a > l) }' &&
    fail "not healthy after ${health_limit} s (state: $status)"
  sleep 0.2
done
t_healthy=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
check_out=$(docker inspect -f '{{range .State.Health.Log}}{{.ExitCode}} {{.Output}}{{end}}' "$cid" | head -1)
echo "image-smoke: healthy after $t_healthy s (docker run to health status healthy); check said: $check_out"

# One pose request: the README's five points, symmetric about x = 321.
answer=$(curl -sS --max-time 5 -H 'content-type: application/json' \
  -d '{"landmarks": [[301, 240], [341, 240], [321, 265], [305, 290], [337, 290]], "scheme": "five"}' \
  "http://127.0.0.1:$port/v1/pose") || fail "POST /v1/pose failed"
echo "image-smoke: POST /v1/pose (README five points) -> $(echo "$answer" | jq -c '{yaw, pitch, roll, method, scheme, model, model_version}')"
echo "$answer" | jq -e '(.yaw | fabs) < 3 and (.roll | fabs) < 3 and (.pitch | isnormal or . == 0)
  and .method == "fit" and .scheme == "five" and .model == "default" and .model_version == "1"' \
  >/dev/null || fail "unexpected answer: $answer"

# One real face with its ground truth, when the shared data is here.
if [ -f "$data" ]; then
  face=$(sed -n 1p "$data")
  req=$(echo "$face" | jq -c '{landmarks: .landmarks_fitted, scheme: "ibug68"}')
  got=$(curl -sS --max-time 5 -H 'content-type: application/json' -d "$req" \
    "http://127.0.0.1:$port/v1/pose") || fail "POST /v1/pose (AFLW face) failed"
  echo "image-smoke: AFLW2000-3D $(echo "$face" | jq -r .image): truth" \
    "$(echo "$face" | jq -c '{yaw, pitch, roll}'), answer $(echo "$got" | jq -c '{yaw, pitch, roll}')"
  jq -n --argjson t "$face" --argjson g "$got" -e \
    '[($t.yaw - $g.yaw), ($t.pitch - $g.pitch), ($t.roll - $g.roll)] | map(fabs) | max < 10' \
    >/dev/null || fail "the AFLW face's pose is more than 10 degrees from its ground truth: $got"
else
  echo "image-smoke: ($data absent: the AFLW face is skipped)"
fi

# Every process of the container as uid 10001 (ps on the engine's host).
uids=$(docker top "$cid" -o pid,uid | awk 'NR > 1 { print $2 }' | sort -u | paste -sd ' ')
[ "$uids" = "10001" ] || fail "processes run as uid(s) $uids, not 10001"
echo "image-smoke: processes run as uid $uids"

# docker stop: SIGTERM (the image's STOPSIGNAL), then SIGKILL after the grace period.
t1=$(date +%s.%N)
docker stop -t "$grace" "$cid" >/dev/null
t_stop=$(awk -v a="$t1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }')
code=$(docker inspect -f '{{.State.ExitCode}}' "$cid")
[ "$code" = 0 ] || fail "exit status $code after docker stop (137: killed after the grace period)"
awk -v s="$t_stop" -v g="$grace" 'BEGIN { exit !(s < g) }' || fail "stop took $t_stop s"
echo "image-smoke: docker stop -> exit 0 in $t_stop s (grace $grace s)"
echo "image-smoke: OK"
