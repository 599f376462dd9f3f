"""A chromium page as a trainer's browser shows the live view: nothing automates it while the attempt runs.

Playwright (``tests/browser_support.py``) keeps the DevTools protocol's Network domain enabled on every page it
drives, so chromium serialises each websocket frame the page receives into an event for Playwright's driver (a
node process), which parses it: at 100 samples/s, three processes' work that no trainer's browser does. Beside
a guide attempt at ordinary priority (a probe, 20 s, 2 cores), the page driven by Playwright left 278 samples more
than 2 ms late, the node driver among the threads on the CPUs while they waited; the same page with nothing
attached, 157 and 214.

So :class:`UnattendedBrowser` starts Debian's chromium itself, with the tests' flags (loopback only, SwiftShader),
and talks to it over the DevTools protocol (a websocket on 127.0.0.1) only to load the page and wait until it is
ready, and again once the attempt is over, to read what the page counted. While the attempt runs no client is
attached: chromium drops a session's domains when its client disconnects.
"""

from __future__ import annotations

import itertools
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from urllib.request import urlopen

from browser_support import CHROMIUM_FLAGS, VIEWPORT, chromium_path, wait_for


class UnattendedPage:
    """A page's DevTools session, opened for each use and closed by :meth:`detach`; ``problems`` is empty (the
    page's own ``surgiplan.errors`` collects its errors: nothing listens to its console while detached)."""

    def __init__(self, websocket_url: str) -> None:
        self._url = websocket_url
        self._socket = None
        self._ids = itertools.count(1)
        self.problems: list[str] = []

    def _call(self, method: str, **params):
        from websockets.sync.client import connect

        if self._socket is None:
            self._socket = connect(self._url, max_size=None, open_timeout=10)
        ident = next(self._ids)
        self._socket.send(json.dumps({"id": ident, "method": method, "params": params}))
        for _ in range(100_000):  # bounded: events of the session come first, each answered within 30 s
            message = json.loads(self._socket.recv(timeout=30))
            if message.get("id") == ident:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]
        raise RuntimeError(f"{method}: no answer among 100,000 messages")

    def evaluate(self, expression: str):
        result = self._call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression!r}: {result['exceptionDetails'].get('text')}")
        return result["result"].get("value")

    def wait_for_timeout(self, milliseconds: float) -> None:
        time.sleep(milliseconds / 1000)

    def detach(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def close(self) -> None:
        """Leave the page (the tab stays, blank, for the next one) and detach."""
        self._call("Page.navigate", url="about:blank")
        self.detach()


class UnattendedBrowser:
    """Debian's chromium (headless, the tests' flags), its DevTools on a free port of 127.0.0.1."""

    def __init__(self) -> None:
        self._profile = Path(tempfile.mkdtemp(prefix="surgiplan-unattended-"))
        flags = [*CHROMIUM_FLAGS, f"--user-data-dir={self._profile}", "--remote-debugging-address=127.0.0.1"]
        size = f"--window-size={VIEWPORT['width']},{VIEWPORT['height']}"
        self._process = subprocess.Popen(
            [chromium_path(), *flags, "--remote-debugging-port=0", size, "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        port_file = self._profile / "DevToolsActivePort"
        for _ in range(600):  # bounded: 30 s for chromium to start
            if port_file.exists() and port_file.read_text().count("\n") >= 1:
                self._port = int(port_file.read_text().split()[0])
                return
            if self._process.poll() is not None:
                break
            time.sleep(0.05)
        self.close()
        raise SystemExit("chromium did not open its DevTools port within 30 s")

    def page(self, url: str, *, ready: str = "window.surgiplan && window.surgiplan.ready", timeout: float = 60_000):
        """The browser's page at ``url``, once ``ready`` is true in it, detached."""
        with urlopen(f"http://127.0.0.1:{self._port}/json/list", timeout=10) as answer:
            targets = json.load(answer)
        target = next(t for t in targets if t["type"] == "page")
        page = UnattendedPage(target["webSocketDebuggerUrl"])
        page._call("Page.navigate", url=url)
        wait_for(page, ready, timeout)  # the tests' poll: evaluate and wait_for_timeout are this page's too
        page.detach()
        return page

    def close(self) -> None:
        self._process.terminate()
        try:
            self._process.wait(10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(10)
        shutil.rmtree(self._profile, ignore_errors=True)
