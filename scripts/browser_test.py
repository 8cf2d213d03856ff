"""The demo page (GET /demo) and the API from a browser, in headless Chromium driven by
Playwright. Run by scripts/browser-test.sh, which makes the venv and finds the binary:

    python scripts/browser_test.py BIN [--chromium /usr/bin/chromium] [--screenshot PNG] [--only PREFIX]

Starts its own servers on free loopback ports (an empty models folder each: the embedded
default model): one that lists the cross-origin page's origin in --cors-origins and serves the
demo, one with CORS off. The checks:

  page      /demo loads with its CSP, no console error, no request to another origin
  explorer  poses projected by the page (noise-free, a profile, a noisy one with missing points,
            five points, MediaPipe when the model serves it): the angles shown equal the API's
            answer to the request the page shows (to the 0.01° shown), and are near the truth;
            the page's landmarks are the mean shape projected by this script's own Pose_Para
            rotation (an independent check of the page's projection)
  paste     a five-point face and an ibug68 face pasted as JSON (and MediaPipe's [{x, y, z}]
            with an image size when the model serves mediapipe478): shown = API, near truth;
            a bad paste shows the server's message
  cors      a page of another origin calls POST /v1/pose with fetch(): the pose when the
            server lists that origin, a TypeError when it does not
  demo stream  the demo's stream mode: a head moving, played in real time (the numbers shown
            change while it plays; the plot draws the raw and smoothed lines and the 90% bands:
            pixels of each colour counted in the canvas), leaving the tab mid-replay stops it,
            and the trajectory below from a file
  stream    scripts/browser_stream.html, served from the other origin, fetches a rendered
            trajectory (traj0: MediaPipe's 478 points per frame, the truth, the timestamps;
            written as JSON to the temp folder from tests/fixtures/rendered/) and streams it on
            two WebSockets, smoothing on and off; the page judges the figures itself (smoothed
            jitter at most 0.75 of the raw, error at most 1.05 of the raw + 0.1 degree) and the
            script prints them. Then traj1 (27 frames MediaPipe missed, sent as frames without a
            face; relative truth: the error scored with each angle's mean offset removed). The
            same page with smoothing off on both must fail; served to a
            server that does not list its origin, the socket errors and closes (1006), the
            console shows the 403, and a handshake with that Origin gets 403 forbidden

Prints one line per check and a summary line "N passed, M failed"; exits 1 on any failure.
"""

import argparse
import gzip
import http.client
import http.server
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import urllib.error
import urllib.request

from playwright.sync_api import sync_playwright

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TIMEOUT_S = 20


# ---- the conventions of ../shared/DESIGN.md, written out independently of the page --------
def rotation(yaw, pitch, roll):
    """R = Rx(pitch) Ry(yaw) Rz(roll), degrees (Pose_Para)."""
    cp, sp = math.cos(math.radians(pitch)), math.sin(math.radians(pitch))
    cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    cr, sr = math.cos(math.radians(roll)), math.sin(math.radians(roll))
    rx = [[1, 0, 0], [0, cp, sp], [0, -sp, cp]]
    ry = [[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]]
    rz = [[cr, sr, 0], [-sr, cr, 0], [0, 0, 1]]

    def mul(a, b):
        return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]

    return mul(mul(rx, ry), rz)


def project(pose, points, s=2.0, t=(300.0, -250.0)):
    """Weak perspective to image pixels: [u, -v] = s (R X)[0:2] + t."""
    r = rotation(*pose)
    out = []
    for x in points:
        rx = [sum(r[i][k] * x[k] for k in range(3)) for i in range(3)]
        out.append([s * rx[0] + t[0], -(s * rx[1] + t[1])])
    return out


def scale_shift_residual(model, observed):
    """RMS distance (px) between `observed` and the best `s * model + t` (no rotation)."""
    pairs = [(m, o) for m, o in zip(model, observed) if o is not None]
    n = len(pairs)
    mm = [sum(m[k] for m, _ in pairs) / n for k in (0, 1)]
    om = [sum(o[k] for _, o in pairs) / n for k in (0, 1)]
    num = sum((m[k] - mm[k]) * (o[k] - om[k]) for m, o in pairs for k in (0, 1))
    den = sum((m[k] - mm[k]) ** 2 for m, _ in pairs for k in (0, 1))
    s = num / den
    err = sum((s * (m[k] - mm[k]) + om[k] - o[k]) ** 2 for m, o in pairs for k in (0, 1))
    return math.sqrt(err / n)


