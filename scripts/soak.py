#!/usr/bin/env python3
# Soak test of `facepose serve`: steady pose traffic over HTTP and gRPC for DURATION seconds
# with a retraining and an activation every CYCLE seconds; reports failed requests and the
# server's memory growth. Run it through scripts/soak.sh (builds the binary, installs wrk, makes
# the venv with h2).
#
#   scripts/soak.sh                                   # 600 s
#   DURATION=60 scripts/soak.sh                       # a short run
#   DURATION=600 HTTP_CONNS=8 GRPC_CALLERS=2 CYCLE=60 WARMUP=20 scripts/soak.sh
#
# One server (target/release/facepose serve --addr 127.0.0.1:PORT --log warn --models TEMP
# --admin-token-file TEMP), then, at once and for WARMUP + DURATION seconds:
# - HTTP: wrk, HTTP_CONNS connections, POST /v1/pose with the 500 real faces of
#   ../shared/data/aflw2000 in turn (`{"landmarks": [...68 points...]}`: ibug68, the default
#   method: no "method" field);
# - gRPC: GRPC_CALLERS processes, each on one HTTP/2 connection, calling Estimate (one face,
#   Landmark messages) and EstimateBatch (16 faces, packed xy) in turn with the same faces;
# - every CYCLE seconds (the first CYCLE/2 in): an upload of 60 shapes of ../shared/data/bfm68/population_1000.json
#   (a different draw each time) to POST /v1/models with "activate": false, the job followed
#   until it ends, then POST /v1/models/default/versions/N:activate of the version it wrote.
# The warm-up (WARMUP s of load and one retraining + activation) ends before the RSS at the
# start is read. RSS: VmRSS every 0.5 s; "start" and "end" are the medians of the 10 s after
# the warm-up and of the last 10 s of the load (single samples move with the requests in
# flight).
# Failed requests: any non-2xx or socket error of wrk, any gRPC call not OK, any retraining job
# not `succeeded`, any activation not 200. Targets: 0 failed, RSS growth <= 10%.
# Exits 1 if a target is missed. Not part of CI.
import collections
import json
import os
import random
import re
import secrets
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import multiprocessing as mp

sys.dont_write_bytecode = True
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from abuse import (DATA, Grpc, Server, grpc_message, http_call, pb_batch, pb_estimate,  # noqa: E402
                   real_faces)

DURATION = float(os.environ.get("DURATION", "600"))
WARMUP = float(os.environ.get("WARMUP", "20"))
HTTP_CONNS = int(os.environ.get("HTTP_CONNS", "8"))
GRPC_CALLERS = int(os.environ.get("GRPC_CALLERS", "2"))
CYCLE = float(os.environ.get("CYCLE", "60"))
SHAPES_PER_UPLOAD = 60

WRK_LUA = r"""
local bodies = {}
for line in io.lines(os.getenv("BODIES")) do bodies[#bodies + 1] = line end
local i = 0
wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
setup = function(thread) thread:set("id", #bodies) end
init = function(args) i = math.random(#bodies) end
request = function()
  i = i % #bodies + 1
  return wrk.format(nil, nil, nil, bodies[i])
end
done = function(summary, latency, requests)
  local e = summary.errors
  io.write(string.format("SUMMARY requests=%d non2xx=%d connect=%d read=%d write=%d timeout=%d p50_us=%d p99_us=%d\n",
    summary.requests, e.status, e.connect, e.read, e.write, e.timeout,
    latency:percentile(50), latency:percentile(99)))
end
"""


def top_varint(msg, field):
    """A top-level varint field of a protobuf message (0 when absent)."""
    i, value = 0, 0
    while i < len(msg):
        key, i = read_varint(msg, i)
        num, wire = key >> 3, key & 7
        if wire == 0:
            v, i = read_varint(msg, i)
            if num == field:
                value = v
        elif wire == 1:
            i += 8
        elif wire == 2:
            n, i = read_varint(msg, i)
            i += n
        elif wire == 5:
            i += 4
        else:
            raise ValueError("wire type %d" % wire)
    return value


def read_varint(b, i):
    shift = value = 0
    while True:
        c = b[i]
        i += 1
        value |= (c & 0x7F) << shift
        shift += 7
        if not c & 0x80:
            return value, i


