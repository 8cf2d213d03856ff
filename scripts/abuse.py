#!/usr/bin/env python3
# Abuse test of `facepose serve`: hostile clients against one server, one case after another,
# while /healthz is probed and the server's memory is sampled. Run it through scripts/abuse.sh,
# which builds the release binary and makes the venv with `h2` that the gRPC cases need.
#
#   scripts/abuse.sh                          # every case, 20 s each (40 s for c and d)
#   ABUSE_CASES="a e" scripts/abuse.sh        # some cases
#   ABUSE_SECONDS=10 ABUSE_LONG_SECONDS=35 scripts/abuse.sh
#
# Each case gets a fresh server (target/release/facepose serve --addr 127.0.0.1:PORT --log warn
# --models EMPTY_TEMP_DIR, open-file limit 8192 so that the default --max-connections is 8064),
# warmed up with a few real poses (AFLW2000-3D landmarks from ../shared/data) before its idle
# RSS is read. During the case a thread probes GET /healthz every 10 ms on a kept-alive
# connection and another every 100 ms on a fresh one (latency = request written to answer
# read; a probe fails on a non-200, an error or 2 s without an answer), and a third reads
# VmRSS every 50 ms (peak: the largest sample or VmHWM, reset through /proc/PID/clear_refs at
# the case's start). The attackers run in child processes at nice ABUSE_NICE (10), so that on
# a small machine the probes measure the server, not the probing client's share of the cores.
#
#   baseline  no load: the probes alone
#   a   gRPC EstimateBatch of 8 MiB, b"\x0a\x00" * 4194272 (empty faces), 4 callers
#   b1  POST /v1/pose:batch, 480,000 {"landmarks":[]} faces (8.2 MB), 20 concurrent
#   b2  POST /v1/pose, 1.6 million null landmarks (8 MB), 60 concurrent
#   c   slowloris: 1,000 connections sending a header byte every 3 s each (reopened when closed)
#   d   2,000 idle TCP connections (nothing sent)
#   d2  past the cap: a server with --max-connections 1000, 1,000 idle connections held, then
#       new connections sending GET /healthz, answered 503 (only kept-alive probes here: a
#       fresh probe connection past the cap is refused by design)
#   e   20,000-character and 7 MB scheme / method / model values, HTTP and gRPC (Estimate);
#       every answer must be under 2 KiB
#   w1  WebSocket (GET /v1/pose:stream) frames of 9 MB, over --max-body: a close 1009 each
#   w2  3,000 WebSocket streams opened and held (1,500 from each of 2 clients): --max-streams
#       (1024) open, the rest refused at the handshake (503)
#   w3  WebSocket slow readers (--ws-queue 8): 8 clients sending 100-face frames as fast as the
#       server takes them and reading nothing: each stream closed with 1008
#   w4  WebSocket frames after the client's close (a frame, the close, 20 frames): the first
#       answered, the close echoed (1000), the rest ignored
#
# Targets per case (docs: the abuse issue): peak RSS under 2x the idle RSS before the case,
# /healthz p99 under 50 ms, no /healthz failure; and (ours) the server alive at the end with
# only the answers the case expects. Prints a Markdown table; exits 1 if any target is missed.
# Not part of CI.
import collections
import json
import math
import multiprocessing as mp
import os
import resource
import select
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

try:
    import h2.config
    import h2.connection
    import h2.events
    import h2.exceptions
    import h2.settings
except ImportError:  # pragma: no cover
    sys.exit("abuse.py needs the h2 package: run it through scripts/abuse.sh (it makes the venv)")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("FACEPOSE_BIN", os.path.join(ROOT, "target/release/facepose"))
DATA = os.environ.get("FACEPOSE_DATA", os.path.join(ROOT, "../shared/data"))
SECONDS = float(os.environ.get("ABUSE_SECONDS", "20"))
LONG_SECONDS = float(os.environ.get("ABUSE_LONG_SECONDS", "40"))
NICE = int(os.environ.get("ABUSE_NICE", "10"))
SERVER_NOFILE = 8192
KIB = 1024
MIB = 1024 * 1024

GRPC_CODES = {0: "OK", 1: "CANCELLED", 2: "UNKNOWN", 3: "INVALID_ARGUMENT",
              4: "DEADLINE_EXCEEDED", 5: "NOT_FOUND", 6: "ALREADY_EXISTS",
              7: "PERMISSION_DENIED", 8: "RESOURCE_EXHAUSTED", 9: "FAILED_PRECONDITION",
              10: "ABORTED", 11: "OUT_OF_RANGE", 12: "UNIMPLEMENTED", 13: "INTERNAL",
              14: "UNAVAILABLE", 15: "DATA_LOSS", 16: "UNAUTHENTICATED"}


# ---------------------------------------------------------------------------------------------
# Faces, JSON bodies and protobuf messages
# ---------------------------------------------------------------------------------------------

def real_faces(limit=None):
    """68-point faces (ibug68, image pixels) of the AFLW2000-3D development split: the 3DMM
    fits' landmarks, which are of the default `projected` landmark style."""
    faces = []
    with open(os.path.join(DATA, "aflw2000/aflw2000_dev.jsonl")) as f:
        for line in f:
            faces.append([[float(x), float(y)] for x, y in json.loads(line)["landmarks_fitted"]])
            if limit and len(faces) >= limit:
                break
    return faces


def varint(n):
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def pb_bytes(field, data):
    return varint(field << 3 | 2) + varint(len(data)) + data


def pb_double(field, v):
    return varint(field << 3 | 1) + struct.pack("<d", v)


def pb_str(field, s):
    return pb_bytes(field, s.encode() if isinstance(s, str) else s) if s else b""


