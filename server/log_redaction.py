"""Secrets never reach a log line: tokens in URLs and ``Authorization`` values are masked.

The WebSocket feed takes the API token as ``?token=`` (browsers cannot set headers on a
WebSocket), and uvicorn writes every request's path with its query string to its access log and
every WebSocket handshake to ``uvicorn.error`` (issue 12: the token was in the log in clear).
:class:`RedactSecrets` rewrites a record's message and arguments before any handler formats
them; :func:`redact_uvicorn_logs` puts it on uvicorn's loggers while a server runs, and the
command line puts it on its own log handler, so every logger that reaches the terminal is
covered.
"""

from __future__ import annotations

import logging
import re
from typing import Final

MASK: Final = "***"
_SECRET_PARAMETER = re.compile(
    r"(?i)(?<![A-Za-z0-9_])((?:access_|api_|auth_)?token|api_?key|secret|password|key_secret)"
    r"(=|%3D)([^&\s\"'#;]+)"
)
"""``name=value`` where name is a secret's (in a query string, a form, a command line)."""
_BEARER = re.compile(r"(?i)(authorization['\"]?\s*[:,=]\s*b?['\"]?\s*bearer\s+)([^\s\"',;)]+)")
"""The credentials of an ``Authorization: Bearer …`` header, written as text or as uvicorn's
trace log prints headers (``(b'authorization', b'Bearer …')``)."""

UVICORN_LOGGERS: Final = ("uvicorn.access", "uvicorn.error", "uvicorn.asgi")
"""Access lines, WebSocket handshakes (``"WebSocket /ws/skeletons?token=…" [accepted]``), and
the ASGI messages of ``--log-level trace``."""


def redact(text: str) -> str:
    """``text`` with the value of every secret query parameter and bearer token masked."""
    text = _SECRET_PARAMETER.sub(lambda m: f"{m[1]}{m[2]}{MASK}", text)
    return _BEARER.sub(lambda m: f"{m[1]}{MASK}", text)


def _redacted(value: object) -> object:
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, bytes | bytearray):  # uvicorn's trace log shows raw header bytes
        return redact(bytes(value).decode("latin-1")).encode("latin-1")
    if isinstance(value, tuple | list):
        return type(value)(_redacted(v) for v in value)
    return value


class RedactSecrets(logging.Filter):
    """A logging filter that masks secrets in a record's message and arguments; drops nothing.

    On a logger it sees the records created on that logger; on a handler, every record the
    handler writes (whichever logger they come from).
    """

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.args:
            if isinstance(record.msg, str):
                record.msg = redact(record.msg)
            return True
        # Arguments one by one, so that formatters reading them (uvicorn's access log takes
        # the path from args[2]) still find them where they were.
        if isinstance(record.args, dict):
            record.args = {k: _redacted(v) for k, v in record.args.items()}
        else:
            record.args = tuple(_redacted(a) for a in record.args)
        # The format string is masked only as the whole message: masking "token=%s" alone would
        # eat its placeholder and break the formatting.
        try:
            message = record.getMessage()
        except (TypeError, ValueError):  # a broken record: logging reports it as it is
            return True
        if redact(message) != message:
            record.msg, record.args = redact(message), None
        return True


def redact_uvicorn_logs() -> None:
    """Put a :class:`RedactSecrets` on each of uvicorn's loggers that has none yet.

    For the life of the process: masking secrets is never wrong, and several servers in one
    process (tests) then share one filter per logger instead of removing each other's.
    """
    for name in UVICORN_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactSecrets) for f in logger.filters):
            logger.addFilter(RedactSecrets())
