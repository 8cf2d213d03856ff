# shellcheck shell=bash
# Sourced helper (from the repository's root): `facepose serve` on a free loopback port, waited
# for, and stopped.
#
#   . scripts/lib/release.sh; . scripts/lib/server.sh
#   release_build                                   # sets BIN
#   trap 'server_stop; rm -rf "$WORK"' EXIT          # the caller's own trap calls server_stop
#   server_admin_files "$WORK"                       # optional: sets MODELS, TOKEN, TOKENFILE
#   server_start "$WORK/server.log" --log warn --models "$MODELS" --admin-token-file "$TOKENFILE"
#   curl "$BASE/healthz"; ...
#   server_stop
#
# server_start runs "$BIN serve --addr 127.0.0.1:PORT ARGS..." with stdout and stderr to the
# log file (`-`: left on the terminal), PORT a free loopback port (asked of the kernel; if the
# server loses it to another process before binding, a new port is tried, 3 times at most),
# then polls GET /readyz every SERVER_POLL seconds (0.05) for SERVER_READY_TIMEOUT seconds (30)
# at most. Sets PORT, BASE (http://127.0.0.1:PORT), PID and READY_MS (from the start to the
# first 200). The server exiting, or not being ready in time, prints the log's last lines and
# exits the script with status 1.

# free_port: prints a loopback TCP port that is free now.
free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# server_admin_files DIR: a models folder DIR/models and an admin token (ADMIN_TOKEN, else a
# random one) in the file DIR/admin-token (mode 0600). Sets MODELS, TOKEN and TOKENFILE.
server_admin_files() {
  MODELS=$1/models
  mkdir -p "$MODELS"
  TOKEN=${ADMIN_TOKEN:-$(python3 -c 'import secrets; print(secrets.token_hex(32))')}
  TOKENFILE=$1/admin-token
  (umask 077 && printf '%s\n' "$TOKEN" >"$TOKENFILE")
}

# server_start LOG [SERVE_ARG]...: starts the server and waits for /readyz (see above).
server_start() {
  local log=$1 attempt t0 deadline
  shift
  : "${BIN:?server_start: BIN is not set (release_build sets it)}"
  for attempt in 1 2 3; do
    PORT=$(free_port)
    BASE=http://127.0.0.1:$PORT
    echo "== starting the server on $BASE" >&2
    t0=$(date +%s%N)
    if [ "$log" = - ]; then
      "$BIN" serve --addr "127.0.0.1:$PORT" "$@" &
    else
      "$BIN" serve --addr "127.0.0.1:$PORT" "$@" >"$log" 2>&1 &
    fi
    PID=$!
    deadline=$((t0 + ${SERVER_READY_TIMEOUT:-30} * 1000000000))
    while ! curl -sf --max-time 2 -o /dev/null "$BASE/readyz"; do
      if ! kill -0 "$PID" 2>/dev/null; then
        wait "$PID" 2>/dev/null || true
        PID=
        if [ "$log" != - ] && [ "$attempt" -lt 3 ] && grep -qi 'address.*in use' "$log"; then
          echo "== port $PORT taken meanwhile; another" >&2
          continue 2
        fi
        echo "server exited before it was ready" >&2
        [ "$log" = - ] || tail -20 "$log" >&2
        exit 1
      fi
      if [ "$(date +%s%N)" -ge "$deadline" ]; then
        echo "server not ready after ${SERVER_READY_TIMEOUT:-30} s" >&2
        [ "$log" = - ] || tail -20 "$log" >&2
        exit 1
      fi
      sleep "${SERVER_POLL:-0.05}"
    done
    # shellcheck disable=SC2034 # for the caller
    READY_MS=$((($(date +%s%N) - t0) / 1000000))
    return 0
  done
}

# server_stop: stops the server server_start started (SIGTERM, then waits for it); nothing when
# none runs. Put it in the caller's EXIT trap.
server_stop() {
  if [ -n "${PID:-}" ]; then
    kill "$PID" 2>/dev/null || true
    wait "$PID" 2>/dev/null || true
    PID=
  fi
}
