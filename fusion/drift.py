"""Drift detection: has a sensor moved since its calibration was committed?

A bumped sensor keeps reporting good skeletons, but in the wrong place of the world: its views
no longer agree with the other sensors' views of the same person. This module keeps, per pair
of sensors, a sliding window of the trunk points both saw of one person at the same fusion
instants (world frame, placed with the committed poses), and estimates the rigid correction
(rotation + translation, weighted Kabsch: :func:`skelfuse.calibration.rigid.fit_rigid`) that
would bring one sensor's points onto the other's.

What normally disagrees between views is left out, as the skeleton calibration does
(:mod:`skelfuse.calibration.skeleton_pose`): only the midline trunk points (mirror-invariant
by construction, and on the vertical axis about which a tracker turns the body toward itself),
and only joints Tracked in both views. A window whose pelvis positions spread less than
``MIN_SPREAD_M`` (a person standing still: a poorly conditioned fit) gives no estimate.

Blame: a sensor's correction is the *smallest* of its pairwise corrections, so with three or
more sensors only the sensor that disagrees with every other one is flagged (the others agree
with each other). With two sensors the pair is ambiguous: both are flagged.

Hysteresis: a sensor is flagged after ``drift_confirm_checks`` consecutive checks whose
correction exceeds a threshold (``drift_threshold_deg`` or ``drift_threshold_mm``), and cleared
after as many checks below ``DRIFT_CLEAR_RATIO`` of them. Checks without an estimate (nobody
moving, one sensor alone) change nothing.

Time is the fusion instants' (``t_s`` of each step); nothing here reads a clock. Frames and
units: world frame, metres; corrections in degrees and millimetres.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import CalibrationError
from skelfuse.calibration.rigid import fit_rigid, rotation_angle_deg
from skelfuse.calibration.skeleton_pose import FEATURES
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import FusedPerson, View
from skelfuse.protocol.skeleton import JointId, TrackingState

FloatArray = npt.NDArray[np.float64]

SAMPLE_HZ: Final = 10.0
"""Instants kept per second per pair: consecutive 30 Hz frames add little but cost."""
MIN_SAMPLES: Final = 30
"""Instants a pair needs in its window for an estimate (3 s at ``SAMPLE_HZ``)."""
MIN_SPREAD_M: Final = 0.3
"""The pelvis positions of the window must spread this far (the second-largest standard
deviation, metres) for an estimate: a person standing still pins the fit poorly."""
ROTATION_MIN_SPREAD_M: Final = 0.45
"""The rotation counts against a sensor only from this spread on: below it, its noise reached
1.5° in normal motion (bench/drift.py), while the shift of the person stayed under 15 mm. A
bumped sensor's rotation shows as a shift too (2° at 3 m moves the person 100 mm), so the
shift alone catches bumps while people move little."""
DRIFT_CLEAR_RATIO: Final = 0.6
"""A flag clears once the correction stays below this share of the thresholds."""

_FEATURE_A = np.array([a for a, _, _ in FEATURES])
_FEATURE_B = np.array([b for _, b, _ in FEATURES])
_FEATURE_W = np.array([w for _, _, w in FEATURES], dtype=np.float64)
_PELVIS = next(i for i, (a, _, _) in enumerate(FEATURES) if a == JointId.SPINE_BASE)


def trunk_points(view: View) -> FloatArray:
    """(F, 3) the view's midline trunk points (``skeleton_pose.FEATURES``; world, metres),
    NaN where a joint they need is not Tracked."""
    tracked = view.states == TrackingState.TRACKED
    points: FloatArray = (view.joints_world[_FEATURE_A] + view.joints_world[_FEATURE_B]) / 2.0
    ok = tracked[_FEATURE_A] & tracked[_FEATURE_B]
    points[~ok] = np.nan
    return points


@dataclass(frozen=True, slots=True)
class Correction:
    """The rigid correction one sensor's views need to agree with another's.

    rotation_deg: angle of the correcting rotation. shift_mm: how far it moves the centroid of
    the window's points (where the person was: what fusion suffers from). spread_m: the
    pelvis spread of the window. samples: instants used.
    """

    rotation_deg: float
    shift_mm: float
    spread_m: float
    samples: int

    def severity(self, threshold_deg: float, threshold_mm: float) -> float:
        """The larger of the two as a share of its threshold (≥ 1: over a threshold); the
        rotation only from ``ROTATION_MIN_SPREAD_M`` on."""
        rotation = (
            self.rotation_deg / threshold_deg if self.spread_m >= ROTATION_MIN_SPREAD_M else 0
        )
        return max(rotation, self.shift_mm / threshold_mm)


def estimate_correction(src: FloatArray, dst: FloatArray) -> Correction | None:
    """The correction mapping ``src`` trunk points onto ``dst`` over a window.

    Args:
        src: (N, F, 3) one sensor's trunk points per instant (world, metres; NaN: missing).
        dst: (N, F, 3) the other sensor's points at the same instants.

    Returns:
        None when fewer than ``MIN_SAMPLES`` instants, too little spread, or a degenerate fit.
    """
    if len(src) < MIN_SAMPLES:
        return None
    pelvis = src[:, _PELVIS]
    pelvis = pelvis[np.isfinite(pelvis).all(axis=1)]
    if len(pelvis) < MIN_SAMPLES:
        return None
    spread = float(np.sort(np.std(pelvis, axis=0))[-2])
    if spread < MIN_SPREAD_M:
        return None
    weights = np.broadcast_to(_FEATURE_W, src.shape[:2]).reshape(-1)
    p, q = src.reshape(-1, 3), dst.reshape(-1, 3)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    try:
        fit = fit_rigid(p[ok], q[ok], weights[ok])
    except CalibrationError:
        return None
    centre = np.average(p[ok], axis=0, weights=weights[ok])
    moved = fit.T_dst_from_src[:3, :3] @ centre + fit.T_dst_from_src[:3, 3] - centre
    return Correction(
        rotation_angle_deg(fit.T_dst_from_src),
        float(np.linalg.norm(moved)) * 1000.0,
        spread,
        len(src),
    )


@dataclass(slots=True)
class SensorDrift:
    """One sensor's drift state (what ``/api/sensors`` and ``/metrics`` show)."""

    moved: bool = False
    correction: Correction | None = None
    """The latest estimate (None: none possible yet)."""
    against: str | None = None
    """The sensor the latest estimate compares with (the one it agrees with best)."""
    checked_t_s: float | None = None
    flagged_t_s: float | None = None
    over: int = 0
    under: int = 0

    def to_json(self) -> dict[str, object]:
        c = self.correction
        return {
            "moved": self.moved,
            "rotation_deg": None if c is None else round(c.rotation_deg, 3),
            "shift_mm": None if c is None else round(c.shift_mm, 1),
            "against": self.against,
            "samples": None if c is None else c.samples,
            "checked_t_s": self.checked_t_s,
            "flagged_t_s": self.flagged_t_s,
        }


