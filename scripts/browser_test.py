"""The demo page (GET /demo) and the API from a browser, in headless Chromium driven by
Playwright. Run by scripts/browser-test.sh, which makes the venv and finds the binary:

    python scripts/browser_test.py BIN [--chromium /usr/bin/chromium] [--screenshot PNG]

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

Prints one line per check and a summary line "N passed, M failed"; exits 1 on any failure.
"""

import argparse
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


# ---- driving the page ----------------------------------------------------------------------
def attr(page, name):
    return page.locator("body").get_attribute(name)


def wait_for(page, predicate, what):
    """Polls `predicate()` (the page's CSP forbids the string evaluation that Playwright's
    wait_for_function needs)."""
    deadline = time.time() + TIMEOUT_S
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
    def __init__(self):
        self.results = []

    def run(self, name, fn, *args):
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
    args = ap.parse_args()

    work = tempfile.mkdtemp(prefix="facepose-browser-")
    site = os.path.join(work, "site")
    os.makedirs(site)
    with open(os.path.join(site, "call.html"), "w") as f:
        f.write(CROSS_ORIGIN_PAGE)
    other = page_server(site)
    other_origin = f"http://127.0.0.1:{other.server_address[1]}"

    services = []
    checks = Checks()
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
