"""A bound on HTTP request bodies that holds whether or not the client says the length.

A ``Content-Length`` over the limit is answered 413 at once, before any of the body is read. A
chunked body (no length) is counted as the application reads it: the read that passes the limit
raises :class:`BodyTooLarge` instead of returning the bytes, and the answer is 413 with
``Connection: close``, so uvicorn drops the connection rather than read the rest (issue 12: an
8 MiB chunked body was read in full and parsed; a 128 MiB one took the server to 504 MB).

At most ``limit`` bytes plus one ASGI message (uvicorn's read size, 64 KiB) are ever held.
"""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


class BodyTooLarge(HTTPException):
    """The request body passed the limit while being read (an HTTP 413).

    An :class:`HTTPException` on purpose: FastAPI lets those through its body parsing (any other
    error there becomes a 400) and answers them with their status, detail and headers.
    """

    def __init__(self, limit: int) -> None:
        super().__init__(413, too_large_detail(limit), headers={"Connection": "close"})


def too_large_detail(limit: int) -> str:
    return f"request body larger than {limit} bytes"


class BodyLimit:
    """ASGI middleware: HTTP request bodies over ``limit`` bytes get 413 before they are read.

    Args:
        app: the application it wraps.
        limit: the largest body accepted, bytes (``Settings.max_body_bytes``).
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = Headers(scope=scope).get("content-length")
        if length is not None and (not length.isdigit() or int(length) > self.limit):
            await self._refuse(scope, receive, send)
            return
        received = 0
        started = False

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        async def watched_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted_receive, watched_send)
        except BodyTooLarge:
            # An application that does not answer HTTPException itself (a mounted sub-app).
            if started:
                raise
            await self._refuse(scope, receive, send)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        response = JSONResponse(
            {"detail": too_large_detail(self.limit)},
            status_code=413,
            headers={"Connection": "close"},
        )
        await response(scope, receive, send)
