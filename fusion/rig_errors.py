"""Each sensor's error, learned from the rig itself: per sensor, joint and what the view sees.

A sensor type's prior (:func:`skelfuse.fusion.priors.prior_variances`) says how far a view's
joint is from the truth on average; a real rig mixes good and bad positions and units, and a
sensor's errors depend on what it sees. So fusion learns, live, the variance of each sensor's
joints from the rig's own data and weighs each view's joint by the inverse of it
(:mod:`skelfuse.fusion.weigh`).

What is learned
---------------
The 3-D error variance ``σ²`` (m²) of each sensor's view of each of the 25 joints, in
:data:`BINS` bins of what is observable about the view: where the sensor stands relative to
the person (:data:`~skelfuse.fusion.priors.SECTORS` directions 45° apart, from in front round
the person's left: a side view sees the near limbs and guesses the far ones), the joint's
tracking state (Tracked; Inferred), and the distance (nearer or farther than
``learning.far_m``). A view between two directions is between their bins: its variance is
interpolated geometrically in angle and its residual teaches both in proportion. The joint's own
bin is what self-occlusion by the trunk depends on: the left knee seen from the person's right
is a different bin from the left knee seen from the left.

Each sensor also learns how much larger its noise is along its viewing rays than across them
(a time-of-flight depth error, a camera's distance from the body's apparent size): the
residuals' squares along and across the ray, pooled over its joints, from its type's
``depth_noise_ratio``. Fusion then weighs its joints per axis (the ray weighting of
:mod:`skelfuse.fusion.view_factors`) when the ratio is at least :data:`MIN_DEPTH_RATIO`.

How (leave-one-out residuals)
-----------------------------
After each fusion step, view k's joint is compared with the weighted mean ``m₋ₖ`` of the
*other* views of the same person (never with a fusion it takes part in, so no view's error
teaches itself). With independent view errors::

    E|x_k − m₋ₖ|² = σ_k² + V₋ₖ,   V₋ₖ = Σ_{i≠k} w_i² σ_i² / (Σ_{i≠k} w_i)²

so each residual gives a sample ``y = |x_k − m₋ₖ|² − V₋ₖ`` of ``σ_k²`` (V from the current
estimates). A heavy tail (a glitch, a wrong label) must not teach a sensor that it is bad: a
residual counts at most ``learning.cap`` times its expected square. With two views only their
sum is identifiable: the split stays where the priors put it until a third view or another
bin tells more.

Each sensor keeps exponentially forgotten sums (time constant ``learning.forget_s``, counted
only while the sensor sees someone: an empty room forgets nothing; shorter in a sensor's first
minute, when the samples taken with the prior's estimates must go quickly), at two levels:

- per (sensor, joint), the residuals in units of the prior's variance of their bin, shrunk to
  1 (the prior) with ``learning.prior_samples`` pseudo-samples: how much better or worse than
  its type this sensor is;
- per (sensor, joint, bin), shrunk to that level times the bin's prior with
  ``learning.bin_samples`` pseudo-samples: a bin seen rarely keeps the sensor's level and the
  prior's shape.

A sensor that is moved or degrades is re-learned within about ``forget_s``. The estimates are
never below :data:`MIN_VARIANCE`: no view is ever trusted absolutely.

Shapes: R known sensors (rows, in order of first sight), 25 joints, B = :data:`BINS`; N views
of P persons stacked as :class:`skelfuse.fusion.weigh.ViewBatch` stacks them. Metres, world
frame. The loops are compiled with numba; :func:`warm_up` compiles them at start.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.priors import KINECT_V2, SECTORS, SensorPrior, prior_variances
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, jit_inline, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
J = JointId

BINS: Final = SECTORS * 4
"""Bins per (sensor, joint): sector × (Tracked, Inferred) × (near, far); :func:`bin_of` gives
the index."""
MIN_VARIANCE: Final = 0.005**2
"""The least variance (m²) a view's joint is given: 5 mm, a depth sensor's jitter at best."""
MIN_DEPTH_RATIO: Final = 1.3
"""A sensor whose learned noise along its rays is less than this times that across is fused as
isotropic."""
GROUPS: Final[Mapping[str, tuple[int, ...]]] = {
    "trunk": (J.SPINE_BASE, J.SPINE_MID, J.NECK, J.HEAD, J.SPINE_SHOULDER, J.SHOULDER_LEFT,
              J.SHOULDER_RIGHT, J.HIP_LEFT, J.HIP_RIGHT),
    "arms": (J.ELBOW_LEFT, J.WRIST_LEFT, J.HAND_LEFT, J.HAND_TIP_LEFT, J.THUMB_LEFT,
             J.ELBOW_RIGHT, J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT, J.THUMB_RIGHT),
    "legs": (J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT, J.KNEE_RIGHT, J.ANKLE_RIGHT, J.FOOT_RIGHT),
}  # fmt: skip
"""The joint groups a sensor's learned error is shown by (``/api/sensors``, the viewer)."""


