"""``surgiplan view``: a run's report served on 127.0.0.1, and the live viewer.

* :func:`serve_directory` serves a run's output directory (``report.html``
  and the figures beside it) over HTTP on 127.0.0.1 only, read-only.
* :class:`LiveViewer` is ``surgiplan view --live``: one port on 127.0.0.1
  serves the viewer page at ``/``, takes a running stage's feed at
  ``/feed`` (``surgiplan run --live``, :class:`surgiplan.live.WebSocketFeed`)
  and relays it to every page watching at ``/watch``. A page that connects
  late first gets the scene, the running stage and what it did so far. The
  relay never waits for a page: each page has its own bounded queue
  (drop-oldest, the drops counted and shown in the page) and a page that
  stops reading is disconnected (:mod:`.relay`), so no page can slow the
  feed or grow the viewer's memory, and the feed never waits for the
  viewer (see ``WebSocketFeed``).

Bounds: at most :data:`MAX_WATCHERS` pages and :data:`MAX_FEEDS` feeds at
once, messages of at most 4 MiB from a feed and 64 KiB from a page, pings
every 20 s (a dead peer is dropped after 20 s more), and ``exit_after``
seconds at most when given. Only loopback addresses are ever bound.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import http.server
import json
import logging
import mimetypes
import threading
import webbrowser
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...errors import OutputError
from ...live import DEFAULT_PORT
from . import access, page
from .relay import Watcher

log = logging.getLogger(__name__)

HOST = "127.0.0.1"
MAX_WATCHERS = 16
MAX_FEEDS = 4
#: what a page that connects late is sent of the running stage: its latest samples and events
HISTORY = 20_000
EVENTS = 1_000
#: what a request without the token gets (with a 403), whatever it asked for
FORBIDDEN = "403: open the URL `surgiplan view` printed: it carries this viewer's token\n"
CHANNELS = ("run", "scene", "stage", "tip", "event", "status", "run_end", "drops")


def _open(url: str, open_browser: bool, announce: Callable[[str], None]) -> None:
    announce(url)
    if open_browser:
        try:
            webbrowser.open(url)
        except Exception as exc:  # no browser on this machine: the URL is printed
            log.info("could not open a browser: %s", exc)


# ----------------------------------------------------------------------------- a run's report


class _Handler(http.server.BaseHTTPRequestHandler):
    """GET and HEAD of the files of one run's output directory, for the holder of its token (see :mod:`.access`)."""

    timeout = 10  # a client that stalls is dropped
    root: Path
    token: str

    def log_message(self, format, *args):
        log.debug("view: " + format, *args)

    def do_GET(self):
        self._serve(body=True)

    def do_HEAD(self):
        self._serve(body=False)

    def do_POST(self):
        query = self.path.partition("?")[2]
        if not access.authorised(self.token, query, self.headers, self.server.server_address[1]):
            self._reply(403, FORBIDDEN)
        else:
            self._reply(405, "read-only\n")

    do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_POST

    def _reply(self, status: int, message: str, *, body: bool = True) -> None:
        data = message.encode()
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if body:
            self.wfile.write(data)

    def _serve(self, body: bool) -> None:
        raw, _, query = self.path.partition("?")
        port = self.server.server_address[1]
        if not access.authorised(self.token, query, self.headers, port):
            self._reply(403, FORBIDDEN, body=body)
            return
        status, file, message = access.resolve(self.root, raw)
        if file is None:
            self._reply(status, message, body=body)
            return
        try:
            data = file.read_bytes()
        except OSError:
            self._reply(404, "not found\n", body=body)
            return
        self.send_response(200)
        self.send_header("Content-Type", mimetypes.guess_type(file.name)[0] or "application/octet-stream")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        if access.token_from_query(query) is not None:  # the page's own requests (figures) carry the cookie
            self.send_header("Set-Cookie", access.set_cookie(port, self.token))
        self.end_headers()
        if body:
            self.wfile.write(data)


