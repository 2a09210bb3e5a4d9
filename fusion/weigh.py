"""Steps 5–6 of the pipeline on a batch: every view's per-joint weights, and the fusions.

:func:`weigh_and_fuse` weighs each view's joints by the body terms alone (tracking state, bone
length, range of motion: :func:`~skelfuse.fusion.confidence.body_weights`) and fuses them, which
tells where each person stands; then by how frontally the person faces each sensor and how well
each view sees each joint (``weights.view_reliability``), fusing after each; last, the
confidence apps receive and which views carried each joint.

In numpy that is a dozen calls with their arguments' gathers and pads, ~140 µs at 4 sensors ×
6 people for ~20 µs of arithmetic, so the step is one loop compiled with numba (:func:`_weigh_loop`)
running the stages' own loops in order: :func:`~skelfuse.fusion.confidence.body_loop`,
:func:`weighted_loop` on the views padded as
:meth:`ViewBatch.pad` pads them (NaN joints, weight 0), the facing and
:func:`~skelfuse.fusion.view_factors.view_factor_loop` and
:func:`~skelfuse.fusion.confidence.confidence_loop`. The loop runs in phases (:data:`BODY` …
:data:`CONFIDENCE`); two terms that are numpy code of their own stage run between two phases
when they are on: the ray weighting of a camera that guesses depth after each fusion
(:meth:`ViewBatch.fuse`) and the view reliability after the view
factors. :func:`warm_up` compiles the loop
(or loads numba's cache) at start, so no frame waits for a compilation.

Weighted fusion (second section): each joint as the weighted mean of the views that have it.
Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn``, C the weights of :mod:`skelfuse.fusion.confidence`.
:func:`carriers` tells which views a fused joint came from (the Cauchy pass can discount views
far from that consensus). Shapes: P persons fused at once, each with up to S views (a person
with fewer is padded with NaN views of weight 0, which changes no sum or product), J = 25
joints; metres, world frame. :func:`weighted_mean` is one loop compiled with numba
(:func:`weighted_loop`): per joint, the sums over the views start from 0 and add view after
view, a view counting where its point is finite and its weight positive.

The batch it works on (:class:`ViewBatch`, last section): the views of P persons stacked (N
views; person ``person_of[i]``, its ``slot_of[i]``-th view); per-person sums use (P, widest,
...) blocks padded after the real views with NaN views of weight 0, which leaves every sum and
product as it is for one person alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_loop
from skelfuse.fusion.confidence import (
    BODY_TABLES,
    body_loop,
    confidence_loop,
    joint_confidence,
    range_of_motion_factors,
    sensor_terms,
)
from skelfuse.fusion.mirror_scores import slots
from skelfuse.fusion.priors import SensorPrior
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.view_factors import (
    cosines_loop,
    depth_noise_ratios,
    ray_weighted_mean,
    reliability_factors,
    view_factor_loop,
)
from skelfuse.fusion.views import View
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "MIN_SHARE",
    "ViewBatch",
    "Weighed",
    "carriers",
    "confidence_and_carriers",
    "fuse_views",
    "weigh_and_fuse",
    "weighted_loop",
    "weighted_mean",
]

BODY: Final = 0
"""Phase: the body weights and the first fusion."""
FACING: Final = 1
"""Phase: each person's facing and where it stands, each view's facing cosine."""
VIEWS: Final = 2
"""Phase: the view factors (facing) and the fusion under them."""
CONFIDENCE: Final = 3
"""Phase: the confidence and the carriers."""
_NOT_USED: Final = np.ones((1, 1))
"""What the loop gets for a term that is off (it reads nothing of it; never written)."""
_TABLES: Final[tuple[tuple[IntArray, IntArray], tuple[IntArray, IntArray]]] = (
    (plain(BODY_TABLES[0][0], np.intp), plain(BODY_TABLES[0][1], np.intp)),
    (plain(BODY_TABLES[1][0], np.intp), plain(BODY_TABLES[1][1], np.intp)),
)
""":data:`~skelfuse.fusion.confidence.BODY_TABLES` as the loop takes them."""
_Body = tuple[
    FloatArray,
    IntArray,
    FloatArray,
    FloatArray,
    tuple[bool, bool],
    float,
    tuple[tuple[IntArray, IntArray], tuple[IntArray, IntArray]],
]
"""The body terms' arguments of :func:`_weigh_loop` (its docstring)."""


