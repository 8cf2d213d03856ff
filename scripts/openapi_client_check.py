"""Calls a running `facepose serve` through the Python client that openapi-python-client
generated from its own /openapi.json (scripts/openapi-client.sh sets it all up).

    python scripts/openapi_client_check.py BASE_URL TOKEN CLIENT_DIR OPENAPI_JSON DATA_DIR

CLIENT_DIR holds the generated package `facepose_client`; DATA_DIR is the shared data
(../shared/data). Every check uses the generated functions and models only (no hand-written
HTTP): a real face of AFLW2000-3D (its `landmarks_reannotated`, against the line's
ground-truth angles), a batch with one bad face, an error body parsed into the generated
types, the admin token refused, and the admin routes: a retraining job from bfm68 shapes on a
small grid, a second one cancelled through the `:cancel` route while it waits, and a rollback
to version 1 through the `:activate` route once the first has written version 2. The server
must have an empty models folder. Prints one line per check and a summary; exits 1 if any
check fails.
"""

import importlib
import json
import sys
import time
import traceback

TOLERANCE_DEG = 10.0


def main() -> int:
    base, token, client_dir, doc_path, data_dir = sys.argv[1:6]
    sys.path.insert(0, client_dir)
    from facepose_client import AuthenticatedClient, Client
    from facepose_client.api.models import list_models
    from facepose_client.api.operations import readyz
    from facepose_client.api.pose import pose, pose_batch
    from facepose_client.api.registry import (
        activate_version,
        cancel_job,
        get_job,
        list_versions,
        retrain,
    )
    from facepose_client.models import (
        BatchError,
        BatchFace,
        BatchPose,
        BatchRequest,
        BatchResponse,
        ErrorBody,
        ErrorKind,
        Job,
        JobState,
        ModelsResponse,
        PoseRequest,
        PoseResponse,
        RetrainRequest,
        Status,
        TrainingOptions,
        TrainingOptionsGridType1,
        VersionsResponse,
    )

    with open(doc_path, encoding="utf-8") as f:
        doc = json.load(f)
    with open(f"{data_dir}/aflw2000/aflw2000_dev.jsonl", encoding="utf-8") as f:
        faces = [json.loads(line) for line in f]
    with open(f"{data_dir}/bfm68/population_249.json", encoding="utf-8") as f:
        population = json.load(f)
    # Faces within ±30° of frontal: the rigid and shape fits are well within 10° there.
    moderate = [f for f in faces if max(abs(f["yaw"]), abs(f["pitch"]), abs(f["roll"])) <= 30]
    anon = Client(base_url=base, raise_on_unexpected_status=True, timeout=30.0)
    admin = AuthenticatedClient(
        base_url=base, token=token, raise_on_unexpected_status=True, timeout=60.0
    )
    results: list[tuple[str, bool, str]] = []

    def check(name):
        def run(f):
            try:
                detail = f()
                results.append((name, True, detail or ""))
            except Exception as e:  # noqa: BLE001 (a failed check, whatever its kind)
                line = traceback.extract_tb(e.__traceback__)[-1].lineno
                results.append((name, False, f"{type(e).__name__} at line {line}: {e}"))
            return f

        return run

    def angle_errors(got, want) -> list[float]:
        return [abs(getattr(got, k) - want[k]) for k in ("yaw", "pitch", "roll")]

    @check("every documented operation has a generated function")
    def _():
        missing = []
        n = 0
        for path, item in doc["paths"].items():
            for method, op in item.items():
                if method not in ("get", "put", "post", "delete", "patch", "head", "options"):
                    continue
                n += 1
                tag, op_id = op["tags"][0], op["operationId"]
                try:
                    module = importlib.import_module(f"facepose_client.api.{tag}.{op_id}")
                    assert callable(module.sync_detailed)
                except (ImportError, AttributeError, AssertionError):
                    missing.append(f"{method.upper()} {path} ({tag}.{op_id})")
        assert not missing, f"not generated: {missing}"
        return f"{n} operations"

    @check("GET /readyz")
    def _():
        r = readyz.sync(client=anon)
        assert isinstance(r, Status) and r.status == "ready", r
        return r.status

    @check("GET /v1/models")
    def _():
        r = list_models.sync(client=anon)
        assert isinstance(r, ModelsResponse), r
        names = [m.name for m in r.models]
        assert r.default_model in names, (r.default_model, names)
        return f"models {names}, default {r.default_model}"

    @check("POST /v1/pose: a real face against its ground truth")
    def _():
        face = moderate[0]
        body = PoseRequest(landmarks=face["landmarks_reannotated"], id=face["image"])
        r = pose.sync(client=anon, body=body)
        assert isinstance(r, PoseResponse), r
        assert r.id == face["image"], r.id
        assert len(r.visible) == 68 and len(r.rotation) == 3, r
        errs = angle_errors(r, face)
        assert max(errs) < TOLERANCE_DEG, (
            f"{face['image']}: got yaw {r.yaw:.1f} pitch {r.pitch:.1f} roll {r.roll:.1f}, "
            f"truth {face['yaw']:.1f} {face['pitch']:.1f} {face['roll']:.1f}"
        )
        return (
            f"{face['image']} ({r.method}): yaw {r.yaw:.1f}/{face['yaw']:.1f} "
            f"pitch {r.pitch:.1f}/{face['pitch']:.1f} roll {r.roll:.1f}/{face['roll']:.1f} "
            f"(got/truth, max error {max(errs):.1f} deg)"
        )

    @check("POST /v1/pose:batch: real faces and one bad face")
    def _():
        batch = moderate[:8]
        # Five points in a batch named ibug68 (unnamed, 5 points would be five or dlib5, and
        # the error would ask for the scheme instead).
        bad = [[100.0, 100.0]] * 5
        body = BatchRequest(
            faces=[
                BatchFace(landmarks=f["landmarks_reannotated"], id=i) for i, f in enumerate(batch)
            ]
            + [BatchFace(landmarks=bad, id="bad")],
            method="fit-shape",
            scheme="ibug68",
        )
        r = pose_batch.sync(client=anon, body=body)
        assert isinstance(r, BatchResponse), r
        assert (r.succeeded, r.failed) == (len(batch), 1), (r.succeeded, r.failed)
        assert len(r.results) == len(batch) + 1
        worst = 0.0
        for i, (res, want) in enumerate(zip(r.results, batch)):
            assert isinstance(res, BatchPose), (i, res)
            assert res.id == i, (i, res.id)
            assert res.method == "fit-shape", res.method
            worst = max(worst, *angle_errors(res, want))
        assert worst < TOLERANCE_DEG, f"worst angle error {worst:.1f} deg"
        last = r.results[-1]
        assert isinstance(last, BatchError), last
        assert last.id == "bad" and last.error.code == ErrorKind.INVALID_ARGUMENT, last
        assert "68" in last.error.message, last.error.message
        return f"{r.succeeded} poses (worst angle error {worst:.1f} deg), 1 error: {last.error.message}"

    @check("POST /v1/pose: wrong point count is 422 with a typed error body")
    def _():
        face = moderate[0]
        body = PoseRequest(landmarks=face["landmarks_reannotated"][:67])
        r = pose.sync_detailed(client=anon, body=body)
        assert r.status_code == 422, r.status_code
        assert isinstance(r.parsed, ErrorBody), r.parsed
        assert r.parsed.error.code == ErrorKind.INVALID_ARGUMENT, r.parsed.error.code
        assert "67" in r.parsed.error.message, r.parsed.error.message
        return f"422 {r.parsed.error.code.value}: {r.parsed.error.message}"

    @check("POST .../versions/{version}:activate without the token is 401")
    def _():
        r = activate_version.sync_detailed(client=anon, name="default", version="1:activate")
        assert r.status_code == 401, r.status_code
        assert isinstance(r.parsed, ErrorBody), r.parsed
        assert r.parsed.error.code == ErrorKind.UNAUTHENTICATED, r.parsed.error.code
        return f"401 {r.parsed.error.code.value}"

    def upload(notes: str) -> RetrainRequest:
        # 12 shapes, a coarse grid without fine bins, a small basis: a job of a few seconds.
        grid = {"coarse": {"yaw": [-30, 30, 10], "pitch": [-30, 30, 10]}, "bins": []}
        return RetrainRequest(
            shapes=population["shapes"][:12],
            options=TrainingOptions(
                grid=TrainingOptionsGridType1.from_dict(grid), components=4, epsilons=[1e-5]
            ),
            notes=notes,
        )

    jobs: dict[str, Job] = {}

    @check("POST /v1/models (admin): a retraining job")
    def _():
        r = retrain.sync_detailed(client=admin, body=upload("openapi client check"))
        assert r.status_code == 202, (r.status_code, r.content[:300])
        assert isinstance(r.parsed, Job), r.parsed
        assert r.headers["location"] == f"/v1/models/jobs/{r.parsed.id}", r.headers
        jobs["trained"] = r.parsed
        return f"202, job {r.parsed.id} {r.parsed.state.value}, {r.parsed.uploaded} shapes"

    @check("POST /v1/models/jobs/{id}:cancel (admin): a job waiting behind it")
    def _():
        queued = retrain.sync(client=admin, body=upload("cancelled"))
        assert isinstance(queued, Job), queued
        r = cancel_job.sync_detailed(client=admin, id=f"{queued.id}:cancel")
        assert r.status_code == 200, (r.status_code, r.content[:300])
        assert r.parsed.id == queued.id and r.parsed.state == JobState.CANCELLED, r.parsed
        again = get_job.sync(client=anon, id=queued.id)
        assert again.state == JobState.CANCELLED, again.state
        return f"job {queued.id}: {queued.state.value} -> {r.parsed.state.value}"

    @check("GET /v1/models/jobs/{id}: the first job writes version 2")
    def _():
        first = jobs["trained"]
        deadline = time.monotonic() + 90
        job = get_job.sync(client=anon, id=first.id)
        while job.state in (JobState.QUEUED, JobState.RUNNING) and time.monotonic() < deadline:
            time.sleep(0.2)
            job = get_job.sync(client=anon, id=first.id)
        assert job.state == JobState.SUCCEEDED, (job.state, job.error)
        assert job.version == "2", job.version
        versions = list_versions.sync(client=anon, name="default")
        assert versions.active == "2", versions.active
        return f"{job.state.value}, version {job.version} active"

    @check("POST /v1/models/{name}/versions/{version}:activate (admin): roll back to 1")
    def _():
        before = list_versions.sync(client=anon, name="default")
        assert isinstance(before, VersionsResponse), before
        r = activate_version.sync_detailed(client=admin, name="default", version="1:activate")
        assert r.status_code == 200, (r.status_code, r.content[:300])
        assert r.parsed.name == "default" and r.parsed.version == "1", r.parsed
        after = list_versions.sync(client=anon, name="default")
        assert after.active == "1", after.active
        face = moderate[0]
        served = pose.sync(client=anon, body=PoseRequest(landmarks=face["landmarks_reannotated"]))
        assert served.model_version == "1", served.model_version
        ids = [v.version for v in after.versions]
        return f"versions {ids}: active {before.active} -> {after.active}, poses from version 1"

    width = max(len(n) for n, _, _ in results)
    for name, ok, detail in results:
        print(f"{'ok  ' if ok else 'FAIL'} {name:<{width}}  {detail}")
    failed = sum(not ok for _, ok, _ in results)
    print(f"{len(results) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