def pb_face(points, scheme="", method="", packed=False, face_id=""):
    """facepose.v1.Face: Landmark messages (field 1) or packed xy (field 7)."""
    if packed:
        body = pb_bytes(7, struct.pack("<%dd" % (2 * len(points)), *[c for p in points for c in p]))
    else:
        body = b"".join(pb_bytes(1, pb_double(1, x) + pb_double(2, y)) for x, y in points)
    return body + pb_str(2, scheme) + pb_str(3, method) + pb_str(5, face_id)


def pb_estimate(points, scheme="", method="", model="", packed=False):
    """facepose.v1.EstimateRequest."""
    return pb_bytes(1, pb_face(points, scheme, method, packed)) + pb_str(2, model)


def pb_batch(faces, model="", packed=True):
    """facepose.v1.EstimateBatchRequest."""
    return b"".join(pb_bytes(1, pb_face(f, packed=packed)) for f in faces) + pb_str(2, model)


# ---------------------------------------------------------------------------------------------
# HTTP/1.1 on raw sockets
# ---------------------------------------------------------------------------------------------

class ConnectionClosed(Exception):
    pass


def http_request(method, path, body=b"", content_type="application/json", headers=()):
    head = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1"]
    if body or method == "POST":
        head.append(f"Content-Type: {content_type}")
        head.append(f"Content-Length: {len(body)}")
    head.extend(headers)
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


def parse_response(buf, eof=False):
    """(status, header bytes, body, total bytes, close) of the first complete response in
    `buf`, or None while incomplete."""
    end = buf.find(b"\r\n\r\n")
    if end < 0:
        return None
    lines = bytes(buf[:end]).decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    hdrs = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        hdrs[k.strip().lower()] = v.strip()
    start = end + 4
    close = hdrs.get("connection", "").lower() == "close"
    if "content-length" in hdrs:
        n = int(hdrs["content-length"])
        if len(buf) < start + n:
            return None
        return status, start, bytes(buf[start:start + n]), start + n, close
    if hdrs.get("transfer-encoding", "").lower() == "chunked":
        pos, body = start, bytearray()
        while True:
            le = buf.find(b"\r\n", pos)
            if le < 0:
                return None
            size = int(bytes(buf[pos:le]).split(b";")[0], 16)
            if len(buf) < le + 2 + size + 2:
                return None
            body += buf[le + 2:le + 2 + size]
            pos = le + 2 + size + 2
            if size == 0:
                return status, start, bytes(body), pos, close
    if status in (204, 304) or 100 <= status < 200:
        return status, start, b"", start, close
    if eof:
        return status, start, bytes(buf[start:]), len(buf), True
    return None


def exchange(sock, data, timeout):
    """Sends `data` on `sock` while reading, and returns the first response as
    (status, total response bytes, body, close). A server may answer before it has read the
    whole request (and close): the answer counts."""
    deadline = time.monotonic() + timeout
    sock.setblocking(False)
    poller = select.poll()
    view = memoryview(data)
    sent, buf, sending = 0, bytearray(), True
    while True:
        want = select.POLLIN | (select.POLLOUT if sending and sent < len(view) else 0)
        poller.register(sock, want)
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("no answer within %.1f s" % timeout)
        for _, ev in poller.poll(left * 1000):
            if ev & select.POLLOUT and sending and sent < len(view):
                try:
                    sent += sock.send(view[sent:sent + MIB])
                except (BlockingIOError, InterruptedError):
                    pass
                except (BrokenPipeError, ConnectionResetError):
                    sending = False
            if ev & (select.POLLIN | select.POLLHUP | select.POLLERR):
                try:
                    chunk = sock.recv(1 << 16)
                except (BlockingIOError, InterruptedError):
                    continue
                except ConnectionResetError:
                    chunk = b""
                    if not buf:
                        raise ConnectionClosed("connection reset before an answer")
                if chunk:
                    buf += chunk
                    r = parse_response(buf)
                else:
                    r = parse_response(buf, eof=True)
                    if r is None:
                        raise ConnectionClosed(
                            "connection closed before an answer (%d of %d bytes sent)"
                            % (sent, len(view)))
                if r is not None:
                    status, _, body, total, close = r
                    # An answer before the whole request was sent: the connection is done.
                    return status, total, body, close or not chunk or sent < len(view)


def connect(port, timeout=5.0):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def http_call(port, method, path, body=b"", headers=(), timeout=10.0):
    """One request on a fresh connection: (status, body)."""
    s = connect(port)
    try:
        status, _, rbody, _ = exchange(s, http_request(method, path, body, headers=headers), timeout)
        return status, rbody
    finally:
        s.close()


# ---------------------------------------------------------------------------------------------
# gRPC on HTTP/2 (the h2 package for the framing; messages built by hand)
# ---------------------------------------------------------------------------------------------

