"""A real headless browser for the tests of report.html and the live view: Debian's chromium, driven by Playwright.

Never `playwright install` (it downloads a browser build): Playwright's client drives the system's
chromium (`executable_path`). Chromium is kept off the network by its flags (no background
networking, component updates, sync, QUIC or first-run fetches; a fresh profile), and every page is
watched: a request to anything but file:// or 127.0.0.1 fails the test. WebGL runs on SwiftShader
(no GPU). Tests skip, saying why, only where no browser can be had.

Checked with strace over the whole chromium process tree while a report loads: no sendto/sendmsg
and no TCP connect to any address but loopback. Chromium still connect()s a UDP socket to a public
IPv6 address (its IPv6-reachability probe: a UDP connect sends no packet, it only picks a route).
"""

from __future__ import annotations

import io
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--disable-extensions",
    "--metrics-recording-only",
    "--no-pings",
    "--disable-domain-reliability",
    "--disable-client-side-phishing-detection",
    "--disable-breakpad",
    "--no-default-browser-check",
    "--disable-features=Translate,OptimizationHints,MediaRouter,DialMediaRouteProvider,AutofillServerCommunication,"
    "CertificateTransparencyComponentUpdater",
    # no host resolves but 127.0.0.1: nothing can be reached by name (pages use file:// and 127.0.0.1 only)
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
#: the chromium driver's own messages about SwiftShader are warnings, never errors
VIEWPORT = {"width": 1400, "height": 850}


def chromium_path() -> str:
    path = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
    if path is None:
        pytest.skip("no chromium on this machine (apt-get install chromium; `make test` installs it)")
    return path


