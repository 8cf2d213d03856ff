#!/usr/bin/env python3
"""WebSocket streams through the balancer, for scripts/compose-test.sh (docs/DEPLOY.md,
"WebSockets behind the balancer").

Subcommands (each prints one JSON summary line on stdout, progress on stderr):

  streams --victim NAME [--streams N] [--before S] [--after S] [--expect-code C]... -- COMMAND...
      N streams (GET /v1/pose:stream) opened through the balancer, each sending a rendered
      head trajectory (tests/fixtures/rendered/traj*.jsonl.gz: the exact projections of the
      68 points, `oracle.ibug68`) at 30 frames a second with Kalman smoothing on, as a
      tracker's page would (one face, track id "t1"). After S seconds COMMAND runs (a
      `docker kill` or a restart of replica NAME); the streams that NAME served see a close
      or a drop; each reconnects through the balancer at once (0.1 s, then every 0.2 s) and
      starts a fresh track (smoothing turned on again in its first frame, the same track id),
      until every stream has streamed S seconds on its new connection. Then every answer is
      awaited and each stream is closed (1000). Checked, each failure named in "problems":
      the streams spread over the replicas with NAME serving at least one; every answer came
      in order and smoothed; only NAME's streams closed, each once, with an expected code;
      each reconnected within --reconnect-bound seconds to another replica; the first answer
      after a reconnect is the raw estimate of its frame (a fresh track: the Kalman filter
      starts from the estimate) while the old connection's answers were not (their state was
      smoothed); every frame sent on the last connections was answered; the closes at the end
      were clean (1000).
  quiet --seconds S
      one stream through the balancer: a frame, S seconds of silence (no frame, no ping from
      the client; the server's first ping comes after --ws-ping-interval, 20 s), then a frame:
      answered on the same connection (HAProxy's `timeout tunnel`, not `timeout server`,
      bounds a silent tunnel).
  long --seconds S
      one stream through the balancer sending frames at 30 a second for S seconds: every frame
      answered on the one connection, closed (1000) by the client at the end (run while the
      replicas age their connections: an upgraded connection is not aged).

Only 127.0.0.1 (the published port) is contacted.
"""

import argparse
import asyncio
import gzip
import json
import os
import sys
import time
import urllib.request
from collections import Counter

from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

LB = os.environ.get("FACEPOSE_LB", "127.0.0.1:8080")
URL = "ws://%s/v1/pose:stream" % LB
FIXTURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "fixtures",
                        "rendered")
FPS = 30.0
# A fresh track's first answer is the estimate itself (the filter starts from it): equal to the
# raw pose within rounding; a smoothed answer of a turning head differs by far more.
FRESH_DEG = 1e-3
SMOOTHED_DEG = 0.1


def log(*a):
    print("compose_ws:", *a, file=sys.stderr, flush=True)


def trajectory(i):
    """The 68 exact landmarks of each frame of rendered trajectory i (150 frames, 30 fps)."""
    path = os.path.join(FIXTURES, "traj%d.jsonl.gz" % (i % 6))
    with gzip.open(path, "rt") as f:
        frames = [json.loads(line) for line in f if line.strip()]
    frames.sort(key=lambda r: r["trajectory"]["frame"])
    return [r["oracle"]["ibug68"] for r in frames]


def ping_pong(n, k):
    """Frame k of a trajectory of n frames played forth and back (no jump at its end)."""
    k %= 2 * n - 2
    return k if k < n else 2 * n - 2 - k


def close_of(e):
    """(code, reason) of a closed connection: 1006 when no close frame came (a drop)."""
    if e.rcvd is not None:
        return e.rcvd.code, e.rcvd.reason
    return 1006, "no close frame: the connection dropped"


class Conn:
    """One connection of a stream: what it sent and what came back."""

    def __init__(self, served_by, t_open, attempts):
        self.served_by = served_by
        self.t_open = t_open
        self.attempts = attempts  # handshakes that failed before this one
        self.sent = {}  # frame_id -> (trajectory frame, time sent)
        self.answers = []  # (frame_id, trajectory frame, yaw, pitch, roll, smoothed, time)
        self.out_of_order = 0
        self.errors = []
        self.close = None  # (code, reason, time)


