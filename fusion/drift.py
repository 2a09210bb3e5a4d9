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

Baseline: the correction under the committed calibration is not zero for a rig whose
calibration is only good to some millimetres and degrees (the skeleton + ICP calibration of the
demo rig: ~18 mm, some degrees). So what is flagged is *change*: per ordered pair of sensors,
the first ``BASELINE_CHECKS`` estimates after a reset whose pelvis spread reaches
``ROTATION_MIN_SPREAD_M`` (both rotation and shift well conditioned) give the pair's baseline
correction (their medoid: the one closest to the others); afterwards a check compares the
correction with it (:func:`relative_correction`: the rotation ``R·R0ᵀ`` and how far the two
corrections place the window's centroid apart). A bump before the baseline is complete is
part of the baseline, so it is not flagged. The monitor is reset on every calibration change
(commit, rollback, import), which starts the baselines afresh.

Blame: a sensor's correction is the *smallest* of its pairwise corrections, so with three or
more sensors only the sensor that disagrees with every other one is flagged (the others agree
with each other). With two sensors the pair is ambiguous: both are flagged.

Hysteresis: a sensor is flagged after ``drift.confirm_checks`` consecutive checks whose
correction relative to its baseline exceeds a threshold (``drift.threshold_deg`` or
``drift.threshold_mm``), and cleared after as many checks below ``DRIFT_CLEAR_RATIO`` of
them. Checks without an estimate (nobody moving, one sensor alone, no baseline yet) change
nothing.

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
1.5° in normal motion (bench/calibration/drift.py), while the shift of the person stayed under
15 mm. A bumped sensor's rotation shows as a shift too (2° at 3 m moves the person 100 mm), so the
shift alone catches bumps while people move little."""
BASELINE_CHECKS: Final = 5
"""Well-conditioned estimates (spread ≥ ``ROTATION_MIN_SPREAD_M``) a pair's baseline is taken
from, after each reset: their medoid, so one odd window does not set it."""
DRIFT_CLEAR_RATIO: Final = 0.6
"""A flag clears once the correction stays below this share of the thresholds."""

_FEATURE_A = np.array([a for a, _, _ in FEATURES])
_FEATURE_B = np.array([b for _, b, _ in FEATURES])
_FEATURE_W = np.array([w for _, _, w in FEATURES], dtype=np.float64)
_TRACKED = int(TrackingState.TRACKED)  # a plain int: 5× faster to compare arrays with
_PELVIS = next(i for i, (a, _, _) in enumerate(FEATURES) if a == JointId.SPINE_BASE)


def trunk_points(view: View) -> FloatArray:
    """(F, 3) the view's midline trunk points (``skeleton_pose.FEATURES``; world, metres),
    NaN where a joint they need is not Tracked."""
    tracked = view.states == _TRACKED
    points: FloatArray = (view.joints_world[_FEATURE_A] + view.joints_world[_FEATURE_B]) / 2.0
    ok = tracked[_FEATURE_A] & tracked[_FEATURE_B]
    points[~ok] = np.nan
    return points


@dataclass(frozen=True, slots=True)
class Correction:
    """The rigid correction one sensor's views need to agree with another's.

    rotation_deg: angle of the correcting rotation. shift_mm: how far it moves the centroid of
    the window's points (where the person was: what fusion suffers from). spread_m: the
    pelvis spread of the window. samples: instants used. transform: the (4, 4) correction
    ``T_dst_from_src`` (world frame, metres). centre: (3,) the weighted centroid of the window's
    ``src`` points (world, metres). Both are None for a relative correction.
    """

    rotation_deg: float
    shift_mm: float
    spread_m: float
    samples: int
    transform: FloatArray | None = field(default=None, repr=False, compare=False)
    centre: FloatArray | None = field(default=None, repr=False, compare=False)

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
        fit.T_dst_from_src,
        centre,
    )


def relative_correction(current: Correction, baseline: Correction) -> Correction:
    """How far ``current`` has changed since ``baseline`` (same ordered pair).

    rotation_deg: the angle of ``R·R0ᵀ``. shift_mm: how far apart the two corrections place the
    centroid of the *current* window's points (the same terms as ``Correction.shift_mm``: what
    the change means for where fusion puts the person). spread_m and samples: the current's.

    Raises:
        ValueError: a correction without its transform and centre (itself a relative one).
    """
    if current.transform is None or current.centre is None or baseline.transform is None:
        raise ValueError("relative_correction needs estimated corrections, not relative ones")
    t, t0, c = current.transform, baseline.transform, current.centre
    rotation = t[:3, :3] @ t0[:3, :3].T
    apart = (t[:3, :3] @ c + t[:3, 3]) - (t0[:3, :3] @ c + t0[:3, 3])
    return Correction(
        rotation_angle_deg(rotation),
        float(np.linalg.norm(apart)) * 1000.0,
        current.spread_m,
        current.samples,
    )


def medoid(candidates: list[Correction], threshold_deg: float, threshold_mm: float) -> Correction:
    """The candidate whose relative corrections to the others are smallest in sum (each as the
    larger share of its threshold, rotation included): a median for rigid transforms.

    Raises:
        ValueError: no candidates.
    """
    if not candidates:
        raise ValueError("medoid of no corrections")

    def distance(a: Correction, b: Correction) -> float:
        r = relative_correction(a, b)
        return max(r.rotation_deg / threshold_deg, r.shift_mm / threshold_mm)

    return min(candidates, key=lambda a: sum(distance(b, a) for b in candidates))


@dataclass(slots=True)
class SensorDrift:
    """One sensor's drift state (what ``/api/sensors`` and ``/metrics`` show)."""

    moved: bool = False
    correction: Correction | None = None
    """The latest estimate under the committed calibration, against ``against`` (None: none
    possible yet). Not zero on an imperfect calibration: what counts is ``relative``."""
    against: str | None = None
    """The sensor the latest estimate compares with: the one whose pair has changed least since
    its baseline (before any baseline: the one it agrees with best)."""
    baseline: Correction | None = None
    """The pair's baseline correction (with ``against``; None: not complete yet)."""
    relative: Correction | None = None
    """The latest correction relative to ``baseline`` (what the flag is decided on)."""
    checked_t_s: float | None = None
    flagged_t_s: float | None = None
    over: int = 0
    under: int = 0

    def to_json(self) -> dict[str, object]:
        """The ``drift`` of a sensor row: ``rotation_deg``/``shift_mm`` the latest correction
        under the committed calibration; ``baseline_*`` the pair's baseline (None: still being
        taken); ``relative_*`` the change since it, which the flag is decided on."""
        c, b, r = self.correction, self.baseline, self.relative
        return {
            "moved": self.moved,
            "rotation_deg": None if c is None else round(c.rotation_deg, 3),
            "shift_mm": None if c is None else round(c.shift_mm, 1),
            "against": self.against,
            "samples": None if c is None else c.samples,
            "baseline_rotation_deg": None if b is None else round(b.rotation_deg, 3),
            "baseline_shift_mm": None if b is None else round(b.shift_mm, 1),
            "relative_rotation_deg": None if r is None else round(r.rotation_deg, 3),
            "relative_shift_mm": None if r is None else round(r.shift_mm, 1),
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
        self._candidates: dict[tuple[str, str], list[Correction]] = {}
        """Per ordered pair (me, other): well-conditioned estimates collected for its baseline."""
        self._baselines: dict[tuple[str, str], Correction] = {}
        self._last_sample_t: float | None = None
        self._last_check_t: float | None = None

    def reset(self) -> None:
        """Forget every window, baseline and flag (a new calibration: the old points and
        corrections no longer apply)."""
        self.sensors.clear()
        self._pairs.clear()
        self._candidates.clear()
        self._baselines.clear()
        self._last_sample_t = self._last_check_t = None

    def observe(self, t_s: float, persons: Iterable[FusedPerson]) -> None:
        """Feed one fusion instant ``t_s`` (seconds): sample the persons' views, check when due."""
        if self._last_sample_t is None or t_s - self._last_sample_t >= 1.0 / SAMPLE_HZ - 1e-6:
            self._last_sample_t = t_s
            for person in persons:
                self._sample(t_s, person.views)
        if self._last_check_t is None:
            self._last_check_t = t_s
        elif t_s - self._last_check_t >= self.settings.drift.check_interval_s:
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
        """Estimate every sensor's correction over the window ending at ``t_s``, collect or
        compare with the pairs' baselines, update flags."""
        s = self.settings
        thresholds = (s.drift.threshold_deg, s.drift.threshold_mm)
        # per sensor: (relative severity, raw, relative, baseline, other) of its best pair;
        # raw-only candidates (no baseline yet) rank after any pair with a baseline
        best: dict[str, tuple[bool, float, Correction, Correction | None, str]] = {}
        for (a, b), window in self._pairs.items():
            window.prune(t_s - s.drift.window_s)
            if len(window.times) < MIN_SAMPLES:
                continue
            first, second = np.stack(window.first), np.stack(window.second)
            for me, other, src, dst in ((a, b, first, second), (b, a, second, first)):
                correction = estimate_correction(src, dst)
                if correction is None:
                    continue
                relative = self._against_baseline((me, other), correction)
                key: tuple[bool, float, Correction, Correction | None, str]
                if relative is None:
                    key = (True, correction.severity(*thresholds), correction, None, other)
                else:
                    key = (False, relative.severity(*thresholds), correction, relative, other)
                if me not in best or key[:2] < best[me][:2]:
                    best[me] = key
        for sensor_id, (waiting, severity, correction, relative, other) in best.items():
            state = self.sensors.setdefault(sensor_id, SensorDrift())
            state.correction, state.against, state.checked_t_s = correction, other, t_s
            state.baseline = self._baselines.get((sensor_id, other))
            state.relative = relative
            if waiting:
                continue  # no baseline to compare with: no evidence either way
            if severity >= 1.0:
                state.over, state.under = state.over + 1, 0
            elif severity < DRIFT_CLEAR_RATIO:
                state.over, state.under = 0, state.under + 1
            else:
                state.over = state.under = 0
            if not state.moved and state.over >= s.drift.confirm_checks:
                state.moved, state.flagged_t_s = True, t_s
            elif state.moved and state.under >= s.drift.confirm_checks:
                state.moved, state.flagged_t_s = False, None

    def _against_baseline(self, pair: tuple[str, str], correction: Correction) -> Correction | None:
        """The correction relative to the pair's baseline; None while the baseline is still
        being collected (a well-conditioned ``correction`` then joins its candidates)."""
        baseline = self._baselines.get(pair)
        if baseline is not None:
            return relative_correction(correction, baseline)
        if correction.spread_m >= ROTATION_MIN_SPREAD_M:
            candidates = self._candidates.setdefault(pair, [])
            candidates.append(correction)
            if len(candidates) >= BASELINE_CHECKS:
                s = self.settings
                self._baselines[pair] = medoid(
                    candidates, s.drift.threshold_deg, s.drift.threshold_mm
                )
                del self._candidates[pair]
        return None

    def status(self, sensor_id: str) -> SensorDrift | None:
        """The sensor's drift state (None: never seen together with another sensor)."""
        return self.sensors.get(sensor_id)