class Browser:
    """One chromium for a test module; pages record their console errors and every request."""

    def __init__(self) -> None:
        try:
            from playwright.sync_api import sync_playwright
        except ImportError:
            pytest.skip("Playwright's client is not installed (pip install -e '.[browser]'; `make test` does)")
        executable = chromium_path()
        self._profile = tempfile.mkdtemp(prefix="surgiplan-chromium-")
        self._playwright = sync_playwright().start()
        try:
            self.context = self._playwright.chromium.launch_persistent_context(
                self._profile, executable_path=executable, args=CHROMIUM_FLAGS, headless=True, viewport=VIEWPORT
            )
        except Exception as exc:
            self._playwright.stop()
            pytest.skip(f"chromium does not start here: {exc}")

    def page(self, url: str, *, ready: str = "window.surgiplan && window.surgiplan.ready", timeout: float = 60_000):
        page = self.context.new_page()
        page.requests = []
        page.problems = []
        page.on("request", lambda r: page.requests.append(r.url))
        page.on("console", lambda m: page.problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
        page.on("pageerror", lambda e: page.problems.append(f"page error: {e}"))
        page.goto(url)
        wait_for(page, ready, timeout)
        return page

    def close(self) -> None:
        try:
            self.context.close()
        finally:
            self._playwright.stop()
            shutil.rmtree(self._profile, ignore_errors=True)


def wait_for(page, expression: str, timeout: float = 30_000) -> None:
    """Poll ``expression`` in the page until it is true (the page's CSP forbids Playwright's eval-based wait)."""
    import time

    deadline = time.monotonic() + timeout / 1000
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise TimeoutError(f"{expression!r} still false after {timeout / 1000:.0f} s")
        page.wait_for_timeout(25)


def offsite(requests: list[str], allowed=("file://", "data:", "http://127.0.0.1:", "ws://127.0.0.1:")) -> list[str]:
    """The requests that left this machine's files and loopback."""
    return [u for u in requests if not u.startswith(allowed)]


def canvas_pixels(page) -> np.ndarray:
    """The 3D canvas as an (h, w, 3) uint8 array, from a screenshot of it."""
    from PIL import Image

    png = page.locator("#view > canvas").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def drawn_fraction(pixels: np.ndarray, background=(0xF7, 0xF7, 0xF4), tolerance: int = 6) -> float:
    """The fraction of pixels that are not the scene's background colour."""
    return float(np.mean(np.any(np.abs(pixels.astype(int) - np.array(background)) > tolerance, axis=2)))


def red_pixels(pixels: np.ndarray) -> int:
    """Pixels of the below-threshold red (#d62728, shaded)."""
    p = pixels.astype(int)
    return int(np.count_nonzero((p[..., 0] > 150) & (p[..., 1] < 90) & (p[..., 2] < 90)))


def start_view(args: list[str], exit_after: float = 120.0, env=None):
    """``surgiplan view ARGS --no-browser`` (it exits after ``exit_after`` s): (the process, the URL it prints,
    with its token)."""
    import re
    import subprocess
    import sys
    import time

    command = [sys.executable, "-m", "surgiplan.cli", "view", *args, "--no-browser", "--exit-after", str(exit_after)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        match = re.search(r"(http://127\.0\.0\.1:\d+/\S*)", line)
        if match:
            return process, match.group(1)
        if not line and process.poll() is not None:
            break
    process.kill()
    raise AssertionError(f"surgiplan view {' '.join(args)} did not start: {process.stderr.read()}")


def feed_url(page_url: str, path: str = "/feed") -> str:
    """The websocket address of the live viewer whose page is ``page_url``, with the page's token."""
    from urllib.parse import parse_qs, urlsplit

    parts = urlsplit(page_url)
    return f"ws://{parts.netloc}{path}?token={parse_qs(parts.query)['token'][0]}"


def start_live_view(exit_after: float = 120.0):
    """``surgiplan view --live`` on a free port of 127.0.0.1: (the process, the page's URL, with its token;
    :func:`feed_url` gives the feed's)."""
    return start_view(["--live", "--port", "0"], exit_after)


def stalled_client(page_url: str, receive_buffer: int = 4096):
    """A websocket client of the live viewer whose page is ``page_url`` that upgrades to ``/watch`` (with the
    page's token and origin) and then never reads: a socket whose receive buffer is ``receive_buffer`` bytes."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(page_url)
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    s.settimeout(10)
    s.connect((parts.hostname, parts.port))
    s.sendall(
        (
            f"GET /watch?{parts.query} HTTP/1.1\r\n"
            f"Host: {parts.netloc}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            f"Origin: http://{parts.netloc}\r\n\r\n"
        ).encode()
    )
    head = b""
    for _ in range(1000):  # the 101 answer, and not a byte more
        head += s.recv(1)
        if head.endswith(b"\r\n\r\n"):
            break
    if not head.startswith(b"HTTP/1.1 101"):
        s.close()
        raise AssertionError(f"the viewer did not upgrade the stalled client: {head!r}")
    return s


@contextmanager
def live_view(exit_after: float = 120.0, env=None):
    """``surgiplan view --live`` (:func:`start_view`) for the ``with`` block: yields the page's URL, with its
    token; the viewer is terminated at the end."""
    process, url = start_view(["--live", "--port", "0"], exit_after, env)
    try:
        yield url
    finally:
        process.terminate()
        process.wait(10)


def watch_live(page_url: str, on_item, timeout: float = 60.0, most: int = 1_000_000) -> None:
    """Watch the live viewer whose page is ``page_url`` as a page does (``/watch`` with the page's token and
    origin) until the stage's ``status``: ``on_item(item, now)`` for every item it relays (``now``: time.time()
    at the message's arrival). Bounded: ``most`` messages, ``timeout`` s each."""
    import json
    import time
    from urllib.parse import urlsplit

    from websockets.sync.client import connect

    with connect(feed_url(page_url, "/watch"), origin=f"http://{urlsplit(page_url).netloc}") as socket:
        for _ in range(most):
            message = json.loads(socket.recv(timeout=timeout))
            now = time.time()
            for item in message if isinstance(message, list) else [message]:
                on_item(item, now)
                if item["channel"] == "status":
                    return


@contextmanager
def serving(viewer, exit_after: float = 120.0):
    """A :class:`~surgiplan.outputs.report.server.LiveViewer` serving in a thread of this process for the
    ``with`` block (its queues and memory can be read); stopped at the end."""
    import asyncio
    import threading

    ready = threading.Event()
    loop = asyncio.new_event_loop()
    serve = viewer.serve(open_browser=False, exit_after=exit_after, announce=lambda _: ready.set())
    thread = threading.Thread(target=loop.run_until_complete, args=(serve,), daemon=True)
    thread.start()
    try:
        assert ready.wait(20), "the live viewer did not start"
        yield viewer
    finally:
        viewer.stop()
        thread.join(10)
