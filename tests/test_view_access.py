"""``surgiplan view`` serves a run only to the holder of its token, and never a path outside the run's output.

Requests go over raw sockets (the paths are sent byte for byte as written here, no client normalises them);
every refusal asserts the exact status and that no byte of what it aimed at was sent.
"""

from __future__ import annotations

import asyncio
import json
import re
import socket
import threading
import time

import pytest
from surgiplan.outputs.report import access
from surgiplan.outputs.report.server import LiveViewer, serve_directory

SECRET = b"SECRET-TRAINEE-DATA-7f3a"
REPORT = b"<html>REPORT-OK</html>"


def request(port: int, path: str, headers: tuple[str, ...] = (), method: str = "GET") -> tuple[int, dict, bytes]:
    """(status, headers, body) of one HTTP/1.1 request sent as written."""
    lines = [f"{method} {path} HTTP/1.1", f"Host: 127.0.0.1:{port}", "Connection: close", *headers, "", ""]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall("\r\n".join(lines).encode("latin-1"))
        data = b""
        for _ in range(10_000):  # bounded: the server closes after its answer
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    status_line, *header_lines = head.decode("latin-1").split("\r\n")
    fields = {}
    for line in header_lines:
        name, _, value = line.partition(":")
        fields[name.strip().lower()] = value.strip()
    return int(status_line.split()[1]), fields, body


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A run's output directory served by ``serve_directory`` in a thread: (port, token, tmp)."""
    tmp = tmp_path_factory.mktemp("served")
    out = tmp / "out"
    (out / "figures").mkdir(parents=True)
    (out / "report.html").write_bytes(REPORT)
    (out / "figures" / "overview.png").write_bytes(b"\x89PNG-FIGURE")
    (tmp / "secret.txt").write_bytes(SECRET)
    (out / "link.txt").symlink_to(tmp / "secret.txt")  # a symlink pointing out of the output
    (out / "outside").symlink_to(tmp)  # a directory symlink pointing out
    urls: list[str] = []
    thread = threading.Thread(
        target=serve_directory,
        args=(out,),
        kwargs={"open_browser": False, "exit_after": 60, "announce": urls.append},
        daemon=True,
    )
    thread.start()
    for _ in range(500):
        if urls:
            break
        time.sleep(0.02)
    match = re.fullmatch(r"http://127\.0\.0\.1:(\d+)/report\.html\?token=([A-Za-z0-9_-]{40,})", urls[0])
    assert match, urls
    return int(match.group(1)), match.group(2), tmp


def test_the_token_opens_the_report_and_sets_a_cookie_for_its_own_requests(served):
    port, token, _ = served
    status, headers, body = request(port, f"/report.html?token={token}")
    assert (status, body) == (200, REPORT)
    cookie = headers["set-cookie"]
    assert (
        cookie.startswith(f"{access.cookie_name(port)}={token};")
        and "HttpOnly" in cookie
        and "SameSite=Strict" in cookie
    )
    # the page's figures: the cookie alone
    status, _, body = request(port, "/figures/overview.png", (f"Cookie: other=1; {access.cookie_name(port)}={token}",))
    assert (status, body) == (200, b"\x89PNG-FIGURE")
    assert request(port, f"/?token={token}")[::2] == (200, REPORT)  # / is the report
    status, headers, body = request(port, f"/report.html?token={token}", method="HEAD")
    assert (status, body, headers["content-length"]) == (200, b"", str(len(REPORT)))


@pytest.mark.parametrize(
    "credentials",
    [
        "",  # none
        "?token=",
        "?token=wrong",
        "?token={token}x",  # a longer token
        "?tok={token}",
        "#cookie-of-another-port",
    ],
)
@pytest.mark.parametrize("path", ["/report.html", "/", "/figures/overview.png", "/link.txt", "/../secret.txt"])
def test_without_the_token_403_and_nothing_served(served, path, credentials):
    port, token, _ = served
    headers: tuple[str, ...] = ()
    if credentials == "#cookie-of-another-port":
        headers, credentials = (f"Cookie: {access.cookie_name(port + 1)}={token}",), ""
    status, fields, body = request(port, path + credentials.format(token=token), headers)
    assert status == 403
    assert body == access_forbidden() and "set-cookie" not in fields
    assert REPORT not in body and SECRET not in body and b"PNG" not in body


def access_forbidden() -> bytes:
    from surgiplan.outputs.report.server import FORBIDDEN

    return FORBIDDEN.encode()


@pytest.mark.parametrize(
    "path, status",
    [
        ("/../secret.txt", 400),
        ("/figures/../../secret.txt", 400),
        ("/./report.html", 400),
        ("/%2e%2e/secret.txt", 400),  # encoded dots: still a .. segment
        ("/%2E%2E/secret.txt", 400),
        ("/%2e%2e%2fsecret.txt", 400),  # an encoded separator
        ("/..%2fsecret.txt", 400),
        ("/figures%2F..%2F..%2Fsecret.txt", 400),
        ("/..%5csecret.txt", 400),  # an encoded backslash
        ("/..\\secret.txt", 400),  # a backslash
        ("/figures\\..\\..\\secret.txt", 400),
        ("/report.html%00.png", 400),  # NUL
        ("/%ff%fe", 400),  # not UTF-8
        ("//{tmp}/secret.txt", 404),  # an absolute path (http.server folds the leading //): not under the output
        ("/{tmp}/secret.txt", 404),  # an absolute path, taken relative to the output: not there
        ("/link.txt", 403),  # a symlink to a file outside
        ("/outside/secret.txt", 403),  # through a symlinked directory
        ("/figures/", 404),  # no directory listings
        ("/figures", 404),
        ("/nothing.html", 404),
    ],
)
def test_no_path_outside_the_run_is_served(served, path, status):
    port, token, tmp = served
    got, fields, body = request(port, path.format(tmp=str(tmp).lstrip("/")) + f"?token={token}")
    assert got == status, body
    assert SECRET not in body and REPORT not in body and b"PNG" not in body
    assert fields["content-type"].startswith("text/plain") and len(body) < 100


