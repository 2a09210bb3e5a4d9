"""Body-based confidence of each joint of each view: tracking state, bone length, range of motion.

Report A (``shared/papers.md``) multiplies body-based terms into the tracking-state weight of
each joint of each view; here they multiply the inverse of the view's learned error variance
(fusion/rig_errors.py), which covers the tracking state. Everything here is a pure function on
arrays; :mod:`skelfuse.fusion.weigh` combines the terms (:func:`body_weights` and the learned
variances) and fuses with them. :func:`joint_confidence` is the one
place the confidence apps receive with each fused joint is computed.

Shapes: S views of one person, 25 joints, 24 bones (:data:`protocol.skeleton.BONES` order).
Positions in metres, world frame (+Y up). Every term is in (0, 1], 1 meaning "no doubt", and a
NaN input gives 1 (no evidence either way: a missing joint already has weight 0).

Bone length (report A, with the printed sign corrected)
-------------------------------------------------------
``f(Δl) = exp(−|Δl| / scale)``, Δl the difference between the length a view implies and the
person's reference length. Chosen over ``1 / (1 + a·|Δl|)`` because it is the likelihood of a
Laplace-distributed length error, so the product along a chain, ``exp(−Σ|Δl| / scale)``, is
the likelihood of the whole chain; and because it decays fast enough that a glitch (a limb 15–40
cm off while still Tracked) ends with a weight near 0 (``exp(−10)`` at 30 cm, where
``1/(1 + a·|Δl|)`` would still give 0.09 with the same half-weight point).

Each bone's factor lands on its child joint and is propagated multiplicatively outward from
SpineBase along :data:`PARENTS` (in :func:`body_loop`): a doubtful elbow makes wrist, hand, hand tip
and thumb doubtful too (report A: ``C_k(n+1) = C_kn · f(...)``).

Range of motion
---------------
Angles are measured in the view's own body frame (left = hips and shoulders, up = SpineBase →
SpineShoulder, forward = left × up), so they are independent of where the person stands and of
the sensor. An angle ``excess`` degrees outside its range gives ``exp(−excess / scale)`` on the
distal joint of the angle (and, by propagation, on everything beyond it). Limits (degrees;
sources: AAOS, *Joint Motion: Method of Measuring and Recording*, 1965, the reference ranges
reproduced in Norkin & White, *Measurement of Joint Motion: A Guide to Goniometry*, 5th ed.,
2016; Soucie et al., "Range of motion measurements: reference values and a database for
comparison studies", *Haemophilia* 17(3), 2011, for hyperextension in healthy adults):

=================================  ============  ============================================
angle (factor lands on)            range         notes
=================================  ============  ============================================
knee flexion (ankle)               −5 … 145      AAOS 0–135, Soucie ≈ 140; ≤ 5° hyperextension
elbow flexion, unsigned (wrist)    0 … 150       AAOS 0–150; the hinge axis turns with the arm,
                                                 so only the unsigned angle is checked
hip flexion (knee)                 −30 … 130     AAOS flexion 120, extension 30; +10 because the
                                                 trunk axis includes lumbar flexion (squats)
hip abduction (knee)               −30 … 50      AAOS abduction 45, adduction 30
shoulder extension (elbow)         ≤ 60          AAOS extension 60 (flexion/abduction to 180
                                                 cover everything else)
ankle: shank → foot (foot)         25 … 150      neutral ≈ 70–90 (where the sensor puts the foot
                                                 joint), dorsiflexion 20, plantarflexion 50
neck: trunk → head (head)          0 … 70        AAOS cervical flexion 45, extension 45, plus
                                                 the SpineShoulder–Neck offset
=================================  ============  ============================================

Knee, hip and ankle are *signed* in the body frame, which is what makes the term see a skeleton
whose left and right are swapped: its forward axis is reversed, so every bent knee looks
hyperextended and every foot points backwards.

Implementation
--------------
Each term is a loop compiled with numba, so a step pays one call per term, not a dozen numpy
operations on arrays of a few dozen rows: :func:`body_loop` (bone length × range of motion,
propagated, where the state counts) and :func:`confidence_loop` (the confidence and the views
that carried each joint). A bone length is ``sqrt((dx² + dy²) + dz²)``, products and sums over a
person's views start from 1 and 0 and take view after view, and ``exp`` and ``pow`` are the C
library's. Each sensor's prior enters as one row of :func:`sensor_terms` (fusion/priors.py).
:func:`warm_up` compiles the loops (or loads numba's cache) at start, so no frame waits for a
compilation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import CHAIN_ORDER, rom_factors_and_forward
from skelfuse.fusion.priors import SensorPrior, distinct_priors
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import BONES, PARENTS, JointId

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
J = JointId


_BONE_CHILD: Final = np.array([child for _, child in BONES])
_BONE_PARENT: Final = np.array([parent for parent, _ in BONES])
_CHAIN: Final = (np.array(CHAIN_ORDER[1:]), np.array([PARENTS[j] for j in CHAIN_ORDER[1:]]))
BODY_TABLES: Final = ((_BONE_PARENT, _BONE_CHILD), _CHAIN)
"""The body terms' index tables: each bone's parent and child joint; the joints below
SpineBase, parents first, and their parents (what :func:`body_loop` takes)."""

TERM_COLUMNS: Final = 5
"""Columns of a :func:`sensor_terms` row: whether a NotTracked, Inferred, Tracked joint counts
at all (1.0 or 0.0: the prior's state weight is positive; how much it counts is its learned
variance's, fusion/rig_errors.py), fixed bone lengths (1.0: the bone-length term leaves the
view alone), and the range-of-motion scale k."""


def range_of_motion_factors(views: npt.ArrayLike, scale_deg: float) -> FloatArray:
    """Local range-of-motion factor of each joint (not yet propagated).

    Args:
        views: (S, 25, 3) joints, metres, world frame.
        scale_deg: degrees outside the range that divide the factor by e.

    Returns:
        (S, 25) float64 in (0, 1]; 1 where every angle landing on the joint is in range or
        unknown.
    """
    return rom_factors_and_forward(views, scale_deg)[0]


def sensor_terms(
    settings: FusionSettings, priors: Sequence[SensorPrior] | None, count: int
) -> tuple[FloatArray, IntArray]:
    """Each distinct sensor prior's terms as one row (:data:`TERM_COLUMNS`), and each view's row.

    Args:
        settings: the values a prior leaves ``None``; priors: (N,) each view's, or None: the
            settings' for every view; count: N.

    Returns:
        (K, 9) float64 rows (one for the settings when ``priors`` is None) and (N,) intp.
        Frames repeat the same settings and priors: the rows are kept per pair of objects.
    """
    if priors is None:
        of_view: IntArray = np.zeros(count, dtype=np.intp)
        key: tuple[int, ...] = (id(settings),)
        distinct: list[SensorPrior] = [SensorPrior("settings")]
    else:
        distinct, of_view = distinct_priors(priors)
        key = (id(settings), id(of_view))
    kept = _terms.get(key)
    if kept is None or kept[0] is not settings:
        if len(_terms) >= _KEPT:
            _terms.clear()
        rows = np.array([_row(p, settings) for p in distinct], dtype=np.float64)
        kept = _terms[key] = (settings, of_view, rows)
    return kept[2], of_view


def _row(prior: SensorPrior, settings: FusionSettings) -> list[float]:
    """``prior``'s row of :func:`sensor_terms`."""
    fixed = 1.0 if prior.fixed_bone_lengths else 0.0
    counts = [1.0 if weight > 0 else 0.0 for weight in prior.table(settings)]
    return [*counts, fixed, prior.rom_scale]