class Weighed(NamedTuple):
    """What steps 5–6 give the rest of the step (P persons, N views, S the widest person).

    weights: (N, 25) each view's final per-joint weights; fused: (P, 25, 3) metres, world, NaN
    where no view counts; cosines: (N,) each view's facing cosine (NaN: unknown); confidence:
    (P, 25) in [0, 1]; carried: (P, S, 25) which views carried each fused joint.
    """

    weights: FloatArray
    fused: FloatArray
    cosines: FloatArray
    confidence: FloatArray
    carried: BoolArray


def weigh_and_fuse(
    batch: ViewBatch,
    rom: FloatArray | None,
    references: FloatArray,
    track_facings: FloatArray,
    fused_once: Sequence[bool],
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
) -> Weighed:
    """Steps 5–6 (module docstring) for P persons' N views, labels corrected.

    Args:
        batch: the views, each person's consecutive.
        rom: (N, 25) range-of-motion factors of each view as labelled, or None (computed here
            when ``weights.range_of_motion``).
        references: (P, 24) each person's reference bone lengths, metres (NaN: unknown; the
            bone-length term is off while no person has any).
        track_facings: (P, 3) each person's facing from its track, horizontal unit vectors
            (NaN: unknown).
        fused_once: (P,) whether each person was fused before (else its facing is taken from
            this step's first fusion).
        settings: which terms are on, and their scales.
        priors: (N,) each view's sensor prior, or None: the settings' values for every view.
    """
    s = settings
    count, persons, size = len(batch.joints), len(batch.counts), batch.joints.shape[1]
    out = Weighed(
        np.empty((count, size)),
        np.empty((persons, size, 3)),
        np.empty(count),
        np.empty((persons, size)),
        np.empty((persons, batch.widest, size), dtype=np.bool_),
    )
    stands = np.empty((count, 3))
    terms, of_view = sensor_terms(s, priors, count)
    if s.weights.range_of_motion and rom is None:
        rom = range_of_motion_factors(batch.joints, s.weights.rom_scale_deg)
    factors = rom if s.weights.range_of_motion else None
    body: _Body = (
        terms, plain(of_view, np.intp),
        plain(references) if s.weights.bone_length else _NOT_USED,
        _NOT_USED if factors is None else plain(factors),
        (s.weights.bone_length, factors is not None), float(s.weights.bone_length_scale_m), _TABLES,
    )  # fmt: skip
    views = (
        plain(track_facings), plain(np.asarray(fused_once, dtype=np.bool_), np.bool_),
        bool(s.weights.facing),
    )  # fmt: skip
    phase = BODY
    for stop in _stops(batch, s):
        _weigh_loop(
            phase, stop, plain(batch.joints), plain(batch.states, np.uint8),
            plain(batch.sensors), (plain(batch.starts, np.intp), batch.widest), body, views,
            (*out, stands),
        )  # fmt: skip
        _between(stop, batch, out, s)
        phase = stop + 1
    return out


def _stops(batch: ViewBatch, settings: FusionSettings) -> list[int]:
    """The phases after which :func:`_between` runs a term of its own, then :data:`CONFIDENCE`."""
    s = settings
    stops = {CONFIDENCE}
    if batch.depth_ratios is not None:
        stops |= {BODY, VIEWS}
    if s.weights.view_reliability:
        stops.add(VIEWS)
    return sorted(stops)


def _between(stop: int, batch: ViewBatch, out: Weighed, settings: FusionSettings) -> None:
    """The terms that run after phase ``stop``: the view reliability after :data:`VIEWS` and the
    ray weighting after each fusion (in place in ``out``)."""
    s = settings
    refuse = batch.depth_ratios is not None and stop in (BODY, VIEWS)
    if stop == VIEWS and s.weights.view_reliability:  # 5. how well each view sees each joint
        out.weights[:] *= reliability_factors(
            batch.joints,
            out.cosines,
            batch.sensors,
            batch.starts.tolist(),
            s.weights.view_lean_fraction,
            s.weights.view_error_m,
            s.weights.view_jitter_per_m2,
            s.weights.view_occlusion_m,
            batch.states,
        )
        refuse = True
    if refuse:
        out.fused[:] = batch.fuse(out.weights)


