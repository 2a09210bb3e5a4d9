"""Steps 5–6 of the pipeline on a batch: every view's per-joint weights, and the fusions.

:func:`weigh_and_fuse` weighs each view's joints by the body terms alone (bone length, range of
motion: :func:`~skelfuse.fusion.confidence.body_weights`) and fuses them, which tells where
each person stands and faces; then by the inverse of each view's joint's learned error
variance in its bin (where its sensor stands relative to the person, its tracking state, its
distance: :mod:`skelfuse.fusion.rig_errors`), fusing again; then a view far off the others
(a glitch) is weighed down by a Student-t factor on its leave-one-out residual and the joints
fused a last time; last, the confidence apps receive and which views carried each joint.

The scale of the weights: a joint whose learned variance is the Kinect v2 prior's for a
Tracked joint seen from in front and near weighs ``state_weights[2]`` (0.7) before the body
terms, so the confidence apps receive (``joint_confidence``) keeps its meaning; a better view
weighs more, a worse one less.

In numpy that is a dozen calls with their arguments' gathers and pads, so the step is one loop
compiled with numba (:func:`_weigh_loop`) running the stages' own loops in order:
:func:`~skelfuse.fusion.confidence.body_loop`, :func:`weighted_loop` on the views padded as
:meth:`ViewBatch.pad` pads them (NaN joints, weight 0), the facing,
:func:`~skelfuse.fusion.rig_errors.view_bins_loop`,
:func:`~skelfuse.fusion.rig_errors.robust_factors_loop` and
:func:`~skelfuse.fusion.confidence.confidence_loop`. The loop runs in phases (:data:`BODY` …
:data:`CONFIDENCE`); each fusion of a person with a view whose noise is larger along its ray
is weighed per axis (:func:`~skelfuse.fusion.view_factors.ray_loop`), and the loop stops after
the learned weighting for the single-limb labels (:mod:`skelfuse.fusion.limb_labels`).
:func:`warm_up` compiles the loop (or loads numba's cache) at start, so no frame waits for a
compilation.

Weighted fusion (second section): each joint as the weighted mean of the views that have it.
Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn``. :func:`carriers` tells which views a fused joint
came from. Shapes: P persons fused at once, each with up to S views (a person with fewer is
padded with NaN views of weight 0, which changes no sum or product), J = 25 joints; metres,
world frame. :func:`weighted_mean` is one loop compiled with numba (:func:`weighted_loop`): per
joint, the sums over the views start from 0 and add view after view, a view counting where its
point is finite and its weight positive.

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
from skelfuse.fusion.limb_labels import LIMBS, limb_swap_loop
from skelfuse.fusion.mirror_scores import slots
from skelfuse.fusion.priors import KINECT_V2, SensorPrior, prior_variances
from skelfuse.fusion.rig_errors import robust_factors_loop, variance_at, view_bins_loop
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.view_factors import (
    cosines_loop,
    depth_noise_ratios,
    ray_loop,
    ray_weighted_mean,
)
from skelfuse.fusion.views import View
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "MIN_SHARE",
    "Learned",
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
"""Phase: each view's joints' bins and learned variances, and the fusion under them."""
ROBUST: Final = 3
"""Phase: the Student-t factors of views far off the others, and the last fusion."""
CONFIDENCE: Final = 4
"""Phase: the confidence and the carriers."""
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
_Views = tuple[FloatArray, BoolArray, IntArray, FloatArray, FloatArray, tuple[bool, float, float]]
"""The views' arguments of :func:`_weigh_loop` (its docstring)."""
_NOT_USED: Final = np.ones((1, 1))
"""What the loop gets for a term that is off (it reads nothing of it; never written)."""


class Learned(NamedTuple):
    """Each view's sensor in the learned error table, and the table (fusion/rig_errors.py).

    rows: (N,) each view's row; variance: (R, 25, B) m², the learned (or prior) variances.
    """

    rows: IntArray
    variance: FloatArray


