"""Rolling statistics for health figures (fusion time, lag) without unbounded memory."""

from __future__ import annotations

from collections import deque
from statistics import median


class RollingStats:
    """The last ``size`` samples of one quantity."""

    def __init__(self, size: int = 300) -> None:
        self._samples: deque[float] = deque(maxlen=size)

    def add(self, value: float) -> None:
        self._samples.append(value)

    @property
    def count(self) -> int:
        return len(self._samples)

    def median(self) -> float:
        return median(self._samples) if self._samples else 0.0

    def maximum(self) -> float:
        return max(self._samples, default=0.0)
