"""The clock that timed server logic reads, passed in so tests can drive it instead of the wall.

Calibration runs pace their capture and stamp their runs with it; unit tests give them a fake
whose ``sleep`` advances its own time at once.
"""

from __future__ import annotations

import asyncio
import time
from typing import Protocol


class Clock(Protocol):
    def time(self) -> float:
        """Wall-clock time, Unix seconds (the clock frames are aligned on)."""
        ...

    def monotonic(self) -> float:
        """Seconds on a clock that never jumps (for durations)."""
        ...

    async def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` on this clock."""
        ...


class SystemClock:
    """The real clocks and ``asyncio.sleep``."""

    def time(self) -> float:
        return time.time()

    def monotonic(self) -> float:
        return time.monotonic()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)
