#!/usr/bin/env bash
# The served OpenAPI document through the tools clients use: openapi-spec-validator validates
# it, openapi-python-client generates a Python client from it (a warning, such as an endpoint
# it skips, is a failure), and scripts/openapi_client_check.py calls the server through that
# client: a real AFLW2000-3D face against its ground truth, a batch with a bad face, a typed
# error body, and an admin activation through the `:activate` route (docs/API.md, "OpenAPI
# and generated clients").
#
#   scripts/openapi-client.sh
#
# Creates (or reuses) a Python venv in target/openapi-client-venv with pinned versions of both
# tools, builds the release binary, starts the server on a free loopback port with a temporary
# models folder and admin token, waits for /readyz, then runs the three steps. The document
# goes to target/openapi-client/openapi.json, the client to
# target/openapi-client/facepose_client. Prints each step's outcome and a one-line summary;
# exits non-zero on any failure. Every step is bounded in time (TIMEOUT seconds each, 120 by
# default). Data: FACEPOSE_DATA (default ../shared/data). Not part of CI.
set -euo pipefail
cd "$(dirname "$0")/.."

SPEC_VALIDATOR_VERSION=0.9.0
CLIENT_GENERATOR_VERSION=0.29.1
TIMEOUT=${TIMEOUT:-120}
DATA=${FACEPOSE_DATA:-../shared/data}
FACES="$DATA/aflw2000/aflw2000_dev.jsonl"
VENV=target/openapi-client-venv
OUT=target/openapi-client
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# shellcheck source=scripts/lib/server.sh
. scripts/lib/server.sh
WORK=$(mktemp -d)
trap 'server_stop; rm -rf "$WORK"' EXIT

[ -f "$FACES" ] && [ -f "$DATA/bfm68/population_249.json" ] || { echo "no shared data in $DATA (set FACEPOSE_DATA)"; exit 1; }

venv_ensure "$VENV" "openapi-spec-validator==$SPEC_VALIDATOR_VERSION" \
    "openapi-python-client==$CLIENT_GENERATOR_VERSION"
# The generator formats its output with ruff, installed beside it.
export PATH="$PWD/$VENV/bin:$PATH"

# The server, with a temporary models folder and admin token (sets BIN, TOKEN, BASE, PID, ...).
release_build
server_admin_files "$WORK"
server_start "$WORK/server.log" --log warn --models "$MODELS" --admin-token-file "$TOKENFILE"

rm -rf "$OUT"
mkdir -p "$OUT"
curl -sf --max-time 10 -o "$OUT/openapi.json" "$BASE/openapi.json"

declare -a summary
failed=0
step() { # name, command...
    local name=$1
    shift
    echo "== $name"
    if timeout "$TIMEOUT" "$@"; then
        summary+=("ok    $name")
    else
        summary+=("FAIL  $name (exit $?)")
        failed=$((failed + 1))
    fi
}

step "openapi-spec-validator $SPEC_VALIDATOR_VERSION" \
    openapi-spec-validator "$OUT/openapi.json"
step "openapi-python-client $CLIENT_GENERATOR_VERSION generate --fail-on-warning" \
    openapi-python-client generate --path "$OUT/openapi.json" --meta none \
    --output-path "$OUT/facepose_client" --overwrite --fail-on-warning
if [ -d "$OUT/facepose_client" ]; then
    step "calls through the generated client (scripts/openapi_client_check.py)" \
        "$VENV/bin/python" scripts/openapi_client_check.py "$BASE" "$TOKEN" "$OUT" \
        "$OUT/openapi.json" "$DATA"
else
    summary+=("FAIL  calls through the generated client (no client generated)")
    failed=$((failed + 1))
fi

if grep -qiE "panicked|ERROR" "$WORK/server.log"; then
    echo "== server log (errors)"
    grep -iE "panicked|ERROR" "$WORK/server.log" | head -20
fi
echo "== summary"
printf '%s\n' "${summary[@]}"
echo "$((${#summary[@]} - failed)) passed, $failed failed"
[ "$failed" -eq 0 ]