def test_the_server_is_read_only(served):
    port, token, _ = served
    for method in ("POST", "PUT", "DELETE"):
        status, _, body = request(port, f"/report.html?token={token}", ("Content-Length: 0",), method=method)
        assert status == 405 and REPORT not in body
        status, _, body = request(port, "/report.html", ("Content-Length: 0",), method=method)
        assert (status, body) == (403, access_forbidden())


def test_every_start_draws_a_new_token(cli, tmp_path):
    (tmp_path / "report.html").write_bytes(REPORT)
    (tmp_path / "result.json").write_text('{"stages": []}')
    tokens = set()
    for _ in range(2):
        code, out, err = cli("view", tmp_path, "--no-browser", "--exit-after", "0.05", "--port", "0")
        assert code == 0, err
        tokens.update(re.findall(r"/report\.html\?token=([A-Za-z0-9_-]+)", out))
    assert len(tokens) == 2 and all(len(t) >= 40 for t in tokens)


# ----------------------------------------------------------------------------- the live viewer


@pytest.fixture
def viewer():
    viewer = LiveViewer(port=0)
    loop = asyncio.new_event_loop()
    announced: list[str] = []
    thread = threading.Thread(
        target=loop.run_until_complete,
        args=(viewer.serve(open_browser=False, exit_after=60, announce=announced.append),),
        daemon=True,
    )
    thread.start()
    for _ in range(500):
        if len(announced) >= 2:
            break
        time.sleep(0.02)
    viewer.announced = announced
    yield viewer
    viewer.stop()
    thread.join(10)


def test_the_live_viewer_prints_its_token_and_refuses_everything_without_it(viewer):
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    port, token = viewer.bound, viewer.token
    assert viewer.announced[0] == f"http://127.0.0.1:{port}/?token={token}"
    assert (
        f"{access.TOKEN_ENV}={token} " in viewer.announced[1] and f"ws://127.0.0.1:{port}/feed" in viewer.announced[1]
    )
    origin = f"http://127.0.0.1:{port}"
    for path in ("/", "/index.html", "/feed", "/watch", "/nothing", "/?token=wrong"):
        status, fields, body = request(port, path, (f"Origin: {origin}",) if path == "/watch" else ())
        assert (status, body) == (403, access_forbidden()), path
        assert "set-cookie" not in fields
    # websocket upgrades: no token, a wrong one, another port's cookie
    for url, headers in (
        (f"ws://127.0.0.1:{port}/watch", {}),
        (f"ws://127.0.0.1:{port}/watch?token=wrong", {}),
        (f"ws://127.0.0.1:{port}/watch", {"Cookie": f"{access.cookie_name(port + 1)}={token}"}),
        (f"ws://127.0.0.1:{port}/feed", {}),
        (f"ws://127.0.0.1:{port}/feed", {"Authorization": "token wrong"}),
    ):
        with pytest.raises(InvalidStatus) as refused:
            connect(url, origin=origin if "/watch" in url else None, additional_headers=headers, open_timeout=5)
        assert refused.value.response.status_code == 403
        assert refused.value.response.body == access_forbidden()
    assert viewer.watchers == set() and viewer.feeds == 0 and viewer.received == 0

    # the page with its token sets the cookie its websocket then carries
    status, fields, body = request(port, f"/?token={token}")
    assert status == 200 and b"surgiplan live view" in body
    assert fields["set-cookie"].startswith(f"{access.cookie_name(port)}={token};")
    with connect(
        f"ws://127.0.0.1:{port}/watch", origin=origin, additional_headers={"Cookie": fields["set-cookie"].split(";")[0]}
    ) as watcher:
        assert json.loads(watcher.recv(timeout=5)) == []


def test_a_feed_with_a_wrong_token_is_refused_and_stops_trying(viewer, monkeypatch):
    from surgiplan.live import WebSocketFeed

    monkeypatch.setenv(access.TOKEN_ENV, "not-the-token")
    feed = WebSocketFeed(viewer.feed_url, retry_for=10)
    feed.publish("tip", {"t": 0.0, "tip": [0.0, 0.0, 0.0]})
    feed._thread.join(10)
    assert feed.refused and not feed.active and viewer.received == 0
    # the token from the environment (what `surgiplan view --live` prints) is let in
    monkeypatch.setenv(access.TOKEN_ENV, viewer.token)
    feed = WebSocketFeed(viewer.feed_url, retry_for=10)
    feed.publish("tip", {"t": 0.0, "tip": [0.0, 0.0, 0.0]})
    feed.close()
    assert not feed.refused and feed.sent == 1 and viewer.received == 1