def bin_of(sector: int, tracked: bool, far: bool) -> int:
    """The bin index of a view's joint: sector (0 in front, counting round the person's left)
    × state × distance; the next sector's bin is ``(index + 4) % BINS``."""
    return sector * 4 + (0 if tracked else 2) + (1 if far else 0)


@dataclass(frozen=True, slots=True)
class SensorErrors:
    """One sensor's learned error as shown to apps and to the person setting up the rig.

    groups_mm: per joint group (:data:`GROUPS`), the RMS 3-D error (mm) of the sensor's joints
        in the bins it has been seeing them in lately (its prior's, before any evidence);
    samples: the evidence behind it, in (forgotten) views of a joint per joint;
    learned: whether the evidence outweighs the prior (``samples ≥ learning.prior_samples``).
    """

    groups_mm: dict[str, float]
    samples: float
    learned: bool


class Observed(NamedTuple):
    """One fusion step's views as :meth:`RigErrors.observe` learns from them (N views of P
    persons, each person's consecutive).

    joints: (N, 25, 3) as fused (labels corrected), metres, world; weights: (N, 25) their
    final fusion weights; variances: (N, 25) the variances they were weighed by (m²); rows:
    (N,) each view's sensor row (:meth:`RigErrors.rows_of`); bins: (N, 25) each joint's bin
    (:func:`view_bins_loop`, −1: none); between: (N,) how far each view is towards the next
    sector's bin; starts: (P + 1,) each person's first view, then N; sensors: (N, 3) where
    each view's sensor stands (metres, world; NaN: unknown).
    """

    joints: FloatArray
    weights: FloatArray
    variances: FloatArray
    rows: IntArray
    bins: IntArray
    between: FloatArray
    starts: IntArray
    sensors: FloatArray


