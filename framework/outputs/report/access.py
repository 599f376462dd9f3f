"""Who may see a run: the per-run token of ``surgiplan view``, and the paths it may serve.

A trainee's attempts are personal data, and every local user can reach 127.0.0.1. So ``surgiplan view`` (a run's
report) and ``surgiplan view --live`` (the live viewer and its feed) follow Jupyter's model: each start draws a
random token (:func:`new_token`, :func:`secrets.token_urlsafe`) and prints the URL that carries it
(``http://127.0.0.1:PORT/?token=...``). A request presents the token in the URL's query (``token=``), in a
cookie (:func:`cookie_name`; set on the first page the token opened, so the page's own requests, figures and
websocket, carry it) or in an ``Authorization: token ...`` header (``surgiplan run --live`` with
``SURGIPLAN_LIVE_TOKEN``). Tokens are compared in constant time (:func:`hmac.compare_digest`). Without the
token: 403 and nothing served, websocket upgrades included.

:func:`resolve` maps a request's path to a file of the run's output directory, and refuses anything else: ``..``
or ``.`` segments, backslashes, percent-encoded separators (``%2f``, ``%5c``) and NUL are a 400; a file that
resolves outside the directory (a symlink pointing out) a 403; directories (no listings) and missing files a
404.
"""

from __future__ import annotations

import hmac
import os
import re
import secrets
from collections.abc import Iterable, Mapping
from pathlib import Path
from urllib.parse import parse_qs, unquote

from ...live import TOKEN_ENV, redact

__all__ = ["PARAM", "TOKEN_ENV", "authorised", "cookie_name", "new_token", "presented", "redact", "resolve"]
__all__ += ["set_cookie", "token_from_query"]

#: the query parameter, as in Jupyter
PARAM = "token"

_ENCODED_SEPARATOR = re.compile(r"%(2f|5c|00)", re.IGNORECASE)


def new_token() -> str:
    """A fresh random token (256 bits, URL-safe)."""
    return secrets.token_urlsafe(32)


def cookie_name(port: int) -> str:
    """The token's cookie for the viewer on ``port`` (cookies do not tell ports apart: one name per port)."""
    return f"surgiplan-token-{port}"


def set_cookie(port: int, token: str) -> str:
    """The ``Set-Cookie`` value that lets the page's own requests carry ``token``."""
    return f"{cookie_name(port)}={token}; Path=/; HttpOnly; SameSite=Strict"


def presented(query: str, headers: Mapping[str, str] | Iterable, port: int) -> list[str]:
    """The tokens a request presents: its query's ``token=``, its cookie for ``port``, ``Authorization: token``."""
    tokens = list(parse_qs(query, keep_blank_values=True).get(PARAM, []))
    get_all = getattr(headers, "get_all", None) or getattr(headers, "get_list", None)
    cookies = get_all("Cookie") if get_all else [headers.get("Cookie")]
    for header in cookies or []:
        for part in (header or "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == cookie_name(port):
                tokens.append(value)
    authorization = headers.get("Authorization") or ""
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() == "token" and value.strip():
        tokens.append(value.strip())
    return tokens


def authorised(expected: str, query: str, headers, port: int) -> bool:
    """Whether the request presents ``expected`` (each candidate compared in constant time)."""
    want = expected.encode()
    return any(hmac.compare_digest(token.encode("utf-8", "replace"), want) for token in presented(query, headers, port))


def token_from_query(query: str) -> str | None:
    """The ``token=`` of a query, if any."""
    values = parse_qs(query, keep_blank_values=True).get(PARAM)
    return values[0] if values else None


def resolve(root: Path, raw_path: str) -> tuple[int, Path | None, str]:
    """(status, file, message) for a request's path (still percent-encoded, without its query) under ``root``.

    200 and the file (its real path, inside ``root``'s real path); else the status to answer and why.
    ``/`` is the report (``report.html``).
    """
    if _ENCODED_SEPARATOR.search(raw_path) or "\\" in raw_path:
        return 400, None, "bad path: encoded separators and backslashes are refused\n"
    try:
        path = unquote(raw_path, errors="strict") if "%" in raw_path else raw_path
    except UnicodeDecodeError:
        return 400, None, "bad path: not UTF-8\n"
    if not path.startswith("/") or path.startswith("//") or "\\" in path or "\x00" in path:
        return 400, None, "bad path\n"
    segments = path[1:].split("/")
    if any(segment in (".", "..") for segment in segments):
        return 400, None, "bad path: no . or .. segments\n"
    relative = "/".join(s for s in segments if s) or "report.html"
    base = Path(os.path.realpath(root))
    target = Path(os.path.realpath(base / relative))
    if base != target and base not in target.parents:
        return 403, None, "outside the run's output directory\n"
    if not target.is_file():
        return 404, None, "not found\n"
    return 200, target, ""