class Weighed(NamedTuple):
    """What steps 5–6 give the rest of the step (P persons, N views, S the widest person).

    weights: (N, 25) each view's final per-joint weights; fused: (P, 25, 3) metres, world, NaN
    where no view counts; cosines: (N,) each view's facing cosine (NaN: unknown); confidence:
    (P, 25) in [0, 1]; carried: (P, S, 25) which views carried each fused joint; bins: (N, 25)
    each view's joint's bin (:func:`~skelfuse.fusion.rig_errors.bin_of`, −1: NotTracked);
    between: (N,) how far each view is towards the next sector's bin; variances: (N, 25) each
    view's joints' learned variances (m², inf where NotTracked).
    """

    weights: FloatArray
    fused: FloatArray
    cosines: FloatArray
    confidence: FloatArray
    carried: BoolArray
    bins: IntArray
    between: FloatArray
    variances: FloatArray


def weigh_and_fuse(
    batch: ViewBatch,
    rom: FloatArray | None,
    references: FloatArray,
    track_facings: FloatArray,
    fused_once: Sequence[bool],
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
    learned: Learned,
    track_joints: FloatArray,
) -> Weighed:
    """Steps 5–6 (module docstring) for P persons' N views, whole views' labels corrected
    (single limbs' are put right here, in place in ``batch``).

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
        learned: each view's sensor's learned variances.
        track_joints: (P, 25, 3) each person's track skeleton (read where ``fused_once``).
    """
    s = settings
    count, persons, size = len(batch.joints), len(batch.counts), batch.joints.shape[1]
    out = Weighed(
        np.empty((count, size)),
        np.empty((persons, size, 3)),
        np.empty(count),
        np.empty((persons, size)),
        np.empty((persons, batch.widest, size), dtype=np.bool_),
        np.empty((count, size), dtype=np.intp),
        np.empty(count),
        np.empty((count, size)),
    )
    views = (
        plain(track_facings), plain(np.asarray(fused_once, dtype=np.bool_), np.bool_),
        plain(learned.rows, np.intp), learned.variance, weight_scale(s),
        (bool(s.weights.view_bins), float(s.learning.far_m), float(s.learning.robust_dof)),
    )  # fmt: skip
    stretched = batch.depth_ratios is not None
    rays = (
        plain(batch.depth_ratios) if batch.depth_ratios is not None else np.ones(count),
        stretched,
    )
    work = (np.empty((count, 3)), np.empty((count, 3)))

    _weigh_loop(
        BODY, CONFIDENCE, plain(batch.joints), plain(batch.states, np.uint8),
        plain(batch.sensors), (plain(batch.starts, np.intp), batch.widest),
        _body_terms(batch, rom, references, s, priors), views, rays,
        (plain(track_joints), bool(s.mirror.limbs)), out, work,
    )  # fmt: skip
    return out


def _body_terms(
    batch: ViewBatch,
    rom: FloatArray | None,
    references: FloatArray,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
) -> _Body:
    """The body terms' arguments of :func:`_weigh_loop` (``rom`` None: computed here)."""
    s = settings
    terms, of_view = sensor_terms(s, priors, len(batch.joints))
    if s.weights.range_of_motion and rom is None:
        rom = range_of_motion_factors(batch.joints, s.weights.rom_scale_deg)
    factors = rom if s.weights.range_of_motion else None
    return (
        terms, plain(of_view, np.intp),
        plain(references) if s.weights.bone_length else _NOT_USED,
        _NOT_USED if factors is None else plain(factors),
        (s.weights.bone_length, factors is not None), float(s.weights.bone_length_scale_m), _TABLES,
    )  # fmt: skip


def weight_scale(settings: FusionSettings) -> FloatArray:
    """(25,) what a joint's weight is before its body terms when its variance is 1 m²: the
    Kinect v2 prior's variance of a frontal, near, Tracked joint times its state weight
    (module docstring), so that such a joint weighs ``state_weights[2]``."""
    kept = _scales.get(id(settings))
    if kept is None or kept[0] is not settings:
        front = prior_variances(KINECT_V2, settings)[:, 0]
        kept = _scales[id(settings)] = (settings, front * settings.weights.state_weights[2])
        if len(_scales) > 16:
            _scales.pop(next(iter(_scales)))
    return kept[1]


_scales: dict[int, tuple[FusionSettings, FloatArray]] = {}
""":func:`weight_scale` by the identity of the settings (kept with them, so no id is reused)."""


