"""When to hold a WebSocket client's next frame until it has read the last one (pacing).

The kernel cannot tell the server whether a client has *read* a frame: on loopback a frame
counts as delivered once it sits in the client's receive buffer, and Linux grows that buffer
(to hundreds of KiB, tens of frames) while a slow reader falls behind. A pong can tell: a client
answers a ping once it has read everything before it. So every ``ping_every`` frames a ping
follows the frame; a client that has not answered it after ``late_after_frames`` more frames
(or whose socket is full) is *paced*: from then on each frame is followed by a ping, and the
next frame waits for the pong, so the client reads one frame at a time and each is the newest
when it asked. A paced client whose pongs come back within ``quick_pong_s`` twice in a row
keeps up again and is released (a viewer that paused for a moment is not held to the pace of
its worst second). New clients start paced.

A client that keeps up costs one ping every ``ping_every`` frames. One that is slow from the
start never finds a queue; one that falls behind later reads at most ``ping_every`` +
``late_after_frames`` frames queued before it, once, and then the newest frame each time.

Lateness is counted in frames sent, not in seconds: a server whose own event loop stalls (a
busy machine) reads pongs late and sends fewer frames alike, and must not take every client
for a slow one (measured at load 8-11 with a 0.25 s limit: 500 clients lost 3,033 frames).

Times (for the quick pongs) are seconds on any monotonic clock, passed in.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class Pacer:
    """One client's pacing state (see the module's docstring)."""

    ping_every: int = 10
    late_after_frames: int = 8
    """About a quarter of a second at 30 fps: a viewer that stalls for less (a garbage
    collection, a busy moment) keeps getting every frame, only later; pacing would turn that lag
    into lost frames."""
    quick_pong_s: float = 0.05
    quick_pongs_to_release: int = 2
    """Quick pongs in a row that release a paced client: a slow reader's first read may be
    quick (it reads the greeting and the next message at once), its later ones are not."""
    paced: bool = True
    """A new client starts paced: one that is slow from the start never gets a queue, and one
    that keeps up is released after its first ``quick_pongs_to_release`` frames."""
    quick_pongs: int = 0
    ping_sent_at: float | None = None
    """When the unanswered ping was sent (None: no ping waits for its pong)."""
    frames_since_ping: int = 0

    def after_frame(self, now: float) -> tuple[bool, bool]:
        """A frame has left the server: (send a ping after it, wait for the pong before the next).

        ``now``: the clock's time.
        """
        self.frames_since_ping += 1
        if self.ping_sent_at is not None and self.frames_since_ping > self.late_after_frames:
            self.paced = True
            self.quick_pongs = 0
        ping = self.ping_sent_at is None and (
            self.paced or self.frames_since_ping >= self.ping_every
        )
        if ping:
            self.ping_sent_at = now
            self.frames_since_ping = 0
        return ping, self.paced and self.ping_sent_at is not None

    def on_pong(self, now: float) -> None:
        """The client answered the ping (it has read everything sent before it)."""
        if self.ping_sent_at is None:
            return
        if now - self.ping_sent_at < self.quick_pong_s:
            self.quick_pongs += 1
            if self.quick_pongs >= self.quick_pongs_to_release:
                self.paced = False
        else:
            self.quick_pongs = 0
        self.ping_sent_at = None

    def on_full(self) -> None:
        """The client's socket refused bytes: it reads more slowly than the feed."""
        self.paced = True
        self.quick_pongs = 0
