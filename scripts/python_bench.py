"""The Python package's speed and accuracy on real faces, beside the Rust in-process figure and
OpenCV's solvePnP called from Python (scripts/python-bench.sh runs it).

- Faces: the AFLW2000-3D dev faces with every |angle| <= 99° (491), their fitted and
  re-annotated 68 points and five points from the re-annotated ones (eye centres, nose tip,
  mouth corners), as crates/core/benches/real_faces.rs takes them.
- facepose (Python): `facepose.estimate` on the whole (B, N, 2) array, one thread
  (`threads=1`), 30 runs over the batch after a warm-up one: the minimum and the median of the
  time per face; the minimum with every core; and one face per call (the median over the
  faces, after a warm-up pass).
- Rust in process, the same loop: python/examples/core_batch.rs, every face through
  `pose::estimate` once per run, 30 runs, the core compiled as the extension's (python/'s
  release profile), in the same run of this script just before: minimum and median. The
  minimum is the figure to compare on a shared machine: it is a run that no other process
  preempted (the medians move with the machine's load, as the two columns show).
- Rust, criterion: `real/{set}/{method}` of `cargo bench --bench real_faces` (crates/core; the
  root's bench profile), each iteration estimating every face once: its median per face.
- OpenCV: `cv2.solvePnP` with SOLVEPNP_SQPNP and SOLVEPNP_EPNP, one thread, the generic 3D
  face being the default model's mean shape (its five anchor means for `five`), the camera as
  tutorials set it up (focal length = image width 450, principal point the centre); each call
  timed alone (median over the faces), the rotation turned into facepose's frame
  (R = diag(1, -1, -1) R_cv) and Pose_Para angles.
- MAE: the mean of the pitch, yaw and roll mean absolute errors against the ground truth, in
  degrees (angle differences wrapped to ±180°).

    python scripts/python_bench.py CRITERION_OUTPUT CORE_BATCH_OUTPUT DATASET
"""

import json
import math
import os
import re
import statistics
import sys
import time

import cv2
import numpy as np

import facepose

IMAGE = 450
F = np.diag([1.0, -1.0, -1.0])


def pose_para(r):
    yaw = math.atan2(-r[0, 2], math.hypot(r[0, 0], r[0, 1]))
    pitch = math.atan2(r[1, 2], r[2, 2])
    roll = math.atan2(r[0, 1], r[0, 0])
    return [math.degrees(a) for a in (yaw, pitch, roll)]


def wrap(d):
    return (d + 180.0) % 360.0 - 180.0


def five_of(p):
    return np.array([p[36:42].mean(0), p[42:48].mean(0), p[30], p[48], p[54]])


def mae(angles, truth):
    """angles, truth: (B, 3) yaw, pitch, roll."""
    e = np.abs(wrap(angles - truth))
    return e.mean(0).mean()


def rust_figures(path, faces):
    """criterion's median per face, µs, by (set, method)."""
    out = {}
    text = open(path).read()
    units = {"ns": 1e-3, "µs": 1.0, "us": 1.0, "ms": 1e3, "s": 1e6}
    for m in re.finditer(r"real/(\w+)/([\w-]+)\s+time:\s+\[\S+ \S+ (\S+) (\S+) ", text):
        out[(m.group(1), m.group(2))] = float(m.group(3)) * units[m.group(4)] / faces
    return out


def timed(f, runs):
    """(minimum, median) of `runs` calls, µs."""
    ts = []
    for _ in range(runs):
        t = time.perf_counter_ns()
        f()
        ts.append(time.perf_counter_ns() - t)
    return min(ts) / 1000, statistics.median(ts) / 1000


def core_figures(path):
    """core_batch's (min, median) per face, µs, by (set, method)."""
    out = {}
    for line in open(path):
        set_, method, lo, med = line.split()
        out[(set_, method)] = (float(lo), float(med))
    return out