@jit
def _weigh_loop(
    first: int,
    last: int,
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    sensors: FloatArray,
    places: tuple[IntArray, int],
    body: _Body,
    views: tuple[FloatArray, BoolArray, bool],
    out: tuple[FloatArray, FloatArray, FloatArray, FloatArray, BoolArray, FloatArray],
) -> None:
    """Run the phases ``first`` to ``last`` of :func:`weigh_and_fuse` (module docstring).

    joints (N, 25, 3), states (N, 25), sensors (N, 3): the views; places: (P + 1,) each
    person's first view, then N, and the widest person; body: the :func:`sensor_terms` rows and
    each view's, the references (P, 24), the rom factors (N, 25), whether each of these two
    terms is on, the bone-length scale; views: the track facings (P, 3), whether each person
    was fused before (P,), the facing term on; out: weights, fused, cosines,
    confidence, carried (:class:`Weighed`) and where each view's person stands (N, 3).
    """
    weights, fused, cosines, confidence, carried, stands = out
    starts, widest = places
    facings, once, facing_on = views
    padded = np.empty((len(starts) - 1, widest, joints.shape[1], 3))
    padded_weights = np.empty(padded.shape[:3])
    if first <= BODY <= last:
        _body_phase(joints, states, starts, body, weights)
        _fuse(joints, weights, starts, padded, padded_weights, fused)
    if first <= FACING <= last:
        _facing_phase(joints, sensors, starts, facings, once, fused, stands, cosines)
    if first <= VIEWS <= last and facing_on:
        factors = np.empty(len(cosines))
        view_factor_loop(cosines, body[0], body[1], factors)
        for v in range(len(factors)):
            for j in range(weights.shape[1]):
                weights[v, j] = weights[v, j] * factors[v]
        _fuse(joints, weights, starts, padded, padded_weights, fused)
    if first <= CONFIDENCE <= last:
        _pad(joints, weights, starts, padded, padded_weights)
        confidence_loop(padded, padded_weights, MIN_SHARE, confidence, carried)


@jit
def _body_phase(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    starts: IntArray,
    body: _Body,
    weights: FloatArray,
) -> None:
    """``body_weights`` with each view's person's reference lengths; the bone-length term is
    off while no person has any."""
    terms, of_view, references, rom, flags, scale_m, (bones, chain) = body
    known = False
    if flags[0]:
        for p in range(references.shape[0]):
            for b in range(references.shape[1]):
                known = known or math.isfinite(references[p, b])
    per_view = np.empty((joints.shape[0], references.shape[1]))
    if known:
        for p in range(len(starts) - 1):
            for v in range(starts[p], starts[p + 1]):
                per_view[v] = references[p]
    body_loop(
        joints, states, terms, of_view, per_view, rom, (known, flags[1]), scale_m, bones, chain,
        weights,
    )  # fmt: skip


@jit
def _pad(
    joints: FloatArray,
    weights: FloatArray,
    starts: IntArray,
    padded: FloatArray,
    padded_weights: FloatArray,
) -> None:
    """The views (N, 25, 3) and weights (N, 25) per person as ``ViewBatch.pad`` pads them:
    (P, S, 25, 3) with NaN joints and (P, S, 25) with weight 0 after each person's views."""
    for p in range(padded.shape[0]):
        count = starts[p + 1] - starts[p]
        for s in range(padded.shape[1]):
            for j in range(padded.shape[2]):
                inside = s < count
                padded_weights[p, s, j] = weights[starts[p] + s, j] if inside else 0.0
                for c in range(3):
                    padded[p, s, j, c] = joints[starts[p] + s, j, c] if inside else math.nan


@jit
def _fuse(
    joints: FloatArray,
    weights: FloatArray,
    starts: IntArray,
    padded: FloatArray,
    padded_weights: FloatArray,
    fused: FloatArray,
) -> None:
    """Each person's weighted mean (P, 25, 3) of its views under ``weights``."""
    _pad(joints, weights, starts, padded, padded_weights)
    weighted_loop(padded, padded_weights, fused)


