"""What a candidate grid phase would have done, replayed over the sensors' recent frames
(:mod:`skelfuse.fusion.alignment` re-chooses the grid's phase with these every second).

Pure functions on arrays of times (seconds): each sensor's last capture times modulo its frame
period, and how long after capture each of those frames was first seen by the policy. The
``deadline`` replay (:func:`replayed_horizons`) runs once a second inside the fusion step that
triggers it, over (candidates × sensors × frames): one compiled loop per candidate, the modulo
as ``np.mod`` takes it (``fmod``, then the divisor's sign), the sum over sensors element after
element from 0, the mean over frames as numpy's pairwise sum.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.mirror_distances import pairwise
from skelfuse.jit import jit, jit_inline, plain

FloatArray = npt.NDArray[np.float64]

REPLAYED_AT_ONCE = 65_536
"""At most this many (candidate, sensor, frame) elements :func:`replayed_waits` replays
together, the candidates split evenly: the arrays then stay in the cache. 129 candidates of 16
sensors × 60 frames (the re-phase of 16 sensors at 30 fps) go in two parts; 4 or 10 sensors
stay in one. The same bits: each candidate's sums are its own."""


def _parts(phases_s: FloatArray, captures_s: FloatArray) -> list[FloatArray]:
    """``phases_s`` split evenly into parts of at most :data:`REPLAYED_AT_ONCE` elements (one
    candidate a part when a single one has more)."""
    most = max(1, REPLAYED_AT_ONCE // max(captures_s.size, 1))  # candidates in one part
    count = -(-len(phases_s) // most)
    if count <= 1:
        return [phases_s]
    size = -(-len(phases_s) // count)  # at most ``most``, the parts as even as can be
    return [phases_s[lo : lo + size] for lo in range(0, len(phases_s), size)]


def circular_phase(times_s: Sequence[float], period_s: float) -> float:
    """The mean phase of ``times_s`` modulo ``period_s`` (seconds in [0, period)), as the angle
    of the mean of unit vectors, so that phases either side of 0 average to 0, not period/2.

    Raises:
        ValueError: ``times_s`` is empty.
    """
    if not times_s:
        raise ValueError("no times to take a phase of")
    origin = times_s[0]  # Unix seconds are large: take phases of differences (precision)
    omega = 2.0 * math.pi / period_s
    # Each angle once, both sums left to right as a generator's: the same floats, in half the
    # time (25 → 11 µs for 60 frames; once a second per sensor).
    angles = [omega * (t - origin) for t in times_s]
    c = sum(map(math.cos, angles))
    s = sum(map(math.sin, angles))
    return (origin + math.atan2(s, c) / omega) % period_s


def delay_spread(delays_s: FloatArray) -> float:
    """How widely the sensors' delivery delays scatter: the median over sensors of each one's
    p90 − p10 (seconds), from ``delays_s`` (S, L), S ≥ 1, L ≥ 2.

    The percentiles are ``np.percentile``'s (its default, linear interpolation), the same
    floats from one sort instead of two of its calls (330 → 15 µs for 4 sensors × 60 frames:
    once a second, inside a fusion step)."""
    ordered = np.sort(delays_s, axis=1)
    spreads = _linear_percentile(ordered, 0.9) - _linear_percentile(ordered, 0.1)
    return float(statistics.median(spreads.tolist()))  # np.median's floats: (a + b) / 2


JITTER_SETTLED_SHARE = 2 / 3
"""``jitter_fallback_s``: the deadline comes back once the delays' scatter is below this share of
the threshold that took it away (hysteresis: the scatter of 60 frames is itself noisy)."""


def judged_jittery(spread_s: float, threshold_s: float, was_jittery: bool) -> bool:
    """Whether delays scattering ``spread_s`` (:func:`delay_spread`) are too wide for a deadline
    at ``threshold_s`` (seconds): over it, or, judged so before, over
    :data:`JITTER_SETTLED_SHARE` of it."""
    return spread_s > threshold_s * (JITTER_SETTLED_SHARE if was_jittery else 1.0)


def jitter_report(jittery: bool, spread_s: float) -> str:
    """What the jitter fall-back decided, in words (for the log); ``spread_s`` in seconds."""
    spread_ms = 1e3 * spread_s
    if jittery:
        return (
            f"delivery delays scatter {spread_ms:.1f} ms (over alignment_jitter_fallback_s): "
            "waiting for every sensor, as alignment = 'phased', until they settle"
        )
    return f"delivery delays settled ({spread_ms:.1f} ms): the deadline is back"


def _linear_percentile(ordered: FloatArray, q: float) -> FloatArray:
    """The ``q`` quantile (0..1) of each row of ``ordered`` (S, L), rows sorted: numpy's
    ``linear`` method step by step (its virtual index, and its two-sided interpolation)."""
    n = ordered.shape[1]
    index = (n - 1) * q
    below = math.floor(index)
    gamma = index - below
    a, b = ordered[:, below], ordered[:, min(below + 1, n - 1)]
    # From the nearer end, as numpy interpolates.
    value: FloatArray = b - (b - a) * (1.0 - gamma) if gamma >= 0.5 else a + (b - a) * gamma
    return value


def replayed_waits(
    phases_s: FloatArray, captures_s: FloatArray, delays_s: FloatArray, periods_s: FloatArray
) -> FloatArray:
    """For each candidate grid phase, the mean wait the sensors' recent frames would have given:
    per frame (the sensors' i-th newest frames taken as one instant's), the max over sensors of
    (time from the instant before the capture to the capture) + (its delay until seen).

    Args:
        phases_s: (C,) candidate grid phases, seconds in [0, grid period).
        captures_s: (S, L) each sensor's last L capture times modulo its period, seconds.
        delays_s: (S, L) how long after capture each of those frames was seen, seconds.
        periods_s: (S,) the sensors' frame periods, seconds.

    Returns:
        (C,) mean wait per candidate, seconds.
    """
    parts = _parts(phases_s, captures_s)
    if len(parts) > 1:
        return np.concatenate([replayed_waits(p, captures_s, delays_s, periods_s) for p in parts])
    work = np.subtract(captures_s[None], phases_s[:, None, None])  # one array, in place
    ahead = np.mod(work, periods_s[None, :, None], out=work)
    waits: FloatArray = np.add(ahead, delays_s[None], out=work).max(axis=1).mean(axis=1)
    return waits


def replayed_horizons(
    phases_s: FloatArray,
    captures_s: FloatArray,
    delays_s: FloatArray,
    periods_s: FloatArray,
    deadline_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For each candidate grid phase, what the ``deadline`` policy would have done with the
    sensors' recent frames: a sensor whose frame after the instant would have been seen later
    than ``deadline_s`` after it is late, carried forward from its frame before the instant by
    its *horizon* (time from that capture to the instant).

    Args: as :func:`replayed_waits`, and the deadline (seconds after the instant).

    Returns:
        (C,) the mean over frames of the sum over sensors of squared horizons (s²);
        (C,) the mean wait for the last on-time sensor (seconds; 0 when all are late);
        (C, S) the share of frames in which each sensor was late.
    """
    count = len(phases_s)
    cost, waits = np.empty(count), np.empty(count)
    shares = np.empty((count, captures_s.shape[0]))
    _horizons_loop(
        plain(phases_s),
        plain(captures_s),
        plain(delays_s),
        plain(periods_s),
        float(deadline_s),
        cost,
        waits,
        shares,
    )
    return cost, waits, shares


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now, off any latency-bound path."""
    times = np.zeros((1, 2))
    replayed_horizons(np.zeros(1), times, times, np.ones(1), 0.01)


@jit
def _horizons_loop(  # the candidates' loop and its two modulo forms: one piece
    phases: FloatArray,
    captures: FloatArray,
    delays: FloatArray,
    periods: FloatArray,
    deadline: float,
    cost: FloatArray,
    waits: FloatArray,
    shares: FloatArray,
) -> None:
    """:func:`replayed_horizons` into ``cost``, ``waits`` and ``shares``."""
    sensors, frames = captures.shape
    squared = np.empty(frames)  # per frame, the sum over sensors of squared horizons
    last = np.empty(frames)  # per frame, the latest on-time sensor's wait
    # Each sensor's earliest and latest capture phase (NaN: the general modulo throughout).
    lowest, highest = np.empty(sensors), np.empty(sensors)
    for s in range(sensors):
        lowest[s], highest[s] = np.min(captures[s]), np.max(captures[s])
    for c in range(len(phases)):
        phase = phases[c]
        squared[:] = 0.0  # numpy sums over the sensors from 0
        last[:] = 0.0  # no sensor: no wait
        for s in range(sensors):
            period = periods[s]
            late_frames = 0
            # np.mod is fmod, then the divisor's sign (a zero takes the divisor's). Within a
            # period either side of 0 (a sensor at the grid's rate or slower) fmod gives the
            # value itself: there one addition, in a loop LLVM vectorises (7× quicker than
            # with fmod in it); elsewhere Python's float modulo, which numba keeps (np.mod's).
            if highest[s] - phase < period and lowest[s] - phase > -period:
                for f in range(frames):
                    ahead = captures[s, f] - phase
                    ahead = ahead + period if ahead < 0.0 else ahead  # −0 keeps a sign only
                    late_frames += _replay_frame(ahead, delays[s, f], period, deadline, s, f,
                                                 squared, last)  # fmt: skip
            else:
                for f in range(frames):
                    ahead = (captures[s, f] - phase) % period
                    late_frames += _replay_frame(ahead, delays[s, f], period, deadline, s, f,
                                                 squared, last)  # fmt: skip
            shares[c, s] = late_frames / frames
        cost[c] = _frames_sum(squared, frames) / frames
        waits[c] = _frames_sum(last, frames) / frames


@jit
def _frames_sum(values: FloatArray, n: int) -> float:
    """numpy's sum of the first ``n`` ``values`` along a contiguous axis: :func:`pairwise` up to
    its blocks of 128, halved (a multiple of 8 first) above as numpy's pairwise sum recurses."""
    if n <= 128:
        return pairwise(values, n)
    half = n // 2
    half -= half % 8
    return _frames_sum(values, half) + _frames_sum(values[half:], n - half)


@jit_inline
def _replay_frame(
    ahead: float,
    delay: float,
    period: float,
    deadline: float,
    s: int,
    f: int,
    squared: FloatArray,
    last: FloatArray,
) -> int:
    """One sensor's frame ``f`` at one candidate phase: 1 if late, else 0; its squared horizon
    added to ``squared[f]``, its wait (0 when late) taken into ``last[f]`` as ``np.maximum``
    takes it over the sensors (sensor 0's as it is; a NaN stays)."""
    seen = ahead + delay
    late = seen > deadline
    horizon = period - ahead if late else 0.0
    wait = 0.0 if late else seen
    squared[f] += horizon * horizon
    latest = last[f]
    last[f] = wait if s == 0 or wait > latest or wait != wait else latest
    return 1 if late else 0
