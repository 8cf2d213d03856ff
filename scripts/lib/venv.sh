# shellcheck shell=bash
# Sourced helper (from the repository's root): a Python venv with pinned packages, made once and
# re-used while it checks out.
#
#   . scripts/lib/venv.sh
#   venv_ensure target/peers-venv --check 'import cv2, numpy' \
#       'opencv-python-headless>=4.10,<6' 'numpy>=1.26,<3'
#   venv_ensure --python "${PYTHON:-python3}" --requires-python 3.8-3.12 \
#       --check 'import mediapipe' target/detector-venv 'mediapipe==0.10.14' ...
#
# The venv at DIR is re-used when its python runs, every `name==version` requirement is
# installed at that version and every other requirement's distribution is installed
# (importlib.metadata), and the --check code (Python) runs without error. Otherwise the venv is
# made (or kept, if its python runs) and the requirements are installed with pip (quiet,
# 5 retries, VENV_TIMEOUT seconds at most, 600 by default), after a line on stderr saying what.
# --requires-python A-B: the interpreter that makes the venv must be CPython A to B (checked
# only when the venv has to be made; exit status 2 and a message otherwise).
# Sets VENV_PY (DIR/bin/python). Returns non-zero (does not exit) when the venv or pip fails,
# so a caller can say why: `venv_ensure ... || not_run "pip install failed"`.

# venv_ensure [--python PY] [--requires-python A-B] [--check CODE] DIR REQUIREMENT...
venv_ensure() {
  local py=python3 range="" check="" dir
  while [ $# -gt 0 ]; do
    case "$1" in
    --python) py=${2:?venv_ensure: --python PY}; shift 2 ;;
    --requires-python) range=${2:?venv_ensure: --requires-python A-B}; shift 2 ;;
    --check) check=${2:?venv_ensure: --check CODE}; shift 2 ;;
    *) break ;;
    esac
  done
  dir=${1:?venv_ensure: DIR}
  shift
  VENV_PY=$dir/bin/python
  if _venv_ok "$dir" "$check" "$@"; then
    return 0
  fi
  if [ -n "$range" ]; then
    local lo=${range%-*} hi=${range#*-}
    if ! "$py" -c "import sys; v = sys.version_info[:2]; sys.exit(not ($(echo "$lo" | tr . ,),) <= v <= ($(echo "$hi" | tr . ,),))" 2>/dev/null; then
      echo "$dir needs CPython $lo-$hi; $py is $("$py" -V 2>&1)." >&2
      echo "Set PYTHON to another interpreter." >&2
      return 2
    fi
  fi
  if [ ! -x "$VENV_PY" ] || ! "$VENV_PY" -c '' 2>/dev/null; then
    echo "== making $dir ($("$py" -V 2>&1)): $*" >&2
    "$py" -m venv --clear "$dir" || { echo "venv_ensure: $py -m venv $dir failed" >&2; return 1; }
  else
    echo "== installing in $dir: $*" >&2
  fi
  timeout "${VENV_TIMEOUT:-600}" "$dir/bin/pip" install --quiet --disable-pip-version-check \
    --retries 5 "$@" || { echo "venv_ensure: pip install $* failed" >&2; return 1; }
  _venv_ok "$dir" "$check" "$@" || {
    echo "venv_ensure: $dir still fails its check after pip install" >&2
    return 1
  }
}

# _venv_ok DIR CHECK REQUIREMENT...: the venv runs, has the requirements and passes CHECK.
_venv_ok() {
  local dir=$1 check=$2
  shift 2
  [ -x "$dir/bin/python" ] || return 1
  "$dir/bin/python" - "$@" <<'PY' 2>/dev/null || return 1
import importlib.metadata as m, re, sys
for req in sys.argv[1:]:
    name = re.split(r"[<>=!~;\[ ]", req, maxsplit=1)[0]
    pin = re.fullmatch(r"[^<>=!~;\[ ]+==([^,;]+)", req)
    have = m.version(name)  # PackageNotFoundError: missing
    if pin and have != pin.group(1):
        sys.exit(1)
PY
  [ -z "$check" ] || "$dir/bin/python" -c "$check" 2>/dev/null
}
