#!/usr/bin/env bash
# The demo page and the API from a browser: headless Chromium (Debian's `chromium`) driven by
# Playwright (scripts/browser_test.py): /demo loads under its CSP with no console error and no
# request to another origin; the pose explorer at several poses shows the API's own answer, near
# the truth; the paste box with five-point, ibug68 (and MediaPipe) faces; the demo's stream mode
# (plays in real time, plots raw and smoothed with the 90% bands; replays a trajectory file); a
# page of another origin calling POST /v1/pose with fetch(), allowed by --cors-origins or
# refused; and that origin's page (scripts/browser_stream.html) streaming a rendered trajectory's
# MediaPipe points (tests/fixtures/rendered/traj0.jsonl.gz, turned into JSON in the test's temp
# folder) over GET /v1/pose:stream, smoothed and raw, judging in the page that smoothing cuts the
# jitter and adds no error against the truth (traj1 too: missed frames, relative truth); not
# listed, its socket is refused (403).
#
#   scripts/browser-test.sh [--screenshot docs/demo.png]
#   scripts/browser-test.sh --setup-only   # install what it needs, run nothing (CI, early)
#
# Installs what it needs: Debian's chromium (apt-get, as root) when /usr/bin/chromium is
# missing, and a pinned Playwright in the venv target/browser-test-venv (Playwright's own
# browser download is not used). The binary: $FACEPOSE_BIN, else a release build. Prints one
# line per check and "N passed, M failed, K skipped"; exits 1 on a failure, and 3, saying
# NOT RUN, when Chromium or Playwright cannot be installed. --screenshot saves the explorer
# (1440 px wide, reduced to 192 colours with Pillow, installed for it) to the file given.
set -euo pipefail
cd "$(dirname "$0")/.."

PLAYWRIGHT_VERSION=1.65.2
PILLOW_VERSION=13.0.0
VENV=target/browser-test-venv
CHROMIUM=${CHROMIUM:-/usr/bin/chromium}
SCREENSHOT=""
SETUP_ONLY=""
case "${1:-}" in
--screenshot) SCREENSHOT=${2:?--screenshot FILE} ;;
--setup-only) SETUP_ONLY=1 ;;
"") ;;
*) echo "usage: $0 [--screenshot FILE | --setup-only]" >&2; exit 2 ;;
esac

not_run() {
    echo "browser tests NOT RUN: $*"
    exit 3
}

if [ ! -x "$CHROMIUM" ]; then
    command -v apt-get >/dev/null && [ "$(id -u)" = 0 ] ||
        not_run "no $CHROMIUM, and no apt-get as root to install Debian's chromium"
    echo "== installing Debian's chromium"
    (apt-get update -qq -o Acquire::Retries=3 &&
        DEBIAN_FRONTEND=noninteractive timeout 600 apt-get install -y -qq -o Acquire::Retries=3 \
            --no-install-recommends chromium fonts-dejavu-core >/dev/null) ||
        not_run "apt-get install chromium failed"
    [ -x "$CHROMIUM" ] || not_run "chromium installed, but not at $CHROMIUM"
fi
"$CHROMIUM" --version 2>/dev/null || not_run "$CHROMIUM does not run"

# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
# shellcheck source=scripts/lib/release.sh
. scripts/lib/release.sh
want=("playwright==$PLAYWRIGHT_VERSION")
[ -n "$SCREENSHOT" ] && want+=("pillow==$PILLOW_VERSION")
venv_ensure "$VENV" "${want[@]}" || not_run "the venv or pip install ${want[*]} failed"
[ -n "$SETUP_ONLY" ] && { echo "browser tests: Chromium and $VENV ready"; exit 0; }

# $FACEPOSE_BIN, else the release build.
release_build

args=("$BIN" --chromium "$CHROMIUM")
SHOT_RAW=""
if [ -n "$SCREENSHOT" ]; then
    SHOT_RAW=$(mktemp --suffix .png)
    args+=(--screenshot "$SHOT_RAW")
fi
trap '[ -z "$SHOT_RAW" ] || rm -f "$SHOT_RAW"' EXIT
echo "== browser tests ($("$BIN" --version 2>/dev/null || echo facepose), $("$CHROMIUM" --version 2>/dev/null), playwright $PLAYWRIGHT_VERSION)"
status=0
timeout 600 "$VENV/bin/python" scripts/browser_test.py "${args[@]}" || status=$?
if [ -n "$SCREENSHOT" ] && [ -s "$SHOT_RAW" ]; then
    "$VENV/bin/python" - "$SHOT_RAW" "$SCREENSHOT" <<'END'
import sys
from PIL import Image
image = Image.open(sys.argv[1]).convert("RGB")
image.quantize(colors=192, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(sys.argv[2], optimize=True)
END
    echo "screenshot: $SCREENSHOT ($(stat -c %s "$SCREENSHOT") bytes)"
fi
exit "$status"
