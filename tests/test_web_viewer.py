"""The serve sink watched from a browser: a simulated run (`camnet up` on a small rig, the calibrator
serving Rerun's web viewer) opened in headless Chromium, driven over the DevTools protocol
(websocket-client), shows the live calibration without errors."""

from __future__ import annotations

import base64
import json
import select
import shutil
import subprocess
import sys
import time
import urllib.request
from urllib.parse import urlparse

import numpy as np
import pytest

from camnet.viz_sinks import web_viewer_url
from tests.conftest import free_port
from tests.test_network import rig_file

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (Debian package chromium)")
LOCAL_HOSTS = ("127.0.0.1", "localhost")

def stop(process: subprocess.Popen | None, *, grace_s: float = 10.0) -> None:
    if process is None or process.poll() is not None:
        return
    process.terminate()
    try:
        process.wait(grace_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(10)


def wait_for_line(process: subprocess.Popen, expected: str, timeout_s: float) -> str:
    """The first line of the process's output that contains `expected`."""
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        ready, _, _ = select.select([process.stdout], [], [], 0.5)
        if ready:
            line = process.stdout.readline()
            if expected in line:
                return line
            if not line:
                break
            seen.append(line)
    raise AssertionError(f"the run did not print {expected!r} (exit status {process.poll()}):\n{''.join(seen)}")


class DevTools:
    """A minimal Chrome DevTools protocol client for one page; events are kept in `events`."""

    def __init__(self, port: int, timeout_s: float = 30.0) -> None:
        import websocket

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as response:
                    targets = json.load(response)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        page = next(t for t in targets if t["type"] == "page")
        # Software WebGL makes the first screenshots slow: allow a minute per call.
        self.ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=60, suppress_origin=True)
        self.events: list[dict] = []
        self.next_id = 0

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv())
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise AssertionError(f"{method}: {message['error']}")
                return message["result"]
            self.events.append(message)

    def wait_for_event(self, method: str) -> None:
        while not any(e.get("method") == method for e in self.events):
            self.events.append(json.loads(self.ws.recv()))

    def close(self) -> None:
        self.ws.close()


def screenshot(devtools: DevTools) -> np.ndarray:
    import cv2

    png = base64.b64decode(devtools.call("Page.captureScreenshot", format="png")["data"])
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def data_pixels(image: np.ndarray) -> int:
    """Saturated green-to-cyan pixels: the error colours of a good cloud (turbo at 0.3-1.3 px),
    the cameras' y axes and the series lines. The viewer's own light UI has none (its accents are
    blue and orange), so these count what the data paints."""
    import cv2

    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return int(np.sum((hsv[..., 1] > 100) & (hsv[..., 2] > 60) & (hsv[..., 0] >= 35) & (hsv[..., 0] <= 95)))


def problems(events: list[dict], page_host: str) -> list[str]:
    """Console errors, uncaught exceptions and failed requests to our own servers.

    The machine may be offline: requests the viewer makes to the internet (fonts, update check,
    usage statistics, examples) fail and are not counted, nor are the fetch rejections they cause;
    every failed request to `page_host` is.
    """
    urls = {}
    found = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Network.requestWillBeSent":
            urls[params["requestId"]] = params["request"]["url"]
        elif method == "Network.loadingFailed":
            url = urls.get(params["requestId"], "?")
            if urlparse(url).hostname == page_host:
                found.append(f"request failed: {url}: {params.get('errorText')}")
        elif method == "Runtime.exceptionThrown":
            details = params["exceptionDetails"]
            found.append(f"exception: {details.get('exception', {}).get('description', details.get('text'))}"[:300])
        elif method == "Runtime.consoleAPICalled" and params["type"] in ("error", "assert"):
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in params["args"])
            if not text.startswith("TypeError: Failed to fetch"):
                found.append(f"console.{params['type']}: {text}"[:300])
        elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
            entry = params["entry"]
            offline = entry.get("source") == "network" and urlparse(entry.get("url", "")).hostname not in LOCAL_HOSTS
            if not offline:
                found.append(f"log: {entry['text']} {entry.get('url', '')}"[:300])
    return found


def test_web_viewer_shows_a_simulated_run(tmp_path):
    import cv2

    web_port, grpc_port, debug_port = free_port(), free_port(), free_port()
    host = "127.0.0.1"
    url = web_viewer_url(host=host, web_port=web_port, grpc_port=grpc_port)
    run = browser = devtools = None
    try:
        # The whole network on its own loopback port: sim drivers, matcher, calibrator serving the viewer.
        run = subprocess.Popen(
            [sys.executable, "-m", "camnet.cli", "up", rig_file(tmp_path, 4), "--forever", "--run-dir",
             str(tmp_path / "run"), "--listen", f"tcp/127.0.0.1:{free_port()}",
             "--rerun", f"serve={web_port},{grpc_port}"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        wait_for_line(run, " solve ", timeout_s=180)  # the first calibration is out
        browser = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             # WebGL on the CPU: Chromium asks for this opt-in before it falls back to SwiftShader.
             "--enable-unsafe-swiftshader", f"--user-data-dir={tmp_path / 'profile'}",
             f"--remote-debugging-port={debug_port}", "--window-size=1280,800", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        devtools = DevTools(debug_port)
        for domain in ("Runtime", "Log", "Network", "Page"):
            devtools.call(f"{domain}.enable")
        devtools.call("Page.navigate", url=url)
        devtools.wait_for_event("Page.loadEventFired")

        deadline = time.monotonic() + 120
        image = screenshot(devtools)
        while data_pixels(image) < 500 and time.monotonic() < deadline:
            time.sleep(1.0)
            image = screenshot(devtools)
        time.sleep(2.0)  # let late console messages arrive
        image = screenshot(devtools)
        cv2.imwrite(str(tmp_path / "viewer.png"), image)

        assert image.std() > 10, f"blank screenshot (std {image.std():.1f}), see {tmp_path / 'viewer.png'}"
        assert data_pixels(image) >= 500, f"the viewer shows no data, see {tmp_path / 'viewer.png'}"
        grpc_requests = [e for e in devtools.events if e.get("method") == "Network.requestWillBeSent"
                         and urlparse(e["params"]["request"]["url"]).port == grpc_port]
        assert grpc_requests, "the viewer never contacted the gRPC server"
        assert problems(devtools.events, host) == []
    finally:
        if devtools is not None:
            devtools.close()
        stop(browser)
        stop(run, grace_s=30)  # camnet up stops its nodes first