def serve_directory(
    out: Path,
    *,
    port: int = 0,
    open_browser: bool = True,
    exit_after: float | None = None,
    announce: Callable[[str], None] = print,
    token: str | None = None,
) -> None:
    """Serve ``out`` read-only on 127.0.0.1:``port`` (0: a free port) to the holder of ``token`` (None: a new
    one) and open its report.html; the URL announced carries the token."""
    token = token or access.new_token()
    handler = type("Handler", (_Handler,), {"root": Path(out), "token": token})
    try:
        server = http.server.ThreadingHTTPServer((HOST, port), handler)
    except OSError as exc:
        raise OutputError(f"cannot listen on {HOST}:{port}: {exc.strerror or exc}", location="--port") from None
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True)
    thread.start()
    try:
        _open(f"http://{HOST}:{server.server_address[1]}/report.html?token={token}", open_browser, announce)
        threading.Event().wait(exit_after)  # until Ctrl-C, or exit_after seconds
    finally:
        server.shutdown()
        server.server_close()


# ----------------------------------------------------------------------------- the live viewer


class LiveViewer:
    """The live viewer's state and its websocket server (see the module docstring)."""

    def __init__(
        self, port: int = DEFAULT_PORT, *, token: str | None = None, fps: float | None = None, **relay: Any
    ) -> None:
        self.port = port
        #: each page's relay bounds (:class:`.relay.Watcher`'s keywords; its defaults when empty)
        self.relay = relay
        #: what every request must present (see :mod:`.access`); printed in the URLs :meth:`serve` announces
        self.token = token or access.new_token()
        self.watchers: set = set()
        self.feeds = 0
        self.received = 0
        self.sticky: dict[str, Any] = {}
        self.tips: collections.deque = collections.deque(maxlen=HISTORY)
        self.events: collections.deque = collections.deque(maxlen=EVENTS)
        self.page = page(
            {
                "live": True,
                # the page's frames a second (0: the display's rate); None: 30 on a software renderer (report.js)
                **({"fps": float(fps)} if fps is not None else {}),
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

        path, _, query = request.path.partition("?")

        def respond(status: int, reason: str, body: bytes, kind: str = "text/plain; charset=utf-8", cookie=False):
            headers = Headers(
                [("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")]
            )
            if cookie:  # the page's websocket to /watch carries the token in this cookie
                headers["Set-Cookie"] = access.set_cookie(self.bound, self.token)
            return Response(status, reason, headers, body)

        if not access.authorised(self.token, query, request.headers, self.bound):
            return respond(403, "Forbidden", FORBIDDEN.encode())
        if path in ("/", "/index.html"):
            cookie = access.token_from_query(query) is not None
            return respond(200, "OK", self.page.encode(), "text/html; charset=utf-8", cookie=cookie)
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
        items += [{"channel": c, "payload": self.sticky[c]} for c in ("status", "run_end", "drops") if c in self.sticky]
        return json.dumps(items)

    async def _watch(self, connection) -> None:
        watcher = Watcher(connection, **self.relay)
        self.watchers.add(watcher)  # from now on what the feed sends waits in its queue
        try:
            await asyncio.wait_for(connection.send(self._snapshot()), watcher.stall_after)
            watcher.start()
            async for _ in connection:  # a page sends nothing; this waits for it to close
                pass
        except Exception as exc:
            log.debug("view: a page went away: %s", exc)
        finally:
            self.watchers.discard(watcher)
            await watcher.stop()

    async def _feed(self, connection) -> None:
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
                message = json.dumps(items)
                for watcher in list(self.watchers):  # never waits: each page's own bounded queue
                    watcher.offer(message, len(items))
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
            _open(self.url, open_browser, announce)
            announce(
                f"feed a run into it: {access.TOKEN_ENV}={self.token} surgiplan run PIPELINE --live {self.feed_url}"
            )
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), exit_after)

    @property
    def url(self) -> str:
        """The viewer page's URL, with the token."""
        return f"http://{HOST}:{self.bound}/?token={self.token}"

    @property
    def feed_url(self) -> str:
        """Where ``surgiplan run --live`` sends (the token goes in ``SURGIPLAN_LIVE_TOKEN``, or ``?token=``)."""
        return f"ws://{HOST}:{self.bound}/feed"

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
    token: str | None = None,
    fps: float | None = None,
) -> LiveViewer:
    """Run the live viewer on 127.0.0.1:``port`` until Ctrl-C (or ``exit_after`` seconds), for the holder of
    ``token`` (None: a new one); its page draws at most ``fps`` frames a second (0: the display's rate; None: 30
    when the browser renders WebGL in software, the display's rate otherwise)."""
    viewer = LiveViewer(port, token=token, fps=fps)
    asyncio.run(viewer.serve(open_browser=open_browser, exit_after=exit_after, announce=announce))
    return viewer