class Grpc:
    """One HTTP/2 connection, unary gRPC calls one after another."""

    def __init__(self, port, timeout=30.0):
        self.port, self.timeout = port, timeout
        self.sock = connect(port, timeout)
        self.sock.settimeout(timeout)
        self.h2 = h2.connection.H2Connection(
            h2.config.H2Configuration(client_side=True, header_encoding="utf-8"))
        self.h2.initiate_connection()
        self.h2.update_settings({h2.settings.SettingCodes.INITIAL_WINDOW_SIZE: 16 * MIB})
        self.h2.increment_flow_control_window(64 * MIB)
        self.flush()

    def flush(self):
        d = self.h2.data_to_send()
        if d:
            self.sock.sendall(d)

    def close(self):
        try:
            self.h2.close_connection()
            self.flush()
        except Exception:
            pass
        self.sock.close()

    def call(self, rpc, message, metadata=(), service="facepose.v1.PoseService"):
        """(status name, grpc-message, response bytes: headers + trailers + data, data)."""
        sid = self.h2.get_next_available_stream_id()
        self.h2.send_headers(sid, [
            (":method", "POST"), (":scheme", "http"), (":path", f"/{service}/{rpc}"),
            (":authority", f"127.0.0.1:{self.port}"), ("content-type", "application/grpc"),
            ("te", "trailers"), *metadata])
        payload = b"\x00" + struct.pack(">I", len(message)) + message
        sent, done = 0, False
        status, gmsg, size, data = None, "", 0, bytearray()
        deadline = time.monotonic() + self.timeout

        def headers_of(hs):
            nonlocal status, gmsg, size
            for k, v in hs:
                size += len(k) + len(v)
                if k == "grpc-status":
                    status = GRPC_CODES.get(int(v), v)
                elif k == "grpc-message":
                    gmsg = v
        while True:
            while sent < len(payload) and not done:
                try:
                    n = min(self.h2.local_flow_control_window(sid),
                            self.h2.max_outbound_frame_size, len(payload) - sent)
                except (h2.exceptions.StreamClosedError, KeyError):
                    break
                if n <= 0:
                    break
                try:
                    self.h2.send_data(sid, payload[sent:sent + n],
                                      end_stream=sent + n == len(payload))
                except h2.exceptions.StreamClosedError:
                    break
                sent += n
                if sent % (MIB) < n:
                    self.flush()
            self.flush()
            if done:
                break
            if time.monotonic() > deadline:
                raise TimeoutError("gRPC %s: no answer within %.0f s" % (rpc, self.timeout))
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise ConnectionClosed("connection closed during %s" % rpc)
            for ev in self.h2.receive_data(chunk):
                if isinstance(ev, h2.events.ConnectionTerminated):
                    if status is None:
                        raise ConnectionClosed("GOAWAY (%s) during %s" % (ev.error_code, rpc))
                    done = True
                if getattr(ev, "stream_id", sid) != sid:
                    continue
                if isinstance(ev, h2.events.ResponseReceived):
                    headers_of(ev.headers)
                elif isinstance(ev, h2.events.TrailersReceived):
                    headers_of(ev.headers)
                elif isinstance(ev, h2.events.DataReceived):
                    size += len(ev.data)
                    data += ev.data
                    self.h2.acknowledge_received_data(ev.flow_controlled_length, sid)
                elif isinstance(ev, h2.events.StreamEnded):
                    done = True
                elif isinstance(ev, h2.events.StreamReset):
                    done = True
                    if status is None:
                        status = "RST_STREAM(%s)" % ev.error_code
            self.flush()
        return status, gmsg, size, bytes(data)


def grpc_message(data):
    """The first message of a gRPC response body."""
    if len(data) < 5:
        return b""
    n = struct.unpack(">I", data[1:5])[0]
    return data[5:5 + n]


# ---------------------------------------------------------------------------------------------
# The server, and what watches it
# ---------------------------------------------------------------------------------------------

def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Server:
    """target/release/facepose serve on a free loopback port with its own models folder."""

    def __init__(self, extra=(), nofile=SERVER_NOFILE, env=None, models=None, log_name="server"):
        self.extra, self.nofile, self.env = list(extra), nofile, env
        self.tmp = tempfile.mkdtemp(prefix="facepose-%s-" % log_name)
        self.models = models or os.path.join(self.tmp, "models")
        os.makedirs(self.models, exist_ok=True)
        self.log_path = os.path.join(self.tmp, log_name + ".log")
        self.proc = None

    def start(self):
        self.port = free_port()
        args = [BIN, "serve", "--addr", f"127.0.0.1:{self.port}", "--log", "warn",
                "--models", self.models, *self.extra]
        nofile = self.nofile

        def limits():
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))
            os.setpgrp()
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT,
                                     preexec_fn=limits, env=self.env)
        t0 = time.monotonic()
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError("server exited with %s: %s" % (self.proc.returncode, self.log_tail()))
            try:
                if http_call(self.port, "GET", "/readyz", timeout=1)[0] == 200:
                    break
            except OSError:
                pass
            if time.monotonic() - t0 > 20:
                raise RuntimeError("server not ready after 20 s")
            time.sleep(0.01)
        self.ready_ms = (time.monotonic() - t0) * 1000
        return self

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def status(self, key):
        try:
            with open(f"/proc/{self.proc.pid}/status") as f:
                for line in f:
                    if line.startswith(key + ":"):
                        return int(line.split()[1])
        except OSError:
            return None
        return None

    def rss_kb(self):
        return self.status("VmRSS")

    def reset_peak(self):
        try:
            with open(f"/proc/{self.proc.pid}/clear_refs", "w") as f:
                f.write("5")
            return True
        except OSError:
            return False

    def log_tail(self, n=20):
        try:
            with open(self.log_path, "rb") as f:
                return b"\n".join(f.read().splitlines()[-n:]).decode("utf-8", "replace")
        except OSError:
            return ""

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc:
            self.log.close()
        subprocess.run(["rm", "-rf", self.tmp])


def listen_drops():
    """The kernel's ListenOverflows + ListenDrops (TcpExt): SYNs dropped because an accept
    queue was full (the whole machine's, which is mostly ours here)."""
    try:
        with open("/proc/net/netstat") as f:
            lines = [l.split() for l in f if l.startswith("TcpExt:")]
        d = dict(zip(lines[0][1:], map(int, lines[1][1:])))
        return d.get("ListenOverflows", 0), d.get("ListenDrops", 0)
    except (OSError, IndexError, ValueError):
        return None


