"""The same answers everywhere: the same faces through the package, `facepose estimate` (the
CLI) and `facepose serve` (POST /v1/pose:batch) give the same fields, bit for bit: the CLI and
the service print floats as their shortest round-trip decimal (serde_json's
float_roundtrip), which Python's float() reads back to the same double. Bad faces give the
same message everywhere.

The binary: FACEPOSE_BIN, else target/{release,debug}/facepose (CARGO_TARGET_DIR or the
repository's target/), else `cargo build --locked --bin facepose` here."""

import json
import os
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import facepose
from conftest import REPO, rotation


def facepose_bin() -> Path:
    env = os.environ.get("FACEPOSE_BIN")
    if env:
        return Path(env)
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    for profile in ("release", "debug"):
        p = target / profile / "facepose"
        if p.is_file():
            return p
    cargo = shutil.which("cargo")
    if cargo is None:
        pytest.fail("no facepose binary: set FACEPOSE_BIN or build it (cargo build --bin facepose)")
    subprocess.run([cargo, "build", "--locked", "--bin", "facepose"], cwd=REPO, check=True)
    return target / "debug" / "facepose"


def cases(aflw, data):
    """(name, options, faces): landmark lists with None for missing points."""
    fitted = [f["landmarks_fitted"] for f in aflw]
    rean = [f["landmarks_reannotated"] for f in aflw]
    five_idx = ([36, 37, 38, 39, 40, 41], [42, 43, 44, 45, 46, 47], [30], [48], [54])
    five = [[list(np.mean([f[i] for i in g], 0)) for g in five_idx] for f in rean]
    rng = np.random.default_rng(3)
    missing = []
    for f in fitted[:150]:
        g = [list(p) for p in f]
        for i in rng.choice(68, 8, replace=False):
            g[i] = None
        missing.append(g)
    # MediaPipe Face Mesh points: the canonical mesh turned, projected and normalized to a
    # 1280 x 720 frame, as Face Landmarker reports them (x, y fractions of the image).
    with open(data / "mediapipe" / "canonical_face_468.json") as f:
        v = np.array(json.load(f)["vertices"])
    mp = []
    for k in range(40):
        yaw, pitch, roll = rng.uniform(-50, 50), rng.uniform(-30, 30), rng.uniform(-20, 20)
        p = (v @ rotation(yaw, pitch, roll).T)[:, :2] * [3.0, -3.0] + [640, 360]
        p += rng.normal(0, 0.5, p.shape)
        mp.append((p / [1280, 720]).tolist())
    bad = [
        fitted[0][:5],  # 5 points in ibug68
        [[5.0, 5.0]] * 68,  # degenerate
        [[float(x) for x in row] for row in rng.uniform(100, 400, (68, 2))],  # not a face
        [[0.3, 0.4]] * 34 + [[0.5, 0.6]] * 34,  # normalized, no image size
    ]
    return [
        ("fitted-auto", {}, fitted),
        ("reannotated-contour", {"landmark_style": "contour"}, rean),
        ("five-fit", {"scheme": "five", "method": "fit"}, five),
        ("missing-regression", {"method": "regression"}, missing),
        ("camera-fit", {"method": "fit", "camera": [1000.0, 1000.0, 250.0, 250.0]}, fitted[:120]),
        ("geometry", {"method": "geometry"}, fitted[:120]),
        ("conventions", {"conventions": ["quaternion", "euler:preset=openface", "opencv"], "camera": [450.0, 450.0, 225.0, 225.0]}, fitted[:100]),
        ("mediapipe478-normalized", {"image_size": [1280.0, 720.0]}, mp),
        ("bad-faces", {"scheme": "ibug68"}, bad),
    ]


def package(opts, faces):
    pts = [np.array([[np.nan, np.nan] if p is None else p for p in f], dtype=float) for f in faces]
    b = facepose.estimate(pts, errors="keep", **opts)
    out = []
    for i in range(len(b)):
        if b.errors[i] is not None:
            out.append({"error": str(b.errors[i])})
        else:
            d = b[i].to_dict()
            del d["model"], d["model_version"]
            out.append(d)
    return out


