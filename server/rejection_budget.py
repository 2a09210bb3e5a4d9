"""A bound on the work one misbehaving connection can cause: its rejections per time window.

Rejecting a message means decoding it first; a peer firing thousands of malformed messages a
second would make the server spend its time on them. Each connection (ZeroMQ routing id) may
have ``limit`` messages rejected per ``window_s``; past that, everything it sends is dropped
unread until its window ends (and counted by the caller). A well-behaved agent never comes
near the limit: it has nothing rejected at all.
"""

from __future__ import annotations

from dataclasses import dataclass

REJECTIONS_PER_WINDOW = 50
"""Rejections a connection may cause per window before its messages are dropped unread."""
WINDOW_S = 1.0
MAX_TRACKED = 4096
"""Connections remembered at once; the oldest windows are forgotten first beyond this."""


@dataclass(slots=True)
class _Window:
    started: float
    rejections: int = 0


class RejectionBudget:
    """Per-connection rejection counts over fixed windows; times are monotonic seconds."""

    def __init__(
        self,
        limit: int = REJECTIONS_PER_WINDOW,
        window_s: float = WINDOW_S,
        max_tracked: int = MAX_TRACKED,
    ) -> None:
        self.limit = limit
        self.window_s = window_s
        self._max_tracked = max_tracked
        self._windows: dict[bytes, _Window] = {}

    def exhausted(self, peer: bytes, now: float) -> bool:
        """True while ``peer`` has used up its rejections in its current window: drop its
        messages unread."""
        window = self._windows.get(peer)
        return (
            window is not None
            and window.rejections >= self.limit
            and now - window.started < self.window_s
        )

    def note(self, peer: bytes, now: float) -> bool:
        """Count one rejection of ``peer``'s; True when this one used up its budget (the moment
        to log, once per window)."""
        window = self._windows.get(peer)
        if window is None or now - window.started >= self.window_s:
            if window is None and len(self._windows) >= self._max_tracked:
                self._forget_oldest()
            self._windows.pop(peer, None)  # re-inserted last: the dict stays oldest first
            window = self._windows[peer] = _Window(now)
        window.rejections += 1
        return window.rejections == self.limit

    def _forget_oldest(self) -> None:
        # Dicts keep insertion order and a reset window is re-inserted: the first is the oldest.
        for peer in list(self._windows)[: max(1, len(self._windows) // 4)]:
            del self._windows[peer]