class RigErrors:
    """The learned variances of every sensor fusion has seen (module docstring)."""

    def __init__(self, settings: FusionSettings) -> None:
        self.settings = settings
        self._rows: dict[str, int] = {}
        self._priors: list[SensorPrior] = []
        self.prior = np.empty((0, JOINT_COUNT, BINS))
        """(R, 25, B) each sensor's prior variances, m²."""
        self.variance = np.empty((0, JOINT_COUNT, BINS))
        """(R, 25, B) the current estimates, m² (what fusion weighs by)."""
        self._bin_sums = np.empty((0, 2, JOINT_COUNT, BINS))  # Σ y and Σ 1, forgotten
        self._level_sums = np.empty((0, 2, JOINT_COUNT))  # Σ y / prior and Σ 1, forgotten
        self._ray_sums = np.empty((0, 2))  # Σ along² / E and Σ across² / 2E, forgotten
        self._prior_ratio = np.empty(0)
        self.depth_ratio = np.empty(0)
        """(R,) each sensor's noise along its viewing ray over that across it (≥ 1)."""
        self._last_s = np.empty(0)
        self._seen_s = np.empty(0)  # seconds each sensor has seen someone since its prior

    @property
    def sensor_ids(self) -> list[str]:
        """The sensors known, in row order."""
        return list(self._rows)

    def rows_of(self, sensor_ids: Sequence[str], priors: Sequence[SensorPrior]) -> IntArray:
        """(N,) each view's sensor row; a sensor seen the first time starts from its prior."""
        rows = self._rows
        for sensor_id, prior in zip(sensor_ids, priors, strict=True):
            if sensor_id not in rows:
                self._add(sensor_id, prior)
            elif self._priors[rows[sensor_id]] is not prior:  # the agent announced another type
                self.forget(sensor_id, prior)
        return np.array([rows[s] for s in sensor_ids], dtype=np.intp)

    def _add(self, sensor_id: str, prior: SensorPrior) -> None:
        self._rows[sensor_id] = len(self._rows)
        self._priors.append(prior)
        table = prior_variances(prior, self.settings)[None]
        self.prior = np.concatenate([self.prior, table])
        self.variance = np.concatenate([self.variance, table])
        self._bin_sums = np.concatenate([self._bin_sums, np.zeros((1, 2, JOINT_COUNT, BINS))])
        self._level_sums = np.concatenate([self._level_sums, np.zeros((1, 2, JOINT_COUNT))])
        self._ray_sums = np.concatenate([self._ray_sums, np.zeros((1, 2))])
        self._prior_ratio = np.append(self._prior_ratio, prior.depth_noise_ratio)
        self.depth_ratio = np.append(self.depth_ratio, prior.depth_noise_ratio)
        self._last_s = np.append(self._last_s, math.nan)
        self._seen_s = np.append(self._seen_s, 0.0)

    def depth_ratios(self, rows: IntArray) -> FloatArray | None:
        """(N,) each view's learned depth ratio (its sensor's, by ``rows``), or None when every
        one is below :data:`MIN_DEPTH_RATIO` (fused as isotropic: the per-axis fusion is not
        worth its cost below it)."""
        ratios = self.depth_ratio[rows]
        if not (ratios >= MIN_DEPTH_RATIO).any():
            return None
        stretched: FloatArray = np.where(ratios >= MIN_DEPTH_RATIO, ratios, 1.0)
        return stretched

    def forget(self, sensor_id: str, prior: SensorPrior | None = None) -> None:
        """Start ``sensor_id`` again from its prior (``prior``: a new one), e.g. once it is
        recalibrated or its agent announces another sensor type."""
        row = self._rows.get(sensor_id)
        if row is None:
            return
        if prior is not None:
            self._priors[row] = prior
            self.prior[row] = prior_variances(prior, self.settings)
            self._prior_ratio[row] = prior.depth_noise_ratio
        self.variance[row] = self.prior[row]
        self.depth_ratio[row] = self._prior_ratio[row]
        self._bin_sums[row] = 0.0
        self._level_sums[row] = 0.0
        self._ray_sums[row] = 0.0
        self._last_s[row] = math.nan
        self._seen_s[row] = 0.0

    def observe(self, batch: Observed, t_s: float) -> None:
        """Learn from one fusion step's views (module docstring; nothing with learning off).

        Args:
            batch: the step's views, weights, bins and variances (:class:`Observed`).
            t_s: the step's instant (seconds; forgetting counts time between steps).
        """
        learning = self.settings.learning
        if not learning.enabled or len(batch.rows) == 0:
            return
        learn_loop(
            (plain(batch.joints), plain(batch.weights), plain(batch.variances),
             plain(batch.sensors)),
            (plain(batch.rows, np.intp), plain(batch.bins, np.intp), plain(batch.between)),
            plain(batch.starts, np.intp),
            (self.prior, self._bin_sums, self._level_sums, self._ray_sums, self._last_s,
             self._seen_s, self._prior_ratio),
            (float(t_s), float(learning.forget_s), float(learning.cap),
             float(learning.prior_samples), float(learning.bin_samples)),
            (self.variance, self.depth_ratio),
        )  # fmt: skip

    def summary(self) -> dict[str, SensorErrors]:
        """Each sensor's learned error by joint group (:class:`SensorErrors`), by sensor id."""
        learning = self.settings.learning
        out: dict[str, SensorErrors] = {}
        for sensor_id, row in self._rows.items():
            counts = self._bin_sums[row, 1]  # (25, B)
            total = counts.sum(axis=1)
            # Each joint's variance in the bins the sensor has been seeing it in; the prior's
            # bins alike before any evidence.
            seen = np.where(total[:, None] > 0, counts, 1.0)
            mean = (seen * self.variance[row]).sum(axis=1) / seen.sum(axis=1)
            groups = {
                name: float(np.sqrt(mean[list(joints)].mean()) * 1000)
                for name, joints in GROUPS.items()
            }
            samples = float(self._level_sums[row, 1].mean())
            out[sensor_id] = SensorErrors(groups, samples, samples >= learning.prior_samples)
        return out


