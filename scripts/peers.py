"""OpenCV's solvePnP with a generic 3D face beside facepose's methods, on the same real faces
and in the same run: microseconds per estimate and mean absolute error per angle.

Run by scripts/peers.sh (which makes the venv and builds facepose). Arguments: the facepose
binary, the AFLW2000-3D file, the model bundle whose mean shape is OpenCV's 3D face, the
output Markdown file.

- Faces: those of the file with every |angle| <= 99 (`within_99`), the set `facepose eval`
  scores; landmark sets `fitted` and `reannotated` (68 points) and `five` (eye centres, nose
  tip, mouth corners, from the re-annotated ones).
- OpenCV: cv2.solvePnP with SOLVEPNP_SQPNP, SOLVEPNP_EPNP and SOLVEPNP_ITERATIVE, one thread,
  no distortion, the 3D face = the served model's mean shape in its frame (x towards the
  subject's left, y up, z towards the camera, mm), the 2D points as given (pixels). Two
  cameras: as tutorials set it up (focal length = image width, principal point the image
  centre) and a long focal length (100 x the width: near orthographic, the projection the
  data's ground truth was made with). The rotation goes to facepose's frame as docs/API.md
  says (R = diag(1, -1, -1) R_cv) and to Pose_Para angles by DESIGN.md's formulas.
- Time: each call timed alone with perf_counter_ns, median and mean over the faces, Python's
  call overhead included; the overhead itself (the same timing around cv2.Rodrigues, the
  cheapest call with array arguments) is reported so that it can be taken off.
- facepose: `facepose eval --protocol real` on the same file in the same run, its MAE rows and
  its time per face (one core, parsing included).
"""

import json
import math
import statistics
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

IMAGE = 450  # AFLW2000-3D images are 450 x 450
F = np.diag([1.0, -1.0, -1.0])
FLAGS = [("SQPnP", cv2.SOLVEPNP_SQPNP), ("EPnP", cv2.SOLVEPNP_EPNP),
         ("ITERATIVE", cv2.SOLVEPNP_ITERATIVE)]


def pose_para(r):
    """Pose_Para (yaw, pitch, roll) in degrees of R = Rx(pitch) Ry(yaw) Rz(roll)."""
    yaw = math.atan2(-r[0, 2], math.hypot(r[0, 0], r[0, 1]))
    pitch = math.atan2(r[1, 2], r[2, 2])
    roll = math.atan2(r[0, 1], r[0, 0])
    return [math.degrees(a) for a in (yaw, pitch, roll)]


def wrap(d):
    return (d + 180.0) % 360.0 - 180.0


def five_of(p):
    mean = lambda idx: [sum(p[i][0] for i in idx) / len(idx), sum(p[i][1] for i in idx) / len(idx)]
    return [mean(range(36, 42)), mean(range(42, 48)), p[30], p[48], p[54]]


def model_points(bundle):
    b = json.load(open(bundle))
    mean = np.array(b["mean"], dtype=np.float64)
    # `five`: the anchor means of the 68 points, as the model's own five-point subset.
    five = np.array([mean[36:42].mean(0), mean[42:48].mean(0), mean[30], mean[48], mean[54]])
    return {"ibug68": mean, "five": five}


def opencv_rows(faces, models):
    cv2.setNumThreads(1)
    rows = []
    sets = [("fitted", "ibug68", lambda f: f["landmarks_fitted"]),
            ("reannotated", "ibug68", lambda f: f["landmarks_reannotated"]),
            ("five (from reannotated)", "five", lambda f: five_of(f["landmarks_reannotated"]))]
    for camera, focal in [("focal = width", IMAGE), ("focal = 100 x width", 100 * IMAGE)]:
        k = np.array([[focal, 0, IMAGE / 2], [0, focal, IMAGE / 2], [0, 0, 1]], dtype=np.float64)
        for name, flag in FLAGS:
            for source, scheme, get in sets:
                obj = models[scheme]
                errs, times, failed, behind = [], [], 0, 0
                for f in faces:
                    img = np.array(get(f), dtype=np.float64)
                    t = time.perf_counter_ns()
                    try:
                        ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=flag)
                    except cv2.error:
                        ok = False
                    times.append(time.perf_counter_ns() - t)
                    if not ok:
                        failed += 1
                        continue
                    # A solution with the face behind the camera is still what the caller
                    # gets; it is counted.
                    behind += int(tvec[2, 0] < 0)
                    r = F @ cv2.Rodrigues(rvec)[0]
                    yaw, pitch, roll = pose_para(r)
                    errs.append([abs(wrap(pitch - f["pitch"])), abs(wrap(yaw - f["yaw"])),
                                 abs(wrap(roll - f["roll"]))])
                e = np.array(errs) if errs else np.full((1, 3), np.nan)
                rows.append({
                    "method": f"OpenCV {name}", "camera": camera, "source": source,
                    "faces": len(faces), "failed": failed, "behind": behind,
                    "pitch": e[:, 0].mean(), "yaw": e[:, 1].mean(), "roll": e[:, 2].mean(),
                    "mae": e.mean(),
                    "us_median": statistics.median(times) / 1000,
                    "us_mean": statistics.fmean(times) / 1000,
                })
    return rows


