# Sourced by scripts/abuse.sh and scripts/soak.sh, from the repository's root: builds the
# release binary and makes (once) the venv under target/abuse-venv with the h2 package, which
# frames the scripts' gRPC calls. Sets VENV.
echo "== building (release)"
cargo build --release --locked --bin facepose 2>&1 | tail -1

VENV=target/abuse-venv
if ! "$VENV/bin/python" -c 'import h2' 2>/dev/null; then
    echo "== making $VENV (h2)"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet 'h2>=4,<5'
fi