@jit
def learn_loop(
    views: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    places: tuple[IntArray, IntArray, FloatArray],
    starts: IntArray,
    state: tuple[
        FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
    ],
    settings: tuple[float, float, float, float, float],
    out: tuple[FloatArray, FloatArray],
) -> None:
    """:meth:`RigErrors.observe` in one call: forget each seen sensor's sums, add the step's
    samples (:func:`observe_loop`), and estimate the seen sensors' variances and depth ratios
    again (:func:`estimate_loop`). views: joints, weights, variances, sensors
    (:class:`Observed`); places: rows, bins, between; state: the prior (R, 25, B), the bin,
    level and ray sums, each sensor's last instant, seconds seen and prior depth ratio;
    settings: the instant and ``learning``'s forget_s, cap, prior_samples, bin_samples; out:
    the variances (R, 25, B) and depth ratios (R,)."""
    rows = places[0]
    prior, bin_sums, level_sums, ray_sums, last_s, seen_s, prior_ratio = state
    t_s, forget_s, cap, prior_samples, bin_samples = settings
    seen = np.zeros(len(last_s), dtype=np.bool_)
    for v in range(len(rows)):
        seen[rows[v]] = True
    decay = np.ones(len(last_s))
    for r in range(len(last_s)):
        if not seen[r]:
            continue
        elapsed = t_s - last_s[r]
        elapsed = 0.0 if not math.isfinite(elapsed) else min(max(elapsed, 0.0), 1.0)
        seen_s[r] += elapsed
        # Early on, forget faster: a sample's value depends on the estimates when it was
        # taken, and the first are the prior's; half the time seen so far (plus 2 s) until
        # that reaches forget_s.
        decay[r] = math.exp(-elapsed / min(forget_s, 2.0 + 0.5 * seen_s[r]))
        last_s[r] = t_s
    observe_loop(views, places, starts, prior, decay, cap, (bin_sums, level_sums, ray_sums))
    rows_seen = np.flatnonzero(seen)
    estimate_loop(rows_seen, bin_sums, level_sums, prior, (prior_samples, bin_samples), out[0])
    for row in rows_seen:  # the prior's ratio as prior_samples samples of it
        r = int(row)
        ratio2 = prior_ratio[r] * prior_ratio[r]
        weight = prior_samples / (2.0 + ratio2)
        value = (ray_sums[r, 0] + weight * ratio2) / (ray_sums[r, 1] + weight)
        out[1][r] = math.sqrt(max(value, 1.0))


@jit
def observe_loop(
    views: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    places: tuple[IntArray, IntArray, FloatArray],
    starts: IntArray,
    prior: FloatArray,
    decay: FloatArray,
    cap: float,
    sums: tuple[FloatArray, FloatArray, FloatArray],
) -> None:
    """Forget each seen sensor's sums by ``decay`` (R,), then add each view's leave-one-out
    residual samples (module docstring) to ``sums``: per (row, Σy | Σ1, joint, bin), per
    (row, Σy/prior | Σ1, joint), and per row the residual's squares along and across the
    view's ray over their expected share. views: joints, weights, variances (N, 25) as fused,
    sensors; places: each view's row (N,), its joints' bins (N, 25) and how far it is towards
    the next sector's (N,)."""
    joints, weights, variances, sensors = views
    rows, bins, between = places
    bin_sums, level_sums, ray_sums = sums
    for r in range(len(decay)):
        if decay[r] != 1.0:
            bin_sums[r] *= decay[r]
            level_sums[r] *= decay[r]
            ray_sums[r] *= decay[r]
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        for k in range(lo, hi):
            for j in range(joints.shape[1]):
                b = bins[k, j]
                if b < 0 or not weights[k, j] > 0.0:
                    continue
                others, residual = left_out(joints, weights, variances, lo, hi, k, j)
                distance = residual[0] ** 2 + residual[1] ** 2 + residual[2] ** 2
                if not math.isfinite(distance):
                    continue  # nobody else sees this joint: nothing to judge it against
                expected = variances[k, j] + others
                share = variances[k, j] / expected  # of the residual, view k's (EM's E-step)
                sample = share * share * min(distance, cap * expected) + share * others
                r, a = rows[k], between[k]
                after = (b + 4) % prior.shape[2]
                scale = (1.0 - a) * prior[r, j, b] + a * prior[r, j, after]
                bin_sums[r, 0, j, b] += (1.0 - a) * sample
                bin_sums[r, 1, j, b] += 1.0 - a
                bin_sums[r, 0, j, after] += a * sample
                bin_sums[r, 1, j, after] += a
                level_sums[r, 0, j] += sample / scale
                level_sums[r, 1, j] += 1.0
                _add_ray_sample(
                    joints[k, j], sensors[k], residual, share, expected, cap, ray_sums[r]
                )