@jit
def _weigh_loop(
    first: int,
    last: int,
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    sensors: FloatArray,
    places: tuple[IntArray, int],
    body: _Body,
    views: _Views,
    rays: tuple[FloatArray, bool],
    limbs: tuple[FloatArray, bool],
    out: tuple[
        FloatArray, FloatArray, FloatArray, FloatArray, BoolArray, IntArray, FloatArray, FloatArray
    ],
    work: tuple[FloatArray, FloatArray],
) -> None:
    """Run the phases ``first`` to ``last`` of :func:`weigh_and_fuse` (module docstring).

    joints (N, 25, 3), states (N, 25), sensors (N, 3): the views; places: (P + 1,) each
    person's first view, then N, and the widest person; body: the :func:`sensor_terms` rows and
    each view's, the references (P, 24), the rom factors (N, 25), whether each of these two
    terms is on, the bone-length scale; views: the track facings (P, 3), whether each person
    was fused before (P,), each view's learned-variance row (N,), the variances (R, 25, B),
    :func:`weight_scale` (25,), whether views are binned by where they stand, the far
    distance and the Student-t degrees of freedom (0: no robust pass); rays: each view's depth
    ratio (N,) and whether any is not 1 (then fused along the rays); limbs: each person's
    track skeleton (P, 25, 3) and whether single limbs' labels are checked (after the learned
    weighting; the step's first phases again if one is swapped); out: weights, fused,
    cosines, confidence, carried, bins, between, variances (:class:`Weighed`); work: where
    each view's person stands (N, 3), its facing (N, 3).
    """
    weights, fused, cosines, confidence, carried, bins, between, variances = out
    stands, facing_of = work
    starts, widest = places
    facings, once, rows, table, scale, (binned, far_m, dof) = views
    padded = np.empty((len(starts) - 1, widest, joints.shape[1], 3))
    padded_weights = np.empty(padded.shape[:3])
    along = (sensors, rays[0], rays[1])
    learned = (rows, table, scale, binned, far_m)
    swapped = np.zeros((len(rows), 2), dtype=np.bool_)
    for again in range(2):  # again: a limb's labels were put right, so weighed again
        if again and not swapped.any():
            break
        if again or first <= BODY <= last:
            _body_phase(joints, states, starts, body, weights)
            _fuse(joints, weights, starts, (padded, padded_weights), along, fused)
        if again or first <= FACING <= last:
            _facing_phase(joints, sensors, starts, facings, once, fused, stands, facing_of, cosines)
        if again or first <= VIEWS <= last:
            _views_phase(
                facing_of, stands, sensors, states, learned, (bins, between), variances, weights
            )
            _fuse(joints, weights, starts, (padded, padded_weights), along, fused)
            if not again and limbs[1]:
                limb_swap_loop(joints, states, weights, starts, limbs[0], once, LIMBS, swapped)
    if first <= ROBUST <= last and dof > 0.0:
        factors = np.empty(weights.shape)
        robust_factors_loop(joints, weights, variances, starts, dof, factors)
        for v in range(len(rows)):
            for j in range(weights.shape[1]):
                weights[v, j] = weights[v, j] * factors[v, j]
        _fuse(joints, weights, starts, (padded, padded_weights), along, fused)
    if first <= CONFIDENCE <= last:
        _pad(joints, weights, starts, padded, padded_weights)
        confidence_loop(padded, padded_weights, MIN_SHARE, confidence, carried)


