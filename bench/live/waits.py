"""The alignment wait of each fused instant, reconstructed from the agents' capture stamps.

The server fuses output instant ``t`` once every live sensor has a frame whose capture time,
mapped onto the server's clock when the frame arrived (``capture + offset``, the sensor's clock
offset estimate at that moment), is at or past ``t`` (``aligned`` and ``phased`` alike; under
``phased`` the instants follow the sensors' phases, so some sensor's mapped frames land only a
millisecond or two after them). The wait is the server-clock time of the last frame it needed
minus ``t``, on the same clock as the server's own ``lag`` (fusion start − ``t``), which it can
therefore never exceed.

Two things matter for that: the captures must be compared and reported *mapped* (a raw agent
stamp minus a server instant mixes two clocks: off by the offset), and mapped with the offset
the server used at the time, not the one it reports at the end of a run (its estimate moves by
fractions of a millisecond, enough to put a frame 1 ms after an instant before it, and the
instant's wait a whole frame period too long). The bench therefore samples every sensor's
offset during the run (:class:`OffsetSeries`) and interpolates it at each capture.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
Floats = npt.NDArray[np.floating[Any]]


class OffsetSeries(NamedTuple):
    """A sensor's clock offset estimate (server − agent, seconds) as sampled during a run.

    times_s: when each sample was read (server clock, Unix seconds), increasing.
    offsets_s: the estimate then. Before the first and after the last sample it is held.
    """

    times_s: FloatArray
    offsets_s: FloatArray

    @classmethod
    def constant(cls, offset_s: float) -> OffsetSeries:
        return cls(np.zeros(1), np.full(1, offset_s))

    def at(self, t_s: Floats) -> FloatArray:
        """The estimate at each of ``t_s`` (linear between samples)."""
        out: FloatArray = np.interp(t_s, self.times_s, self.offsets_s)
        return out


def offset_series(
    samples: Sequence[tuple[float, Mapping[str, float | None]]],
) -> dict[str, OffsetSeries]:
    """Per sensor, its offset samples ``(time_s, {sensor_id: clock_offset_s or None})`` as a
    series (samples without an estimate left out; a sensor never estimated is missing)."""
    points: dict[str, list[tuple[float, float]]] = {}
    for t_s, offsets in sorted(samples, key=lambda sample: sample[0]):
        for sensor_id, offset in offsets.items():
            if offset is not None:
                points.setdefault(sensor_id, []).append((t_s, float(offset)))
    return {
        sensor_id: OffsetSeries(np.array([t for t, _ in p]), np.array([o for _, o in p]))
        for sensor_id, p in points.items()
    }


def alignment_waits(
    fused_t: Floats, captures: Mapping[str, Floats], offsets: Mapping[str, OffsetSeries]
) -> FloatArray:
    """Per fused instant (server clock, s): the mapped capture time of the last frame it needed,
    minus the instant (seconds; NaN where some sensor has no frame at or after it).

    Args:
        fused_t: the instants the server fused (the feed's ``t``), seconds.
        captures: per sensor, its frames' capture stamps (agent clock, seconds), increasing.
        offsets: per sensor, its offset estimate over the run (a sensor without one: 0).
    """
    completing = np.full(fused_t.shape, -np.inf)
    for sensor_id, caps in captures.items():
        if not len(caps):
            continue
        series = offsets.get(sensor_id, OffsetSeries.constant(0.0))
        mapped = caps + series.at(caps)
        # A later estimate may map a frame before its predecessor by a hair: keep the order.
        mapped = np.maximum.accumulate(mapped)
        idx = np.searchsorted(mapped, fused_t, side="left")
        first = np.where(idx < len(mapped), mapped[np.minimum(idx, len(mapped) - 1)], np.nan)
        completing = np.fmax(completing, first)
    out: FloatArray = np.asarray(completing - fused_t, dtype=np.float64)
    return out