@jit_inline
def _add_ray_sample(
    point: FloatArray,
    sensor: FloatArray,
    residual: tuple[float, float, float],
    share: float,
    expected: float,
    cap: float,
    sums: FloatArray,
) -> None:
    """Add a residual's square along the ray from ``sensor`` to ``point`` and its mean
    square per axis across it, each over ``expected`` and weighed by the view's ``share``."""
    d0, d1, d2 = point[0] - sensor[0], point[1] - sensor[1], point[2] - sensor[2]
    length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if not (length > 0.0 and math.isfinite(length)):
        return
    along = (residual[0] * d0 + residual[1] * d1 + residual[2] * d2) / length
    total = residual[0] ** 2 + residual[1] ** 2 + residual[2] ** 2
    sums[0] += share * min(along * along / expected, cap)
    sums[1] += share * min(0.5 * (total - along * along) / expected, cap)


@jit_inline
def left_out(
    joints: FloatArray, weights: FloatArray, variances: FloatArray, lo: int, hi: int, k: int, j: int
) -> tuple[float, tuple[float, float, float]]:
    """The variance (m²) of the weighted mean of views ``lo``..``hi`` but ``k`` of joint ``j``,
    and view k's residual to it (m); NaN when no other view has the joint."""
    total = spread = m0 = m1 = m2 = 0.0
    for i in range(lo, hi):
        w = weights[i, j]
        y = joints[i, j]
        if i == k or not w > 0.0 or not math.isfinite(y[0] + y[1] + y[2]):
            continue
        total += w
        spread += w * w * variances[i, j]
        m0 += w * y[0]
        m1 += w * y[1]
        m2 += w * y[2]
    x = joints[k, j]
    if total <= 0.0 or not math.isfinite(x[0] + x[1] + x[2]):
        return math.nan, (math.nan, math.nan, math.nan)
    return spread / (total * total), (x[0] - m0 / total, x[1] - m1 / total, x[2] - m2 / total)


@jit
def estimate_loop(
    seen: IntArray,
    bin_sums: FloatArray,
    level_sums: FloatArray,
    prior: FloatArray,
    shrinkage: tuple[float, float],
    variance: FloatArray,
) -> None:
    """The seen rows' variances from their sums, each level shrunk to the one above it
    (module docstring), never below :data:`MIN_VARIANCE`."""
    prior_samples, bin_samples = shrinkage
    for r in seen:
        for j in range(variance.shape[1]):
            level = (level_sums[r, 0, j] + prior_samples) / (level_sums[r, 1, j] + prior_samples)
            for b in range(variance.shape[2]):
                anchor = max(level, 0.0) * prior[r, j, b]
                value = (bin_sums[r, 0, j, b] + bin_samples * anchor) / (
                    bin_sums[r, 1, j, b] + bin_samples
                )
                variance[r, j, b] = max(value, MIN_VARIANCE)