@jit
def _views_phase(
    facing_of: FloatArray,
    stands: FloatArray,
    sensors: FloatArray,
    states: npt.NDArray[np.uint8],
    learned: tuple[IntArray, FloatArray, FloatArray, bool, float],
    places: tuple[IntArray, FloatArray],
    variances: FloatArray,
    weights: FloatArray,
) -> None:
    """Each view's joints' bins (``places``: bins, between) and learned variances, and the
    weights over them (in place). learned: each view's row, the table (R, 25, B), the weight
    scale (25,), whether views are binned by where they stand, the far distance."""
    rows, table, scale, binned, far_m = learned
    bins, between = places
    view_bins_loop(facing_of, stands, sensors, states, (binned, far_m), (bins, between))
    for v in range(len(rows)):
        for j in range(weights.shape[1]):
            b = bins[v, j]
            if b < 0:
                variances[v, j], weights[v, j] = math.inf, 0.0
                continue
            variances[v, j] = variance_at(table, rows[v], j, b, between[v])
            weights[v, j] = weights[v, j] * scale[j] / variances[v, j]


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
    pads: tuple[FloatArray, FloatArray],
    rays: tuple[FloatArray, FloatArray, bool],
    fused: FloatArray,
) -> None:
    """Each person's weighted mean (P, 25, 3) of its views under ``weights``; persons with a
    view whose noise is larger along its ray (``rays``: each view's sensor (N, 3), its ratio
    (N,), whether any is not 1) fused along the rays (``ViewBatch.fuse``)."""
    padded, padded_weights = pads
    _pad(joints, weights, starts, padded, padded_weights)
    weighted_loop(padded, padded_weights, fused)
    sensors, ratios, stretched = rays
    if not stretched:
        return
    persons, widest = padded.shape[0], padded.shape[1]
    padded_sensors = np.full((persons, widest, 3), math.nan)
    padded_ratios = np.ones((persons, widest))
    for p in range(persons):
        for s in range(starts[p + 1] - starts[p]):
            padded_sensors[p, s] = sensors[starts[p] + s]
            padded_ratios[p, s] = ratios[starts[p] + s]
            across = (2.0 + ratios[starts[p] + s] ** 2) / 3.0  # a 3-D precision, across the ray
            for j in range(padded.shape[2]):
                padded_weights[p, s, j] *= across
    ray_loop(padded, padded_weights, padded_sensors, padded_ratios, False, fused)


@jit
def _facing_phase(
    joints: FloatArray,
    sensors: FloatArray,
    starts: IntArray,
    facings: FloatArray,
    once: BoolArray,
    fused: FloatArray,
    stands: FloatArray,
    facing_of: FloatArray,
    cosines: FloatArray,
) -> None:
    """Fill ``stands`` (N, 3) with where each view's person stands (``ViewBatch.body_positions``:
    its fused SpineBase, else the mean of its views' known coordinates), ``facing_of`` (N, 3)
    with its facing and ``cosines`` (N,) with each view's facing cosine; a person fused the
    first time faces as its fusion does."""
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
            facing_of[v] = own[0]
    cosines_loop(facing_of, stands, sensors, cosines)


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now: the step's, every phase, and the
    weighted mean's."""
    views = np.zeros((2, 25, 3))
    settings = FusionSettings()
    terms, of_view = sensor_terms(settings, None, 2)
    out = (
        np.empty((2, 25)), np.empty((1, 25, 3)), np.empty(2), np.empty((1, 25)),
        np.empty((1, 2, 25), dtype=np.bool_), np.empty((2, 25), dtype=np.intp), np.empty(2),
        np.empty((2, 25)),
    )  # fmt: skip
    table = prior_variances(KINECT_V2, settings)[None]
    _weigh_loop(
        BODY, CONFIDENCE, views, np.zeros((2, 25), np.uint8), np.ones((2, 3)),
        (np.array([0, 2], dtype=np.intp), 2),
        (terms, of_view, np.ones((1, 24)), np.ones((2, 25)), (True, True), 0.05, _TABLES),
        (np.ones((1, 3)), np.zeros(1, dtype=np.bool_), np.zeros(2, dtype=np.intp), table,
         weight_scale(settings), (True, 2.5, 4.0)),
        (np.full(2, 2.0), True), (np.zeros((1, 25, 3)), True), out,
        (np.empty((2, 3)), np.empty((2, 3))),
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
    are 1: from the sensor types' priors here (only ``rgb`` has more); the pipeline sets each
    sensor's learned ratio (fusion/rig_errors.py).
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
        # A weight is the inverse of a view's 3-D variance; across the ray, per axis, its
        # variance is that over (2 + ratio²), i.e. its precision (2 + ratio²) / 3 times more.
        across = padded * ((2.0 + ratios**2) / 3.0)[:, :, None]
        return ray_weighted_mean(joints, across, sensors, ratios, fused)

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