def grpc_caller(port, faces, stop, queue, seed):
    """Estimate and EstimateBatch in turn on one connection until `stop`."""
    rnd = random.Random(seed)
    counts = collections.Counter()
    errors = collections.Counter()
    conn = None
    n = 0
    while not stop.is_set():
        n += 1
        if n % 2:
            rpc, msg = "Estimate", pb_estimate(faces[rnd.randrange(len(faces))])
        else:
            k = rnd.randrange(len(faces) - 16)
            rpc, msg = "EstimateBatch", pb_batch(faces[k:k + 16])
        try:
            if conn is None:
                conn = Grpc(port, timeout=30)
            status, gmsg, _, data = conn.call(rpc, msg)
            counts[(rpc, status)] += 1
            if status != "OK":
                errors["%s %s %s" % (rpc, status, gmsg[:120])] += 1
            elif rpc == "EstimateBatch":
                failed = top_varint(grpc_message(data), 5)
                if failed:
                    counts[(rpc, "OK with failed faces")] += 1
                    counts[(rpc, status)] -= 1
                    errors["EstimateBatch: %d faces failed" % failed] += 1
        except Exception as e:  # noqa: BLE001 - every failure counts
            counts[(rpc, "error")] += 1
            errors["%s %s: %s" % (rpc, type(e).__name__, str(e)[:120])] += 1
            if conn is not None:
                conn.sock.close()
            conn = None
    if conn is not None:
        conn.close()
    queue.put({"counts": dict(counts), "errors": dict(errors)})


def upload_body(population, rnd, cycle):
    shapes = rnd.sample(population, SHAPES_PER_UPLOAD)
    return json.dumps({"model": "default", "shapes": shapes, "activate": False,
                       "notes": "soak cycle %d" % cycle}).encode()


class Registry(threading.Thread):
    """A retraining (activate: false) and the activation of its version every CYCLE s."""

    def __init__(self, port, token, population):
        super().__init__(daemon=True)
        self.port, self.auth = port, ("Authorization: Bearer " + token,)
        self.population = population
        self.rnd = random.Random(2027)
        self.stop_ev = threading.Event()
        self.log = []       # (t, what, ok, detail)
        self.jobs_ok = self.jobs_failed = self.act_ok = self.act_failed = 0
        self.cycles = 0
        self.lock = threading.Lock()

    def cycle(self):
        t0 = time.monotonic()
        self.cycles += 1
        st, body = http_call(self.port, "POST", "/v1/models",
                             upload_body(self.population, self.rnd, self.cycles),
                             headers=self.auth, timeout=60)
        if st != 202:
            self.jobs_failed += 1
            self.log.append((t0, "upload", False, "HTTP %d %s" % (st, body[:300])))
            return
        job = json.loads(body)
        while job["state"] in ("queued", "running"):
            time.sleep(0.5)
            st, body = http_call(self.port, "GET", "/v1/models/jobs/" + job["id"], timeout=30)
            if st != 200:
                self.jobs_failed += 1
                self.log.append((t0, "job", False, "GET job: HTTP %d %s" % (st, body[:300])))
                return
            job = json.loads(body)
        train_s = time.monotonic() - t0
        if job["state"] != "succeeded":
            self.jobs_failed += 1
            self.log.append((t0, "job", False, "%s: %s" % (job["state"], job.get("error"))))
            return
        self.jobs_ok += 1
        version = job["version"]
        st, body = http_call(self.port, "POST", "/v1/models/default/versions/%s:activate" % version,
                             headers=self.auth, timeout=30)
        ok = st == 200
        if ok:
            self.act_ok += 1
        else:
            self.act_failed += 1
        self.log.append((t0, "retrain + activate", ok,
                         "version %s: trained in %.1f s (kept %s of %s), activation HTTP %d%s"
                         % (version, train_s, job["validation"]["kept"], job["validation"]["total"],
                            st, "" if ok else " " + body[:300].decode("utf-8", "replace"))))

    def run(self):
        # The first cycle half a period in: the RSS at the start is read before it.
        nxt = time.monotonic() + CYCLE / 2
        self.stop_ev.wait(CYCLE / 2)
        while not self.stop_ev.is_set():
            try:
                with self.lock:
                    self.cycle()
            except Exception as e:  # noqa: BLE001
                self.jobs_failed += 1
                self.log.append((time.monotonic(), "cycle", False, repr(e)))
            nxt += CYCLE
            self.stop_ev.wait(max(0, nxt - time.monotonic()))