class Stream:
    def __init__(self, index, landmarks):
        self.index = index
        self.landmarks = landmarks
        self.conns = []
        self.skipped = 0  # video frames that fell while the stream had no connection
        self.failed_handshakes = []  # reasons
        self.ws = None
        self.conn = None


async def receive(stream, ws, conn):
    expect = 0
    try:
        async for msg in ws:
            a = json.loads(msg)
            fid = a["frame_id"]
            if fid != expect:
                conn.out_of_order += 1
            expect = fid + 1
            face = a["faces"][0]
            if "pose" not in face:
                conn.errors.append(face.get("error"))
                continue
            p = face["pose"]
            conn.answers.append((fid, conn.sent[fid][0], p["yaw"], p["pitch"], p["roll"],
                                 p.get("smoothed") is True, time.time()))
    except ConnectionClosed as e:
        code, reason = close_of(e)
        conn.close = (code, reason, time.time())


async def run_stream(stream, state):
    """Connects, streams, reconnects after a close until state["stop"] is set."""
    attempts = 0
    while not state["stop"]:
        try:
            ws = await connect(URL, open_timeout=5, ping_interval=None, close_timeout=5,
                               max_size=2**22)
        except Exception as e:  # refused handshake (HTTP 5xx), timeout, connection refused
            attempts += 1
            stream.failed_handshakes.append("%s %s" % (type(e).__name__, str(e)[:80]))
            await asyncio.sleep(0.2)
            continue
        conn = Conn(ws.response.headers.get("x-served-by"), time.time(), attempts)
        attempts = 0
        stream.conns.append(conn)
        stream.ws, stream.conn = ws, conn
        await receive(stream, ws, conn)
        stream.ws = None
        if conn.close is None:  # ended by our own close (the iterator stops without raising)
            conn.close = (ws.close_code if ws.close_code is not None else 1006,
                          ws.close_reason or "", time.time())
        if state["stop"]:
            break
        log("stream %d: closed %s %r by %s" % (stream.index, conn.close[0], conn.close[1],
                                               conn.served_by))
        await asyncio.sleep(0.1)


async def tick(streams, state):
    """The video: every 1/FPS s each stream's next frame, sent when the stream is connected."""
    k = 0
    t0 = time.monotonic()
    while not state["ticking_stop"]:
        for s in streams:
            n = len(s.landmarks)
            f = ping_pong(n, k + 11 * s.index)  # streams at different places of their motions
            ws, conn = s.ws, s.conn
            if ws is None or conn is None or conn.close is not None:
                s.skipped += 1
                continue
            fid = len(conn.sent)
            frame = {"frame_id": fid, "timestamp_us": 1_000_000 + round(k * 1e6 / FPS),
                     "faces": [{"id": "t1", "landmarks": s.landmarks[f]}]}
            if fid == 0:
                frame["smoothing"] = {"enabled": True}  # Kalman, the defaults
            conn.sent[fid] = (f, time.time())
            try:
                await ws.send(json.dumps(frame))
            except ConnectionClosed:
                del conn.sent[fid]
                s.skipped += 1
        k += 1
        delay = t0 + k / FPS - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)


def raw_poses(landmarks):
    """The unsmoothed estimate of each landmark set (POST /v1/pose:batch through the balancer)."""
    body = json.dumps({"faces": [{"landmarks": lm, "id": i} for i, lm in enumerate(landmarks)]})
    req = urllib.request.Request("http://%s/v1/pose:batch" % LB, data=body.encode(),
                                 headers={"content-type": "application/json"})
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(req, timeout=20) as r:
        res = json.load(r)["results"]
    return [(x["yaw"], x["pitch"], x["roll"]) for x in res]


def deg_diff(a, b):
    return max(abs((x - y + 180) % 360 - 180) for x, y in zip(a, b))


