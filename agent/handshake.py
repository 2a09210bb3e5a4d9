"""Why an agent gets no connection: ZeroMQ handshake failures, said in the agent's log.

A CurveZMQ server (``skelfuse server --curve``) drops an agent that has no key, or whose key it
does not allowlist, during the ZeroMQ handshake: the agent's messages are never delivered and
nothing comes back, so without this it would retry in silence forever. The socket's monitor
reports each failed handshake; :class:`HandshakeWatch` turns them into one clear warning per
cause (repeated at most every :data:`REPEAT_S`) and counts them, and says so too when no
``welcome`` came for :data:`NO_WELCOME_S` without any such report. The handshake itself is not
changed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import zmq
from zmq.utils.monitor import parse_monitor_message

logger = logging.getLogger(__name__)

NO_WELCOME_S = 10.0
"""Unregistered this long (since start or since the last welcome was lost): say so."""
REPEAT_S = 30.0
"""The same warning at most this often (the agent retries every second or two)."""

_WATCHED = (
    zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_AUTH
    | zmq.EVENT_HANDSHAKE_SUCCEEDED
)


class HandshakeWatch:
    """Reads an agent socket's monitor; call :meth:`poll` from the thread that owns the socket.

    ``failures`` counts failed handshakes by cause: ``no_key`` (the server needs CurveZMQ and
    this agent has no key), ``unexpected_key`` (this agent has keys, the server uses none),
    ``key_refused`` (the server does not allowlist this agent's key), ``protocol`` (anything
    else, e.g. not a skelfuse server).
    """

    def __init__(
        self,
        socket: zmq.Socket[Any],
        endpoint: str,
        has_keys: bool,
        clock: Callable[[], float],
    ) -> None:
        self._socket = socket
        self._monitor = socket.get_monitor_socket(_WATCHED)
        self._endpoint = endpoint
        self._has_keys = has_keys
        self._clock = clock
        self._unregistered_since = clock()
        self._warned: dict[str, float] = {}
        self.failures: dict[str, int] = {}

    def poll(self, registered: bool) -> None:
        """Handle the monitor's pending events; ``registered``: whether a welcome holds now."""
        while self._monitor.poll(0):
            event = parse_monitor_message(self._monitor.recv_multipart())
            if event["event"] == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                continue
            cause = self._cause(int(event["event"]), int(event["value"]))
            self.failures[cause] = self.failures.get(cause, 0) + 1
            self._warn(cause, _ADVICE[cause].format(endpoint=self._endpoint))
        now = self._clock()
        if registered:
            self._unregistered_since = now
        elif now - self._unregistered_since >= NO_WELCOME_S and not self.failures:
            self._warn(
                "no_welcome",
                f"no welcome from {self._endpoint} after {now - self._unregistered_since:.0f} s: "
                "is the server running and reachable (firewall, address)? A server started "
                "with --curve needs this agent to have --key and --server-key "
                "(docs/security.md)",
            )

    def _cause(self, event: int, value: int) -> str:
        if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
            return "key_refused"
        if value == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
            return "unexpected_key" if self._has_keys else "no_key"
        return "protocol"

    def _warn(self, cause: str, text: str) -> None:
        now = self._clock()
        if now - self._warned.get(cause, -float("inf")) >= REPEAT_S:
            self._warned[cause] = now
            logger.warning("%s", text)

    def close(self) -> None:
        """Stop monitoring (before the socket closes)."""
        self._socket.disable_monitor()
        self._monitor.close(linger=0)


_ADVICE = {
    "no_key": "the server at {endpoint} refused the connection: it requires CurveZMQ (it runs "
    "with --curve) and this agent has no key. Start the agent with --key "
    "<sensor id>.key_secret --server-key server.key ('skelfuse keys create' on the server "
    "makes them; docs/security.md)",
    "unexpected_key": "the server at {endpoint} does not use CurveZMQ but this agent was given "
    "keys: drop --key and --server-key, or start the server with --curve",
    "key_refused": "the server at {endpoint} refused this agent's CurveZMQ key: it is not in the "
    "server's keys/agents/ (or the server has not been restarted since it was added); "
    "docs/security.md",
    "protocol": "the ZeroMQ handshake with {endpoint} failed: is that a skelfuse server's agent "
    "port?",
}