@dataclass(slots=True)
class _PairWindow:
    times: deque[float] = field(default_factory=deque)
    first: deque[FloatArray] = field(default_factory=deque)
    second: deque[FloatArray] = field(default_factory=deque)

    def prune(self, oldest_t_s: float) -> None:
        while self.times and self.times[0] < oldest_t_s:
            self.times.popleft()
            self.first.popleft()
            self.second.popleft()


class DriftMonitor:
    """Per-sensor drift state, fed once per fusion step (module docstring)."""

    def __init__(self, settings: FusionSettings) -> None:
        self.settings = settings
        self.sensors: dict[str, SensorDrift] = {}
        self._pairs: dict[tuple[str, str], _PairWindow] = {}
        self._last_sample_t: float | None = None
        self._last_check_t: float | None = None

    def reset(self) -> None:
        """Forget every window and flag (a new calibration: the old points no longer apply)."""
        self.sensors.clear()
        self._pairs.clear()
        self._last_sample_t = self._last_check_t = None

    def observe(self, t_s: float, persons: Iterable[FusedPerson]) -> None:
        """Feed one fusion instant ``t_s`` (seconds): sample the persons' views, check when due."""
        if self._last_sample_t is None or t_s - self._last_sample_t >= 1.0 / SAMPLE_HZ - 1e-6:
            self._last_sample_t = t_s
            for person in persons:
                self._sample(t_s, person.views)
        if self._last_check_t is None:
            self._last_check_t = t_s
        elif t_s - self._last_check_t >= self.settings.drift_check_interval_s:
            self._last_check_t = t_s
            self.check(t_s)

    def _sample(self, t_s: float, views: Iterable[View]) -> None:
        by_sensor: dict[str, FloatArray] = {}
        for view in views:
            by_sensor.setdefault(view.sensor_id, trunk_points(view))
        for sensor_id in by_sensor:
            self.sensors.setdefault(sensor_id, SensorDrift())
        names = sorted(by_sensor)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                window = self._pairs.setdefault((a, b), _PairWindow())
                window.times.append(t_s)
                window.first.append(by_sensor[a])
                window.second.append(by_sensor[b])

    def check(self, t_s: float) -> None:
        """Estimate every sensor's correction over the window ending at ``t_s``; update flags."""
        s = self.settings
        best: dict[str, tuple[float, Correction, str]] = {}
        for (a, b), window in self._pairs.items():
            window.prune(t_s - s.drift_window_s)
            if len(window.times) < MIN_SAMPLES:
                continue
            first, second = np.stack(window.first), np.stack(window.second)
            for me, other, src, dst in ((a, b, first, second), (b, a, second, first)):
                correction = estimate_correction(src, dst)
                if correction is None:
                    continue
                severity = correction.severity(s.drift_threshold_deg, s.drift_threshold_mm)
                if me not in best or severity < best[me][0]:
                    best[me] = (severity, correction, other)
        for sensor_id, (severity, correction, other) in best.items():
            state = self.sensors.setdefault(sensor_id, SensorDrift())
            state.correction, state.against, state.checked_t_s = correction, other, t_s
            if severity >= 1.0:
                state.over, state.under = state.over + 1, 0
            elif severity < DRIFT_CLEAR_RATIO:
                state.over, state.under = 0, state.under + 1
            else:
                state.over = state.under = 0
            if not state.moved and state.over >= s.drift_confirm_checks:
                state.moved, state.flagged_t_s = True, t_s
            elif state.moved and state.under >= s.drift_confirm_checks:
                state.moved, state.flagged_t_s = False, None

    def status(self, sensor_id: str) -> SensorDrift | None:
        """The sensor's drift state (None: never seen together with another sensor)."""
        return self.sensors.get(sensor_id)
