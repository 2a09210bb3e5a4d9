"""The source read in its own thread, so the agent's link answers the server at once.

Why: the server measures each agent's clock offset from echoed heartbeats (docs/fusion.md §1),
and an echo is stamped when the agent handles the heartbeat. Read in the same thread as the
source, a heartbeat waited in the socket until the source's next frame (up to a frame period,
33 ms at 30 fps), which biased the offset by minus half that wait; heartbeats come every 15th
frame period, so the wait, and the bias, was the same at every sample of a sensor and no
choice of the quickest samples could remove it. Measured with ten agents on one machine: the
server mapped sensors' capture times up to 13 ms apart (docs/benchmarks.md, "Load").

With this thread the link's thread waits on its socket *and* on :meth:`CaptureThread.fileno`
(a socket pair written once per capture), and handles whichever comes first.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from queue import Empty, SimpleQueue
from types import TracebackType

from skelfuse.agent.sources.base import Capture, SkeletonSource

READ_TIMEOUT_S = 0.1
"""How long one ``next_capture`` may wait before the thread looks at its stop flag."""


class CaptureThread:
    """Reads ``source`` until closed; :meth:`take` hands over the captures in order.

    An exception from the source ends the thread and is raised by the next :meth:`take`, as
    it was raised to the agent's loop when that loop read the source itself.
    """

    def __init__(self, source: SkeletonSource, name: str = "agent-capture") -> None:
        self._source = source
        self._captures: SimpleQueue[Capture] = SimpleQueue()
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._wake_read, self._wake_write = socket.socketpair()
        self._wake_read.setblocking(False)
        self._wake_write.setblocking(False)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                capture = self._source.next_capture(timeout_s=READ_TIMEOUT_S)
                if capture is not None:
                    self._captures.put(capture)
                    self._wake()
        except BaseException as exc:  # handed to the agent's loop by take()
            self._error = exc
            self._wake()

    def _wake(self) -> None:
        # The pair full (the reader is behind: it drains the whole queue) or closed: no byte.
        with contextlib.suppress(OSError):
            self._wake_write.send(b"\x00")

    def fileno(self) -> int:
        """A file descriptor readable when a capture (or the source's error) is waiting."""
        return self._wake_read.fileno()

    def take(self) -> list[Capture]:
        """The captures read since the last call, oldest first (maybe none).

        Raises:
            Exception: whatever the source raised (then no more captures come).
        """
        with contextlib.suppress(OSError):  # BlockingIOError: drained
            while self._wake_read.recv(4096):
                pass
        captures: list[Capture] = []
        while True:
            try:
                captures.append(self._captures.get_nowait())
            except Empty:
                break
        if not captures and self._error is not None:
            raise self._error
        return captures

    def close(self, timeout_s: float = 2 * READ_TIMEOUT_S + 1.0) -> None:
        """Stop reading (after the source's current wait) and release the socket pair."""
        self._stop.set()
        self._thread.join(timeout=timeout_s)
        self._wake_read.close()
        self._wake_write.close()

    def __enter__(self) -> CaptureThread:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
