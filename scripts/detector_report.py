"""facepose on what real detectors found on real photographs: MediaPipe's Face Mesh against
dlib's predictors on the same faces, the consistency of each under transforms of the photograph
whose true pose change is known, and MediaPipe's own facial transformation matrix beside them.

Run by scripts/detector-report.sh (which builds facepose). Arguments: the facepose binary, the
fixture folder (tests/fixtures/detectors, made by scripts/detector-landmarks.sh), the output
Markdown file. The standard library only: no detector runs here, the fixtures hold what they
found.

- facepose: `facepose estimate --method M` on the fixtures' points as a client sends them:
  dlib's in pixels with `"landmark_style": "contour"` (2D-style: trained on 300-W); MediaPipe's
  normalized, with `"image_size": [width, height]`, as scheme `mediapipe478` (and, to check that
  the iris points take no part, `mediapipe468`).
- MediaPipe's matrix (see scripts/detector_landmarks.py for how it is made): its upper 3x3 R
  maps the canonical face into MediaPipe's camera space, whose axes (x right, y up, z towards
  the viewer) and canonical frame are facepose's camera and model frames, so Pose_Para angles
  come from R by DESIGN.md's formulas with no change of sign. Its translation assumes a camera
  with a vertical field of view of 63°, but its rotation is that of MediaPipe's landmarks, whose
  depth the network predicts for the face crop: it does not depend on where the face sits in
  the image (the cropped copy moves the face off the centre and shortens the assumed focal
  length in pixels by a quarter; the rotation stays within half a degree), so it compares
  directly with facepose's weak-perspective rotation.
- Transforms: mirroring maps R to S R S (S = diag(-1, 1, 1): yaw and roll change sign); turning
  the photograph by θ clockwise maps R to Rz(θ) R (roll + θ when yaw and pitch are 0); scaling
  and cropping change nothing. The error of a copy is its angles minus those expected from the
  original's, degrees.
"""

import json
import math
import os
import subprocess
import sys

# The copies on which dlib's predictors hold (tests/integration/detectors.rs, `dlib_holds`).
DLIB_HOLDS = {
    "astronaut/original",
    "astronaut/mirrored",
    "astronaut/rotated+20",
    "astronaut/rotated-20",
    "astronaut/scaled0.6",
    "astronaut/cropped",
}
GROUPS = [
    ("the astronaut and the copies dlib follows", lambda n: n in DLIB_HOLDS),
    ("the copies turned by 40°", lambda n: n.startswith("astronaut/") and n not in DLIB_HOLDS),
    ("the LFW faces", lambda n: n.startswith("lfw_subset/")),
]
# (label, detector, how facepose is asked)
DLIB68 = "dlib 68, auto"
DLIB68_FIT = "dlib 68, fit"
DLIB5 = "dlib 5, auto"
MP_AUTO = "MediaPipe 478, auto"
MP_FIT = "MediaPipe 478, fit"
MP_SHAPE = "MediaPipe 478, fit-shape"
MP_468 = "MediaPipe 468, auto"
MATRIX = "MediaPipe's matrix"


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def rx(deg):
    s, c = math.sin(math.radians(deg)), math.cos(math.radians(deg))
    return [[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]]


def ry(deg):
    s, c = math.sin(math.radians(deg)), math.cos(math.radians(deg))
    return [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]


def rz(deg):
    s, c = math.sin(math.radians(deg)), math.cos(math.radians(deg))
    return [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]


def rotation(yaw, pitch, roll):
    """R = Rx(pitch) Ry(yaw) Rz(roll) (DESIGN.md)."""
    return matmul(rx(pitch), matmul(ry(yaw), rz(roll)))


def pose_para(r):
    """(yaw, pitch, roll) in degrees of R = Rx(pitch) Ry(yaw) Rz(roll)."""
    yaw = math.atan2(-r[0][2], math.hypot(r[0][0], r[0][1]))
    pitch = math.atan2(r[1][2], r[2][2])
    roll = math.atan2(r[0][1], r[0][0])
    return tuple(math.degrees(a) for a in (yaw, pitch, roll))


def wrap(d):
    return (d + 180.0) % 360.0 - 180.0


def expected(change, r):
    """The angles a copy should have, from the original's rotation r and the fixture's words."""
    if change == "none":
        m = r
    elif change.startswith("mirror"):
        s = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        m = matmul(s, matmul(r, s))
    elif change.startswith("roll changes by "):
        m = matmul(rz(float(change.split()[-1])), r)
    else:
        sys.exit(f"unknown transform {change!r}")
    return pose_para(m)


