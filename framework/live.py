"""Live feeds: what a running stage is doing, published for ``surgiplan view --live``.

A stage that runs for a while with something to watch (an ``execute`` stage
moving a device, a ``guide`` stage following a trainee) publishes samples on
its :attr:`StageContext.live <surgiplan.results.StageContext.live>` feed::

    context.live.publish("tip", {"t": 1.25, "tip": [x, y, z], "clearance": 0.004})
    context.live.publish("event", {"t": 1.3, "kind": "below_threshold", "message": "..."})

The default feed (:class:`LiveFeed`) drops everything, so publishing costs
nothing when nobody watches; ``surgiplan run --live`` (see
``surgiplan.outputs.report``) connects a feed that forwards to a viewer on
127.0.0.1. Publishing never blocks the stage: a feed that cannot keep up
drops samples, never delays the control loop.

Channels and payloads (JSON values, SI units):

* ``stage``: ``{"name", "kind", "plugin", "path_from"?, "recommended"?: [[x, y, z], ...]}`` when a stage starts;
* ``tip``: ``{"t", "tip": [x, y, z], "commanded"?: [x, y, z], "clearance"?, "deviation"?}``;
* ``event``: ``{"t", "kind", "message"}``;
* ``status``: ``{"status", "message"?}`` when the stage ends;
* ``drops``: ``{"feed": n}`` samples the feed dropped so far (sent by :class:`WebSocketFeed` when it grows; the
  viewer adds ``{"page": n}``, what it dropped for one page), shown in the page.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class LiveFeed:
    """A feed nobody watches: every publication is dropped."""

    #: whether anyone is watching (a stage may skip preparing payloads when not)
    active: bool = False

    def publish(self, channel: str, payload: Mapping[str, Any]) -> None:
        """Send ``payload`` on ``channel``; never blocks, never raises."""

    def close(self) -> None:
        """Stop publishing (the run calls it when it ends); this feed holds nothing to flush."""
        pass

    def threads(self) -> list[int]:
        """The native ids of the threads this feed runs (a sender): a stage that paces real time runs them at its
        own scheduling while it does (a sender that holds Python's GIL when something preempts it would hold up
        the stage until it runs again); none here."""
        return []


# ----------------------------------------------------------------------------- a feed to a live viewer

#: where ``surgiplan view --live`` listens by default, and where ``surgiplan run --live`` sends
DEFAULT_PORT = 8765
DEFAULT_URL = f"ws://127.0.0.1:{DEFAULT_PORT}/feed"

#: the largest message a feed sends, in characters (a batch above it is split; the viewer takes up to 4 MiB)
MAX_MESSAGE = 2**20

#: channels whose latest payload is sent again first whenever the feed (re)connects
STICKY = ("run", "scene", "stage")

#: the environment variable ``surgiplan run --live`` takes the live viewer's token from when its URL has no
#: ``?token=`` (an environment is private to its user; a command line is in every local user's process list)
TOKEN_ENV = "SURGIPLAN_LIVE_TOKEN"


def redact(url: str) -> str:
    """``url`` with its ``token=`` hidden (for logs and messages)."""
    import re

    return re.sub(r"([?&]token=)[^&#]*", r"\1…", url)


def loopback_url(url: str) -> tuple[str, int, str]:
    """(host, port, path) of a ``ws://`` URL on this machine; anything else is a
    :class:`~surgiplan.errors.ConfigError`."""
    import ipaddress
    from urllib.parse import urlsplit

    from .errors import ConfigError

    try:
        parts = urlsplit(url)
        host, port = parts.hostname or "", parts.port
    except ValueError as exc:
        raise ConfigError(f"live viewer address {url!r} is not a URL ({exc})", location="--live") from None
    if parts.scheme != "ws" or not host or port is None:
        raise ConfigError(f"live viewer address {url!r}: give ws://127.0.0.1:PORT/feed", location="--live")
    try:
        local = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        local = False
    if not local:
        raise ConfigError(
            f"live viewer address {url!r} is not on this machine: a run feeds only a viewer on 127.0.0.1 or ::1",
            location="--live",
        )
    return host, port, parts.path or "/feed"


class WebSocketFeed(LiveFeed):
    """Forwards publications to a live viewer (``surgiplan view --live``) over a websocket on loopback.

    :meth:`publish` only appends to a bounded queue and wakes a sender thread: it never blocks and never
    raises, whatever the viewer does. The sender batches what has queued (one websocket message per
    batch), so thousands of samples a second cost one send every few milliseconds. When the queue is full
    the oldest samples are dropped (counted in ``dropped``). The latest ``run``, ``scene`` and
    ``stage`` payloads are sent again first on every (re)connection, so a viewer started late still
    draws the scene and the running stage. Connection attempts are bounded: one a second for
    ``retry_for`` seconds, after which the feed stops trying and drops everything.
    """

    active = True

    def __init__(
        self,
        url: str = DEFAULT_URL,
        *,
        queue_size: int = 50_000,
        retry_for: float = 30.0,
        open_timeout: float = 2.0,
        token: str | None = None,
    ) -> None:
        import collections
        import os
        import threading

        loopback_url(url)
        self.url = url
        token = token or os.environ.get(TOKEN_ENV)
        self._headers = [("Authorization", f"token {token}")] if token and "token=" not in url else []
        self.retry_for = float(retry_for)
        self.open_timeout = float(open_timeout)
        self.sent = 0
        self.dropped = 0
        self.connected = False
        #: the viewer refused the token (403): the feed stopped trying
        self.refused = False
        self._queue: collections.deque = collections.deque(maxlen=queue_size)
        self._sticky: dict[str, Any] = {}
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="surgiplan-live-feed", daemon=True)
        self._thread.start()

    def publish(self, channel: str, payload: Mapping[str, Any]) -> None:
        if not self.active:
            return
        if channel in STICKY:
            self._sticky[channel] = payload
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        self._queue.append((channel, payload))
        self._wake.set()

    def threads(self) -> list[int]:
        return [self._thread.native_id] if self._thread.is_alive() and self._thread.native_id else []

    def close(self, timeout: float = 3.0) -> None:
        """Send what is queued (for at most ``timeout`` seconds), then close the connection."""
        self._closing.set()
        self._wake.set()
        self._thread.join(timeout)
        self.active = False

    # ------------------------------------------------------------------ the sender thread
    def _encode(self, items) -> str:
        import json

        from .storage import _json_default

        return json.dumps([{"channel": c, "payload": p} for c, p in items], default=_json_default, allow_nan=False)

    def _send(self, socket, batch: list) -> None:
        """Send ``batch`` as one message, or halves of it while its text exceeds :data:`MAX_MESSAGE`."""
        text = self._encode(batch)
        if len(text) > MAX_MESSAGE and len(batch) > 1:
            half = len(batch) // 2
            self._send(socket, batch[:half])
            self._send(socket, batch[half:])
        else:
            socket.send(text)

    def _run(self) -> None:
        import logging
        import time

        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus, InvalidURI
        from websockets.sync.client import connect

        log = logging.getLogger(__name__)
        give_up = time.monotonic() + self.retry_for
        warned = reconnect = False
        reported = 0
        while True:
            try:
                socket = connect(
                    self.url,
                    open_timeout=self.open_timeout,
                    close_timeout=1.0,
                    max_size=2**20,
                    additional_headers=self._headers,
                )
            except (OSError, TimeoutError, InvalidHandshake, InvalidURI) as exc:
                if isinstance(exc, InvalidStatus) and exc.response.status_code == 403:
                    # a wrong or missing token: trying again will not help
                    log.error(
                        "the live viewer at %s refused the feed (403): give the token `surgiplan view --live` "
                        "printed (%s=... or ?token=...)",
                        redact(self.url),
                        TOKEN_ENV,
                    )
                    self.refused = True
                    break
                if not warned:
                    log.warning(
                        "no live viewer at %s (%s): start `surgiplan view --live`; trying for %.0f s",
                        redact(self.url),
                        exc,
                        max(0.0, give_up - time.monotonic()),
                    )
                    warned = True
                if time.monotonic() >= give_up or self._closing.is_set():
                    break
                self._closing.wait(1.0)
                continue
            self.connected = True
            log.info("live feed connected to %s", redact(self.url))
            try:
                with socket:
                    sticky = list(self._sticky.items())
                    if sticky and (reconnect or self.dropped):  # else they are still in the queue
                        socket.send(self._encode(sticky))
                    while True:
                        self._wake.wait(0.05)
                        self._wake.clear()
                        batch = []
                        while self._queue and len(batch) < 5000:
                            batch.append(self._queue.popleft())
                        if self.dropped != reported:  # the page shows what the feed dropped
                            reported = self.dropped
                            socket.send(self._encode([("drops", {"feed": reported})]))
                        if batch:
                            self._send(socket, batch)
                            self.sent += len(batch)
                        elif self._closing.is_set():
                            break
            except (ConnectionClosed, OSError, TimeoutError, ValueError) as exc:
                log.warning("live viewer at %s went away (%s)", redact(self.url), exc)
            finally:
                self.connected = False
            if self._closing.is_set():
                break
            give_up = time.monotonic() + self.retry_for  # the viewer went away: look for it again, for a while
            warned, reconnect = False, True
        self.active = False
        self._queue.clear()
