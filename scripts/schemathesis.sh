#!/usr/bin/env bash
# Property-based API test of `facepose serve` against its own OpenAPI document (Schemathesis).
#
#   scripts/schemathesis.sh                        # 300 examples per operation, every check
#   MAX_EXAMPLES=30 scripts/schemathesis.sh        # a quick pass
#   scripts/schemathesis.sh --include-path-regex '^/v1/pose'   # extra arguments go to
#                                                  # `schemathesis run`
#
# Creates (or reuses) a Python venv in target/schemathesis-venv with a pinned Schemathesis,
# builds the release binary, starts the server on a free loopback port with a temporary models
# folder and an admin token (ADMIN_TOKEN, else a random one), sent as `Authorization: Bearer ...`
# on every request so that the admin routes are tested too (`ignored_auth` checks that they
# refuse a request without it). Waits for /readyz, then runs every phase (examples, coverage,
# fuzzing, stateful) with every check against $BASE/openapi.json, WORKERS (2) at a time.
# Prints Schemathesis' own report (each failure with a curl command that reproduces it; the
# token shows as [Filtered]: put `Authorization: Bearer $ADMIN_TOKEN` back), then one line per
# operation: requests, status codes, failed checks. Reports (JUnit, NDJSON, the OpenAPI
# document tested) go to target/schemathesis/report/, crash files to target/schemathesis/
# (replay: cd target/schemathesis && ../schemathesis-venv/bin/st replay ID). Exits non-zero on
# any failure. Writes only to the temporary models folder (retraining, activating, deleting
# versions). About 4 minutes at 300 examples on 2 cores. Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

SCHEMATHESIS_VERSION=4.32.5
MAX_EXAMPLES=${MAX_EXAMPLES:-300}
WORKERS=${WORKERS:-2}
VENV=target/schemathesis-venv
VENV_ABS="$PWD/$VENV"
OUT=target/schemathesis
# What counts as accepting a valid request (422 too; the file says why).
CONFIG="$PWD/scripts/schemathesis.toml"
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# shellcheck source=scripts/lib/server.sh
. scripts/lib/server.sh
WORK=$(mktemp -d)
trap 'server_stop; rm -rf "$WORK"' EXIT

venv_ensure --check 'import schemathesis' "$VENV" "schemathesis==$SCHEMATHESIS_VERSION"

# The server, with a temporary models folder and admin token (sets BIN, TOKEN, BASE, PID, ...).
release_build
server_admin_files "$WORK"
server_start "$WORK/server.log" --log warn --models "$MODELS" --admin-token-file "$TOKENFILE"

rm -rf "$OUT/report"
mkdir -p "$OUT/report"
curl -sf -o "$OUT/report/openapi.json" "$BASE/openapi.json"
echo "== schemathesis $SCHEMATHESIS_VERSION: every check, $MAX_EXAMPLES examples per operation"
# Run from $OUT: Schemathesis keeps its crash files (.schemathesis/, for `st replay`) and
# Hypothesis its caches (.hypothesis/) in the working directory. No example database: one
# replaying stored failures makes Hypothesis skip generating for those operations, so every
# run generates afresh (the seed is printed; --seed N repeats a run).
rc=0
(cd "$OUT" && "$VENV_ABS/bin/schemathesis" --config-file "$CONFIG" run "$BASE/openapi.json" \
    --checks all \
    --max-examples "$MAX_EXAMPLES" \
    --workers "$WORKERS" \
    --header "Authorization: Bearer $TOKEN" \
    --generation-database none \
    --continue-on-failure \
    --report junit,ndjson --report-junit-path report/junit.xml \
    --report-ndjson-path report/events.ndjson \
    --no-color \
    "$@") || rc=$?

echo "== per operation (requests, status codes, checks that failed)"
"$VENV/bin/python" - "$OUT/report/events.ndjson" "$OUT/report/openapi.json" <<'PY' || true
# One row per documented operation; requests with other methods (the unsupported_method
# check's probes) are counted per path in an "other methods" row.
import collections, json, sys
ops = collections.defaultdict(lambda: {"n": 0, "codes": collections.Counter(),
                                       "failed": collections.Counter(), "phases": set()})
try:
    lines = open(sys.argv[1], encoding="utf-8")
    doc = json.load(open(sys.argv[2], encoding="utf-8"))
except (OSError, ValueError) as e:
    sys.exit(f"no NDJSON report or OpenAPI document: {e}")
documented = {f"{m.upper()} {p}" for p, item in doc.get("paths", {}).items() for m in item
              if m in ("get", "put", "post", "delete", "options", "head", "patch", "trace")}
for line in lines:
    event = json.loads(line)
    done = event.get("ScenarioFinished")
    if not done:
        continue
    rec = done.get("recorder", {})
    for cid, case in rec.get("cases", {}).items():
        value = case.get("value", {})
        path = value.get("path", rec.get("label", "?"))
        name = f"{value.get('method', '?')} {path}"
        op = ops[name if name in documented else f"(other methods) {path}"]
        op["phases"].add(done.get("phase", "?"))
        inter = rec.get("interactions", {}).get(cid)
        if inter is None:
            continue  # a step of a stateful scenario that was not sent
        op["n"] += 1
        resp = inter.get("response") or {}
        op["codes"][resp.get("status_code", "none")] += 1
        for check in rec.get("checks", {}).get(cid, []):
            if check.get("status") == "failure":
                op["failed"][check["name"]] += 1
width = max((len(k) for k in ops), default=9)
print(f"{'operation':<{width}}  {'requests':>8}  status codes / failed checks (requests)")
failing = 0
for name in sorted(ops, key=lambda k: (k.split(" ", 1)[1], k)):
    op = ops[name]
    codes = " ".join(f"{c}:{n}" for c, n in sorted(op["codes"].items(), key=lambda x: str(x[0])))
    failed = ", ".join(f"{c} ({n})" for c, n in op["failed"].most_common())
    failing += bool(failed)
    print(f"{name:<{width}}  {op['n']:>8}  {codes}")
    print(f"{'':<{width}}  {'':>8}  {'FAILED: ' + failed if failed else 'ok'}")
print(f"{len(ops) - failing} passed, {failing} failed")
PY

if grep -qiE "panicked|ERROR" "$WORK/server.log"; then
    echo "== server log (errors)"
    grep -iE "panicked|ERROR" "$WORK/server.log" | head -20
fi
exit "$rc"
