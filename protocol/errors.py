"""Errors of the protocol layer.

ProtocolError
├── DecodeError        the bytes are not a valid message (reason says which rule failed)
└── VersionMismatch    a well-formed message of a protocol version we do not speak
"""

from __future__ import annotations


class ProtocolError(Exception):
    """Base class of every wire-protocol error."""


class DecodeError(ProtocolError):
    """A message that cannot be accepted.

    ``reason`` is a short machine-readable tag (``malformed``, ``bad_field``, ``bad_shape``,
    ``non_finite``, ``out_of_range``, ``too_large``, ``unknown_type``...) used to count rejected
    frames by cause; the message text says what was received.
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class VersionMismatch(DecodeError):
    """The message's ``v`` is not a version this build speaks."""

    def __init__(self, received: object, supported: int) -> None:
        super().__init__(
            "version",
            f"protocol version {received!r} is not supported (this build speaks v{supported})",
        )
        self.received = received
        self.supported = supported
