"""Progress of ``skelfuse mocap`` on stderr: frames done of the total, and the time left.

On a terminal one line is redrawn in place (carriage return); otherwise (a log, CI) a line is
written at each tenth of the way, so a long run shows it is alive without flooding the log.
The clock is injected, so tests drive the estimate without waiting.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO


def format_eta(seconds: float) -> str:
    """``"12 s"``, ``"3 min 05 s"``, ``"1 h 02 min"``."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Progress:
    """Frames done out of a total, with an estimate of the time left at the rate so far.

    Args:
        stage: what is being done (``"detecting"``, ``"fusing"``).
        out: the stream (stderr).
        clock: monotonic seconds (injected in tests).
        interactive: redraw one line (a terminal) or write a line per tenth; default: whether
            ``out`` is a terminal.
    """

    def __init__(
        self,
        stage: str,
        out: TextIO,
        *,
        clock: Callable[[], float] = time.monotonic,
        interactive: bool | None = None,
    ) -> None:
        self.stage = stage
        self._out = out
        self._clock = clock
        self._interactive = out.isatty() if interactive is None else interactive
        self._started = clock()
        self._totals: dict[int, int] = {}
        self._done: dict[int, int] = {}
        self._tenths_shown = -1
        self._dirty = False

    @property
    def total(self) -> int:
        return sum(self._totals.values())

    @property
    def done(self) -> int:
        return sum(self._done.values())

    def set_total(self, part: int, frames: int) -> None:
        """Part ``part`` (a video) has ``frames`` frames."""
        self._totals[part] = max(frames, 0)

    def update(self, part: int, done: int) -> None:
        """Part ``part`` has ``done`` frames done; shows the line if it is due."""
        self._done[part] = done
        # A video header may undercount: never report more done than the total.
        self._totals[part] = max(self._totals.get(part, 0), done)
        self._show()

    def line(self) -> str:
        """``"detecting: 140/400 frames (35 %), about 9 s left"``."""
        total, done = self.total, self.done
        percent = 100 * done / total if total else 0.0
        text = f"{self.stage}: {done}/{total} frames ({percent:.0f} %)"
        elapsed = self._clock() - self._started
        if 0 < done < total and elapsed > 0:
            text += f", about {format_eta(elapsed / done * (total - done))} left"
        elif done >= total > 0:
            text += f", {format_eta(elapsed)}"
        return text

    def finish(self) -> None:
        """End the line (a terminal) or write the last one (a log) if not yet written."""
        if self._interactive:
            if self._dirty:
                self._out.write("\r" + self.line() + "\n")
                self._dirty = False
        elif self._tenths_shown < 10:
            self._out.write(self.line() + "\n")
            self._tenths_shown = 10
        self._out.flush()

    def _show(self) -> None:
        total = self.total
        if self._interactive:
            self._out.write("\r" + self.line())
            self._dirty = True
        else:
            tenths = 10 * self.done // total if total else 0
            if tenths <= self._tenths_shown:
                return
            self._tenths_shown = tenths
            self._out.write(self.line() + "\n")
        self._out.flush()
