"""When to fuse the next output instant: the fusion engine's alignment policy (docs/fusion.md §2).

Output instants lie on a grid of ``output_hz`` on the server clock. Each policy decides, given
when each live sensor's newest frame was captured, whether the next instant can be fused now:

- ``aligned``: the grid has phase 0; an instant is fused once every live sensor has a frame at
  or after it (each sensor is then interpolated, never extrapolated). The wait is set by the
  sensor whose capture phase comes last after the grid's: up to one frame period.
- ``phased``: the same rule, on a grid whose phase follows the sensors' capture phases. The
  candidates are just before each sensor's capture phase (:data:`PHASE_MARGINS_S`); the one
  whose wait for the last sensor, replayed over the sensors' last :data:`PHASE_SAMPLES` frames
  (capture times and delays until seen), is smallest is taken (re-chosen every
  :data:`REPHASE_EVERY_S`, and only for a gain of :data:`REPHASE_GAIN_S`, so the grid does not
  hop on noise). Which instants are fused changes; how each is fused does not.
- ``deadline``: as ``phased``, but an instant is also fused when ``deadline_s`` has passed since
  it, whoever has reported: a sensor whose newest frame is before the instant is *late*, and is
  extrapolated to it when its newest frame is at most ``max_extrapolation_s`` before the
  instant, otherwise left out of that instant. Two options tune it to the rig from the sensors'
  observed capture phases and delays: ``grid = "horizon"`` puts the grid where the late sensors'
  extrapolation is shortest (the sum of squared horizons, replayed over the same frames as
  ``phased``, :func:`replayed_horizons`) instead of where the wait for the last
  sensor is; with ``skip_expected_late`` an instant does not wait for a sensor whose frame is
  expected after the deadline anyway (late in most replayed frames): it is fused as soon as
  the others are in and that sensor's frame from before the instant is (at the deadline when
  every sensor is expected late), never before the server clock reaches it: a camera stamping
  frames after they arrive (an uncalibrated lag) must not leave the rest out.
  With ``wait_for_phase`` there is no deadline until the grid's phase is first chosen (about
  a second): the grid the first frames put is anywhere against the sensors' phases, and a
  deadline there carries late sensors by up to a period. With ``jitter_fallback_s`` there is
  none either while the sensors' delivery delays scatter wider than that (a jittery link, such
  as Wi-Fi): a sensor expected on time then misses the deadline at random and is carried most
  of a period; the policy waits as ``phased`` does until the scatter settles. With a
  scatter below that, ``deadline_grace_s`` gives a sensor expected on time whose frame missed
  the deadline by a hair a few milliseconds more before it is carried.

The replay (last section): what a candidate grid phase would have done over the sensors' recent
frames, as pure functions on arrays of times (seconds): each sensor's last capture times modulo
its frame period, and how long after capture each of those frames was first seen by the policy.
The ``deadline`` replay (:func:`replayed_horizons`) runs once a second inside the fusion step
that triggers it, over (candidates × sensors × frames): one compiled loop per candidate, the
modulo as ``np.mod`` takes it (``fmod``, then the divisor's sign), the sum over sensors element
after element from 0, the mean over frames as numpy's pairwise sum.

Pure logic on times: nothing here reads a clock (the engine passes ``now_s``, server clock, Unix
seconds), so tests drive it with a clock of their own.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.mirror_scores import pairwise
from skelfuse.fusion.sensors import SensorState
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, jit_inline, plain

Policy = Literal["aligned", "phased", "deadline"]
Grid = Literal["wait", "horizon"]
FloatArray = npt.NDArray[np.float64]

REPHASE_EVERY_S = 1.0
"""How often (server seconds) the grid's phase is re-chosen from the sensors' phases."""
REPHASE_GAIN_S = 0.001
"""A new phase is taken only when it cuts the expected wait by more than this (hysteresis)."""
PHASE_MARGINS_S = (0.0005, 0.001, 0.002, 0.004)
"""The grid is put one of these before the sensor phase it is aligned with (whichever replays
best), so that the scatter of that sensor's capture times (delivery jitter moving the one-way
clock offset, clock noise) does not make its frame miss the instant by a hair: a whole period's
wait."""
PHASE_SAMPLES = 60
"""Frames per sensor the phase and delay estimates are taken over (2 s at 30 fps)."""
PHASE_MIN_SAMPLES = 30
"""Frames every sensor must have before the phase is first chosen: the first few frames' clock
mapping is still settling (a grid chosen from them measured worse than phase 0)."""
EXPECTED_LATE_SHARE = 0.5
"""``skip_expected_late``: a sensor late in more than this share of the replayed frames is not
waited for."""
HORIZON_TIE_S = 1e-4
"""``grid = "horizon"``: the replayed wait (seconds) counts this much (seconds², per second of
wait) beside the squared horizons, so that among grids as good for extrapolation (every sensor
on time, say) the one that waits least wins."""


@dataclass(frozen=True, slots=True)
class SensorTiming:
    """One live sensor as the policy sees it.

    newest_s: capture time of its newest frame (server clock, Unix seconds).
    period_s: its nominal frame period (seconds).
    """

    sensor_id: str
    newest_s: float
    period_s: float


def live_timings(
    sensors: Iterable[SensorState], now_s: float, max_wait_s: float
) -> list[SensorTiming]:
    """The connected sensors whose newest frame is at most ``max_wait_s`` old at ``now_s``
    (server clock): those the next instant waits for; one silent for longer holds nobody back."""
    return [
        SensorTiming(sensor.sensor_id, t, 1.0 / max(sensor.nominal_fps, 1.0))
        for sensor in sensors
        if sensor.connected and (t := sensor.latest_time()) is not None and t >= now_s - max_wait_s
    ]


@dataclass(frozen=True, slots=True)
class Instant:
    """An output instant to fuse now.

    t_s: the instant (server clock, Unix seconds).
    late: ``(sensor_id, seconds)`` for each sensor whose newest frame is that much before
        ``t_s``, to be extrapolated to it (``deadline`` only; empty when all are on time).
    left_out: the sensors further behind than the extrapolation bound, not fused this instant.
    """

    t_s: float
    late: tuple[tuple[str, float], ...] = ()
    left_out: tuple[str, ...] = ()


@dataclass(slots=True)
class _SensorPhase:
    """What has been seen of one sensor: capture times and how long after capture each frame
    was first seen by the policy (its delivery delay as fusion experiences it)."""

    newest_s: float = -math.inf
    captures: deque[float] = field(default_factory=lambda: deque(maxlen=PHASE_SAMPLES))
    delays: deque[float] = field(default_factory=lambda: deque(maxlen=PHASE_SAMPLES))


class Alignment:
    """The output grid and the policy deciding when its next instant is fused.

    Args:
        policy: ``aligned``, ``phased`` or ``deadline`` (module docstring).
        output_hz: instants per second.
        deadline_s: ``deadline``: fuse at the latest this long after the instant.
        max_extrapolation_s: ``deadline``: the furthest a late sensor is extrapolated.
        grid: ``deadline``: place the grid for the least wait (``wait``, as ``phased``) or
            for the shortest extrapolation of late sensors (``horizon``).
        skip_expected_late: ``deadline``: do not wait for sensors expected late.
        wait_for_phase: ``deadline``: until the grid's phase is first chosen (every sensor has
            :data:`PHASE_MIN_SAMPLES` frames), wait for every sensor as ``phased`` does.
        jitter_fallback_s: ``deadline``: while the sensors' delivery delays scatter wider than
            this (seconds; the median over sensors of each one's p90 − p10 over its last
            :data:`PHASE_SAMPLES` frames, taken at each re-phase), wait for every sensor as
            ``phased`` does, on ``phased``'s grid; 0: never.
        deadline_grace_s: ``deadline`` with ``skip_expected_late``: at the deadline, while a
            sensor expected on time (not in :attr:`expected_late`) has no frame at or after
            the instant, wait up to this much longer (seconds; module docstring); 0: never.
    """

    def __init__(
        self,
        policy: Policy,
        output_hz: float,
        deadline_s: float = 0.010,
        max_extrapolation_s: float = 0.034,
        grid: Grid = "wait",
        skip_expected_late: bool = False,
        wait_for_phase: bool = False,
        jitter_fallback_s: float = 0.0,
        deadline_grace_s: float = 0.0,
    ) -> None:
        self.deadline_grace_s = deadline_grace_s if policy == "deadline" else 0.0
        self.policy = policy
        self.grid: Grid = grid if policy == "deadline" else "wait"
        self.skip_expected_late = skip_expected_late and policy == "deadline"
        self.wait_for_phase = wait_for_phase
        self.jitter_fallback_s = jitter_fallback_s if policy == "deadline" else 0.0
        self.jittery = False
        """``jitter_fallback_s``: the delays scatter too wide for a deadline (re-judged with the
        phase): instants wait for every sensor as under ``phased``."""
        self.delay_spread_s: float | None = None
        """The delays' scatter at the last re-phase (seconds), once measured."""
        self.expected_late: frozenset[str] = frozenset()
        """``skip_expected_late``: the sensors the pending instants do not wait for (late in
        most replayed frames at the chosen phase); re-chosen with the phase."""
        self.period_s = 1.0 / output_hz
        self.deadline_s = deadline_s
        self.max_extrapolation_s = max_extrapolation_s
        self.phase_s = 0.0
        """The grid's phase (seconds in [0, period)): instants are ``phase_s + n · period_s``."""
        self._last_t = 0.0
        self._sensors: dict[str, _SensorPhase] = {}
        self._next_rephase_s = -math.inf
        self._due_s: float | None = None

    @classmethod
    def of(cls, settings: FusionSettings, output_hz: float) -> Alignment:
        """The policy ``settings`` choose (``alignment`` and the ``alignment_*`` fields)."""
        s = settings
        return cls(
            s.alignment.policy, output_hz, s.alignment.deadline_s, s.alignment.max_extrapolation_s,
            s.alignment.grid, s.alignment.skip_expected_late, s.alignment.wait_for_phase,
            s.alignment.jitter_fallback_s, s.alignment.deadline_grace_s,
        )  # fmt: skip

    @property
    def due_s(self) -> float | None:
        """When the pending instant is fused whatever arrives (server clock): its deadline.
        None under ``aligned`` / ``phased``, or while nothing is pending."""
        return self._due_s

    def next_instant(self, sensors: Sequence[SensorTiming], now_s: float) -> Instant | None:
        """The instant to fuse at ``now_s``, or None when it must wait (or nothing is live).

        The instant returned is taken: the next call looks for the one after it. After a stall
        the grid jumps to the newest fusable instant instead of fusing stale ones.

        Args:
            sensors: the live sensors (a sensor silent for longer than the hub's ``max_wait_s``
                is not live and holds nobody back).
            now_s: the server clock, Unix seconds.
        """
        if not sensors:
            self._due_s = None
            return None
        ready_until = min(s.newest_s for s in sensors)
        if self.policy == "aligned":
            return self._aligned(ready_until)
        self._observe(sensors, now_s)
        period = self.period_s
        fusable = ready_until
        if self._deadline_on():
            fusable = max(ready_until, now_s - self.deadline_s)
        next_t = self._grid_point(self._last_t + period)
        if next_t < fusable - 2 * period:  # start, or resync after a stall
            next_t = self._grid_floor(fusable)
        if next_t > ready_until:
            # Until the sensors' phases are known the grid is where the first frames put it, and
            # a deadline there carries late sensors by up to a period: wait as ``phased`` does.
            if not self._deadline_on() or self._settling():
                self._due_s = None
                return None
            waited = [s.newest_s for s in sensors if s.sensor_id not in self.expected_late]
            # Never before the deadline, even with every sensor expected late: the frame each
            # was captured just before the instant is then in, and carried least. Nor, with
            # others in, before an expected-late sensor's frame from just before the instant
            # is: without it that sensor is beyond the bound and left out of every instant.
            due = next_t + self.deadline_s
            waited_in = bool(waited) and min(waited) >= next_t
            bound = next_t - self.max_extrapolation_s
            waited_in &= all(
                s.newest_s >= bound for s in sensors if s.sensor_id in self.expected_late
            )
            # A sensor expected on time whose frame missed the deadline by a hair (jitter)
            # gets the grace: carried, it would be extrapolated most of a period.
            grace_until = due + self.deadline_grace_s
            missing = min(waited, default=next_t) < next_t  # none expected on time: no grace
            if self.skip_expected_late and due <= now_s < grace_until and missing:
                self._due_s = grace_until
                return None
            # Nor before the clock reaches it (module docstring: a camera stamping frames late).
            if now_s >= due or (waited_in and now_s >= next_t):
                instant = self._late_instant(next_t, sensors)
                if len(sensors) > len(instant.left_out):
                    return self._take(instant, period)
                # Nobody within the bound (all frames held up): wait for the first, as phased
                # would; a stall beyond 2 periods is skipped by the resync above.
            self._due_s = (next_t if waited_in else due) if now_s < due else None
            return None
        return self._take(Instant(next_t), period)

    # --- the rule before issue 11, kept to the bit ----------------------------------------------

    def _aligned(self, ready_until: float) -> Instant | None:
        period = self.period_s
        next_t = self._last_t + period
        if next_t < ready_until - 2 * period:
            next_t = math.floor(ready_until / period) * period  # start, or resync after a stall
        if next_t > ready_until:
            return None
        self._last_t = next_t
        return Instant(next_t)

    # --- the phased grid and the deadline ---------------------------------------------------

    def _grid_point(self, t_s: float) -> float:
        """The grid instant nearest ``t_s`` (after a phase change, the next instant is the one
        nearest a period after the last: the interval is between half and 1.5 periods once)."""
        return self.phase_s + round((t_s - self.phase_s) / self.period_s) * self.period_s

    def _grid_floor(self, t_s: float) -> float:
        """The last grid instant at or before ``t_s``."""
        return self.phase_s + math.floor((t_s - self.phase_s) / self.period_s) * self.period_s

    def _take(self, instant: Instant, period: float) -> Instant:
        self._last_t = instant.t_s
        following = self._grid_point(instant.t_s + period)
        self._due_s = None
        if self._deadline_on() and not self._settling():
            self._due_s = following + self.deadline_s
        return instant

    def _deadline_on(self) -> bool:
        """``deadline``, and the delays not scattered too wide for one (``jitter_fallback_s``)."""
        return self.policy == "deadline" and not self.jittery

    def _settling(self) -> bool:
        """``wait_for_phase``: the grid's phase has not been chosen yet (no deadline)."""
        return self.wait_for_phase and self._next_rephase_s == -math.inf

    def jitter_report(self) -> str:
        """What ``jitter_fallback_s`` decided at the last re-phase, in words (for the log)."""
        return jitter_report(self.jittery, self.delay_spread_s or 0.0)

    def _judge_jitter(self, delays: FloatArray) -> None:
        """``jitter_fallback_s``: whether the delays (S, frames), seconds, scatter too wide for a
        deadline (:func:`judged_jittery`)."""
        if self.jitter_fallback_s <= 0.0:
            return
        self.delay_spread_s = spread = delay_spread(delays)
        self.jittery = judged_jittery(spread, self.jitter_fallback_s, self.jittery)

    def _late_instant(self, t_s: float, sensors: Sequence[SensorTiming]) -> Instant:
        late: list[tuple[str, float]] = []
        left_out: list[str] = []
        for sensor in sensors:
            behind = t_s - sensor.newest_s
            if behind <= 0.0:
                continue
            if behind <= self.max_extrapolation_s:
                late.append((sensor.sensor_id, behind))
            else:
                left_out.append(sensor.sensor_id)
        return Instant(t_s, tuple(late), tuple(left_out))

    def _observe(self, sensors: Sequence[SensorTiming], now_s: float) -> None:
        """Note each sensor's new frames (capture time, delay until seen); re-choose the grid's
        phase every :data:`REPHASE_EVERY_S`."""
        for sensor in sensors:
            seen = self._sensors.get(sensor.sensor_id)
            if seen is None:
                seen = self._sensors[sensor.sensor_id] = _SensorPhase()
            if sensor.newest_s > seen.newest_s:
                seen.newest_s = sensor.newest_s
                seen.captures.append(sensor.newest_s)
                seen.delays.append(max(now_s - sensor.newest_s, 0.0))
        if now_s < self._next_rephase_s:
            return
        history = [self._sensors[sensor.sensor_id] for sensor in sensors]
        frames = min(len(seen.captures) for seen in history)
        if frames < PHASE_MIN_SAMPLES:
            return  # a sensor too new to have a phase: keep the grid until it has one
        self._next_rephase_s = now_s + REPHASE_EVERY_S
        grid = self.period_s
        periods = np.array([sensor.period_s for sensor in sensors])
        captures = np.array([[t % sensor.period_s for t in list(seen.captures)[-frames:]]
                             for sensor, seen in zip(sensors, history, strict=True)])  # fmt: skip
        delays = np.array([list(seen.delays)[-frames:] for seen in history])
        # ``horizon`` also tries the grid just after a sensor's phase: that sensor is then late
        # by a hair (extrapolated by under a millisecond) and the others are placed around it.
        signs = (1.0, -1.0) if self.grid == "horizon" else (1.0,)
        own = [
            circular_phase(h.captures, p) for p, h in zip(periods.tolist(), history, strict=True)
        ]
        candidates = [
            (phase + k * sensor.period_s - sign * margin) % grid
            for sensor, phase in zip(sensors, own, strict=True)
            for k in range(max(1, round(grid / sensor.period_s)))
            for margin in PHASE_MARGINS_S
            for sign in signs
        ]
        phases = np.array([*candidates, self.phase_s])
        self._judge_jitter(delays)
        shares = None  # (S,) each sensor's late share at the phase kept, when replayed already
        if self.grid == "wait" or self.jittery:
            waits = replayed_waits(phases, captures, delays, periods)
            best = int(np.argmin(waits[:-1]))
            if waits[best] < waits[-1] - REPHASE_GAIN_S:
                self.phase_s = candidates[best]
        else:
            cost, waits, late = replayed_horizons(
                phases, captures, delays, periods, self.deadline_s
            )
            score = cost + HORIZON_TIE_S * waits
            best = int(np.argmin(score[:-1]))
            # Hysteresis as for waits: a gain worth a millisecond of wait.
            kept = best if score[best] < score[-1] - HORIZON_TIE_S * REPHASE_GAIN_S else -1
            self.phase_s, shares = float(phases[kept]), late[kept]  # each row replayed alone
        if self.skip_expected_late:
            if shares is None:
                one = np.array([self.phase_s])
                shares = replayed_horizons(one, captures, delays, periods, self.deadline_s)[2][0]
            self.expected_late = frozenset(
                sensor.sensor_id
                for sensor, share in zip(sensors, shares.tolist(), strict=True)
                if share > EXPECTED_LATE_SHARE
            )


# --- The replay: what a candidate grid phase would have done over the sensors' recent frames -----


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
