"""HTTP-side protection: API token, browser origins, request size.

- **Token**: when ``Settings.api_token`` is set, every REST request that changes something
  (POST, PUT, PATCH, DELETE) and every read of people's data (:data:`PERSONAL_DATA_PATHS`: the
  fused skeletons, bone lengths, recordings; :data:`PERSONAL_SENSOR_VIEWS`: a sensor's depth
  cloud and raw bodies) needs ``Authorization: Bearer <token>``, and the
  WebSocket feed needs ``?token=<token>`` (browsers cannot set headers on a WebSocket). Status
  reads (health, sensors, calibration, metrics) stay open for dashboards and health checks.
  Tokens are compared in constant time.
- **Origins**: a browser page from another site must not read the feed through a visitor's
  browser. A WebSocket handshake whose ``Origin`` is neither the server's own host nor in
  ``Settings.allowed_origins`` is refused; clients that send no Origin (apps, scripts) pass.
- **Size**: bodies larger than ``Settings.max_body_bytes`` are refused with 413 before they are
  read, chunked or not (:mod:`skelfuse.server.body_limit`; uvicorn bounds WebSocket messages
  separately with ``ws_max_size``).
"""

from __future__ import annotations

import hmac
from urllib.parse import urlsplit

from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from skelfuse.server.settings import Settings

MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
PERSONAL_DATA_PATHS = ("/api/persons", "/api/recordings")
"""Paths (and everything below them) whose reads return people's motion or body measurements:
the latest fused frame, reference bone lengths, recordings and their downloads or exports."""
PERSONAL_SENSOR_VIEWS = ("/cloud", "/bodies")
"""Below ``/api/sensors/{id}``: a sensor's depth cloud and raw bodies show people too (the list
of sensors itself stays a status read)."""


def needs_token(method: str, path: str) -> bool:
    """Whether an HTTP request needs the API token (when one is set): changes and personal data."""
    if method.upper() in MUTATING_METHODS:
        return True
    path = path.rstrip("/")
    if path.startswith("/api/sensors/") and path.endswith(PERSONAL_SENSOR_VIEWS):
        return True
    return any(path == p or path.startswith(p + "/") for p in PERSONAL_DATA_PATHS)


def token_ok(expected: str | None, presented: str | None) -> bool:
    if expected is None:
        return True
    return presented is not None and hmac.compare_digest(expected.encode(), presented.encode())


def bearer(headers: Headers) -> str | None:
    value = headers.get("authorization", "")
    scheme, _, token = value.partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


def origin_ok(origin: str | None, host: str | None, allowed: tuple[str, ...]) -> bool:
    """True for non-browser clients, the server's own pages, and allow-listed origins."""
    if origin is None:
        return True
    if origin.rstrip("/") in {a.rstrip("/") for a in allowed}:
        return True
    return host is not None and urlsplit(origin).netloc.lower() == host.lower()


class HttpGuard:
    """ASGI middleware: the token on changes and personal data (:func:`needs_token`).

    Body sizes are bounded by :class:`skelfuse.server.body_limit.BodyLimit`.
    """

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.settings = settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        path, root = scope["path"], scope.get("root_path", "")
        if root and path.startswith(root):  # mounted under a prefix: the rule is on app paths
            path = path[len(root) :]
        if needs_token(scope["method"], path) and not token_ok(
            self.settings.api_token, bearer(headers)
        ):
            response = JSONResponse(
                {"detail": "this server needs a token: send 'Authorization: Bearer <token>' "
                 "(the server's --token or SKELFUSE_TOKEN)"},
                status_code=401,
                headers={"WWW-Authenticate": "Bearer"},
            )  # fmt: skip
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)