def percentile(sorted_values, p):
    if not sorted_values:
        return float("nan")
    k = max(0, min(len(sorted_values) - 1, math.ceil(p / 100 * len(sorted_values)) - 1))
    return sorted_values[k]


class HealthProbe(threading.Thread):
    """GET /healthz every `interval` s, on one kept-alive connection (reopened after an
    error) or a fresh connection each time."""

    TIMEOUT = 2.0

    def __init__(self, port, interval, fresh):
        super().__init__(daemon=True)
        self.port, self.interval, self.fresh = port, interval, fresh
        self.stop_ev = threading.Event()
        self.samples = []   # (ms, ok)
        self.errors = collections.Counter()
        self.req = http_request("GET", "/healthz")

    def run(self):
        sock = None
        nxt = time.monotonic()
        while not self.stop_ev.is_set():
            t0 = time.monotonic()
            ok, err = False, None
            try:
                if sock is None:
                    sock = connect(self.port, self.TIMEOUT)
                status, _, _, close = exchange(sock, self.req, self.TIMEOUT)
                ok = status == 200
                if not ok:
                    err = "HTTP %d" % status
                if close or self.fresh or not ok:
                    sock.close()
                    sock = None
            except Exception as e:  # noqa: BLE001 - every failure counts
                err = type(e).__name__ + ": " + str(e)[:80]
                if sock is not None:
                    sock.close()
                sock = None
            ms = (time.monotonic() - t0) * 1000
            self.samples.append((ms, ok))
            if err:
                self.errors[err] += 1
            nxt += self.interval
            delay = nxt - time.monotonic()
            if delay > 0:
                self.stop_ev.wait(delay)
            else:
                nxt = time.monotonic()
        if sock is not None:
            sock.close()


class RssSampler(threading.Thread):
    def __init__(self, server, interval=0.05):
        super().__init__(daemon=True)
        self.server, self.interval = server, interval
        self.stop_ev = threading.Event()
        self.samples = []

    def run(self):
        while not self.stop_ev.is_set():
            kb = self.server.rss_kb()
            if kb is not None:
                self.samples.append(kb)
            self.stop_ev.wait(self.interval)


# ---------------------------------------------------------------------------------------------
# The attackers (child processes; each puts one result dict on the queue)
# ---------------------------------------------------------------------------------------------

def new_result():
    return {"sent": 0, "answers": collections.Counter(), "max_answer": {}, "notes": []}


def merge(results):
    total = new_result()
    for r in results:
        total["sent"] += r["sent"]
        total["answers"].update(r["answers"])
        for k, v in r["max_answer"].items():
            total["max_answer"][k] = max(v, total["max_answer"].get(k, 0))
        total["notes"].extend(r["notes"])
    return total


def attacker(fn, args, stop, queue):
    os.nice(NICE)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    res = new_result()
    try:
        fn(res, stop, *args)
    except Exception as e:  # noqa: BLE001
        res["notes"].append("attacker %s failed: %r" % (fn.__name__, e))
    res["answers"] = dict(res["answers"])
    queue.put(res)


def http_flood(res, stop, port, request, threads, label):
    """`threads` connections each sending `request` again and again (kept alive when the
    server keeps them)."""
    mixed_http_flood(res, stop, port, [(label, request)], threads)


def grpc_flood(res, stop, port, rpc, messages):
    """One connection calling `rpc` with each message of `messages` (label, bytes) in turn."""
    conn, i = None, 0
    while not stop.is_set():
        label, msg = messages[i % len(messages)]
        i += 1
        try:
            if conn is None:
                conn = Grpc(port, timeout=60)
            res["sent"] += 1
            status, _, size, _ = conn.call(rpc, msg)
            res["answers"]["gRPC %s" % status] += 1
            res["max_answer"][label] = max(size, res["max_answer"].get(label, 0))
        except Exception as e:  # noqa: BLE001
            res["answers"]["error: " + type(e).__name__] += 1
            if conn is not None:
                conn.sock.close()
            conn = None
            time.sleep(0.05)
    if conn is not None:
        conn.close()