@jit
def _facing_phase(
    joints: FloatArray,
    sensors: FloatArray,
    starts: IntArray,
    facings: FloatArray,
    once: BoolArray,
    fused: FloatArray,
    stands: FloatArray,
    cosines: FloatArray,
) -> None:
    """Fill ``stands`` (N, 3) with where each view's person stands (``ViewBatch.body_positions``:
    its fused SpineBase, else the mean of its views' known coordinates) and ``cosines`` (N,)
    with each view's facing cosine; a person fused the first time faces as its fusion does."""
    gathered = np.empty((len(cosines), 3))
    own = np.empty((1, 3))
    stand = np.empty(3)
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        spine = fused[p, 0]
        if math.isfinite(spine[0]) and math.isfinite(spine[1]) and math.isfinite(spine[2]):
            stand[:] = spine
        else:  # sums over the padded views from 0, as numpy's
            for c in range(3):
                total = seen = 0.0
                for v in range(lo, hi):
                    if math.isfinite(joints[v, 0, c]):
                        total += joints[v, 0, c]
                        seen += 1.0
                stand[c] = total / seen
        if once[p]:
            own[0] = facings[p]
        else:
            facing_loop(fused[p : p + 1], own)
        for v in range(lo, hi):
            stands[v] = stand
            gathered[v] = own[0]
    cosines_loop(gathered, stands, sensors, cosines)


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now: the step's, every phase, and the
    weighted mean's."""
    views = np.zeros((2, 25, 3))
    terms, of_view = sensor_terms(FusionSettings(), None, 2)
    out = (
        np.empty((2, 25)), np.empty((1, 25, 3)), np.empty(2), np.empty((1, 25)),
        np.empty((1, 2, 25), dtype=np.bool_), np.empty((2, 3)),
    )  # fmt: skip
    _weigh_loop(
        BODY, CONFIDENCE, views, np.zeros((2, 25), np.uint8), np.ones((2, 3)),
        (np.array([0, 2], dtype=np.intp), 2),
        (terms, of_view, np.ones((1, 24)), np.ones((2, 25)), (True, True), 0.05, _TABLES),
        (np.ones((1, 3)), np.zeros(1, dtype=np.bool_), True),
        out,
    )  # fmt: skip
    weighted_mean(np.zeros((1, 2, 25, 3)), np.ones((1, 2, 25)))


# --- Weighted fusion: each joint as the weighted mean of the views that have it ------------------


MIN_SHARE: Final = 0.05
"""A view is a source of a fused joint when it carries at least this share of the weight."""


