"""What the async and the sync feed clients share: the feed's URL, when to try again, and how
long to wait before each try.

A server that answers the handshake with a 4xx refused *this* request (a wrong token, an origin
or a query parameter it does not take): trying again cannot help, so that ends the client with
:class:`FeedRefused`. Anything else (nothing listening yet, a restart, a dropped connection, an
eviction for reading too slowly) is worth another try after a growing pause (:class:`Backoff`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal
from urllib.parse import urlencode, urlsplit, urlunsplit

FEED_PATH = "/ws/skeletons"
Format = Literal["json", "msgpack"]


class FeedError(Exception):
    """The feed cannot be read."""


class FeedRefused(FeedError):
    """The server refused the connection (HTTP 4xx at the handshake: token, origin, parameters).

    status: the HTTP status (403 for all of these with skelfuse's server).
    """

    def __init__(self, status: int, url: str) -> None:
        super().__init__(
            f"the server refused the feed (HTTP {status}) at {redact(url)}: a wrong or missing "
            "token (pass token=...), an origin it does not allow, or a bad query parameter"
        )
        self.status = status


class FeedUnavailable(FeedError):
    """No connection (the server is not there, or the connection broke) and no more tries."""


@dataclass(frozen=True, slots=True)
class Backoff:
    """Pauses between connection attempts: ``first_s``, then ``factor`` times longer each
    time, at most ``max_s``; ``attempts`` tries in a row at most (None: for ever). A connection
    that gets its greeting starts the sequence over."""

    first_s: float = 0.25
    factor: float = 2.0
    max_s: float = 5.0
    attempts: int | None = None

    def delays(self) -> Iterator[float]:
        """The pause before each retry (one fewer than ``attempts``)."""
        delay = self.first_s
        tried = 1
        while self.attempts is None or tried < self.attempts:
            yield delay
            delay = min(delay * self.factor, self.max_s)
            tried += 1


DEFAULT_BACKOFF = Backoff()
"""0.25, 0.5, 1, 2, 4, 5, 5... seconds, for ever."""


def feed_url(
    server: str,
    *,
    token: str | None = None,
    format: Format = "json",
    raw: bool = False,
    rotations: bool = False,
) -> str:
    """The WebSocket URL of the feed with these options.

    Args:
        server: ``http://host:port``, ``ws://host:port`` (https/wss alike), or a full feed URL;
            ``/ws/skeletons`` is added when the path is empty.
        token: the server's ``--token`` (sent as ``?token=``: browsers cannot set a WebSocket
            header, so that is how the server takes it).
        format, raw, rotations: the feed's query parameters (docs/api.md).

    Raises:
        ValueError: an unknown scheme or format.
    """
    parts = urlsplit(server if "://" in server else f"ws://{server}")
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None:
        raise ValueError(f"not an http(s) or ws(s) URL: {server!r}")
    if format not in ("json", "msgpack"):
        raise ValueError(f"format must be json or msgpack, not {format!r}")
    query: dict[str, str] = {}
    if format != "json":
        query["format"] = format
    if raw:
        query["raw"] = "1"
    if rotations:
        query["rotations"] = "1"
    if token is not None:
        query["token"] = token
    path = parts.path.rstrip("/") or FEED_PATH
    joined = "&".join(q for q in (parts.query, urlencode(query)) if q)
    return urlunsplit((scheme, parts.netloc, path, joined, ""))


def redact(url: str) -> str:
    """``url`` with a token's value masked, for messages and logs."""
    parts = urlsplit(url)
    query = "&".join(
        "token=***" if item.startswith("token=") else item
        for item in parts.query.split("&")
        if item
    )
    return urlunsplit((parts.scheme, parts.netloc, parts.path, query, ""))


def refused_status(exc: BaseException) -> int | None:
    """The 4xx status of a handshake the server refused, else None (worth another try)."""
    response = getattr(exc, "response", None)
    status = getattr(response, "status_code", None)
    if isinstance(status, int) and 400 <= status < 500:
        return status
    return None