# ---- servers -------------------------------------------------------------------------------
def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(url, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"content-type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=TIMEOUT_S) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


class Service:
    """`facepose serve` on a free loopback port with an empty models folder."""

    def __init__(self, binary, work, name, *args):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        models = os.path.join(work, name + "-models")
        os.makedirs(models)
        self.log_path = os.path.join(work, name + ".log")
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(
            [binary, "serve", "--addr", f"127.0.0.1:{self.port}", "--log", "warn",
             "--models", models, *args],
            stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.time() + 30
        while time.time() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"{name} exited: {open(self.log_path).read()}")
            try:
                if request(self.base + "/readyz")[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.05)
        raise RuntimeError(f"{name} not ready after 30 s")

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()


CROSS_ORIGIN_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><link rel="icon" href="data:,"><title>another origin</title></head>
<body data-result="">
<script>
(async function () {
  const api = new URLSearchParams(location.search).get("api");
  const body = JSON.parse(decodeURIComponent(location.hash.slice(1)));
  try {
    const res = await fetch(api + "/v1/pose", {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify(body),
    });
    const answer = await res.json();
    document.body.dataset.result = JSON.stringify({ status: res.status, answer });
  } catch (e) {
    document.body.dataset.result = JSON.stringify({ error: e.name, message: e.message });
  }
})();
</script>
</body></html>
"""


def page_server(directory):
    """A static HTTP server of `directory` on a free loopback port: another origin."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **k):
            super().__init__(*a, directory=directory, **k)

        def log_message(self, *a):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RENDERED = os.path.join(ROOT, "tests", "fixtures", "rendered")


def trajectory_json(path):
    """A rendered trajectory (tests/fixtures/rendered/README.md) as the sequence the stream
    pages replay: MediaPipe's 478 normalized points per frame (null where it found no face),
    the timestamps and the true angles."""
    records = [json.loads(line) for line in gzip.open(path, "rt")]
    records.sort(key=lambda r: r["trajectory"]["frame"])
    first = records[0]
    return {
        "name": f"{first['trajectory']['id']} ({first['identity']}, {first['geometry']}, {first['camera']['kind']})",
        "scheme": "mediapipe478",
        "image_size": first["image_size"],
        "truth_absolute": first["truth_absolute"],
        "frames": [{
            "timestamp_us": r["trajectory"]["timestamp_us"],
            "landmarks": r["mediapipe"]["landmarks"] if r["mediapipe"] else None,
            "truth": {k: r["truth"][k] for k in ("yaw", "pitch", "roll")},
        } for r in records],
    }


def ws_handshake(base, origin):
    """A WebSocket handshake to the stream route with `origin`: (status, body)."""
    host = base.split("://", 1)[1]
    conn = http.client.HTTPConnection(host, timeout=TIMEOUT_S)
    conn.request("GET", "/v1/pose:stream", headers={
        "Origin": origin, "Connection": "Upgrade", "Upgrade": "websocket",
        "Sec-WebSocket-Version": "13", "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
    })
    r = conn.getresponse()
    body = r.read() if r.status != 101 else b""
    conn.close()
    return r.status, body


# ---- driving the page ----------------------------------------------------------------------
def attr(page, name):
    return page.locator("body").get_attribute(name)


def wait_for(page, predicate, what, timeout=TIMEOUT_S):
    """Polls `predicate()` (the page's CSP forbids the string evaluation that Playwright's
    wait_for_function needs)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return
        page.wait_for_timeout(30)
    raise AssertionError(f"timed out waiting for {what}")


def run_and_wait(page, button):
    """Clicks `button` and waits until the page has shown the answer to the request it sent."""
    page.wait_for_timeout(250)  # past the explorer's debounce of the inputs just changed
    before = int(attr(page, "data-requested"))
    page.click(button)
    wait_for(page, lambda: int(attr(page, "data-requested")) > before
             and attr(page, "data-done") == attr(page, "data-requested"),
             f"the answer after {button}")


def shown(page):
    """What the page shows: the angles (as displayed), its request body, its error if any."""
    angles = {}
    for k in ("yaw", "pitch", "roll"):
        text = page.locator(f"#est-{k}").text_content()
        angles[k] = None if text == "–" else float(text)
    body = json.loads(page.locator("#request-json").text_content())
    error = page.locator("#error")
    return angles, body, (error.text_content() if error.is_visible() else None)


def set_number(page, name, value):
    page.fill(f"#{name}-num", str(value))
    page.dispatch_event(f"#{name}-num", "change")


class Checks:
    def __init__(self, only=None):
        self.results = []
        self.only = only

    def run(self, name, fn, *args):
        if self.only and not any(name.startswith(o) for o in self.only.split(",")):
            return
        t0 = time.time()
        try:
            note = fn(*args)
            self.results.append(("ok", name, note or "", time.time() - t0))
            print(f"ok    {name}{' (' + note + ')' if note else ''} [{time.time() - t0:.1f}s]", flush=True)
        except Skip as s:
            self.results.append(("skip", name, str(s), 0))
            print(f"skip  {name}: {s}", flush=True)
        except Exception as e:  # noqa: BLE001: every failure is reported, then the next check runs
            self.results.append(("FAIL", name, str(e), time.time() - t0))
            print(f"FAIL  {name}: {e}", flush=True)
            traceback.print_exc(limit=3)


class Skip(Exception):
    pass


def assert_same_as_api(base, angles, body, truth, tol):
    """The angles shown are the API's answer to the body shown (to the 0.01° shown) and are
    within `tol` degrees of the truth (when there is one)."""
    status, answer = request(base + "/v1/pose", body)
    assert status == 200, f"the API answered {status}: {answer}"
    for k in ("yaw", "pitch", "roll"):
        assert angles[k] is not None, f"no {k} shown"
        assert abs(angles[k] - answer[k]) <= 0.005 + 1e-9, \
            f"{k}: the page shows {angles[k]}, the API answers {answer[k]}"
        if truth is not None:
            want = truth[("yaw", "pitch", "roll").index(k)]
            assert abs(answer[k] - want) <= tol, f"{k}: {answer[k]:.3f} vs the truth {want} (tolerance {tol})"
    return answer


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("--chromium", default="/usr/bin/chromium")
    ap.add_argument("--screenshot", help="save a screenshot of the explorer here (PNG)")
    ap.add_argument("--only", help="run only the checks whose name starts with one of these "
                    "(comma-separated; the demo's checks need \"page: /demo\" first)")
    args = ap.parse_args()

    work = tempfile.mkdtemp(prefix="facepose-browser-")
    site = os.path.join(work, "site")
    os.makedirs(site)
    with open(os.path.join(site, "call.html"), "w") as f:
        f.write(CROSS_ORIGIN_PAGE)
    with open(os.path.join(ROOT, "scripts", "browser_stream.html")) as f, \
            open(os.path.join(site, "stream.html"), "w") as g:
        g.write(f.read())
    for name in ("traj0", "traj1"):
        with open(os.path.join(site, name + ".json"), "w") as f:
            json.dump(trajectory_json(os.path.join(RENDERED, name + ".jsonl.gz")), f, separators=(",", ":"))
    with open(os.path.join(site, "traj0.json")) as f:
        sequence = json.load(f)
    other = page_server(site)
    other_origin = f"http://127.0.0.1:{other.server_address[1]}"

    services = []
    checks = Checks(args.only)
    started = time.time()
    try:
        open_to_page = Service(args.binary, work, "cors-on", "--cors-origins", other_origin)
        services.append(open_to_page)
        closed = Service(args.binary, work, "cors-off")
        services.append(closed)
        base = open_to_page.base
        _, models = request(base + "/v1/models")
        model = models["models"][0]
        schemes = {s["name"] for s in model["schemes"]}
        means = {name: request(f"{base}/v1/models/default/schemes/{name}")[1]["mean"] for name in schemes}

        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, args=CHROMIUM_ARGS)
            context = browser.new_context(viewport={"width": 1440, "height": 900})
            context.set_default_timeout(TIMEOUT_S * 1000)
            page = context.new_page()
            console, requests, page_errors, expected_console = [], [], [], []
            page.on("console", lambda m: console.append((m.type, m.text)))
            page.on("pageerror", lambda e: page_errors.append(str(e)))
            page.on("request", lambda r: requests.append(r.url))

            def page_loads():
                resp = page.goto(base + "/demo")
                assert resp.status == 200, resp.status
                csp = resp.headers.get("content-security-policy", "")
                assert "script-src 'sha256-" in csp and "unsafe" not in csp, csp
                wait_for(page, lambda: attr(page, "data-ready") == "1" and attr(page, "data-done") != "0",
                         "the first estimate")
                angles, body, error = shown(page)
                assert error is None, error
                assert_same_as_api(base, angles, body, (30, -10, 5), 1.0)
                return f"{len(requests)} requests"

            checks.run("page: /demo loads under its CSP and shows the first estimate", page_loads)

            def explorer(pose, scheme, noise, missing, tol):
                def check():
                    if scheme not in schemes:
                        raise Skip(f"the model serves no {scheme} (it serves {', '.join(sorted(schemes))})")
                    page.click("#tab-explore")
                    page.select_option("#scheme", scheme)
                    page.select_option("#method", "auto")
                    for name, v in zip(("yaw", "pitch", "roll"), pose):
                        set_number(page, name, v)
                    set_number(page, "noise", noise)
                    set_number(page, "missing", missing)
                    run_and_wait(page, "#run-explore")
                    angles, body, error = shown(page)
                    assert error is None, error
                    assert body.get("scheme") == scheme, body
                    pts = body["landmarks"]
                    nulls = sum(q is None for q in pts)
                    assert nulls == round(len(pts) * missing / 100), f"{nulls} missing of {len(pts)}"
                    # The page's projection against this script's own (up to scale and shift).
                    rms = scale_shift_residual(project(pose, means[scheme], s=1.0, t=(0, 0)), pts)
                    limit = 0.01 if noise == 0 else 3 * noise
                    assert rms <= limit, f"the page's landmarks are {rms:.3f} px RMS from the projection"
                    for k, v in zip(("yaw", "pitch", "roll"), pose):
                        assert float(page.locator(f"#truth-{k}").text_content()) == v
                    answer = assert_same_as_api(base, angles, body, pose, tol)
                    return (f"shown {angles['yaw']:.2f} {angles['pitch']:.2f} {angles['roll']:.2f}, "
                            f"method {answer['method']}, landmarks {rms:.3f} px RMS from ours")
                return check

            for pose, scheme, noise, missing, tol in [
                ((30, -10, 5), "ibug68", 0, 0, 1.0),
                ((70, -5, 3), "ibug68", 0, 0, 1.0),
                ((-20, 15, -10), "ibug68", 1.5, 20, 4.0),
                ((15, 5, -6), "five", 0, 0, 1.0),
                ((-25, 10, 8), "mediapipe478", 0, 0, 1.0),
            ]:
                name = (f"explorer: {scheme} at yaw {pose[0]} pitch {pose[1]} roll {pose[2]}"
                        + (f", noise {noise} px, {missing}% missing" if noise or missing else ""))
                checks.run(name, explorer(pose, scheme, noise, missing, tol))

            def convention(choice, expect_name):
                """The selector's choice goes into the request shown, and the numbers shown are
                the API's answer to that request in that convention."""
                def check():
                    page.click("#tab-explore")
                    page.select_option("#scheme", "ibug68")
                    page.select_option("#method", "auto")
                    for name, v in (("yaw", 25), ("pitch", -8), ("roll", 6), ("noise", 0), ("missing", 0)):
                        set_number(page, name, v)
                    page.select_option("#convention", choice)
                    run_and_wait(page, "#run-explore")
                    angles, body, error = shown(page)
                    assert error is None, error
                    name, _, preset = choice.partition(":")
                    want = {"name": name, "preset": preset} if preset else name
                    assert body.get("conventions") == [want], body
                    values = page.locator("#conv-values")
                    assert page.locator("#conv-answer").is_visible(), "no answer in the convention shown"
                    assert values.get_attribute("data-convention") == expect_name
                    shown_values = json.loads(values.get_attribute("data-values"))
                    answer = assert_same_as_api(base, angles, body, (25, -8, 6), 1.0)
                    a = answer["conventions"][expect_name]
                    api = {
                        "quaternion": lambda: [a["w"], a["x"], a["y"], a["z"]],
                        "euler": lambda: a["angles"],
                        "opencv": lambda: a["rvec"] + a["tvec"],
                        "mediapipe": lambda: [v for row in a["matrix"] for v in row],
                    }[expect_name]()
                    assert len(shown_values) == len(api), (shown_values, api)
                    for x, y in zip(shown_values, api):
                        assert abs(x - y) <= 1e-9 * (1 + abs(y)), f"the page shows {shown_values}, the API answers {api}"
                    cells = [c.text_content() for c in values.locator("span").all()]
                    assert cells == [f"{v:.4f}" for v in api] or len(cells) == len(api), cells
                    code = page.locator("#conv-code").text_content()
                    assert "answer.conventions." + expect_name in code and "Python" in code, code
                    return f"{expect_name}: {', '.join(cells[:4])}{' …' if len(cells) > 4 else ''}"
                return check

            for choice, expect_name in [
                ("quaternion", "quaternion"),
                ("euler:openface", "euler"),
                ("euler:three", "euler"),
                ("euler:unity", "euler"),
                ("euler:pose-para", "euler"),
                ("opencv", "opencv"),
                ("mediapipe", "mediapipe"),
            ]:
                checks.run(f"convention selector: {choice} shows the API's numbers", convention(choice, expect_name))
            if page.url.endswith("/demo"):
                page.select_option("#convention", "")

            def paste(text, scheme, truth, tol, normalized=None, size=None):
                page.click("#tab-paste")
                page.fill("#paste", text)
                page.select_option("#paste-scheme", scheme)
                page.select_option("#paste-method", "auto")
                if normalized is not None:
                    assert page.is_checked("#normalized") == normalized, "normalized not detected"
                if size:
                    page.fill("#img-w", str(size[0]))
                    page.fill("#img-h", str(size[1]))
                run_and_wait(page, "#run-paste")
                angles, body, error = shown(page)
                assert error is None, error
                if scheme == "auto":
                    assert "scheme" not in body, body
                else:
                    assert body["scheme"] == scheme, body
                answer = assert_same_as_api(base, angles, body, truth, tol)
                return body, answer

            def paste_five():
                # The docs' example, then a five-point face at a known pose.
                docs = [[301, 240], [341, 240], [321, 265], [305, 290], [337, 290]]
                _, a = paste(json.dumps(docs), "five", None, None)
                truth = (-20, 10, -4)
                pts = project(truth, means["five"])
                paste(json.dumps(pts), "five", truth, 1.0)
                return f"docs example: yaw {a['yaw']:.2f}, pitch {a['pitch']:.2f}, roll {a['roll']:.2f}"

            checks.run("paste: five points", paste_five)

            def paste_ibug68():
                truth = (25, -8, 6)
                pts = [[round(c, 2) for c in q] for q in project(truth, means["ibug68"])]
                body, _ = paste(json.dumps(pts), "auto", truth, 1.0, normalized=False)
                assert body["landmarks"] == pts, "the page sent other landmarks than pasted"
                assert "image_size" not in body, body

            checks.run("paste: an ibug68 face, scheme by count", paste_ibug68)

            def paste_mediapipe():
                if "mediapipe478" not in schemes:
                    raise Skip("the model serves no mediapipe478 yet")
                truth, (w, h) = (-15, 8, 4), (1280, 720)
                px = project(truth, means["mediapipe478"], s=3.0, t=(w / 2, -h / 2))
                lm = [{"x": u / w, "y": v / h, "z": 0.01} for u, v in px]
                body, _ = paste(json.dumps(lm), "auto", truth, 1.0, normalized=True, size=(w, h))
                assert body["image_size"] == [w, h], body
                assert len(body["landmarks"]) == 478 and len(body["landmarks"][0]) == 2, body

            checks.run("paste: MediaPipe's 478 normalized points with the image size", paste_mediapipe)

            def paste_error():
                first = len(console)
                page.click("#tab-paste")
                page.fill("#paste", "[[1, 2], [3, 4], [5, 7]]")
                page.select_option("#paste-scheme", "ibug68")
                run_and_wait(page, "#run-paste")
                error = page.locator("#error")
                assert error.is_visible(), "no error shown"
                text = error.text_content()
                assert "invalid_argument" in text and "expected 68 points, got 3" in text, text
                assert page.locator("#response-status").text_content().strip() == "422"
                # Chromium logs every 4xx fetch as a console error: this one was asked for.
                expected_console.extend(
                    m for m in console[first:] if "status of 422" in m[1])

            checks.run("paste: a wrong point count shows the server's message", paste_error)

            def plot_pixels():
                """Pixels of the stream plot by colour: the smoothed line, the raw line, and
                the smoothed band (read in the page's canvas)."""
                return page.evaluate("""() => {
                    const c = document.getElementById("stream-plot");
                    // A copy read once (reading the page's canvas again and again makes
                    // Chromium warn in the console).
                    const copy = document.createElement("canvas");
                    copy.width = c.width;
                    copy.height = c.height;
                    const ctx = copy.getContext("2d", { willReadFrequently: true });
                    ctx.drawImage(c, 0, 0);
                    const d = ctx.getImageData(0, 0, c.width, c.height).data;
                    const n = { smooth: 0, raw: 0, band: 0 };
                    for (let i = 0; i < d.length; i += 4) {
                        const [r, g, b] = [d[i], d[i + 1], d[i + 2]];
                        if (b > 200 && r < 90 && g < 140) n.smooth += 1;
                        else if (r > 200 && g > 80 && g < 150 && b < 70) n.raw += 1;
                        else if (b > 200 && b > r + 12 && r > 150) n.band += 1;
                    }
                    return n;
                }""")

            def demo_stream(source, pace):
                page.click("#tab-stream")
                page.select_option("#stream-source", source)
                page.select_option("#stream-pace", pace)
                page.click("#run-stream")
                samples = []
                deadline = time.time() + 60
                while True:
                    state = attr(page, "data-stream-state")
                    if state == "done":
                        break
                    assert state in ("loading", "running"), \
                        f"the stream {state}: {page.locator('#error').text_content()}"
                    assert time.time() < deadline, "the replay did not end in 60 s"
                    if pace == "realtime":
                        samples.append((int(attr(page, "data-stream-answered") or 0),
                                        page.locator("#est-yaw").text_content()))
                        page.wait_for_timeout(400)
                    else:
                        page.wait_for_timeout(50)
                page.wait_for_timeout(100)  # the last frame drawn
                stats = page.locator("#stream-stats")
                figures = json.loads(stats.get_attribute("data-figures"))
                plot = page.locator("#stream-plot")
                pixels = plot_pixels()
                n = int(attr(page, "data-stream-answered"))
                assert figures["answered"] == n == int(attr(page, "data-stream-sent")), figures
                assert int(plot.get_attribute("data-drawn")) >= 2 * 3 * n, plot.get_attribute("data-drawn")
                assert int(plot.get_attribute("data-bands")) >= 6, plot.get_attribute("data-bands")
                assert pixels["smooth"] > 500 and pixels["raw"] > 200 and pixels["band"] > 2000, pixels
                assert page.locator("#est-yaw").text_content() != "–", "no pose shown"
                raw, smooth = figures["raw"]["mean"], figures["smooth"]["mean"]
                assert smooth["step"] < raw["step"], f"the smoothed angles move more than the raw: {figures}"
                return n, samples, figures, pixels, stats.text_content()

            def demo_synthetic():
                n, samples, figures, pixels, text = demo_stream("synthetic", "realtime")
                assert n == 150, n
                # Numbers flow: the count answered and the yaw shown change while it plays.
                counts = [c for c, _ in samples]
                yaws = {y for _, y in samples if y != "–"}
                assert len(samples) >= 4 and len(set(counts)) >= 3 and counts == sorted(counts), samples
                assert len(yaws) >= 3, samples
                raw, smooth = figures["raw"]["mean"], figures["smooth"]["mean"]
                assert smooth["jitter"] < 0.75 * raw["jitter"], figures
                return (f"{len(samples)} samples while playing, answered {counts}; jitter vs truth raw "
                        f"{raw['jitter']:.2f} smoothed {smooth['jitter']:.2f} deg/frame; pixels {pixels}")

            checks.run("demo stream: a head moving, in real time: the numbers flow, the plot draws "
                       "raw, smoothed and the 90% bands", demo_synthetic)

            def demo_leave():
                page.click("#tab-stream")
                page.select_option("#stream-source", "synthetic")
                page.select_option("#stream-pace", "realtime")
                page.click("#run-stream")
                wait_for(page, lambda: int(attr(page, "data-stream-answered") or 0) > 5, "answers")
                page.click("#tab-explore")
                wait_for(page, lambda: attr(page, "data-stream-state") == "stopped", "the replay stopped")
                stopped_at = int(attr(page, "data-stream-answered"))
                page.wait_for_timeout(300)
                assert int(attr(page, "data-stream-answered")) == stopped_at, "answers after leaving the tab"
                page.click("#tab-stream")
                first = json.loads(page.locator("#request-json").text_content())
                assert first["frame_id"] == 0 and first["smoothing"]["enabled"] is True, first
                assert "new WebSocket(" in page.locator("#fetch-code").text_content()
                return f"stopped after {stopped_at} of 150 frames"

            checks.run("demo stream: leaving the tab stops the replay", demo_leave)

            def demo_file():
                page.click("#tab-stream")
                page.select_option("#stream-source", "file")
                page.set_input_files("#stream-file", os.path.join(site, "traj0.json"))
                wait_for(page, lambda: "150 frames" in page.locator("#stream-file-info").text_content(),
                         "the file read")
                n, _, figures, pixels, text = demo_stream("file", "fast")
                assert n == len(sequence["frames"]), n
                raw, smooth = figures["raw"]["mean"], figures["smooth"]["mean"]
                assert smooth["jitter"] < 0.75 * raw["jitter"], figures
                assert smooth["error"] <= 1.05 * raw["error"] + 0.1, figures
                return text

            checks.run("demo stream: the trajectory's MediaPipe points from a file, as fast as answered",
                       demo_file)

            def clean():
                errors = [f"{t}: {m}" for t, m in console
                          if t in ("error", "warning") and (t, m) not in expected_console]
                assert not errors and not page_errors, f"console: {errors} page errors: {page_errors}"
                foreign = [u for u in requests if not (u.startswith(base + "/") or u.startswith("data:"))]
                assert not foreign, f"requests to elsewhere: {foreign}"
                return f"{len(requests)} requests, all to {base}"

            checks.run("page: no console error, no request to another origin", clean)

            if args.screenshot:
                page.click("#tab-explore")
                page.select_option("#scheme", "ibug68")
                for name, v in (("yaw", 30), ("pitch", -10), ("roll", 5), ("noise", 1.5), ("missing", 10)):
                    set_number(page, name, v)
                run_and_wait(page, "#run-explore")
                page.wait_for_timeout(300)
                page.screenshot(path=args.screenshot, full_page=True)
                print(f"screenshot: {args.screenshot}")

            def cross_origin(service, allowed):
                def check():
                    truth = (20, -5, 3)
                    body = {"landmarks": project(truth, means["ibug68"])}
                    other_page = context.new_page()
                    url = (f"{other_origin}/call.html?api={service.base}#"
                           + urllib.request.quote(json.dumps(body)))
                    other_page.goto(url)
                    wait_for(other_page, lambda: other_page.locator("body").get_attribute("data-result"),
                             "the page's fetch()")
                    result = json.loads(other_page.locator("body").get_attribute("data-result"))
                    other_page.close()
                    if allowed:
                        assert result.get("status") == 200, result
                        got = [result["answer"][k] for k in ("yaw", "pitch", "roll")]
                        assert all(abs(g - t) < 1.0 for g, t in zip(got, truth)), got
                        return f"{other_origin} -> {service.base}: yaw {got[0]:.2f}"
                    assert result.get("error") == "TypeError", result
                    return f"{result['error']}: {result['message']}"
                return check

            def stream_page(service, smooth=True, data="traj0"):
                """stream.html of the other origin, streaming the trajectory to `service`:
                its verdict (data-result) and the console messages."""
                other_page = context.new_page()
                messages = []
                other_page.on("console", lambda m: messages.append(m.text))
                ws = service.base.replace("http://", "ws://")
                other_page.goto(f"{other_origin}/stream.html?ws={ws}&data={data}.json"
                                + ("" if smooth else "&smooth=0"))
                wait_for(other_page, lambda: other_page.locator("body").get_attribute("data-result"),
                         "the stream page's verdict", timeout=90)
                result = json.loads(other_page.locator("body").get_attribute("data-result"))
                other_page.close()
                return result, messages

            def figures_note(r):
                raw, sm = r["raw"]["mean"], r["smoothed"]["mean"]
                per = ", ".join(f"{k} {r['raw'][k]['jitter']:.2f}->{r['smoothed'][k]['jitter']:.2f}"
                                for k in ("yaw", "pitch", "roll"))
                return (f"{r['name']}, {r['detected']}/{r['frames']} frames, {r['ms']} ms: "
                        f"jitter |d(angle)-d(truth)| raw {raw['jitter']:.3f} smoothed {sm['jitter']:.3f} "
                        f"deg/frame (x{r['jitter_ratio']:.2f}; {per}); mean |d(angle)| raw {raw['step']:.3f} "
                        f"smoothed {sm['step']:.3f}; error raw {raw['error']:.2f} smoothed {sm['error']:.2f} deg "
                        f"(offset removed {raw['error_offset_removed']:.2f} / {sm['error_offset_removed']:.2f}); "
                        f"90% coverage raw {100 * raw['coverage90']:.0f}% smoothed {100 * sm['coverage90']:.0f}%, "
                        f"width {raw['width90']:.1f} / {sm['width90']:.1f} deg, centre off the angle "
                        f"{raw['centre90']:.2f} / {sm['centre90']:.2f} deg")

            def stream_smooths():
                result, _ = stream_page(open_to_page)
                assert result.get("pass") is True, f"the page's verdict: {result.get('failures')} {result}"
                return figures_note(result)

            checks.run("stream: a page of a listed origin streams MediaPipe's points over the WebSocket; "
                       "in the page, smoothing cuts the jitter and adds no error", stream_smooths)

            def stream_relative():
                result, _ = stream_page(open_to_page, data="traj1")
                assert result.get("pass") is True, f"the page's verdict: {result.get('failures')} {result}"
                assert result["error_scored"] == "error_offset_removed" and result["detected"] < result["frames"], result
                return figures_note(result)

            checks.run("stream: the same with frames MediaPipe missed and a relative truth (traj1)",
                       stream_relative)

            def stream_control():
                result, _ = stream_page(open_to_page, smooth=False)
                assert result.get("pass") is False, f"the page passed with smoothing off: {result}"
                assert any("jitter" in f for f in result["failures"]), result["failures"]
                return f"the page fails it: {result['failures'][0]}"

            checks.run("stream: the same page with smoothing off on both sockets fails (negative control)",
                       stream_control)

            def stream_refused():
                result, messages = stream_page(closed)
                assert result.get("socket_failed") is True, result
                failure = result["failure"]
                assert failure.get("errored") is True and failure.get("code") == 1006 \
                    and failure.get("received") == 0, failure
                said = [m for m in messages if "pose:stream" in m and "403" in m]
                assert said, f"no 403 in the console: {messages}"
                status, body = ws_handshake(closed.base, other_origin)
                assert status == 403 and json.loads(body)["error"]["code"] == "forbidden", (status, body)
                status_ok, _ = ws_handshake(open_to_page.base, other_origin)
                assert status_ok == 101, f"the listed origin's handshake got {status_ok}"
                return f"error then close {failure['code']}; console: {said[0]}; server: 403 (101 when listed)"

            checks.run("stream: a page of an origin not listed cannot open the socket (403)", stream_refused)

            checks.run("cors: fetch() from a listed origin gets the pose", cross_origin(open_to_page, True))
            checks.run("cors: fetch() from an origin not listed fails with a TypeError",
                       cross_origin(closed, False))
            browser.close()
    finally:
        for s in services:
            s.stop()
        other.shutdown()

    for s in services:
        log = open(s.log_path).read()
        if "panicked" in log or " ERROR " in log:
            print(f"server log {s.log_path}:\n{log}")
            checks.results.append(("FAIL", "server log", "errors in the log", 0))
    passed = sum(r[0] == "ok" for r in checks.results)
    failed = sum(r[0] == "FAIL" for r in checks.results)
    skipped = sum(r[0] == "skip" for r in checks.results)
    print(f"browser tests: {time.time() - started:.1f}s")
    print(f"{passed} passed, {failed} failed, {skipped} skipped")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
