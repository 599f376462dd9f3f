"""The live viewer's relay to one page: a bounded queue, drop-oldest, and a stalled page disconnected.

The viewer (:class:`~surgiplan.outputs.report.server.LiveViewer`) hands every batch a feed sends to each page's
:class:`Watcher` with :meth:`Watcher.offer`, which never waits: it appends to the page's own queue, bounded in
messages (``max_messages``) and bytes (``max_bytes``); when the queue is full the oldest messages are dropped and
their samples counted. The page is told how many it lost (a ``drops`` item, ``{"page": n}``, before the next
message it gets), and shows it beside the feed's own drops.

One task per page sends its queue in order with flow control (``send`` waits while the connection's write
buffer is above websockets' high-water mark, 32 KiB), so what a page has not taken waits in its queue, never in an
unbounded buffer. A page that takes nothing is *stalled* and is disconnected once it has lost a whole queue's
worth since its last completed send (``max_messages`` messages or ``max_bytes`` bytes dropped) and that send is
``patience`` seconds ago, or when one send has waited ``stall_after`` seconds. Disconnected means reset (its
transport aborted with ``SO_LINGER`` 0): a stalled peer would not answer a closing handshake, and a FIN would
wait behind the data it never takes. What a stalled page can hold in the viewer is thus bounded by
``max_bytes`` in its queue, the write buffer's high-water mark plus the message being sent, and the kernel's
send buffer (:data:`SEND_BUFFER`); a slow page that keeps taking messages stays connected and loses the oldest.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import socket
import struct
import time

log = logging.getLogger(__name__)

#: per page, at most this many messages waiting (the oldest dropped first)
MAX_MESSAGES = 512
#: and at most this many bytes
MAX_BYTES = 4 * 2**20
#: a page that lost a whole queue's worth and took nothing for this long is disconnected
PATIENCE = 2.0
#: a send that waits this long means the page stopped reading
STALL_AFTER = 5.0
#: the kernel's send buffer for a page's socket (fixed: autotuning on loopback lets it grow to megabytes)
SEND_BUFFER = 64 * 2**10


class Watcher:
    """One page's queue and its sender task (see the module docstring)."""

    def __init__(
        self,
        connection,
        *,
        max_messages: int = MAX_MESSAGES,
        max_bytes: int = MAX_BYTES,
        stall_after: float = STALL_AFTER,
        patience: float = PATIENCE,
    ) -> None:
        self.connection = connection
        self.max_messages = int(max_messages)
        self.max_bytes = int(max_bytes)
        self.stall_after = float(stall_after)
        self.patience = float(patience)
        self.queue: collections.deque[tuple[str, int]] = collections.deque()
        #: bytes waiting in :attr:`queue`
        self.queued_bytes = 0
        #: samples (items) dropped for this page, and messages
        self.dropped = 0
        self.dropped_messages = 0
        self.sent_messages = 0
        #: the most this page ever held in the viewer: its queue plus the connection's write buffer (bytes)
        self.peak_bytes = 0
        #: why the page was disconnected (None while it is not)
        self.disconnected: str | None = None
        self._lost_since_progress = [0, 0]  # messages, bytes
        self._progress_at = time.monotonic()
        self._reported = 0
        self._wake = asyncio.Event()
        self._task: asyncio.Task | None = None
        with contextlib.suppress(Exception):  # bound the kernel's share as well
            sock = connection.transport.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)

    def write_buffer(self) -> int:
        """Bytes in the connection's write buffer (accepted by the transport, not yet by the kernel)."""
        try:
            return int(self.connection.transport.get_write_buffer_size())
        except Exception:
            return 0

    def offer(self, message: str, samples: int) -> None:
        """Queue ``message`` (``samples`` items) for this page; never waits. Drops the oldest when full."""
        if self.disconnected is not None:
            return
        size = len(message)
        self.queue.append((message, samples))
        self.queued_bytes += size
        while self.queue and (len(self.queue) > self.max_messages or self.queued_bytes > self.max_bytes):
            old, count = self.queue.popleft()
            self.queued_bytes -= len(old)
            self.dropped += count
            self.dropped_messages += 1
            self._lost_since_progress[0] += 1
            self._lost_since_progress[1] += len(old)
        self.peak_bytes = max(self.peak_bytes, self.queued_bytes + self.write_buffer())
        lost_messages, lost_bytes = self._lost_since_progress
        idle = time.monotonic() - self._progress_at
        if (lost_messages >= self.max_messages or lost_bytes >= self.max_bytes) and idle >= self.patience:
            self.disconnect(
                f"stalled: {lost_messages} messages ({lost_bytes} bytes) dropped since it last took one, "
                f"{idle:.1f} s ago"
            )
            return
        self._wake.set()

    def disconnect(self, reason: str) -> None:
        """Drop the page now (its transport aborted) and free its queue."""
        if self.disconnected is not None:
            return
        self.disconnected = reason
        log.warning("view: a page was disconnected: %s", reason)
        self.queue.clear()
        self.queued_bytes = 0
        with contextlib.suppress(Exception):  # a reset, not a FIN queued behind data the page will never take
            sock = self.connection.transport.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        with contextlib.suppress(Exception):
            self.connection.transport.abort()
        self._wake.set()

    def start(self) -> asyncio.Task:
        """Start the sender task (on the running loop)."""
        self._task = asyncio.get_running_loop().create_task(self._send_all())
        return self._task

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task

    async def _send(self, message: str) -> None:
        await asyncio.wait_for(self.connection.send(message), self.stall_after)

    async def _send_all(self) -> None:
        try:
            while self.disconnected is None:
                await self._wake.wait()
                self._wake.clear()
                while self.queue and self.disconnected is None:
                    if self.dropped != self._reported:  # tell the page what it lost, first
                        self._reported = self.dropped
                        await self._send(json.dumps([{"channel": "drops", "payload": {"page": self.dropped}}]))
                    message, _ = self.queue.popleft()
                    self.queued_bytes -= len(message)
                    await self._send(message)
                    self.sent_messages += 1
                    self._lost_since_progress = [0, 0]
                    self._progress_at = time.monotonic()
        except TimeoutError:
            self.disconnect(f"stalled: a send waited {self.stall_after:g} s")
        except Exception as exc:  # the page went away
            log.debug("view: a page's sender ended: %s", exc)