def main():
    mp.set_start_method("fork")
    faces = real_faces()
    with open(os.path.join(DATA, "bfm68/population_1000.json")) as f:
        population = json.load(f)["shapes"]
    work = tempfile.mkdtemp(prefix="facepose-soak-")
    bodies = os.path.join(work, "bodies.jsonl")
    with open(bodies, "w") as f:
        for face in faces:
            f.write(json.dumps({"landmarks": face}) + "\n")
    lua = os.path.join(work, "soak.lua")
    with open(lua, "w") as f:
        f.write(WRK_LUA)
    token = secrets.token_hex(32)
    token_file = os.path.join(work, "admin-token")
    with open(token_file, "w") as f:
        f.write(token + "\n")
    server = Server(extra=["--admin-token-file", token_file], log_name="soak").start()
    wrk = None
    procs = []
    try:
        print("== server on 127.0.0.1:%d, ready after %.0f ms, RSS %.1f MiB"
              % (server.port, server.ready_ms, server.rss_kb() / 1024), flush=True)
        total = WARMUP + DURATION
        samples = []  # (t, kb)
        t_start = time.monotonic()
        wrk = subprocess.Popen(
            ["wrk", "-t1", "-c%d" % HTTP_CONNS, "-d%ds" % round(total), "--latency", "--timeout", "5s",
             "-s", lua, "http://127.0.0.1:%d/v1/pose" % server.port],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={**os.environ, "BODIES": bodies})
        stop = mp.Event()
        queue = mp.Queue()
        procs = [mp.Process(target=grpc_caller, args=(server.port, faces, stop, queue, k), daemon=True)
                 for k in range(GRPC_CALLERS)]
        for p in procs:
            p.start()
        registry = Registry(server.port, token, population)
        # The warm-up: load, and one retraining + activation.
        print("== warm-up: %.0f s of load and one retraining + activation" % WARMUP, flush=True)
        with registry.lock:
            registry.cycle()
        print("   %s" % registry.log[-1][3], flush=True)
        while time.monotonic() - t_start < WARMUP:
            samples.append((time.monotonic() - t_start, server.rss_kb()))
            time.sleep(0.5)
        t_measure = time.monotonic() - t_start
        print("== soak: %.0f s, retraining + activation every %.0f s" % (DURATION, CYCLE), flush=True)
        registry.start()
        last_report = 0.0
        while wrk.poll() is None and time.monotonic() - t_start < total + 5:
            t = time.monotonic() - t_start
            kb = server.rss_kb()
            if kb is None:
                break
            samples.append((t, kb))
            if t - last_report >= 60:
                last_report = t
                print("   t=%4.0f s RSS %.1f MiB, retrainings %d ok / %d failed, activations %d ok / %d failed"
                      % (t - t_measure, kb / 1024, registry.jobs_ok, registry.jobs_failed,
                         registry.act_ok, registry.act_failed), flush=True)
            time.sleep(0.5)
        t_end = time.monotonic() - t_start
        stop.set()
        registry.stop_ev.set()
        out = wrk.communicate(timeout=60)[0].decode()
        results = []
        for _ in procs:
            try:
                results.append(queue.get(timeout=60))
            except Exception:  # noqa: BLE001
                pass
        for p in procs:
            p.join(10)
        registry.join(120)
        alive = server.alive()
        time.sleep(2)
        idle_after = server.rss_kb() if alive else None
        hwm = server.status("VmHWM") if alive else None
        versions = None
        if alive:
            st, body = http_call(server.port, "GET", "/v1/models/default/versions")
            if st == 200:
                v = json.loads(body)
                versions = "%d versions, active %s" % (len(v["versions"]), v["active"])
    finally:
        if wrk is not None and wrk.poll() is None:
            wrk.kill()
        for p in procs:
            if p.is_alive():
                p.terminate()
        log_tail = server.log_tail(30)
        server.stop()
        subprocess.run(["rm", "-rf", work])

    m = re.search(r"SUMMARY requests=(\d+) non2xx=(\d+) connect=(\d+) read=(\d+) write=(\d+) "
                  r"timeout=(\d+) p50_us=(\d+) p99_us=(\d+)", out)
    if not m:
        print(out)
        sys.exit("wrk gave no summary")
    w = dict(zip(["requests", "non2xx", "connect", "read", "write", "timeout", "p50", "p99"],
                 map(int, m.groups())))
    http_failed = w["non2xx"] + w["connect"] + w["read"] + w["write"] + w["timeout"]
    gcounts, gerrors = collections.Counter(), collections.Counter()
    for r in results:
        gcounts.update({tuple(k): v for k, v in r["counts"].items()})
        gerrors.update(r["errors"])
    grpc_total = sum(gcounts.values())
    grpc_failed = sum(v for (rpc, st), v in gcounts.items() if st != "OK")
    grpc_lost = GRPC_CALLERS - len(results)

    def median_between(a, b):
        vals = [kb for t, kb in samples if a <= t < b and kb]
        return statistics.median(vals) if vals else float("nan")
    rss_start = median_between(t_measure, t_measure + 10)
    rss_end = median_between(t_end - 10, t_end + 1)
    growth = (rss_end / rss_start - 1) * 100
    failed = http_failed + grpc_failed + registry.jobs_failed + registry.act_failed + grpc_lost
    by_minute = []
    for k in range(int((t_end - t_measure) // 60) + 1):
        vals = [kb for t, kb in samples if t_measure + 60 * k <= t < t_measure + 60 * (k + 1)]
        if vals:
            by_minute.append("%.1f" % (statistics.median(vals) / 1024))

    print()
    print("## Soak (`scripts/soak.sh`, DURATION=%.0f, %s, %d cores, load average %s)"
          % (DURATION, time.strftime("%Y-%m-%d"), os.cpu_count(),
             " ".join(open("/proc/loadavg").read().split()[:3])))
    print()
    print("| what | count | failed | notes |")
    print("|---|---|---|---|")
    print("| HTTP `POST /v1/pose` (wrk, %d connections, 500 real faces, default method) | %s | %d | p50 %.2f ms, p99 %.2f ms; non-2xx %d, socket errors connect %d / read %d / write %d / timeout %d |"
          % (HTTP_CONNS, f"{w['requests']:,}", http_failed, w["p50"] / 1000, w["p99"] / 1000,
             w["non2xx"], w["connect"], w["read"], w["write"], w["timeout"]))
    for rpc in ("Estimate", "EstimateBatch"):
        n = sum(v for (r, _), v in gcounts.items() if r == rpc)
        bad = sum(v for (r, st), v in gcounts.items() if r == rpc and st != "OK")
        print("| gRPC `%s` (%d callers%s) | %s | %d | %s |"
              % (rpc, GRPC_CALLERS, ", 16 faces a call" if rpc == "EstimateBatch" else "",
                 f"{n:,}", bad, ", ".join("%s: %d" % (st, v) for (r, st), v in sorted(gcounts.items()) if r == rpc)))
    print("| retraining jobs (60 shapes, activate: false), warm-up included | %d | %d | |"
          % (registry.jobs_ok + registry.jobs_failed, registry.jobs_failed))
    print("| activations | %d | %d | %s |" % (registry.act_ok + registry.act_failed, registry.act_failed,
                                               versions or ""))
    print("| **all requests** | %s | **%d** | target 0: %s |"
          % (f"{w['requests'] + grpc_total + registry.cycles * 2:,}", failed, "met" if failed == 0 else "**NOT met**"))
    print()
    print("| RSS | MiB |")
    print("|---|---|")
    print("| start (median of the 10 s after the warm-up) | %.1f |" % (rss_start / 1024))
    print("| end (median of the last 10 s of load) | %.1f |" % (rss_end / 1024))
    print("| growth | **%+.1f%%** (target <= 10%%: %s) |" % (growth, "met" if growth <= 10 else "**NOT met**"))
    print("| peak (VmHWM) / idle 2 s after the load | %s / %s |"
          % ("%.1f" % (hwm / 1024) if hwm else "-", "%.1f" % (idle_after / 1024) if idle_after else "-"))
    print("| median per minute of the soak | %s |" % " ".join(by_minute))
    print()
    print("Registry cycles:")
    for t, what, ok, detail in registry.log:
        print("- %s %s: %s" % ("ok" if ok else "FAILED", what, detail))
    if gerrors:
        print("gRPC errors: " + "; ".join("%s x%d" % kv for kv in gerrors.most_common(10)))
    if grpc_lost:
        print("%d gRPC callers gave no result" % grpc_lost)
    if not alive:
        print("SERVER DIED; log:\n" + log_tail)
    ok = failed == 0 and growth <= 10 and alive
    print()
    print("all targets met" if ok else "TARGETS MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