def call_overhead():
    rvec = np.zeros((3, 1))
    times = []
    for _ in range(2000):
        t = time.perf_counter_ns()
        cv2.Rodrigues(rvec)
        times.append(time.perf_counter_ns() - t)
    return statistics.median(times) / 1000


def facepose_rows(binary, dataset):
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([binary, "eval", "--protocol", "real", "--dataset", dataset, "--out", out,
                        "--methods", "auto,fit-shape,fit,regression,geometry"],
                       check=True, stdout=subprocess.DEVNULL)
        rows = json.load(open(f"{out}/report.json"))["real"]
        text = open(f"{out}/report.md").read()
    line = next(l for l in text.splitlines() if l.startswith("Time per face"))
    us = {}
    for part in line.split(": ", 1)[1].rstrip(".").split("; "):
        what, t = part.rsplit(": ", 1)
        us[what] = float(t.split()[0])
    for r in rows:
        # The text names a source as "five (from reannotated)" where the JSON says "five".
        key = f"{r['method']} on {r['source']}"
        r["us"] = next((t for what, t in us.items() if what == key or what.startswith(key + " (")),
                       float("nan"))
    return rows


def main(binary, dataset, bundle, out):
    faces = [json.loads(l) for l in open(dataset)]
    faces = [f for f in faces if f["within_99"]]
    models = model_points(bundle)
    cv_rows = opencv_rows(faces, models)
    overhead = call_overhead()
    fp_rows = facepose_rows(binary, dataset)
    lines = [
        f"{len(faces)} faces of `{dataset}` (every |angle| <= 99°); errors in degrees against the "
        "ground truth; MAE = mean of the pitch, yaw and roll mean absolute errors. One core. "
        f"OpenCV {cv2.__version__} (opencv-python-headless), its 3D face the mean shape of "
        f"`{bundle}`; each call timed alone from Python: the call overhead, timed the same way "
        f"around `cv2.Rodrigues`, is {overhead:.1f} µs and is included in the OpenCV times. "
        "facepose: `facepose eval --protocol real` in the same run (its time per face includes "
        "parsing the landmarks). \"failed\": solvePnP returned false or raised (ITERATIVE needs "
        "6 points without a start; SQPnP refuses the long focal length); \"behind the camera\": "
        "solutions with tvec.z < 0, kept in the errors since that is what a caller gets.",
        "",
        "| estimator | camera | landmarks | failed | behind the camera | pitch | yaw | roll | **MAE** | µs per estimate |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in fp_rows:
        lines.append(f"| facepose `{r['method']}` | none (weak perspective) | {r['source']} | "
                     f"{r['failures']} | - | {r['mae_pitch']:.2f} | {r['mae_yaw']:.2f} | "
                     f"{r['mae_roll']:.2f} | **{r['mae_mean']:.2f}** | {r['us']:.1f} |")
    for r in cv_rows:
        lines.append(f"| {r['method']} | {r['camera']} | {r['source']} | {r['failed']} | {r['behind']} | "
                     f"{r['pitch']:.2f} | {r['yaw']:.2f} | {r['roll']:.2f} | **{r['mae']:.2f}** | "
                     f"{r['us_median']:.1f} (mean {r['us_mean']:.1f}) |")
    text = "\n".join(lines) + "\n"
    open(out, "w").write(text)
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:5])
