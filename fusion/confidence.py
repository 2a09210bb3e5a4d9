"""Body-based confidence of each joint of each view: bone length, range of motion, facing, distance.

Report A (``shared/papers.md``) multiplies body-based terms into the tracking-state weight of
each joint of each view. Everything here is a pure function on arrays;
:mod:`skelfuse.fusion.pipeline` combines the terms (:func:`body_weights`, :func:`view_factors`)
and :mod:`skelfuse.fusion.weighted` fuses with them. :func:`joint_confidence` is the one place the
confidence apps receive with each fused joint is computed.

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
SpineBase along :data:`PARENTS` (:func:`propagate`): a doubtful elbow makes wrist, hand, hand tip
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

Facing and distance
-------------------
A Kinect v2 is best when the person faces it at 1.5–3 m: it assumes the person faces it, turns
the skeleton towards itself by about half the person's yaw relative to it (conventions.md §5),
and its depth noise grows with distance. ``facing = floor + (1 − floor)·((1 + cos θ)/2)^p``,
θ the angle between the person's forward direction and the direction to the sensor (1 facing
it, 0.5^p side-on, ``floor`` from behind); ``distance = exp(−(d_out / scale)²)`` with ``d_out``
how far the horizontal distance is outside the best band.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_stages
from skelfuse.fusion.anatomy import (
    CHAIN_LEVELS,
    CHAIN_ORDER,
    HORIZONTAL,
    rom_factors_and_forward,
    unit,
)
from skelfuse.fusion.points import finite_points
from skelfuse.fusion.priors import SensorPrior, distinct_priors
from skelfuse.fusion.settings import FusionSettings
from skelfuse.protocol.skeleton import BONES, PARENTS, JointId

FloatArray = npt.NDArray[np.float64]
J = JointId


_BONE_CHILD: Final = np.array([child for _, child in BONES])
_BONE_PARENT: Final = np.array([parent for parent, _ in BONES])
_CHAIN: Final = (np.array(CHAIN_ORDER[1:]), np.array([PARENTS[j] for j in CHAIN_ORDER[1:]]))
BODY_TABLES: Final = ((_BONE_PARENT, _BONE_CHILD), _CHAIN)
"""The body terms' index tables: each bone's parent and child joint; the joints below
SpineBase, parents first, and their parents (what the compiled body terms take)."""
"""The joints below SpineBase, parents first, and their parents (the compiled propagate)."""


def propagate(local: npt.ArrayLike) -> FloatArray:
    """Multiply per-joint factors outward along the kinematic chain from SpineBase.

    Args:
        local: (..., 25) factor of each joint alone (its bone, its angle).

    Returns:
        (..., 25) float64: each joint's factor times all its ancestors' factors.
    """
    out = np.array(local, dtype=np.float64, copy=True)
    for children, parents in CHAIN_LEVELS:
        out[..., children] *= out[..., parents]
    return out


def bone_length_factors(
    views: npt.ArrayLike, reference: npt.ArrayLike, scale_m: float
) -> FloatArray:
    """Local bone-length factor of each joint (not yet propagated).

    Args:
        views: (S, 25, 3) joints, metres.
        reference: (24,) reference length of each bone (metres), NaN where unknown; or (S, 24),
            one row per view.
        scale_m: length difference that divides the factor by e.

    Returns:
        (S, 25) float64 in (0, 1]: ``exp(−|l − l_ref| / scale)`` on each bone's child joint;
        1 on SpineBase and wherever the length or the reference is unknown.
    """
    joints = np.asarray(views, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    lengths = np.linalg.norm(joints[:, _BONE_CHILD] - joints[:, _BONE_PARENT], axis=-1)
    diff = np.abs(lengths - ref)
    factor_bones = np.where(np.isfinite(diff), np.exp(-diff / scale_m), 1.0)
    out = np.ones(joints.shape[:2])
    out[:, _BONE_CHILD] = factor_bones
    return out


# --- body frame and angles ----------------------------------------------------------------------


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


def facing_cosines(
    facing: npt.ArrayLike, body_position: npt.ArrayLike, sensor_positions: npt.ArrayLike
) -> FloatArray:
    """cos θ per view: θ between the person's facing and the horizontal direction to the sensor.

    Args:
        facing: (3,) horizontal unit vector (NaN if unknown).
        body_position: (3,) a point on the person (SpineBase), metres, world.
        sensor_positions: (S, 3) sensor positions, metres, world (NaN if unknown).

    Returns:
        (S,) float64 in [−1, 1]; NaN where unknown.
    """
    sensors = np.asarray(sensor_positions, dtype=np.float64)
    if kernels.enabled() and sensors.ndim == 2:  # the same bits in one compiled loop
        one, at = np.asarray(facing, dtype=np.float64), np.asarray(body_position, dtype=np.float64)
        return kernels_stages.facing_cosines(  # (broadcast only when needed: µs a call)
            one if one.shape == sensors.shape else np.broadcast_to(one, sensors.shape),
            at if at.shape == sensors.shape else np.broadcast_to(at, sensors.shape),
            sensors,
        )
    to_sensor = sensors - np.asarray(body_position)
    to_sensor = to_sensor * HORIZONTAL
    cos: FloatArray = (unit(to_sensor) * np.asarray(facing, dtype=np.float64)).sum(-1)
    return cos


def facing_factors(
    cosines: npt.ArrayLike, power: float, floor: float, back_factor: float = 1.0
) -> FloatArray:
    """Facing term per view, (S,) in (0, 1]; 1 where the facing is unknown (NaN).

    ``floor + (1 − floor)·|cos θ|^power``, times ``back_factor`` when the sensor is behind the
    person (cos θ < 0). A sensor's own yaw bias grows with how far the person is turned from
    *its axis*, front or back (a view from behind, once its labels are swapped back by
    :mod:`fusion.mirror`, is fitted as a front view: conventions.md §5), so side views are the
    least trusted; a back view also hides the arms in front of the body, hence ``back_factor``.
    """
    cos = np.asarray(cosines, dtype=np.float64)
    if kernels.enabled() and cos.ndim == 1:  # the same bits in one compiled loop
        return kernels_stages.facing_factors(cos, power, floor, back_factor)
    value = floor + (1.0 - floor) * np.abs(np.clip(cos, -1.0, 1.0)) ** power
    value = np.where(cos < 0, value * back_factor, value)
    return np.where(np.isfinite(cos), value, 1.0)


def distance_factors(
    body_position: npt.ArrayLike,
    sensor_positions: npt.ArrayLike,
    best_m: tuple[float, float],
    scale_m: float,
) -> FloatArray:
    """Distance term per view, (S,) in (0, 1]: 1 inside ``best_m``, Gaussian fall-off outside.

    Args:
        body_position: (3,) SpineBase, metres, world.
        sensor_positions: (S, 3) metres, world; NaN rows give 1.
    """
    delta = np.asarray(sensor_positions, dtype=np.float64) - np.asarray(body_position)
    distance = np.linalg.norm(delta * HORIZONTAL, axis=-1)
    outside = np.maximum(best_m[0] - distance, 0.0) + np.maximum(distance - best_m[1], 0.0)
    return np.where(np.isfinite(outside), np.exp(-((outside / scale_m) ** 2)), 1.0)


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
    if kernels.enabled():  # the same bits in one compiled loop; the code below is the reference
        return kernels_stages.confidence_and_carriers(joints, weights, 0.0)[0]
    usable = finite_points(joints) & (weights > 0)
    w = np.where(usable, weights, 0.0)
    confidence: FloatArray = 1.0 - np.prod(1.0 - np.clip(w, 0.0, 1.0), axis=1)
    confidence[w.sum(axis=1) <= 0] = 0.0
    return confidence


def body_weights(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    references: FloatArray | None,
    rom: FloatArray | None,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None = None,
) -> FloatArray:
    """Each joint's weight from its view alone: tracking state × the body terms, propagated.

    ``state weight × propagate(bone length × range of motion)``: a joint is doubted as much as
    its own bone and angle and every joint between it and SpineBase (module docstring). With
    ``priors`` each view uses its sensor's state table, range-of-motion scale, noise
    (``× 1/noise_scale²``) and, for a fixed-length body model, no bone-length term
    (fusion/priors.py); a Kinect v2 prior gives the same numbers as none.

    Args:
        joints: (N, 25, 3) views, metres, world frame, labels already corrected.
        states: (N, 25) TrackingState values.
        references: (N, 24) the reference bone lengths of each view's person (metres, NaN:
            unknown), or None when no person has any.
        rom: (N, 25) range-of-motion factors already computed (by the mirror step), or None.
        settings: which terms are on, and their scales.
        priors: (N,) each view's sensor prior, or None: the settings' values for every view.

    Returns:
        (N, 25) float64 weights ≥ 0.
    """
    s = settings
    # Each distinct prior's values once, gathered per view (the same floats as view by view).
    distinct, of_view = distinct_priors(priors) if priors is not None else ([], None)
    if all(as_settings(p, s) for p in distinct):  # Kinect v2 alike: the shared table's floats
        of_view = None
    if of_view is None and kernels.enabled():  # the same bits in one compiled loop
        with_rom = s.use_range_of_motion
        return kernels_stages.body_weights(
            joints,
            states,
            s.state_weights,
            references if s.use_bone_length else None,
            (rom if rom is not None else range_of_motion_factors(joints, s.rom_scale_deg))
            if with_rom
            else None,
            s.bone_length_scale_m,
            (_BONE_PARENT, _BONE_CHILD),
            _CHAIN,
        )
    if of_view is None:
        weights = state_weights(states, s.state_weights)
    else:  # each view's own table, gathered (the same floats as the shared table for v2)
        tables = np.array([p.table(s) for p in distinct], dtype=np.float64)[of_view]
        weights = tables[np.arange(len(tables))[:, None], np.asarray(states, dtype=np.intp)]
    local = np.ones(joints.shape[:2])
    if s.use_bone_length and references is not None:
        bones = bone_length_factors(joints, references, s.bone_length_scale_m)
        if of_view is not None:  # a fixed-length body model's offset is not noise
            fixed = np.array([p.fixed_bone_lengths for p in distinct])[of_view]
            bones = np.where(fixed[:, None], 1.0, bones)
        local *= bones
    if s.use_range_of_motion:
        rom_local = rom if rom is not None else range_of_motion_factors(joints, s.rom_scale_deg)
        if of_view is not None:  # exp(−e/s)^(1/k) = exp(−e/(k·s)): scale k per view
            k = np.array([p.rom_scale for p in distinct], dtype=np.float64)[of_view]
            if (k != 1.0).any():
                rom_local = np.where(k[:, None] == 1.0, rom_local, rom_local ** (1.0 / k[:, None]))
        local *= rom_local
    out: FloatArray = weights * propagate(local)
    if of_view is not None:
        noise = np.array([p.noise_scale for p in distinct], dtype=np.float64)[of_view]
        if (noise != 1.0).any():  # inverse-variance weighting against a Kinect v2 view
            out = out / (noise**2)[:, None]
    return out


def as_settings(prior: SensorPrior, settings: FusionSettings) -> bool:
    """Whether ``prior`` changes nothing in :func:`body_weights` (the settings' table, no
    fixed-length body model, range-of-motion scale and noise 1)."""
    return (
        tuple(prior.table(settings)) == tuple(settings.state_weights)
        and not prior.fixed_bone_lengths
        and prior.rom_scale == 1.0
        and prior.noise_scale == 1.0
    )


def view_factors(
    cosines: FloatArray,
    body_positions: FloatArray,
    sensor_positions: FloatArray,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None = None,
) -> FloatArray:
    """Each view's factor from where its sensor stands: facing × distance (the ones switched on).

    Args:
        cosines: (N,) :func:`facing_cosines` of each view (NaN: unknown, factor 1).
        body_positions: (N, 3) where each view's person stands (SpineBase), metres, world.
        sensor_positions: (N, 3) each view's sensor, metres, world (NaN rows: unknown).
        priors: (N,) each view's sensor prior (its facing model), or None: the settings'.

    Returns:
        (N,) float64 in (0, 1].
    """
    s = settings
    factors = np.ones(len(cosines))
    if s.use_facing and priors is None:
        factors *= facing_factors(cosines, s.facing_power, s.facing_floor, s.facing_back_factor)
    elif s.use_facing and priors is not None:
        distinct, of_view = distinct_priors(priors)
        models = [p.facing(s) for p in distinct]
        # One call per distinct facing model (a few sensor types): the same arithmetic, hence
        # the same bits, as the shared model for every Kinect v2 view (an element's factor
        # depends on its own cosine alone).
        if len(set(models)) == 1:
            factors *= facing_factors(cosines, *models[0])
        else:
            for model in set(models):
                rows = np.isin(of_view, [i for i, m in enumerate(models) if m == model])
                factors[rows] *= facing_factors(np.asarray(cosines)[rows], *model)
    if s.use_distance:
        factors *= distance_factors(
            body_positions, sensor_positions, s.distance_best_m, s.distance_scale_m
        )
    return factors