def mixed_http_flood(res, stop, port, requests, threads):
    """`threads` connections, each sending the `requests` (label, bytes) in turn, again and
    again (kept alive when the server keeps them)."""
    lock = threading.Lock()

    def one(k):
        sock, i = None, k
        while not stop.is_set():
            label, req = requests[i % len(requests)]
            i += 1
            try:
                if sock is None:
                    sock = connect(port)
                with lock:
                    res["sent"] += 1
                status, total, _, close = exchange(sock, req, 60)
                with lock:
                    res["answers"]["HTTP %d" % status] += 1
                    res["max_answer"][label] = max(total, res["max_answer"].get(label, 0))
                if close:
                    sock.close()
                    sock = None
            except Exception as e:  # noqa: BLE001
                with lock:
                    res["answers"]["error: " + type(e).__name__] += 1
                if sock is not None:
                    sock.close()
                sock = None
                time.sleep(0.05)
        if sock is not None:
            sock.close()
    ts = [threading.Thread(target=one, args=(k,)) for k in range(threads)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()


def open_many(port, n, res):
    socks = []
    for _ in range(n):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.setblocking(False)
            socks.append(s)
        except OSError as e:
            res["answers"]["connect error: " + type(e).__name__] += 1
    return socks


class SockSet:
    """Sockets watched for the server's answer or close."""

    def __init__(self, socks=()):
        self.poller = select.poll()
        self.by_fd = {}
        for s in socks:
            self.add(s)

    def add(self, s):
        self.by_fd[s.fileno()] = s
        self.poller.register(s, select.POLLIN)

    def __len__(self):
        return len(self.by_fd)

    def reap(self, res, label_closed):
        """Counts and closes the sockets the server answered or closed; returns how many."""
        n = 0
        for fd, _ in self.poller.poll(0):
            s = self.by_fd.pop(fd, None)
            if s is None:
                continue
            self.poller.unregister(fd)
            try:
                data = s.recv(4096)
            except OSError:
                data = b""
            if data.startswith(b"HTTP/"):
                res["answers"]["HTTP %s" % data.split()[1].decode()] += 1
            elif data:
                res["answers"]["other bytes"] += 1
            else:
                res["answers"][label_closed] += 1
            s.close()
            n += 1
        return n

    def close(self):
        for s in self.by_fd.values():
            s.close()


def slowloris(res, stop, port, n, period):
    """n connections, each sending one byte of an endless request head every `period` s;
    a connection the server closes is opened again."""
    head = b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 100000
    t0 = time.monotonic()
    socks = open_many(port, n, res)
    res["sent"] += len(socks)
    watched = SockSet(socks)
    pos = {s.fileno(): 0 for s in socks}
    first_close, sent_bytes = None, 0
    tick, k = 0.1, 0
    while not stop.is_set():
        # Each tick sends a byte on the connections of one slot: every one once a period.
        slots = max(1, int(period / tick))
        for fd, s in list(watched.by_fd.items()):
            if fd % slots == k % slots:
                try:
                    s.send(head[pos[fd]:pos[fd] + 1])
                    pos[fd] += 1
                    sent_bytes += 1
                except OSError:
                    pass
        k += 1
        closed = watched.reap(res, "closed by the server")
        if closed and first_close is None:
            first_close = time.monotonic() - t0
        for _ in range(closed):
            try:
                s = socket.create_connection(("127.0.0.1", port), timeout=5)
                s.setblocking(False)
                res["sent"] += 1
                watched.add(s)
                pos[s.fileno()] = 0
            except OSError as e:
                res["answers"]["connect error: " + type(e).__name__] += 1
        stop.wait(tick)
    res["answers"]["open at the end"] = len(watched)
    res["notes"].append("c: %s header bytes sent" % f"{sent_bytes:,}")
    if first_close is not None:
        res["notes"].append("c: first slowloris connection closed by the server after %.1f s" % first_close)
    watched.close()


def idle_conns(res, stop, port, n):
    """n connections that send nothing."""
    t0 = time.monotonic()
    watched = SockSet(open_many(port, n, res))
    res["sent"] += len(watched)
    first_close = None
    while not stop.is_set():
        if watched.reap(res, "closed by the server") and first_close is None:
            first_close = time.monotonic() - t0
        stop.wait(0.1)
    res["answers"]["open at the end"] = len(watched)
    if first_close is not None:
        res["notes"].append("d: first idle connection closed by the server after %.1f s" % first_close)
    watched.close()


def over_cap(res, stop, port, held, threads):
    """`held` idle connections, then `threads` clients opening new connections with
    GET /healthz (past the cap: 503 expected)."""
    watched = SockSet(open_many(port, held, res))
    time.sleep(0.5)
    watched.reap(res, "held connection closed by the server")
    req = http_request("GET", "/healthz")
    lock = threading.Lock()

    def one():
        while not stop.is_set():
            with lock:
                res["sent"] += 1
            try:
                s = connect(port)
                try:
                    status, total, _, _ = exchange(s, req, 10)
                finally:
                    s.close()
                with lock:
                    res["answers"]["HTTP %d" % status] += 1
                    res["max_answer"]["over the cap"] = max(total, res["max_answer"].get("over the cap", 0))
            except Exception as e:  # noqa: BLE001
                with lock:
                    res["answers"]["error: " + type(e).__name__] += 1
            time.sleep(0.001)
    ts = [threading.Thread(target=one) for _ in range(threads)]
    for t in ts:
        t.start()
    while not stop.is_set():
        stop.wait(0.2)
    for t in ts:
        t.join()
    watched.reap(res, "held connection closed by the server")
    res["answers"]["held open at the end"] = len(watched)
    watched.close()


# ---------------------------------------------------------------------------------------------
# WebSocket (GET /v1/pose:stream), framed by hand (RFC 6455; client frames masked)
# ---------------------------------------------------------------------------------------------

WS_HANDSHAKE = (b"GET /v1/pose:stream HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                b"Sec-WebSocket-Version: 13\r\n\r\n")


def ws_frame(payload, opcode=1):
    """One client frame (FIN, masked with a zero key: the bytes are the payload's)."""
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
    elif n < 1 << 16:
        head = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
    else:
        head = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
    return head + b"\0\0\0\0" + payload


class WsSock:
    """A socket and the bytes read past the last frame."""

    def __init__(self, sock):
        self.sock, self.ws_rest = sock, b""

    def sendall(self, data):
        self.sock.sendall(data)

    def recv(self, n):
        return self.sock.recv(n)

    def settimeout(self, t):
        self.sock.settimeout(t)

    def close(self):
        self.sock.close()


def ws_open(port, timeout=10.0):
    """A socket with its handshake done: (socket, None), or (None, the HTTP status)."""
    s = WsSock(connect(port, timeout))
    s.sendall(WS_HANDSHAKE)
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = s.recv(4096)
        if not chunk:
            s.close()
            return None, "closed"
        buf += chunk
    status = int(buf.split()[1])
    if status != 101:
        s.close()
        return None, "HTTP %d" % status
    s.ws_rest = buf.split(b"\r\n\r\n", 1)[1]
    return s, None


def ws_read(s, timeout):
    """The next server frame: (opcode, payload), or None at EOF."""
    s.settimeout(timeout)
    buf = s.ws_rest

    def need(n):
        nonlocal buf
        while len(buf) < n:
            chunk = s.recv(65536)
            if not chunk:
                raise EOFError
            buf += chunk
    try:
        need(2)
        op, n = buf[0] & 0x0F, buf[1] & 0x7F
        at = 2
        if n == 126:
            need(4)
            n, at = struct.unpack("!H", buf[2:4])[0], 4
        elif n == 127:
            need(10)
            n, at = struct.unpack("!Q", buf[2:10])[0], 10
        need(at + n)
    except EOFError:
        return None
    payload, s.ws_rest = buf[at:at + n], buf[at + n:]
    return op, payload


def ws_until_close(s, res, timeout=10.0, count_answers=False):
    """Reads until the server's close; counts it by code ("WS close 1009"), or how it ended."""
    try:
        while True:
            f = ws_read(s, timeout)
            if f is None:
                res["answers"]["WS closed without a close frame"] += 1
                return
            if f[0] == 8:
                code = struct.unpack("!H", f[1][:2])[0] if len(f[1]) >= 2 else 1005
                res["answers"]["WS close %d" % code] += 1
                return
            if f[0] == 1 and count_answers:
                res["answers"]["WS answer"] += 1
    except OSError as e:
        res["answers"]["error: " + type(e).__name__] += 1
    finally:
        s.close()


def ws_huge(res, stop, port, size):
    """Frames of `size` bytes (over --max-body) again and again, each on a new stream."""
    payload = b'{"faces":[' + b" " * (size - 12) + b"]}"
    frame = ws_frame(payload)
    while not stop.is_set():
        try:
            s, refused = ws_open(port)
            if s is None:
                res["answers"][refused] += 1
                time.sleep(0.05)
                continue
            res["sent"] += 1
            try:
                s.sendall(frame)
            except OSError:
                pass  # the server closed as the frame's header said its size
            ws_until_close(s, res)
        except Exception as e:  # noqa: BLE001
            res["answers"]["error: " + type(e).__name__] += 1
            time.sleep(0.05)


def ws_many(res, stop, port, n):
    """`n` streams opened and held without a frame (past --max-streams: 503)."""
    socks = []
    for _ in range(n):
        if stop.is_set():
            break
        try:
            s, refused = ws_open(port)
            res["sent"] += 1
            if s is None:
                res["answers"][refused] += 1
            else:
                socks.append(s)
        except OSError as e:
            res["answers"]["connect error: " + type(e).__name__] += 1
    res["answers"]["WS open"] += len(socks)
    while not stop.is_set():
        stop.wait(0.2)
    for s in socks:
        s.close()


def ws_slow_reader(res, stop, port, frame):
    """Frames sent as fast as the server takes them and no answer read, on stream after
    stream: each should end with the server's close (1008, reads too slowly)."""
    data = ws_frame(frame)
    while not stop.is_set():
        try:
            s, refused = ws_open(port)
            if s is None:
                res["answers"][refused] += 1
                time.sleep(0.05)
                continue
            s.settimeout(10)
            try:
                while not stop.is_set():
                    s.sendall(data)
                    res["sent"] += 1
            except OSError:
                pass
            ws_until_close(s, res, timeout=10)
        except Exception as e:  # noqa: BLE001
            res["answers"]["error: " + type(e).__name__] += 1
            time.sleep(0.05)


def ws_after_close(res, stop, port, frame):
    """A frame, the client's close, then frames after it: the server answers the first and
    the close, and ignores the rest."""
    close = ws_frame(struct.pack("!H", 1000), opcode=8)
    data = ws_frame(frame)
    while not stop.is_set():
        try:
            s, refused = ws_open(port)
            if s is None:
                res["answers"][refused] += 1
                time.sleep(0.05)
                continue
            res["sent"] += 1
            try:
                s.sendall(data + close + data * 20)
            except OSError:
                pass
            ws_until_close(s, res, count_answers=True)
        except Exception as e:  # noqa: BLE001
            res["answers"]["error: " + type(e).__name__] += 1
            time.sleep(0.05)


# ---------------------------------------------------------------------------------------------
# The cases
# ---------------------------------------------------------------------------------------------

def case_list(faces):
    face = faces[0]
    empty_batch = b"\x0a\x00" * 4194272
    batch_body = b'{"faces":[' + b",".join([b'{"landmarks":[]}'] * 480000) + b"]}"
    nulls_body = b'{"landmarks":[' + b",".join([b"null"] * 1600000) + b"]}"
    long_http, long_grpc = [], []
    for n, nlabel in ((20000, "20k"), (7_000_000, "7MB")):
        s = "x" * n
        for field in ("scheme", "method", "model"):
            body = json.dumps({"landmarks": face, field: s}).encode()
            long_http.append(("HTTP %s %s" % (field, nlabel), http_request("POST", "/v1/pose", body)))
            kw = {field: s}
            long_grpc.append(("gRPC %s %s" % (field, nlabel), pb_estimate(face, **kw)))
    ws_one = json.dumps({"faces": [{"id": "t", "landmarks": face}]}).encode()
    ws_batch = json.dumps({"faces": [{"id": str(i), "landmarks": faces[i % len(faces)]}
                                     for i in range(100)]}).encode()
    return [
        dict(name="baseline", what="no load (the probes alone)", seconds=min(SECONDS, 10),
             procs=[], expect=set()),
        dict(name="a", what="gRPC EstimateBatch, 8 MiB of empty faces, 4 callers",
             procs=[(grpc_flood, ("EstimateBatch", [("a", empty_batch)]))] * 4,
             expect={"gRPC INVALID_ARGUMENT", "gRPC RESOURCE_EXHAUSTED"},
             sizes=f"message {len(empty_batch):,} B"),
        dict(name="b1", what="POST /v1/pose:batch, 480,000 empty faces, 20 concurrent",
             procs=[(http_flood, (http_request("POST", "/v1/pose:batch", batch_body), 5, "b1"))] * 4,
             expect={"HTTP 413", "HTTP 422"}, sizes=f"body {len(batch_body):,} B"),
        dict(name="b2", what="POST /v1/pose, 1.6 M null landmarks, 60 concurrent",
             procs=[(http_flood, (http_request("POST", "/v1/pose", nulls_body), 15, "b2"))] * 4,
             expect={"HTTP 413", "HTTP 422"}, sizes=f"body {len(nulls_body):,} B"),
        dict(name="c", what="slowloris, 1,000 connections, a header byte every 3 s each",
             seconds=LONG_SECONDS, procs=[(slowloris, (1000, 3.0))],
             expect={"open at the end", "closed by the server", "HTTP 408"}),
        dict(name="d", what="2,000 idle TCP connections", seconds=LONG_SECONDS,
             procs=[(idle_conns, (2000,))],
             expect={"open at the end", "closed by the server"}),
        dict(name="d2", what="--max-connections 1000: 1,000 held, new ones GET /healthz",
             extra=["--max-connections", "1000"], fresh_probe=False,
             procs=[(over_cap, (1000, 8))],
             expect={"HTTP 503", "held open at the end", "held connection closed by the server"}),
        dict(name="e", what="20,000-char and 7 MB scheme/method/model, HTTP + gRPC",
             procs=[(mixed_http_flood, (long_http, 3))] * 2
             + [(grpc_flood, ("Estimate", long_grpc))] * 2,
             expect={"HTTP 422", "gRPC INVALID_ARGUMENT"}, max_answer=2 * KIB),
        dict(name="w1", what="WebSocket frames of 9 MB (over --max-body), 4 clients",
             procs=[(ws_huge, (9 * MIB,))] * 4,
             expect={"WS close 1009", "WS closed without a close frame"},
             sizes="frame %s B" % f"{9 * MIB:,}"),
        dict(name="w2", what="3,000 WebSocket streams held open (--max-streams 1024)",
             seconds=LONG_SECONDS, procs=[(ws_many, (1500,))] * 2,
             expect={"WS open", "HTTP 503"}),
        dict(name="w3", what="WebSocket slow readers: 100-face frames, no answer read, 8 clients",
             extra=["--ws-queue", "8"], procs=[(ws_slow_reader, (ws_batch,))] * 8,
             # A client that never reads cannot get the close frame: the server gives up on
             # it after 5 s and drops the connection.
             expect={"WS close 1008", "WS closed without a close frame"},
             sizes="frame %s B" % f"{len(ws_batch):,}"),
        dict(name="w4", what="WebSocket frames after the client's close, 4 clients",
             procs=[(ws_after_close, (ws_one,))] * 4,
             expect={"WS answer", "WS close 1000"}),
    ]


def warm_up(server, faces):
    for f in faces[:20]:
        st, body = http_call(server.port, "POST", "/v1/pose", json.dumps({"landmarks": f}).encode())
        if st != 200:
            raise RuntimeError("warm-up pose: HTTP %d %s" % (st, body[:200]))
    batch = json.dumps({"faces": [{"landmarks": f} for f in faces[:100]]}).encode()
    for _ in range(3):
        http_call(server.port, "POST", "/v1/pose:batch", batch)
    g = Grpc(server.port)
    for f in faces[:20]:
        st, msg, _, _ = g.call("Estimate", pb_estimate(f))
        if st != "OK":
            raise RuntimeError("warm-up gRPC Estimate: %s %s" % (st, msg))
    g.close()
    for _ in range(20):
        http_call(server.port, "GET", "/healthz")


def run_case(case, faces):
    seconds = case.get("seconds", SECONDS)
    server = Server(extra=case.get("extra", ()), log_name="server-" + case["name"]).start()
    row = dict(case=case["name"], what=case["what"])
    try:
        warm_up(server, faces)
        time.sleep(1.0)
        idle = server.rss_kb()
        hwm_ok = server.reset_peak()
        probes = [HealthProbe(server.port, 0.010, fresh=False)]
        if case.get("fresh_probe", True):
            probes.append(HealthProbe(server.port, 0.100, fresh=True))
        sampler = RssSampler(server)
        for t in probes + [sampler]:
            t.start()
        time.sleep(0.3)
        drops0 = listen_drops()
        stop = mp.Event()
        queue = mp.Queue()
        procs = [mp.Process(target=attacker, args=(fn, (server.port, *args), stop, queue),
                            daemon=True)
                 for fn, args in case["procs"]]
        for p in procs:
            p.start()
        time.sleep(seconds)
        stop.set()
        results = []
        deadline = time.monotonic() + 90
        while len(results) < len(procs) and time.monotonic() < deadline:
            try:
                results.append(queue.get(timeout=1))
            except Exception:  # noqa: BLE001 - queue.Empty
                if not any(p.is_alive() for p in procs) and queue.empty():
                    break
        for p in procs:
            p.join(5)
            if p.is_alive():
                p.terminate()
        time.sleep(0.3)
        for t in probes + [sampler]:
            t.stop_ev.set()
        for t in probes + [sampler]:
            t.join()
        total = merge(results)
        drops1 = listen_drops()
        if drops0 and drops1 and drops1 != drops0:
            total["notes"].append("kernel: %d listen-queue overflows, %d SYNs dropped during the case"
                                  % (drops1[0] - drops0[0], drops1[1] - drops0[1]))
        if len(results) < len(procs):
            total["notes"].append("%d of %d attackers gave no result" % (len(procs) - len(results), len(procs)))
        hwm = server.status("VmHWM") if hwm_ok else None
        peak = max([idle] + sampler.samples + ([hwm] if hwm else []))
        lat = sorted(ms for p in probes for ms, _ in p.samples)
        fails = sum(1 for p in probes for _, ok in p.samples if not ok)
        errors = collections.Counter()
        for p in probes:
            errors.update(p.errors)
        alive = server.alive()
        row.update(
            sent=total["sent"], answers=total["answers"], max_answer=total["max_answer"],
            notes=total["notes"], idle_kb=idle, peak_kb=peak, ratio=peak / idle,
            p50=percentile(lat, 50), p99=percentile(lat, 99), max=lat[-1] if lat else float("nan"),
            probes=len(lat), fails=fails, errors=errors, alive=alive,
            probe_detail={("kept-alive" if not p.fresh else "fresh"): (
                percentile(sorted(ms for ms, _ in p.samples), 50),
                percentile(sorted(ms for ms, _ in p.samples), 99),
                len(p.samples)) for p in probes},
            sizes=case.get("sizes"))
        misses = []
        if row["ratio"] >= 2:
            misses.append("RSS %.2fx" % row["ratio"])
        if not row["p99"] < 50:
            misses.append("p99 %.1f ms" % row["p99"])
        if fails:
            misses.append("%d /healthz failures" % fails)
        if not alive:
            misses.append("server died (exit %s)" % server.proc.returncode)
        unexpected = {k: v for k, v in total["answers"].items() if k not in case["expect"]}
        if unexpected:
            misses.append("unexpected answers " + ", ".join("%s: %d" % kv for kv in sorted(unexpected.items())))
        big = {k: v for k, v in total["max_answer"].items() if v >= case.get("max_answer", 1 << 62)}
        if big:
            misses.append("answers of 2 KiB or more: " + ", ".join("%s %d B" % kv for kv in big.items()))
        if len(results) < len(procs) or any(n.startswith("attacker ") for n in total["notes"]):
            misses.append("attackers failed or lost")
        if procs and not total["sent"]:
            misses.append("nothing sent")
        row["misses"] = misses
        if not alive:
            row["notes"].append("server log: " + server.log_tail())
        warns = [l for l in server.log_tail(200).splitlines() if l.strip()]
        if warns:
            row["notes"].append("server log (%d lines), last: %s" % (len(warns), warns[-1][:300]))
    finally:
        server.stop()
    return row


def fmt_answers(answers):
    return ", ".join("%s: %s" % (k, f"{v:,}") for k, v in sorted(answers.items(), key=lambda kv: -kv[1]))


def main():
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    if hard < 4096:
        sys.exit("RLIMIT_NOFILE hard limit %d: cases c and d need more than 3,000 sockets" % hard)
    mp.set_start_method("fork")
    faces = real_faces(100)
    wanted = os.environ.get("ABUSE_CASES", "").split()
    cases = [c for c in case_list(faces) if not wanted or c["name"] in wanted]
    rows = []
    for case in cases:
        print("== case %s: %s (%.0f s)" % (case["name"], case["what"], case.get("seconds", SECONDS)),
              flush=True)
        row = run_case(case, faces)
        rows.append(row)
        print("   sent %s; %s; RSS %.1f -> %.1f MiB (%.2fx); /healthz p50 %.2f p99 %.2f max %.1f ms, %d/%d failed%s"
              % (f"{row['sent']:,}", fmt_answers(row["answers"]), row["idle_kb"] / 1024,
                 row["peak_kb"] / 1024, row["ratio"], row["p50"], row["p99"], row["max"],
                 row["fails"], row["probes"],
                 "" if not row["misses"] else "; MISSED: " + "; ".join(row["misses"])), flush=True)
    print()
    print("## Abuse cases (`scripts/abuse.sh`, %s, %d cores, load average %s)"
          % (time.strftime("%Y-%m-%d"), os.cpu_count(), " ".join(open("/proc/loadavg").read().split()[:3])))
    print()
    print("| case | load | requests sent | answers | idle RSS before | peak RSS | ratio | /healthz p50 / p99 / max | /healthz failures | targets |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print("| %s | %s | %s | %s | %.1f MiB | %.1f MiB | %.2fx | %.2f / %.2f / %.1f ms | %d of %s | %s |" % (
            r["case"], r["what"], f"{r['sent']:,}", fmt_answers(r["answers"]) or "-",
            r["idle_kb"] / 1024, r["peak_kb"] / 1024, r["ratio"], r["p50"], r["p99"], r["max"],
            r["fails"], f"{r['probes']:,}", "met" if not r["misses"] else "**missed**: " + "; ".join(r["misses"])))
    print()
    print("Targets: peak RSS < 2x the idle RSS before the case, /healthz p99 < 50 ms, no /healthz failure,")
    print("the server alive at the end, only the expected answers (case e: every answer < 2 KiB).")
    print()
    for r in rows:
        extra = []
        if r.get("sizes"):
            extra.append(r["sizes"])
        if r["max_answer"]:
            extra.append("largest answer (bytes, headers included): " + ", ".join(
                "%s %d" % kv for kv in sorted(r["max_answer"].items())))
        extra.append("/healthz by probe: " + ", ".join(
            "%s p50 %.2f p99 %.2f ms (%d)" % (k, *v) for k, v in r["probe_detail"].items()))
        if r["errors"]:
            extra.append("/healthz errors: " + fmt_answers(r["errors"]))
        extra.extend(r["notes"])
        print("- %s: %s" % (r["case"], "; ".join(extra)))
    missed = [r["case"] for r in rows if r["misses"]]
    print()
    if missed:
        print("TARGETS MISSED in case(s): " + ", ".join(missed))
        return 1
    print("all targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
