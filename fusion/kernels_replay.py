"""The grid's re-phase replay as one compiled loop (numba).

:func:`skelfuse.fusion.alignment_replay.replayed_horizons` replays every candidate grid phase
over the sensors' last frames, once a second inside the fusion step that triggers it: in numpy
a few passes over a (candidates × sensors × frames) array, 3.1 ms for 129 candidates of 16
sensors × 60 frames (timed alone), which set the step's p99; 0.16 ms here. One loop per
candidate does the same IEEE operations: the modulo as ``np.mod`` takes it (``fmod``, then the
divisor's sign), the sum over sensors element after element from 0 as numpy reduces a middle
axis, the mean over frames as numpy's pairwise sum
(:func:`~skelfuse.fusion.kernels_mirror.pairwise`) over the count; so the same floats, and the
same phase chosen (tests/unit/test_kernels_replay.py).

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, jit_inline, plain
from skelfuse.fusion.kernels_mirror import pairwise

FloatArray = npt.NDArray[np.float64]

FEWEST_FRAMES, MOST_FRAMES = 2, 128
"""The frames per sensor the loop takes (the policy keeps 30 to 60). With one frame numpy sums
over the sensors pairwise (the frames' axis drops out and the sensors' becomes the contiguous
one); :func:`pairwise` sums at most 128 values as numpy does."""

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    times = np.zeros((1, FEWEST_FRAMES))
    horizons(np.zeros(1), times, times, np.ones(1), 0.01)
    warmed.done = True


def horizons(
    phases_s: FloatArray,
    captures_s: FloatArray,
    delays_s: FloatArray,
    periods_s: FloatArray,
    deadline_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`~skelfuse.fusion.alignment_replay.replayed_horizons`, the same floats.

    Args:
        phases_s: (C,) candidate grid phases, seconds.
        captures_s: (S, L) each sensor's last L capture times modulo its period, seconds;
            :data:`FEWEST_FRAMES` ≤ L ≤ :data:`MOST_FRAMES`.
        delays_s: (S, L) how long after capture each of those frames was seen, seconds.
        periods_s: (S,) the sensors' frame periods, seconds.
        deadline_s: the deadline, seconds after the instant.

    Returns:
        (C,) mean squared-horizon sum, (C,) mean wait for the last on-time sensor, (C, S) the
        share of frames each sensor was late.

    Raises:
        ValueError: fewer than :data:`FEWEST_FRAMES` or more than :data:`MOST_FRAMES` frames.
    """
    frames = captures_s.shape[1]
    if not FEWEST_FRAMES <= frames <= MOST_FRAMES:
        raise ValueError(f"{FEWEST_FRAMES} to {MOST_FRAMES} frames per sensor, got {frames}")
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


@jit
def _horizons_loop(  # pragma: no cover - compiled
    phases: FloatArray,
    captures: FloatArray,
    delays: FloatArray,
    periods: FloatArray,
    deadline: float,
    cost: FloatArray,
    waits: FloatArray,
    shares: FloatArray,
) -> None:
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
        cost[c] = pairwise(squared, frames) / frames
        waits[c] = pairwise(last, frames) / frames


@jit_inline
def _replay_frame(  # pragma: no cover - compiled
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