async def cmd_streams(a):
    streams = [Stream(i, trajectory(i)) for i in range(a.streams)]
    state = {"stop": False, "ticking_stop": False}
    tasks = [asyncio.create_task(run_stream(s, state)) for s in streams]
    # Every stream open before the video starts.
    deadline = time.time() + 20
    while any(s.ws is None for s in streams) and time.time() < deadline:
        await asyncio.sleep(0.05)
    problems = []
    if any(s.ws is None for s in streams):
        problems.append("not every stream opened within 20 s")
    ticker = asyncio.create_task(tick(streams, state))
    await asyncio.sleep(a.before)
    before = {"sent": sum(len(s.conns[0].sent) for s in streams),
              "answered": sum(len(s.conns[0].answers) for s in streams)}
    victims = [s for s in streams if s.conns[0].served_by == a.victim]
    log("%d streams, %d on %s; %d frames sent, %d answered; running: %s" % (
        len(streams), len(victims), a.victim, before["sent"], before["answered"],
        " ".join(a.command)))
    t_action = time.time()
    proc = await asyncio.create_subprocess_exec(*a.command, stdout=asyncio.subprocess.DEVNULL,
                                                stderr=asyncio.subprocess.PIPE)
    cmd_task = asyncio.create_task(proc.communicate())
    # Until the command is done and every stream has streamed `after` s on its last connection.
    deadline = t_action + a.timeout
    while time.time() < deadline:
        await asyncio.sleep(0.1)
        if not cmd_task.done():
            continue
        if all(s.ws is not None and s.conn.close is None and
               len(s.conn.answers) >= a.after * FPS * 0.9 and
               (s.conn.t_open < t_action or time.time() - s.conn.t_open >= a.after)
               for s in streams) and time.time() - t_action >= a.after:
            break
    else:
        problems.append("the streams did not all stream %s s after the command within %s s"
                        % (a.after, a.timeout))
    if not cmd_task.done():
        proc.kill()
    _, err = await cmd_task
    if proc.returncode != 0:
        problems.append("%s exited %s: %s" % (" ".join(a.command), proc.returncode,
                                               err.decode(errors="replace")[-200:]))
    t_cmd = time.time() - t_action
    # The end: no new frame; every answer awaited (5 s at most); each stream closed (1000).
    state["ticking_stop"] = True
    await ticker
    deadline = time.time() + 5
    while time.time() < deadline and any(
            s.conn is not None and s.conn.close is None and len(s.conn.answers) < len(s.conn.sent)
            for s in streams):
        await asyncio.sleep(0.05)
    state["stop"] = True
    for s in streams:
        if s.ws is not None:
            await s.ws.close(1000, "done")
    await asyncio.gather(*tasks)

    # Raw estimates of every trajectory frame used, for the fresh-track check.
    raw = {}
    for s in streams:
        used = sorted({x[1] for c in s.conns for x in c.answers})
        raw[s.index] = dict(zip(used, raw_poses([s.landmarks[f] for f in used])))

    spread = Counter(s.conns[0].served_by for s in streams)
    if not victims:
        problems.append("no stream on %s (spread %s)" % (a.victim, dict(spread)))
    if len(spread) < 2:
        problems.append("the streams are not spread over the replicas: %s" % dict(spread))
    closes, per_stream = [], []
    lost = skipped = after_answers = 0
    reconnect_s, first_answer_s, close_after_s = [], [], []
    for s in streams:
        on_victim = s in victims
        cs = s.conns
        for c in cs:
            unsmoothed = sum(1 for x in c.answers if not x[5])
            if unsmoothed:
                problems.append("stream %d: %d answers not smoothed" % (s.index, unsmoothed))
            if c.out_of_order:
                problems.append("stream %d: %d answers out of order" % (s.index, c.out_of_order))
            if c.errors:
                problems.append("stream %d: face errors %s" % (s.index, c.errors[:2]))
        # The connections that ended under the stream (not its own close at the end).
        broken = cs[:-1]
        last = cs[-1]
        if last.close is None or last.close[0] != 1000:
            problems.append("stream %d: the final close was %s, not 1000" % (s.index, last.close))
        if len(last.answers) < len(last.sent):
            problems.append("stream %d: %d of %d frames on its last connection unanswered" % (
                s.index, len(last.sent) - len(last.answers), len(last.sent)))
        if not on_victim and broken:
            problems.append("stream %d on %s (not the victim) closed: %s" % (
                s.index, cs[0].served_by, [c.close[:2] for c in broken]))
        if on_victim and len(broken) != 1:
            problems.append("stream %d on %s: %d connections ended under it (1 expected)" % (
                s.index, a.victim, len(broken)))
        row = {"stream": s.index, "served_by": [c.served_by for c in cs]}
        for old, new in zip(broken, cs[1:]):
            code, reason, t_close = old.close
            closes.append({"code": code, "reason": reason})
            if code not in a.expect_code:
                problems.append("stream %d: close %s %r (expected %s)" % (
                    s.index, code, reason, a.expect_code))
            unanswered = len(old.sent) - len(old.answers)
            lost += unanswered
            after_answers += len(new.answers)
            rs = new.t_open - t_close
            fa = (new.answers[0][6] - t_close) if new.answers else None
            reconnect_s.append(rs)
            close_after_s.append(t_close - t_action)
            if fa is not None:
                first_answer_s.append(fa)
            if new.served_by == a.victim or new.served_by is None:
                problems.append("stream %d reconnected to %s" % (s.index, new.served_by))
            if rs > a.reconnect_bound:
                problems.append("stream %d: reconnected %.2f s after its close (bound %s s)" % (
                    s.index, rs, a.reconnect_bound))
            # Fresh track: the new connection's first answer is the raw estimate; the old
            # connection's answers were smoothed away from it.
            if not new.answers:
                problems.append("stream %d: no answer after reconnecting" % s.index)
                continue
            first = new.answers[0]
            d_first = deg_diff(first[2:5], raw[s.index][first[1]])
            d_old = max((deg_diff(x[2:5], raw[s.index][x[1]]) for x in old.answers), default=0)
            if d_first > FRESH_DEG:
                problems.append("stream %d: first answer after reconnecting %.4f° from the raw "
                                "estimate (a fresh track gives it within %g°)" % (
                                    s.index, d_first, FRESH_DEG))
            if d_old < SMOOTHED_DEG:
                problems.append("stream %d: the old connection's answers within %.4f° of the "
                                "raw estimates (not smoothed?)" % (s.index, d_old))
            row.update({"close": [code, reason], "close_after_action_s": round(t_close - t_action, 2),
                        "sent_on_old": len(old.sent), "answered_on_old": len(old.answers),
                        "unanswered": unanswered, "failed_handshakes": new.attempts,
                        "reconnect_s": round(rs, 3),
                        "first_answer_s": None if fa is None else round(fa, 3),
                        "first_answer_vs_raw_deg": round(d_first, 6),
                        "old_answers_vs_raw_max_deg": round(d_old, 2),
                        "answers_after": len(new.answers)})
        skipped += s.skipped
        per_stream.append(row)
    total_sent = sum(len(c.sent) for s in streams for c in s.conns)
    total_answered = sum(len(c.answers) for s in streams for c in s.conns)

    def stats(v):
        return {"min": round(min(v), 3), "max": round(max(v), 3)} if v else None

    out = {"command": " ".join(a.command), "command_s": round(t_cmd, 2),
           "streams": len(streams), "connections": sum(len(s.conns) for s in streams),
           "spread": dict(spread), "victim": a.victim,
           "on_victim": len(victims), "before": before,
           "close_codes": dict(Counter(str(c["code"]) for c in closes)),
           "close_reasons": sorted({c["reason"] for c in closes}),
           "close_after_action_s": stats(close_after_s),
           "reconnect_s": stats(reconnect_s), "first_answer_after_close_s": stats(first_answer_s),
           "failed_handshakes": sum(len(s.failed_handshakes) for s in streams),
           "handshake_failures": sorted(set(r for s in streams for r in s.failed_handshakes))[:5],
           "unanswered_on_closed": lost, "skipped_while_reconnecting": skipped,
           "answers_after_reconnect": after_answers,
           "sent": total_sent, "answered": total_answered,
           "per_stream": per_stream, "problems": problems, "ok": not problems}
    print(json.dumps(out), flush=True)