def weighted_mean(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The confidence-weighted mean of each person's views (report A, eq. 2).

    Args:
        joints: (P, S, J, 3) positions; NaN where a view has no position (it contributes
            nothing whatever its weight).
        weights: (P, S, J) non-negative (negative or NaN counts as 0); broadcast to that shape.

    Returns:
        (P, J, 3) float64; NaN where no view has a position with a positive weight.
    """
    points = plain(joints)
    if weights.shape != points.shape[:3]:
        weights = np.broadcast_to(weights, points.shape[:3])
    out = np.empty((points.shape[0], points.shape[2], 3))
    weighted_loop(points, plain(weights), out)
    return out


@jit
def weighted_loop(joints: FloatArray, weights: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (P, J, 3) with the weighted mean of ``joints`` (P, S, J, 3) under
    ``weights`` (P, S, J): a view counts where its point is finite and its weight positive;
    NaN where no view counts."""
    for p in range(joints.shape[0]):
        for j in range(joints.shape[2]):
            total = 0.0
            s0 = s1 = s2 = 0.0
            for s in range(joints.shape[1]):
                x0, x1, x2 = joints[p, s, j, 0], joints[p, s, j, 1], joints[p, s, j, 2]
                weight = weights[p, s, j]
                usable = (
                    math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and weight > 0
                )
                if not usable:
                    weight, x0, x1, x2 = 0.0, 0.0, 0.0, 0.0
                total += weight
                s0 += weight * x0
                s1 += weight * x1
                s2 += weight * x2
            if total <= 0:
                out[p, j, 0] = out[p, j, 1] = out[p, j, 2] = math.nan
            else:
                out[p, j, 0], out[p, j, 1], out[p, j, 2] = s0 / total, s1 / total, s2 / total


def fuse_views(joints: npt.ArrayLike, weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """One person's views fused, with the confidence apps receive.

    Args:
        joints: (S, J, 3) positions, metres, world frame; NaN where a view has no position.
        weights: (S, J) non-negative weights.

    Returns:
        fused (J, 3) as :func:`weighted_mean`, and its
        :func:`~skelfuse.fusion.confidence.joint_confidence` (J,).

    Raises:
        ValueError: on shapes other than (S, J, 3) and (S, J).
    """
    views = np.asarray(joints, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if views.ndim != 3 or views.shape[2] != 3 or w.shape != views.shape[:2]:
        raise ValueError(
            f"expected joints (S, J, 3) and weights (S, J), got {views.shape} and {w.shape}"
        )
    return weighted_mean(views[None], w[None])[0], joint_confidence(views[None], w[None])[0]


def confidence_and_carriers(
    joints: FloatArray, weights: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """:func:`~skelfuse.fusion.confidence.joint_confidence` and :func:`carriers` of the same
    views, from one pass (:func:`~skelfuse.fusion.confidence.confidence_loop`).

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        confidence (P, J) float64 and carried (P, S, J) bool.
    """
    w = plain(weights)
    confidence = np.empty((w.shape[0], w.shape[2]))
    carried = np.empty(w.shape, dtype=np.bool_)
    confidence_loop(plain(joints), w, MIN_SHARE, confidence, carried)
    return confidence, carried


def carriers(joints: FloatArray, weights: FloatArray) -> npt.NDArray[np.bool_]:
    """Which views carried each fused joint: at least :data:`MIN_SHARE` of its weight (the
    weight of the views with a position).

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        (P, S, J) bool.
    """
    return confidence_and_carriers(joints, weights)[1]


# --- The view batch: many persons' views stacked, so every per-view step runs once per instant ---


_NO_POSITION = np.full(3, np.nan)


@dataclass(slots=True)
class ViewBatch:
    """The views of P persons stacked: person ``person_of[i]``'s ``slot_of[i]``-th view.

    joints: (N, 25, 3) float64 metres, world; states: (N, 25) uint8; sensors: (N, 3) metres.
    person_of, slot_of (N,) and starts (P + 1,) are shared read-only arrays.
    Per-person sums use (P, widest, ...) blocks padded after the real views (:meth:`pad`).
    depth_ratios: (N,) each view's noise along its sensor's ray over across it, None when all
    are 1 (fusion/view_factors.py: only ``rgb`` views have more).
    """

    views: list[View]
    counts: list[int]
    joints: FloatArray
    states: npt.NDArray[np.uint8]
    sensors: FloatArray
    person_of: npt.NDArray[np.intp]
    slot_of: npt.NDArray[np.intp]
    starts: npt.NDArray[np.intp]
    depth_ratios: FloatArray | None = None

    @classmethod
    def of(cls, clusters: list[list[View]], depth_noise: bool = True) -> ViewBatch:
        """The views of each person stacked; ``depth_noise``: look up each view's depth noise
        ratio (``FusionSettings.weights.sensor_priors``), else treat every view as isotropic."""
        counts = [len(cluster) for cluster in clusters]
        views = [view for cluster in clusters for view in cluster]
        places = slots(tuple(counts))  # cached per shape (read-only arrays): frames repeat
        # np.array on the lists: np.stack's values, a few times faster on these small arrays.
        return cls(
            views,
            counts,
            np.array([v.joints_world for v in views], dtype=np.float64),
            np.array([v.states for v in views]),
            np.array(
                [_NO_POSITION if v.sensor_position is None else v.sensor_position for v in views],
                dtype=np.float64,
            ),
            places.person_of,
            places.slot_of,
            places.starts,
            depth_noise_ratios([v.sensor_type for v in views]) if depth_noise else None,
        )

    @property
    def widest(self) -> int:
        return max(self.counts)

    def pad(self, values: FloatArray, fill: float) -> FloatArray:
        """(N, ...) per-view values as (P, widest, ...), ``fill`` after each person's views.

        When every person has the same number of views there is nothing to fill: the result is
        ``values`` reshaped (sharing its memory, float64); callers read it, never write to it.
        """
        widest = self.widest
        if widest * len(self.counts) == len(self.views):  # every person as wide as the widest
            same: FloatArray = np.ascontiguousarray(values, dtype=np.float64)
            return same.reshape(len(self.counts), widest, *values.shape[1:])
        padded = np.full((len(self.counts), widest, *values.shape[1:]), fill, np.float64)
        padded[self.person_of, self.slot_of] = values
        return padded

    def fuse(self, weights: FloatArray) -> FloatArray:
        """Step 6 on the batch: (P, 25, 3) each person's weighted mean (with each view's noise
        stretched along its sensor's ray for persons seen by a camera that guesses depth)."""
        joints, padded = self.pad(self.joints, np.nan), self.pad(weights, 0.0)
        fused = weighted_mean(joints, padded)
        if self.depth_ratios is None:
            return fused
        sensors, ratios = self.pad(self.sensors, np.nan), self.pad(self.depth_ratios, 1.0)
        return ray_weighted_mean(joints, padded, sensors, ratios, fused)

    def body_positions(self, fused: FloatArray) -> FloatArray:
        """(P, 3) where each person stands: fused SpineBase, else the mean of the views'."""
        fused_spine_ok = np.isfinite(fused[:, 0]).all(axis=-1, keepdims=True)
        if fused_spine_ok.all():  # every person's fused SpineBase known (the usual step)
            known: FloatArray = fused[:, 0].copy()
            return known
        spine = self.joints[:, 0]
        seen = np.isfinite(spine)
        sums = self.pad(np.where(seen, spine, 0.0), 0.0).sum(axis=1)
        counts = self.pad(seen.astype(np.float64), 0.0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_spine = sums / counts
        positions: FloatArray = np.where(fused_spine_ok, fused[:, 0], mean_spine)
        return positions