def cli(binary, tmp, opts, faces):
    path = tmp / "faces.jsonl"
    with open(path, "w") as f:
        for i, face in enumerate(faces):
            f.write(json.dumps({"id": i, "landmarks": face}) + "\n")
    args = [str(binary), "estimate", "--input", str(path)]
    if "scheme" in opts:
        args += ["--scheme", opts["scheme"]]
    if "method" in opts:
        args += ["--method", opts["method"]]
    if "landmark_style" in opts:
        args += ["--landmark-style", opts["landmark_style"]]
    if "camera" in opts:
        args += ["--camera", ",".join(repr(v) for v in opts["camera"])]
    if "image_size" in opts:
        args += ["--image-size", ",".join(repr(v) for v in opts["image_size"])]
    if "conventions" in opts:
        args += ["--conventions", ",".join(opts["conventions"])]
    r = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert r.returncode in (0, 1, 3), r.stderr
    out = []
    for line in r.stdout.splitlines():
        d = json.loads(line)
        assert d.pop("id") == len(out)
        if "error" in d:
            d = {"error": d["error"]}
        out.append(d)
    return out


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    binary = facepose_bin()
    models = tmp_path_factory.mktemp("models")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    p = subprocess.Popen(
        # A long request timeout: this checks answers, not speed, and CI's binary is a test
        # build on cores other work may be using (a 503 timed-out batch failed it once).
        [
            str(binary), "serve", "--addr", f"127.0.0.1:{port}", "--models", str(models),
            "--request-timeout", "300s",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.time() + 60
    while True:
        try:
            with urllib.request.urlopen(url + "/readyz", timeout=1) as r:
                if r.status == 200:
                    break
        except (urllib.error.URLError, ConnectionError, OSError):
            pass
        if p.poll() is not None or time.time() > deadline:
            p.kill()
            pytest.fail(f"facepose serve did not start: {p.stderr.read().decode()[-2000:]}")
        time.sleep(0.1)
    yield url
    p.terminate()
    p.wait(timeout=20)


def service(url, opts, faces):
    out = []
    for start in range(0, len(faces), 1000):
        body = dict(opts)
        body["faces"] = [{"id": start + i, "landmarks": f} for i, f in enumerate(faces[start : start + 1000])]
        if "image_size" in body:
            # image_size is a face's field, not a batch default.
            size = body.pop("image_size")
            for f in body["faces"]:
                f["image_size"] = size
        if "conventions" in body:
            # HTTP takes names or {"name": ..., <parameters>}.
            reqs = []
            for item in body["conventions"]:
                name, *params = item.split(":")
                reqs.append({"name": name, **dict(p.split("=") for p in params)} if params else name)
            body["conventions"] = reqs
        if "camera" in body:
            fx, fy, cx, cy = body["camera"]
            body["camera"] = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
        req = urllib.request.Request(
            url + "/v1/pose:batch",
            data=json.dumps(body).encode(),
            headers={"content-type": "application/json"},
        )
        with urllib.request.urlopen(req, timeout=120) as r:
            answer = json.loads(r.read())
        assert answer["model"] == "default"
        for d in answer["results"]:
            assert d.pop("id") == len(out)
            if "error" in d:
                d = {"error": d["error"]["message"]}
            out.append(d)
    return out


def test_package_cli_and_service_agree(aflw, data, server, tmp_path):
    binary = facepose_bin()
    total = 0
    for name, opts, faces in cases(aflw, data):
        want = package(opts, faces)
        got_cli = cli(binary, tmp_path, opts, faces)
        got_http = service(server, opts, faces)
        assert len(want) == len(got_cli) == len(got_http) == len(faces), name
        for i, (a, b, c) in enumerate(zip(want, got_cli, got_http)):
            # Every field, floats compared with == (bit for bit).
            assert a == b, f"{name} face {i}: package {a}\n cli {b}"
            assert a == c, f"{name} face {i}: package {a}\n service {c}"
        total += len(faces)
        if name == "bad-faces":
            assert all("error" in a for a in want), want
        else:
            assert sum("error" in a for a in want) == 0, name
    assert total > 1900