def main(criterion_out, core_out, dataset):
    cv2.setNumThreads(1)
    faces = [json.loads(l) for l in open(dataset) if l.strip()]
    faces = [f for f in faces if f["within_99"]]
    n = len(faces)
    truth = np.array([[f["yaw"], f["pitch"], f["roll"]] for f in faces])
    fitted = np.array([f["landmarks_fitted"] for f in faces], dtype=np.float64)
    rean = np.array([f["landmarks_reannotated"] for f in faces], dtype=np.float64)
    five = np.array([five_of(p) for p in rean])
    sets = [("fitted", "ibug68", fitted), ("reannotated", "ibug68", rean), ("five", "five", five)]
    rust = rust_figures(criterion_out, n)
    core = core_figures(core_out)
    mean = np.array(json.loads(facepose.Model.default().to_json())["mean"], dtype=np.float64)
    generic = {"ibug68": mean, "five": five_of(mean)}
    cores = os.cpu_count()
    load = os.getloadavg()

    print(f"{n} faces (AFLW2000-3D dev, every |angle| <= 99°); µs per face, min / median of "
          "30 runs of the whole batch; MAE in degrees.\n")
    print("| landmarks | method | Python batch, 1 thread | Rust, same loop | ratio (min) | "
          f"Rust, criterion | Python batch, {cores} threads (min) | Python, one face per call | MAE |")
    print("|---|---|---|---|---|---|---|---|---|")
    ratios, extra, per_call_extra, maes = [], [], [], []
    for name, scheme, arr in sets:
        for method in ("auto", "fit"):
            facepose.estimate(arr, scheme, method, threads=1)  # warm (the regression's caches)
            lo, med = (v / n for v in timed(lambda: facepose.estimate(arr, scheme, method, threads=1), 30))
            allc = timed(lambda: facepose.estimate(arr, scheme, method), 30)[0] / n
            per_call = []
            for p in arr:
                t = time.perf_counter_ns()
                facepose.estimate(p, scheme, method)
                per_call.append(time.perf_counter_ns() - t)
            single = statistics.median(per_call) / 1000
            b = facepose.estimate(arr, scheme, method)
            r = rust.get((name, method))
            c = core.get((name, method))
            cs = f"{c[0]:.2f} / {c[1]:.2f}" if c else "n/a"
            ratio = f"{lo / c[0]:.2f}" if c else "n/a"
            rs = f"{r:.2f}" if r else "n/a"
            if c:
                ratios.append(lo / c[0])
                extra.append(lo - c[0])
            per_call_extra.append(single - lo)
            maes.append(mae(b.angles, truth))
            print(f"| {name} | {method} ({b.method[0]}) | {lo:.2f} / {med:.2f} | {cs} | {ratio} | "
                  f"{rs} | {allc:.2f} | {single:.2f} | {mae(b.angles, truth):.2f} |")

    k = np.array([[IMAGE, 0, IMAGE / 2], [0, IMAGE, IMAGE / 2], [0, 0, 1]], dtype=np.float64)
    print("\nOpenCV solvePnP from Python, one thread, generic face = the default model's mean "
          "shape, focal length = image width:\n")
    print("| landmarks | solver | µs per call (median) | µs per call (mean) | failed | MAE |")
    print("|---|---|---|---|---|---|")
    for name, scheme, arr in sets:
        obj = generic[scheme]
        for solver, flag in (("SQPnP", cv2.SOLVEPNP_SQPNP), ("EPnP", cv2.SOLVEPNP_EPNP)):
            ts, angles, failed, kept = [], [], 0, []
            for i, p in enumerate(arr):
                t = time.perf_counter_ns()
                try:
                    ok, rvec, _ = cv2.solvePnP(obj, p, k, None, flags=flag)
                except cv2.error:
                    ok = False
                ts.append(time.perf_counter_ns() - t)
                if not ok:
                    failed += 1
                    continue
                angles.append(pose_para(F @ cv2.Rodrigues(rvec)[0]))
                kept.append(i)
            e = mae(np.array(angles), truth[kept]) if angles else float("nan")
            print(f"| {name} | {solver} | {statistics.median(ts) / 1000:.2f} | "
                  f"{statistics.fmean(ts) / 1000:.2f} | {failed} | {e:.2f} |")
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    print(f"\nMeasured on: {cpu}, {cores} cores, load average {load[0]:.1f} at the start "
          f"(other processes share the machine: the medians move with them, the minimums "
          f"much less); facepose {facepose.__version__}, numpy {np.__version__}, "
          f"OpenCV {cv2.__version__}, Python {sys.version.split()[0]}.")
    if ratios:
        print(f"\n- ratio (min): the Python batch's per-face time over the Rust loop's, both the "
              f"minimum of 30 runs: {min(ratios):.2f}-{max(ratios):.2f}. The difference, "
              f"{min(extra):.2f}-{max(extra):.2f} µs a face, is the conversion of the arrays in "
              "and out and the service's checks on each face (scheme, coordinates, a finite "
              "answer); it shows most beside the 2 µs rigid fit.")
    print("- criterion's figure is a median over its samples, taken in the same run a minute "
          "earlier under whatever load there was then.")
    print(f"- one face per call: {min(per_call_extra):.1f}-{max(per_call_extra):.1f} µs more "
          "than a face of a batch (the call, the checks of the arguments, a `Pose` with its "
          "numpy arrays); batches avoid it.")
    print("- OpenCV: with the generic face and a pinhole camera, see its MAE beside facepose's "
          f"({min(maes):.2f}-{max(maes):.2f}° above) on the same landmarks.")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3])
