"""``surgiplan view``: a run's report served on 127.0.0.1, and the live viewer.

* :func:`serve_directory` serves a run's output directory (``report.html``
  and the figures beside it) over HTTP on 127.0.0.1 only, read-only.
* :class:`LiveViewer` is ``surgiplan view --live``: one port on 127.0.0.1
  serves the viewer page at ``/``, takes a running stage's feed at
  ``/feed`` (``surgiplan run --live``, :class:`surgiplan.live.WebSocketFeed`)
  and relays it to every page watching at ``/watch``. A page that connects
  late first gets the scene, the running stage and what it did so far. The
  relay never waits for a slow page (``websockets.broadcast`` skips a
  connection whose buffer is full), so no page can slow the feed, and the
  feed never waits for the viewer (see ``WebSocketFeed``).

Bounds: at most :data:`MAX_WATCHERS` pages and :data:`MAX_FEEDS` feeds at
once, messages of at most 4 MiB from a feed and 64 KiB from a page, pings
every 20 s (a dead peer is dropped after 20 s more), and ``exit_after``
seconds at most when given. Only loopback addresses are ever bound.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import http.server
import json
import logging
import threading
import webbrowser
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...errors import OutputError
from ...live import DEFAULT_PORT
from . import page

log = logging.getLogger(__name__)

HOST = "127.0.0.1"
MAX_WATCHERS = 16
MAX_FEEDS = 4
#: what a page that connects late is sent of the running stage: its latest samples and events
HISTORY = 20_000
EVENTS = 1_000
CHANNELS = ("run", "scene", "stage", "tip", "event", "status", "run_end")


def _open(url: str, open_browser: bool, announce: Callable[[str], None]) -> None:
    announce(url)
    if open_browser:
        try:
            webbrowser.open(url)
        except Exception as exc:  # no browser on this machine: the URL is printed
            log.info("could not open a browser: %s", exc)


# ----------------------------------------------------------------------------- a run's report


class _Handler(http.server.SimpleHTTPRequestHandler):
    timeout = 10  # a client that stalls is dropped

    def log_message(self, format, *args):
        log.debug("view: " + format, *args)

    def do_POST(self):
        self.send_error(405)

    do_PUT = do_DELETE = do_PATCH = do_POST


def serve_directory(
    out: Path,
    *,
    port: int = 0,
    open_browser: bool = True,
    exit_after: float | None = None,
    announce: Callable[[str], None] = print,
) -> None:
    """Serve ``out`` read-only on 127.0.0.1:``port`` (0: a free port) and open its report.html."""
    handler = functools.partial(_Handler, directory=str(out))
    try:
        server = http.server.ThreadingHTTPServer((HOST, port), handler)
    except OSError as exc:
        raise OutputError(f"cannot listen on {HOST}:{port}: {exc.strerror or exc}", location="--port") from None
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True)
    thread.start()
    try:
        _open(f"http://{HOST}:{server.server_address[1]}/report.html", open_browser, announce)
        threading.Event().wait(exit_after)  # until Ctrl-C, or exit_after seconds
    finally:
        server.shutdown()
        server.server_close()


# ----------------------------------------------------------------------------- the live viewer


class LiveViewer:
    """The live viewer's state and its websocket server (see the module docstring)."""

    def __init__(self, port: int = DEFAULT_PORT) -> None:
        self.port = port
        self.watchers: set = set()
        self.feeds = 0
        self.received = 0
        self.sticky: dict[str, Any] = {}
        self.tips: collections.deque = collections.deque(maxlen=HISTORY)
        self.events: collections.deque = collections.deque(maxlen=EVENTS)
        self.page = page(
            {
                "live": True,
                "run": {"name": "surgiplan live view", "status": "waiting", "length_unit": "mm", "unit_scale": 1e-3},
                "scene": None,
                "stages": [],
                "notes": [],
            },
            "surgiplan live view",
        )
        self.bound: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None

    # ------------------------------------------------------------------ HTTP and the handshake
    def _process_request(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]

        def respond(status: int, reason: str, body: bytes, kind: str = "text/plain; charset=utf-8"):
            headers = Headers(
                [("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")]
            )
            return Response(status, reason, headers, body)

        if path in ("/", "/index.html"):
            return respond(200, "OK", self.page.encode(), "text/html; charset=utf-8")
        origin = request.headers.get("Origin")
        if path == "/feed":
            if origin is not None:  # a web page may not pose as a running stage
                return respond(403, "Forbidden", b"a feed comes from surgiplan run --live, not from a page\n")
            if self.feeds >= MAX_FEEDS:
                return respond(503, "Service Unavailable", b"too many feeds\n")
            return None
        if path == "/watch":
            allowed = {f"http://{h}:{self.bound}" for h in (HOST, "localhost")}
            if origin not in allowed:  # only this viewer's own page may read the feed
                return respond(403, "Forbidden", b"watch from the page this viewer serves\n")
            if len(self.watchers) >= MAX_WATCHERS:
                return respond(503, "Service Unavailable", b"too many viewers\n")
            return None
        return respond(404, "Not Found", b"not found\n")

    # ------------------------------------------------------------------ connections
    async def _handler(self, connection) -> None:
        path = connection.request.path.split("?", 1)[0]
        if path == "/feed":
            await self._feed(connection)
        else:
            await self._watch(connection)

    def _snapshot(self) -> str:
        items = [{"channel": c, "payload": self.sticky[c]} for c in ("run", "scene", "stage") if c in self.sticky]
        items += [{"channel": "tip", "payload": p} for p in self.tips]
        items += [{"channel": "event", "payload": p} for p in self.events]
        items += [{"channel": c, "payload": self.sticky[c]} for c in ("status", "run_end") if c in self.sticky]
        return json.dumps(items)

    async def _watch(self, connection) -> None:
        self.watchers.add(connection)
        try:
            await connection.send(self._snapshot())
            async for _ in connection:  # a page sends nothing; this waits for it to close
                pass
        except Exception as exc:
            log.debug("view: a page went away: %s", exc)
        finally:
            self.watchers.discard(connection)

    async def _feed(self, connection) -> None:
        from websockets.asyncio.server import broadcast

        self.feeds += 1
        try:
            async for message in connection:
                try:
                    batch = json.loads(message)
                except (TypeError, ValueError):
                    log.warning("view: a feed sent something that is not JSON; ignored")
                    continue
                items = [
                    item
                    for item in (batch if isinstance(batch, list) else [batch])
                    if isinstance(item, dict)
                    and item.get("channel") in CHANNELS
                    and isinstance(item.get("payload"), dict)
                ]
                if not items:
                    continue
                for item in items:
                    channel, payload = item["channel"], item["payload"]
                    if channel == "tip":
                        self.tips.append(payload)
                    elif channel == "event":
                        self.events.append(payload)
                    else:
                        if channel == "stage":
                            self.tips.clear()
                            self.events.clear()
                            self.sticky.pop("status", None)
                        if channel == "run":
                            self.sticky.pop("run_end", None)
                        self.sticky[channel] = payload
                self.received += len(items)
                broadcast(self.watchers, json.dumps(items))
        except Exception as exc:
            log.debug("view: a feed went away: %s", exc)
        finally:
            self.feeds -= 1

    # ------------------------------------------------------------------ running
    async def serve(self, *, open_browser: bool, exit_after: float | None, announce: Callable[[str], None]) -> None:
        from websockets.asyncio.server import serve

        try:
            server = await serve(
                self._handler,
                HOST,
                self.port,
                process_request=self._process_request,
                max_size=4 * 2**20,
                ping_interval=20,
                ping_timeout=20,
                close_timeout=2,
                max_queue=64,
            )
        except OSError as exc:
            raise OutputError(
                f"cannot listen on {HOST}:{self.port}: {exc.strerror or exc} (is another viewer running? "
                "choose another --port, and give `surgiplan run --live ws://127.0.0.1:PORT/feed`)",
                location="--port",
            ) from None
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        async with server:
            self.bound = next(iter(server.sockets)).getsockname()[1]
            _open(f"http://{HOST}:{self.bound}/", open_browser, announce)
            announce(f"feed a run into it: surgiplan run PIPELINE --live ws://{HOST}:{self.bound}/feed")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), exit_after)

    def stop(self) -> None:
        """End :meth:`serve` (from any thread)."""
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)


def serve_live(
    *,
    port: int = DEFAULT_PORT,
    open_browser: bool = True,
    exit_after: float | None = None,
    announce: Callable[[str], None] = print,
) -> LiveViewer:
    """Run the live viewer on 127.0.0.1:``port`` until Ctrl-C (or ``exit_after`` seconds)."""
    viewer = LiveViewer(port)
    asyncio.run(viewer.serve(open_browser=open_browser, exit_after=exit_after, announce=announce))
    return viewer