_KEPT: Final = 64
_terms: dict[tuple[int, ...], tuple[FusionSettings, IntArray, FloatArray]] = {}
""":func:`sensor_terms`' rows by the identities of the settings and of the views' prior indices
(both kept with them, so that no id is reused meanwhile)."""


def state_weights(states: npt.ArrayLike, table: tuple[float, float, float]) -> FloatArray:
    """Per-joint weights from tracking states.

    Args:
        states: (S, J) uint8 TrackingState values.
        table: weight of NotTracked, Inferred, Tracked.

    Returns:
        (S, J) float64 weights.
    """
    return np.asarray(table, dtype=np.float64)[np.asarray(states, dtype=np.intp)]


def joint_confidence(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The confidence apps receive with each fused joint (``confidence`` in docs/api.md).

    ``1 − Π_k (1 − w_k)`` over the views that carry the joint, with each view's final weight
    clipped to [0, 1]: the chance that at least one view is right if view k is right with
    probability w_k. 0 exactly where no view has a position with a positive weight (the
    fused joint is unknown).

    Args:
        joints: (P, S, J, 3) each person's views as fused, metres; NaN where a view has no
            position (and on the padding after a person's real views).
        weights: (P, S, J) the final fusion weights (0 on padding).

    Returns:
        (P, J) float64 in [0, 1].
    """
    w = plain(weights)
    confidence = np.empty((w.shape[0], w.shape[2]))
    carried = np.empty(w.shape, dtype=np.bool_)
    confidence_loop(plain(joints), w, 0.0, confidence, carried)
    return confidence


def body_weights(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    references: FloatArray | None,
    rom: FloatArray | None,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None = None,
) -> FloatArray:
    """Each joint's factor from its view alone: the body terms, propagated.

    ``Π (bone length × range of motion)``, the product over the joint and every joint between
    it and SpineBase (module docstring): a joint is doubted as much as its own bone and angle
    and its ancestors'; 0 for a tracking state whose prior weight is 0. The view's learned
    variance (fusion/rig_errors.py) scales it in the fusion. With ``priors`` each view uses its
    sensor's state table, range-of-motion scale (``factor^(1/k)``: ``exp(−e/(k·s))``) and, for
    a fixed-length body model, no bone-length term (fusion/priors.py); a Kinect v2 prior gives
    the same numbers as none.

    Args:
        joints: (N, 25, 3) views, metres, world frame, labels already corrected.
        states: (N, 25) TrackingState values.
        references: (N, 24) the reference bone lengths of each view's person (metres, NaN:
            unknown), or None when no person has any.
        rom: (N, 25) range-of-motion factors already computed (by the mirror step), or None.
        settings: which terms are on, and their scales.
        priors: (N,) each view's sensor prior, or None: the settings' values for every view.

    Returns:
        (N, 25) float64 factors in [0, 1].
    """
    s = settings
    points = plain(joints)
    terms, of_view = sensor_terms(s, priors, len(points))
    refs = references if s.weights.bone_length else None
    if s.weights.range_of_motion and rom is None:
        rom = range_of_motion_factors(points, s.weights.rom_scale_deg)
    factors = rom if s.weights.range_of_motion else None
    out = np.empty(points.shape[:2])
    body_loop(
        points, plain(states, np.uint8), terms, plain(of_view, np.intp),
        _NOT_USED if refs is None else plain(refs),
        _NOT_USED if factors is None else plain(factors),
        (refs is not None, factors is not None), float(s.weights.bone_length_scale_m),
        (plain(_BONE_PARENT, np.intp), plain(_BONE_CHILD, np.intp)),
        (plain(_CHAIN[0], np.intp), plain(_CHAIN[1], np.intp)), out,
    )  # fmt: skip
    return out


_NOT_USED: Final = np.ones((1, 1))
"""What a loop gets for a term that is off (it reads nothing of it; never written)."""


@jit
def body_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    terms: FloatArray,
    of_view: IntArray,
    references: FloatArray,
    rom: FloatArray,
    flags: tuple[bool, bool],
    scale_m: float,
    bones: tuple[IntArray, IntArray],
    chain: tuple[IntArray, IntArray],
    out: FloatArray,
) -> None:
    """Fill ``out`` (N, 25) with each joint's factor from its view alone (``body_weights``).

    joints: (N, 25, 3); states: (N, 25) tracking states; terms: (K, 5) the
    :func:`sensor_terms` rows, of_view: (N,) each view's; references: (N, 24) reference bone
    lengths (read when ``flags[0]``); rom: (N, 25) range-of-motion factors (read when
    ``flags[1]``); scale_m: the bone-length scale; bones: each bone's parent and child joint;
    chain: the joints below SpineBase parent first, and their parents.
    """
    parents, children = bones
    order, parent_of = chain
    local = np.empty(joints.shape[1])
    for v in range(joints.shape[0]):
        row = terms[of_view[v]]
        for j in range(len(local)):
            local[j] = 1.0
        if flags[0] and row[3] == 0.0:  # bone length: exp(−|l − l_ref| / scale) on the child
            for b in range(len(parents)):
                a, c = joints[v, children[b]], joints[v, parents[b]]
                d0, d1, d2 = a[0] - c[0], a[1] - c[1], a[2] - c[2]
                diff = abs(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - references[v, b])
                local[children[b]] = math.exp(-diff / scale_m) if math.isfinite(diff) else 1.0
        if flags[1]:  # exp(−e/s)^(1/k) = exp(−e/(k·s)): a prior's own scale k
            k = row[4]
            for j in range(len(local)):
                local[j] *= rom[v, j] if k == 1.0 else rom[v, j] ** (1.0 / k)
        for i in range(len(order)):  # outward from SpineBase: each parent already final
            local[order[i]] *= local[parent_of[i]]
        for j in range(len(local)):
            out[v, j] = row[states[v, j]] * local[j]


@jit
def confidence_loop(
    joints: FloatArray,
    weights: FloatArray,
    min_share: float,
    confidence: FloatArray,
    carried: BoolArray,
) -> None:
    """Fill ``confidence`` (P, J) and ``carried`` (P, S, J) from each person's views as fused.

    joints: (P, S, J, 3) NaN where a view has no position; weights: (P, S, J) the final
    weights. ``1 − Π (1 − clip(w, 0, 1))`` over the views with a position and a positive weight
    (0 where none), and which views hold at least ``min_share`` of a joint's weight (of the
    views with a position).
    """
    size, views, count = weights.shape
    for p in range(size):
        for j in range(count):
            product = 1.0
            usable_total = 0.0
            total = 0.0
            for s in range(views):
                point = joints[p, s, j]
                finite = math.isfinite(point[0]) and math.isfinite(point[1])
                finite = finite and math.isfinite(point[2])
                weight = weights[p, s, j]
                used = weight if finite and weight > 0 else 0.0
                clipped = 0.0 if used < 0.0 else (1.0 if used > 1.0 else used)
                product *= 1.0 - clipped
                usable_total += used
                total += weight if finite else 0.0
            confidence[p, j] = 0.0 if usable_total <= 0 else 1.0 - product
            for s in range(views):
                point = joints[p, s, j]
                finite = math.isfinite(point[0]) and math.isfinite(point[1])
                finite = finite and math.isfinite(point[2])
                final = weights[p, s, j] if finite else 0.0
                share = final / total if total > 0 else 0.0
                carried[p, s, j] = share >= min_share and final > 0


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now."""
    views = np.zeros((2, 25, 3))
    states = np.zeros((2, 25), np.uint8)
    body_weights(views, states, np.ones((2, 24)), np.ones((2, 25)), FusionSettings())
    joint_confidence(views[None], np.ones((1, 2, 25)))
