"""A page that stops reading cannot grow the live viewer's memory and is disconnected; the others keep up.

The viewer runs in this process (so its memory can be traced, tracemalloc, and its per-page queues read). A
*stalled* client is a raw socket that completes the websocket upgrade (with the token) and then never reads a
byte (its receive buffer made small). A feed pushes about 40 MB through the viewer; a normal watcher (websockets'
own client) reads everything. With websockets' ``broadcast`` (what the viewer did before) the stalled page's
write buffer grew by every byte pushed; now its share stays under its queue's bound and it is cut off.
"""

from __future__ import annotations

import socket
import threading
import time
import tracemalloc

from browser_support import serving, stalled_client, watch_live
from surgiplan.live import MAX_MESSAGE, WebSocketFeed
from surgiplan.outputs.report.server import LiveViewer

MAX_BYTES = 2**20
EVENTS = 5000
PAD = 8000  # bytes of padding per event: 40 MB in all


def test_a_stalled_page_is_bounded_and_disconnected_while_a_normal_one_gets_everything():

    viewer = LiveViewer(port=0, max_messages=64, max_bytes=MAX_BYTES, stall_after=5, patience=3)
    with serving(viewer):
        port, token = viewer.bound, viewer.token
        tracemalloc.start()
        try:
            stalled_socket = stalled_client(f"http://127.0.0.1:{port}/?token={token}")
            for _ in range(500):
                if viewer.watchers:
                    break
                time.sleep(0.01)
            (stalled,) = viewer.watchers

            got = {"events": 0, "page_drops": 0, "status": False, "closed": None}

            def arrived(item: dict, _now: float) -> None:
                if item["channel"] == "event":
                    got["events"] += 1
                elif item["channel"] == "drops" and "page" in item["payload"]:
                    got["page_drops"] = item["payload"]["page"]
                elif item["channel"] == "status":
                    got["status"] = True

            page_url = f"http://127.0.0.1:{port}/?token={token}"
            normal = threading.Thread(target=watch_live, args=(page_url, arrived), daemon=True)
            normal.start()
            for _ in range(500):
                if len(viewer.watchers) == 2:
                    break
                time.sleep(0.01)
            assert len(viewer.watchers) == 2
            (normal_watcher,) = viewer.watchers - {stalled}
            baseline = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()

            feed = WebSocketFeed(viewer.feed_url, token=token)
            pushed = 0
            for i in range(EVENTS):
                payload = {"t": i / 100, "kind": "note", "message": "x" * PAD}
                pushed += PAD
                feed.publish("event", payload)
                if i % 20 == 19:
                    time.sleep(0.002)  # small batches (a feed message is at most 4 MiB)
            feed.publish("status", {"status": "completed"})
            feed.close(timeout=60)
            normal.join(60)
            peak = tracemalloc.get_traced_memory()[1] - baseline

            # the stalled page: cut off, and its share bounded by its queue plus one write buffer's worth
            for _ in range(2000):  # at most stall_after once the feed ended
                if stalled.disconnected is not None and stalled not in viewer.watchers:
                    break
                time.sleep(0.01)
            assert stalled.disconnected is not None and "stalled" in stalled.disconnected
            assert stalled not in viewer.watchers and normal_watcher.disconnected is None
            # its queue, the write buffer's high-water mark and one message (a feed sends at most MAX_MESSAGE)
            assert stalled.peak_bytes <= MAX_BYTES + 2**15 + MAX_MESSAGE, stalled.peak_bytes
            assert stalled.queued_bytes == 0 and not stalled.queue
            assert stalled.sent_messages < 64  # it took (into the kernel's buffers) hardly anything
            # its socket was closed by the viewer: once what the kernel holds is read, the stream ends
            stalled_socket.settimeout(10)
            received = 0
            try:
                for _ in range(100_000):
                    chunk = stalled_socket.recv(65536)
                    if not chunk:
                        break
                    received += len(chunk)
            except ConnectionResetError:
                pass
            stalled_socket.close()
            assert received < 4 * MAX_BYTES  # the kernel's buffers, a few queue-lengths at most, not 40 MB

            # the normal page got every event, or was told which it lost
            assert feed.sent == EVENTS + 1 and feed.dropped == 0
            assert got["status"] and got["events"] + got["page_drops"] == EVENTS, got
            # the viewer's memory while 40 MB went through: its history of events (1000 kept) and bounded queues
            assert pushed == EVENTS * PAD and peak < 32 * 2**20, peak / 2**20
        finally:
            tracemalloc.stop()


def test_a_viewer_that_stops_reading_the_feed_cannot_hold_the_stage():
    """The other direction: a 'viewer' that accepts the feed's websocket and never reads. Publishing goes on
    (it only appends to the feed's bounded queue), the queue stays within its bound and the excess is counted."""
    import base64
    import hashlib

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    accepted: list[socket.socket] = []

    def accept() -> None:
        server.settimeout(20)
        conn, _ = server.accept()
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        request = b""
        for _ in range(10_000):  # the upgrade request, then nothing is ever read again
            request += conn.recv(1)
            if request.endswith(b"\r\n\r\n"):
                break
        lines = request.split(b"\r\n")
        key = next(line.split(b":", 1)[1].strip() for line in lines if line.lower().startswith(b"sec-websocket-key"))
        accept_key = base64.b64encode(hashlib.sha1(key + b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11").digest())
        conn.sendall(
            b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Accept: " + accept_key + b"\r\n\r\n"
        )
        accepted.append(conn)

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    feed = WebSocketFeed(f"ws://127.0.0.1:{port}/feed", queue_size=1000, token="t")
    for _ in range(500):
        if feed.connected:
            break
        time.sleep(0.01)
    assert feed.connected
    published = 0
    for i in range(200):  # 200 x 1000 samples of 1 kB: far more than the sockets' buffers take
        for j in range(1000):
            feed.publish("tip", {"t": i + j / 1000, "tip": [0.0, 0.0, 0.0], "pad": "x" * 1000})
            published += 1
        assert len(feed._queue) <= 1000
        time.sleep(0.001)
    # the sender is stuck in a send the stalled viewer never takes; the stage went on, and every sample is
    # either sent (into the sockets' buffers), waiting in the bounded queue, or counted as dropped
    batch_in_flight = published - feed.sent - feed.dropped - len(feed._queue)
    assert 0 <= batch_in_flight <= 5000 and feed.dropped > published - 20_000, (feed.sent, feed.dropped)
    feed.active = False  # close() would wait for the stuck send; the sender thread is a daemon
    for conn in accepted:
        conn.close()
    server.close()
    thread.join(5)


def test_a_large_backlog_reaches_the_viewer_in_messages_it_accepts():
    """6 MB queued at once (more than the 4 MiB a viewer accepts in one message): sent in halves, all of it."""
    with serving(LiveViewer(port=0), exit_after=60) as viewer:
        feed = WebSocketFeed(viewer.feed_url, token=viewer.token)
        for i in range(3000):
            feed.publish("event", {"t": i / 100, "kind": "note", "message": "x" * 2000})
        feed.close(timeout=60)
        for _ in range(500):
            if viewer.received == 3000:
                break
            time.sleep(0.01)
        assert feed.sent == 3000 and feed.dropped == 0 and viewer.received == 3000
        assert [e["t"] for e in viewer.events] == [i / 100 for i in range(2000, 3000)]  # the latest 1000, in order
