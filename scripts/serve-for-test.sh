# Sourced by scripts/schemathesis.sh and scripts/openapi-client.sh, from the repository's root,
# with WORK set to a temporary folder that the caller's EXIT trap removes: builds the release
# binary, then starts `facepose serve` on a free loopback port with a models folder in $WORK
# and an admin token (ADMIN_TOKEN, else a random one) in a file, and waits until /readyz
# answers (30 s at most). Sets BIN, MODELS, TOKEN, TOKENFILE, PORT, BASE and PID (the caller's
# trap kills it).
echo "== building (release)"
cargo build --release --locked --bin facepose 2>&1 | tail -1
BIN=target/release/facepose

MODELS="$WORK/models"
mkdir -p "$MODELS"
TOKEN=${ADMIN_TOKEN:-$(python3 -c 'import secrets; print(secrets.token_hex(32))')}
TOKENFILE="$WORK/admin-token"
(umask 077; printf '%s\n' "$TOKEN" >"$TOKENFILE")

PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
BASE="http://127.0.0.1:$PORT"

echo "== starting the server on $BASE (models in $MODELS)"
"$BIN" serve --addr "127.0.0.1:$PORT" --log warn --models "$MODELS" \
    --admin-token-file "$TOKENFILE" 2>"$WORK/server.log" &
PID=$!
for _ in $(seq 1 600); do
    curl -sf -o /dev/null "$BASE/readyz" && break
    kill -0 "$PID" 2>/dev/null || { echo "server exited:"; cat "$WORK/server.log"; exit 1; }
    sleep 0.05
done
curl -sf -o /dev/null "$BASE/readyz" || { echo "server not ready after 30 s"; exit 1; }