@jit
def view_bins_loop(
    facings: FloatArray,
    stands: FloatArray,
    sensors: FloatArray,
    states: npt.NDArray[np.uint8],
    settings: tuple[bool, float],
    out: tuple[IntArray, FloatArray],
) -> None:
    """Fill ``out``: each view's joints' bins (N, 25; :func:`bin_of` of the sector before the
    sensor's direction, −1 where NotTracked) and how far the direction is towards the next
    sector (N,) in [0, 1). From its person's horizontal facing (N, 3; NaN: unknown, taken as
    in front), where the person stands (N, 3) and the view's sensor (N, 3; NaN: unknown, in
    front and near). settings: whether views are binned by where they stand (else every view
    is in front and near: the tracking state alone tells bins apart), the far distance."""
    binned, far_m = settings
    bins, between = out
    step = 2.0 * math.pi / SECTORS
    for v in range(bins.shape[0]):
        d0 = sensors[v, 0] - stands[v, 0]
        d2 = sensors[v, 2] - stands[v, 2]
        distance = math.sqrt(d0 * d0 + d2 * d2)
        f0, f2 = facings[v, 0], facings[v, 2]
        sector, fraction = 0, 0.0
        if binned and distance > 0.0 and math.isfinite(distance) and math.isfinite(f0 + f2):
            along = f0 * d0 + f2 * d2
            left = f2 * d0 - f0 * d2  # the person's left is (f_z, 0, −f_x)
            position = (math.atan2(left, along) % (2.0 * math.pi)) / step
            sector = min(int(position), SECTORS - 1)
            fraction = position - sector
        between[v] = fraction
        far = 1 if binned and distance > far_m else 0
        for j in range(bins.shape[1]):
            state = states[v, j]
            bins[v, j] = -1 if state == 0 else sector * 4 + (0 if state == 2 else 2) + far


@jit_inline
def variance_at(table: FloatArray, row: int, joint: int, b: int, between: float) -> float:
    """The variance of ``table`` (R, 25, B) at ``b`` interpolated ``between`` of the way to the
    next sector's bin, geometrically: between a good direction and a bad one the error grows
    by a factor per degree rather than by millimetres."""
    after = (b + 4) % table.shape[2]
    low: float = table[row, joint, b]
    high: float = table[row, joint, after]
    if between == 0.0 or low == high:
        return low
    value: float = low ** (1.0 - between) * high**between
    return value


@jit
def robust_factors_loop(
    joints: FloatArray,
    weights: FloatArray,
    variances: FloatArray,
    starts: IntArray,
    dof: float,
    out: FloatArray,
) -> None:
    """Fill ``out`` (N, 25) with each view's joint's Student-t factor ``(ν + 3) / (ν + r²/E)``:
    r its distance to the weighted mean of the person's other views, E its expected square
    (its variance plus the others' mean's); 1 where no other view has the joint. The factor is
    1 at a typical residual (r² = 3E), small for a view far off all the others (a glitch)."""
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        for k in range(lo, hi):
            for j in range(joints.shape[1]):
                out[k, j] = 1.0
                if not weights[k, j] > 0.0:
                    continue
                others, residual = left_out(joints, weights, variances, lo, hi, k, j)
                distance = residual[0] ** 2 + residual[1] ** 2 + residual[2] ** 2
                if math.isfinite(distance):
                    expected = variances[k, j] + others
                    out[k, j] = (dof + 3.0) / (dof + distance / expected)


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now."""
    errors = RigErrors(FusionSettings())
    views = np.zeros((2, JOINT_COUNT, 3))
    states = np.full((2, JOINT_COUNT), 2, dtype=np.uint8)
    rows = errors.rows_of(["a", "b"], [KINECT_V2, KINECT_V2])
    bins, between = np.empty((2, JOINT_COUNT), dtype=np.intp), np.empty(2)
    view_bins_loop(
        np.ones((2, 3)), np.zeros((2, 3)), np.ones((2, 3)), states, (True, 2.5), (bins, between)
    )
    starts = np.array([0, 2], dtype=np.intp)
    ones = np.ones((2, JOINT_COUNT))
    errors.observe(Observed(views, ones, ones, rows, bins, between, starts, np.ones((2, 3))), 0.0)
    robust_factors_loop(views, ones, ones, starts, 4.0, np.empty((2, JOINT_COUNT)))