async def cmd_quiet(a):
    lm = trajectory(0)[0]
    problems = []
    async with connect(URL, open_timeout=5, ping_interval=None) as ws:
        served = ws.response.headers.get("x-served-by")
        t0 = time.time()
        got = []
        try:
            for fid in (0, 1):
                if fid == 1:
                    await asyncio.sleep(a.seconds)
                await ws.send(json.dumps({"frame_id": fid, "faces": [{"id": "t1", "landmarks": lm}],
                                          "smoothing": {"enabled": True}}))
                got.append(json.loads(await asyncio.wait_for(ws.recv(), 10))["frame_id"])
            await ws.close(1000, "done")
            close = [ws.close_code, ws.close_reason]
        except ConnectionClosed as e:
            close = list(close_of(e))
            problems.append("closed after %.1f s of silence: %s %r" % (
                time.time() - t0, close[0], close[1]))
    if got != [0, 1]:
        problems.append("answers %s (0 and 1 expected)" % got)
    print(json.dumps({"served_by": served, "silence_s": a.seconds, "answers": got,
                      "close": close, "problems": problems, "ok": not problems}), flush=True)


async def cmd_long(a):
    lm = trajectory(1)
    problems = []
    sent = answered = 0
    close = None
    t0 = time.time()
    async with connect(URL, open_timeout=5, ping_interval=None) as ws:
        served = ws.response.headers.get("x-served-by")

        async def reader():
            nonlocal answered
            async for msg in ws:
                if json.loads(msg)["frame_id"] == answered:
                    answered += 1

        r = asyncio.create_task(reader())
        try:
            k = 0
            while time.time() - t0 < a.seconds and not r.done():
                frame = {"frame_id": k, "faces": [{"id": "t1", "landmarks": lm[ping_pong(len(lm), k)]}]}
                if k == 0:
                    frame["smoothing"] = {"enabled": True}
                await ws.send(json.dumps(frame))
                sent = k = k + 1
                await asyncio.sleep(max(0.0, t0 + k / FPS - time.time()))
            deadline = time.time() + 5
            while answered < sent and time.time() < deadline and not r.done():
                await asyncio.sleep(0.05)
            if r.done():
                problems.append("closed by the other side after %.1f s: %s %r" % (
                    time.time() - t0, ws.close_code, ws.close_reason))
            await ws.close(1000, "done")
        except ConnectionClosed as e:
            problems.append("closed after %.1f s: %s %r" % ((time.time() - t0,) + close_of(e)))
        close = [ws.close_code, ws.close_reason]
        await asyncio.gather(r, return_exceptions=True)
    if answered != sent:
        problems.append("%d of %d frames answered" % (answered, sent))
    print(json.dumps({"served_by": served, "seconds": round(time.time() - t0, 1), "sent": sent,
                      "answered": answered, "close": close, "problems": problems,
                      "ok": not problems}), flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    q = sub.add_parser("streams")
    q.add_argument("--victim", required=True)
    q.add_argument("--streams", type=int, default=6)
    q.add_argument("--before", type=float, default=5)
    q.add_argument("--after", type=float, default=4)
    q.add_argument("--timeout", type=float, default=45)
    q.add_argument("--reconnect-bound", type=float, default=5)
    q.add_argument("--expect-code", type=int, action="append", required=True)
    q.add_argument("command", nargs="+")
    q = sub.add_parser("quiet")
    q.add_argument("--seconds", type=float, default=15)
    q = sub.add_parser("long")
    q.add_argument("--seconds", type=float, default=30)
    a = p.parse_args()
    asyncio.run({"streams": cmd_streams, "quiet": cmd_quiet, "long": cmd_long}[a.cmd](a))


if __name__ == "__main__":
    main()