def estimate(binary, method, requests):
    """facepose's answers to JSON-line requests (one `facepose estimate` run), in order."""
    text = "\n".join(json.dumps(r) for r in requests) + "\n"
    out = subprocess.run(
        [binary, "estimate", "--input", "-", "--method", method],
        input=text,
        capture_output=True,
        text=True,
    )
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    bad = [r for r in rows if "error" in r]
    if out.returncode != 0 or bad or len(rows) != len(requests):
        sys.exit(f"facepose estimate --method {method} ({out.returncode}): {bad} {out.stderr}")
    return rows


def fmt(a):
    return " / ".join(f"{v:.1f}" for v in a)


def diff(a, b):
    return [wrap(x - y) for x, y in zip(a, b)]


def largest(d):
    return max(abs(v) for v in d)


def main(binary, fixtures, out_path):
    with open(os.path.join(fixtures, "dlib.json")) as f:
        dlib = json.load(f)
    with open(os.path.join(fixtures, "mediapipe.json")) as f:
        mp = json.load(f)
    names = [f["image"] for f in mp["faces"]]
    dl = {f["image"]: f for f in dlib["faces"]}
    assert sorted(names) == sorted(dl), "the two fixtures hold different images"

    def dlib68(f):
        return {"landmarks": dl[f["image"]]["ibug68"], "scheme": "ibug68", "landmark_style": "contour"}

    def dlib5(f):
        return {"landmarks": dl[f["image"]]["dlib5"], "scheme": "dlib5"}

    def mp478(f):
        return {"landmarks": f["landmarks"], "scheme": "mediapipe478", "image_size": f["image_size"]}

    def mp468(f):
        return {"landmarks": f["landmarks"][:468], "scheme": "mediapipe468", "image_size": f["image_size"]}

    asks = [
        (DLIB68, "auto", dlib68),
        (DLIB68_FIT, "fit", dlib68),
        (DLIB5, "auto", dlib5),
        (MP_AUTO, "auto", mp478),
        (MP_FIT, "fit", mp478),
        (MP_SHAPE, "fit-shape", mp478),
        (MP_468, "auto", mp468),
    ]
    angles, answered = {}, {}
    for label, method, request in asks:
        for f, r in zip(mp["faces"], estimate(binary, method, [request(f) for f in mp["faces"]])):
            angles[f["image"], label] = (r["yaw"], r["pitch"], r["roll"])
            answered[f["image"], label] = r
    for f in mp["faces"]:
        m = f["facial_transformation_matrix"]
        angles[f["image"], MATRIX] = pose_para([row[:3] for row in m[:3]])

    def worst(x, y, sel):
        """Per angle, the largest |x - y| over the images `sel` picks."""
        d = [diff(angles[n, x], angles[n, y]) for n in names if sel(n)]
        return [max(abs(v[k]) for v in d) for k in range(3)]

    out = []
    w = out.append
    w(
        f"Photographs: {mp['photos']}. Landmarks: {dlib['detector']}; {mp['detector']}; kept in "
        "`tests/fixtures/detectors/` (`scripts/detector-landmarks.sh` made them; "
        "tests/integration/detectors.rs checks them). facepose: `facepose estimate` with the "
        "method named; dlib's points in pixels with `landmark_style: contour`; MediaPipe's as "
        "MediaPipe gives them, normalized, with `image_size`, as `mediapipe478`. For "
        "`mediapipe478`, `auto` is `detector`, the regression trained on MediaPipe's points over the "
        "rendered benchmark's training identities (these points misfit the mesh by more than "
        "`auto`'s cut), `fit` the rigid fit of MediaPipe's mesh (what `auto` answered before, and "
        "still answers for `mediapipe468`) and `fit-shape` the model's shape fit on the mesh "
        "landmarks' ibug68 points; for "
        "dlib's 68 points (`landmark_style: contour`) `auto` is `detector` too, the regression "
        "trained on dlib's points, and `fit` the rigid fit. *MediaPipe's matrix*: the rotation of its facial transformation matrix, "
        "computed by MediaPipe's own face-geometry calculator, the one behind FaceLandmarker's "
        "`facial_transformation_matrixes` (the wheel has no `face_landmarker.task`, so the "
        "calculator runs alone on the Face Mesh points, its metadata rebuilt from the shared "
        "canonical mesh). Its axes and its canonical face's are facepose's, so its angles come "
        "with no change of sign. Angles in degrees, yaw / pitch / roll (Pose_Para)."
    )
    w("")
    w("### The same face through two detectors")
    w("")
    cols = [DLIB68, DLIB68_FIT, DLIB5, MP_AUTO, MP_FIT, MP_SHAPE, MATRIX]
    w("| image | size | " + " | ".join(cols) + " |")
    w("|---|---|" + "---|" * len(cols))
    for f in mp["faces"]:
        n = f["image"]
        size = "x".join(str(v) for v in f["image_size"])
        w(f"| {n} | {size} | " + " | ".join(fmt(angles[n, c]) for c in cols) + " |")
    w("")
    pairs = [
        (MP_AUTO, DLIB68),
        (MP_FIT, DLIB68),
        (MP_SHAPE, DLIB68),
        (MP_FIT, DLIB68_FIT),
        (MATRIX, MP_FIT),
    ]
    w(
        "Differences, yaw / pitch / roll (the first minus the second), per image, and the largest "
        "absolute ones per group:"
    )
    w("")
    w("| image | " + " | ".join(f"{a} − {b}" for a, b in pairs) + " |")
    w("|---|" + "---|" * len(pairs))
    for n in names:
        w(f"| {n} | " + " | ".join(fmt(diff(angles[n, a], angles[n, b])) for a, b in pairs) + " |")
    for label, sel in GROUPS:
        w(
            f"| largest, {label} | "
            + " | ".join(f"**{fmt(worst(a, b, sel))}**" for a, b in pairs)
            + " |"
        )
    w("")
    same = max(largest(diff(angles[n, MP_FIT], angles[n, MP_468])) for n in names)
    misfit = [answered[n, MP_AUTO].get("misfit") for n in names]
    warned = sum(1 for n in names for lab in (DLIB68, MP_AUTO) if answered[n, lab].get("warnings"))
    w(
        f"`mediapipe468` (the 468 mesh points, `auto`: the mesh fit) against `mediapipe478` (with "
        f"the irises, `fit`): "
        f"{same:.3f}° apart at most. Residuals (RMS reprojection error over the inter-ocular "
        "distance): "
        + "; ".join(
            f"{lab}: {min(answered[n, lab]['residual'] for n in names):.3f}-"
            f"{max(answered[n, lab]['residual'] for n in names):.3f}"
            for lab in (DLIB68, MP_AUTO, MP_FIT)
        )
        + (
            f"; misfit of {MP_AUTO}: {min(misfit):.3f}-{max(misfit):.3f}"
            if None not in misfit
            else ""
        )
        + f"; answers with a warning: {warned}."
    )
    w("")
    w("### Transforms whose effect on the pose is known")
    w("")
    w(
        "Per copy of the astronaut: its angles minus those expected from the original's "
        "(mirrored: R → S R S with S = diag(-1, 1, 1), yaw and roll change sign; turned by θ "
        "clockwise: R → Rz(θ) R, which adds θ to roll when yaw and pitch are 0; scaled or "
        "cropped: no change), yaw / pitch / roll, and the largest in bold."
    )
    w("")
    cols = [DLIB68, DLIB5, MP_AUTO, MP_FIT, MP_SHAPE, MATRIX]
    w("| copy | change | " + " | ".join(cols) + " |")
    w("|---|---|" + "---|" * len(cols))
    base = "astronaut/original"
    worst_err = {}
    for f in mp["faces"]:
        n, change = f["image"], f["transform"]
        if n == base or not n.startswith("astronaut/"):
            continue
        cells = []
        for c in cols:
            err = diff(angles[n, c], expected(change, rotation(*angles[base, c])))
            for label, sel in GROUPS:
                if sel(n):
                    worst_err[c, label] = max(worst_err.get((c, label), 0.0), largest(err))
            cells.append(f"{fmt(err)} **{largest(err):.1f}**")
        w(f"| {n} | {change} | " + " | ".join(cells) + " |")
    for label, _ in GROUPS[:2]:
        w(
            f"| largest | {label} | "
            + " | ".join(f"**{worst_err[c, label]:.1f}**" for c in cols)
            + " |"
        )
    text = "\n".join(out) + "\n"
    with open(out_path, "w") as f:
        f.write(text)
    print(text, end="")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3])
