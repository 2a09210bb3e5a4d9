"""How well each view sees: its facing factor, its per-joint reliability and its ray weighting.

**Facing** (each view's factor from where its sensor stands: how frontally the person faces
it). A Kinect v2 is best when the person faces it: it assumes the person faces it and turns the
skeleton towards itself by about half the person's yaw relative to it (conventions.md §5).
``facing = floor + (1 − floor)·|cos θ|^p``, θ the angle between the person's forward direction
and the direction to the sensor (1 facing it or with its back to it, ``floor`` side-on), times
``back_factor`` from behind (:func:`facing_factors`). :func:`view_factors` is one loop compiled
with numba (:func:`view_factor_loop`, the facing factor from :func:`facing_factors_loop`), each
view with its sensor's facing model (:func:`~skelfuse.fusion.confidence.sensor_terms`); ``pow``
is the C library's. :func:`warm_up` compiles the loops (or loads numba's cache) at start, so no
frame waits for a compilation.

**Per-joint view reliability** (:func:`reliability_factors`: how well each view sees each joint,
from the view's geometry). The body terms (:mod:`skelfuse.fusion.confidence`) judge a joint by
its own view's anatomy and the facing term judges a whole view; neither knows that a side view's
*legs and hands* are the worst part of it. A Kinect-style tracker fits a front-facing body and
turns it towards its sensor by a fraction ``lean_fraction`` of the person's yaw relative to the
sensor (the simulator's ``KinectV2Params.facing_bias`` = 0.5, measured on NTU RGB+D;
docs/fusion.md §7). The turn is about the vertical through SpineBase, so a joint at horizontal
distance ``r`` from SpineBase moves by ``2·r·sin(turn / 2)``: nothing at the pelvis, 100–140 mm
at a striding ankle or a hand swung forward in a side view (turn 45°), nothing in a view from
straight in front or behind. That lean, the depth-dependent jitter and self-occlusion by the
trunk add to each joint's own error; each view's joint is then weighed by the inverse of its
expected error variance::

    factor = σ_j² / (σ_j² + lean² + jitter(z)² + hidden·σ_occ²)

relative to the most reliable view of the same person for that joint (the best view gets 1), so
that the confidence apps receive (``joint_confidence``) keeps its scale and a person seen once is
unaffected. ``σ_j`` is the joint's error floor in a frontal view (trunk, limb, extremity).
Shapes: N views (of P persons, ``starts`` giving each person's slice), 25 joints. Positions in
metres, world frame (+Y up). Every factor is in (0, 1]; NaN inputs give 1.

**Ray weighting** (:func:`ray_weighted_mean`: fusion that knows a view's noise is larger along
its sensor's viewing ray than across it). A camera that places a body from its apparent size
(the ``rgb`` sensor type, agent/sources/mono.py) knows well where a joint is across the image
and poorly how far it is: its variance along the ray from the sensor to the joint is ``ratio²``
times that across it (``SensorPrior.depth_noise_ratio``, fusion/priors.py). Treating each view
as a Gaussian with covariance ``σ²·(I + (ratio² − 1)·d·dᵀ)`` (d the unit ray) and its weight w
as 1/σ², the fused joint is the information-weighted mean::

    x = (Σ w·A)⁻¹ · Σ w·A·x_view,   A = I + (1/ratio² − 1)·d·dᵀ  (the inverse covariance shape)

With every ratio 1 this is :func:`fusion.weigh.weighted_mean`; with one view it is that view.
A second view from another direction then fixes the camera's depth while the camera keeps its
say across the image. Only persons with at least one such view are recomputed, so fusion of
Kinect-only rigs keeps its exact bits (the golden replay digests). Shapes as in
:mod:`fusion.weigh`: P persons, S views each (padded with NaN views of weight 0), J joints;
metres, world frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.confidence import sensor_terms
from skelfuse.fusion.points import finite_points
from skelfuse.fusion.priors import PRIORS, SensorPrior
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@jit
def cosines_loop(
    facings: FloatArray, bodies: FloatArray, sensor_positions: FloatArray, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with ``confidence.facing_cosines`` of each view: its person's facing
    (N, 3) against the horizontal unit direction from where it stands (N, 3) to its sensor
    (N, 3). Sums over three components as numpy's: from 0, one after the other."""
    for v in range(len(out)):
        t0 = (sensor_positions[v, 0] - bodies[v, 0]) * 1.0
        t1 = (sensor_positions[v, 1] - bodies[v, 1]) * 0.0
        t2 = (sensor_positions[v, 2] - bodies[v, 2]) * 1.0
        norm = math.sqrt(0.0 + t0 * t0 + t1 * t1 + t2 * t2)
        out[v] = (
            0.0 + t0 / norm * facings[v, 0] + t1 / norm * facings[v, 1] + t2 / norm * facings[v, 2]
        )


@jit
def _power(x: float, exponent: float) -> float:
    """``array ** exponent`` as numpy computes it for a scalar exponent: its fast paths for 2,
    0.5, 1, −1 and 0 (square, sqrt, copy, reciprocal, ones), else the C library's pow."""
    if exponent == 2.0:
        return x * x
    if exponent == 0.5:
        return math.sqrt(x)
    if exponent == 1.0:
        return x
    if exponent == -1.0:
        return 1.0 / x
    if exponent == 0.0:
        return 1.0
    result: float = x**exponent
    return result


@jit
def facing_factors_loop(
    cosines: FloatArray, power: float, floor: float, back_factor: float, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with ``confidence.facing_factors``: ``floor + (1 − floor)·|cos|^power``
    (× ``back_factor`` behind the person), 1 where the cosine is unknown."""
    for v in range(len(out)):
        cos = cosines[v]
        if not math.isfinite(cos):
            out[v] = 1.0
            continue
        clipped = -1.0 if cos < -1.0 else (1.0 if cos > 1.0 else cos)
        value = floor + (1.0 - floor) * _power(abs(clipped), power)
        out[v] = value * back_factor if cos < 0 else value


def facing_cosines(
    facing: npt.ArrayLike, body_position: npt.ArrayLike, sensor_positions: npt.ArrayLike
) -> FloatArray:
    """cos θ per view: θ between the person's facing and the horizontal direction to the sensor.

    Args:
        facing: (..., 3) horizontal unit vectors (NaN if unknown), e.g. (3,) one person's.
        body_position: (..., 3) a point on the person (SpineBase), metres, world.
        sensor_positions: (..., 3) sensor positions, metres, world (NaN if unknown), e.g.
            (S, 3); the three broadcast together.

    Returns:
        (...) float64 in [−1, 1], the broadcast shape without its last axis; NaN where unknown.
    """
    facings = np.asarray(facing, dtype=np.float64)
    bodies = np.asarray(body_position, dtype=np.float64)
    sensors = np.asarray(sensor_positions, dtype=np.float64)
    shape = np.broadcast_shapes(facings.shape, bodies.shape, sensors.shape)
    one, at, to = (  # (broadcast only when needed: µs a call)
        plain((a if a.shape == shape else np.broadcast_to(a, shape)).reshape(-1, 3))
        for a in (facings, bodies, sensors)
    )
    out = np.empty(shape[:-1])
    cosines_loop(one, at, to, out.reshape(-1))
    return out


def facing_factors(
    cosines: npt.ArrayLike, power: float, floor: float, back_factor: float = 1.0
) -> FloatArray:
    """Facing term per view, in (0, 1] with the shape of ``cosines``; 1 where the facing is
    unknown (NaN).

    ``floor + (1 − floor)·|cos θ|^power``, times ``back_factor`` when the sensor is behind the
    person (cos θ < 0). A sensor's own yaw bias grows with how far the person is turned from
    *its axis*, front or back (a view from behind, once its labels are swapped back by
    :mod:`fusion.mirror`, is fitted as a front view: conventions.md §5), so side views are the
    least trusted; a back view also hides the arms in front of the body, hence ``back_factor``.
    """
    cos = plain(cosines)
    out = np.empty(cos.shape)
    facing_factors_loop(
        cos.reshape(-1), float(power), float(floor), float(back_factor), out.reshape(-1)
    )
    return out


def view_factors(
    cosines: FloatArray,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None = None,
) -> FloatArray:
    """Each view's facing factor, each with its sensor type's facing model.

    Args:
        cosines: (N,) :func:`facing_cosines` of each view (NaN: unknown, factor 1).
        settings: the facing model of sensors without a prior of their own.
        priors: (N,) each view's sensor prior (its facing model), or None: the settings'.

    Returns:
        (N,) float64 in (0, 1].
    """
    cos = plain(cosines)
    terms, of_view = sensor_terms(settings, priors, len(cos))
    out = np.empty(len(cos))
    view_factor_loop(cos, terms, plain(of_view, np.intp), out)
    return out


@jit
def view_factor_loop(
    cosines: FloatArray, terms: FloatArray, of_view: IntArray, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with each view's facing factor (:func:`view_factors`).

    cosines: (N,) facing cosines (NaN: factor 1); terms, of_view: :func:`sensor_terms` (the
    facing model in columns 6–8).
    """
    for v in range(len(out)):
        row = terms[of_view[v]]
        facing_factors_loop(cosines[v : v + 1], row[6], row[7], row[8], out[v : v + 1])


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now."""
    views = np.zeros((2, 25, 3))
    view_factors(np.zeros(2), FusionSettings())
    facing_factors(facing_cosines(views[0], views[1], views[0]), 2.0, 0.1, 0.5)


# --- Per-joint view reliability: how well each view sees each joint, from its geometry -----------


J = JointId

TRUNK_JOINTS: Final = (J.SPINE_BASE, J.SPINE_MID, J.NECK, J.HEAD, J.SPINE_SHOULDER, J.HIP_LEFT,
                       J.HIP_RIGHT, J.SHOULDER_LEFT, J.SHOULDER_RIGHT)  # fmt: skip
EXTREMITY_JOINTS: Final = (J.HAND_LEFT, J.HAND_RIGHT, J.HAND_TIP_LEFT, J.HAND_TIP_RIGHT,
                           J.THUMB_LEFT, J.THUMB_RIGHT, J.FOOT_LEFT, J.FOOT_RIGHT)  # fmt: skip
TRUNK_RADIUS_M: Final = 0.13
"""The trunk's radius for self-occlusion (the simulator's trunk capsule)."""
_HORIZONTAL: Final = np.array([1.0, 0.0, 1.0])
_INFERRED: Final = int(TrackingState.INFERRED)
"""A plain int: numpy compares a uint8 array with an IntEnum member 5× slower."""


def error_floor(errors_m: tuple[float, float, float]) -> FloatArray:
    """(25,) each joint's error in a frontal view: ``errors_m`` = (trunk, limb, extremity) m."""
    floor = np.full(JOINT_COUNT, errors_m[1])
    floor[list(TRUNK_JOINTS)] = errors_m[0]
    floor[list(EXTREMITY_JOINTS)] = errors_m[2]
    return floor


def lean_errors(joints: FloatArray, cosines: FloatArray, lean_fraction: float) -> FloatArray:
    """How far each joint is displaced by its view leaning towards its sensor, (N, 25) metres.

    The view's turn is ``lean_fraction · asin|sin θ|`` (θ from :func:`~skelfuse.fusion.
    confidence.facing_cosines`: 0 in front, π behind, whose view is fitted as a front view once
    its labels are swapped back), and a joint at horizontal distance r from SpineBase moves by
    ``2·r·sin(turn / 2)``.

    Args:
        joints: (N, 25, 3) views, metres, world frame.
        cosines: (N,) facing cosines, NaN where unknown (no lean assumed).
        lean_fraction: share of the yaw relative to the sensor a view turns by (0 … 1).

    Returns:
        (N, 25) float64 ≥ 0; 0 where the joint or the facing is unknown.
    """
    cos = np.clip(np.asarray(cosines, dtype=np.float64), -1.0, 1.0)
    turn = lean_fraction * np.arcsin(np.sqrt(1.0 - cos**2))
    offsets = (joints - joints[:, J.SPINE_BASE : J.SPINE_BASE + 1]) * _HORIZONTAL
    radius = np.linalg.norm(offsets, axis=-1)
    lean: FloatArray = 2.0 * radius * np.sin(turn / 2.0)[:, None]
    return np.nan_to_num(lean, nan=0.0)


def hidden_by_trunk(joints: FloatArray, sensor_positions: FloatArray) -> npt.NDArray[np.bool_]:
    """Whether the person's own trunk stands between each joint and its view's sensor, (N, 25).

    The trunk is a vertical cylinder of :data:`TRUNK_RADIUS_M` around SpineMid from SpineBase to
    SpineShoulder high; a joint at that height is hidden when it is farther from the sensor than
    the trunk's axis and, seen from above, the sight line to it passes through the cylinder.
    The trunk's own joints are never hidden (they are on its surface).

    Args:
        joints: (N, 25, 3) views, metres, world frame.
        sensor_positions: (N, 3) each view's sensor, metres, world (NaN rows: nothing hidden).
    """
    flat = joints * _HORIZONTAL
    sensor = (np.asarray(sensor_positions, dtype=np.float64) * _HORIZONTAL)[:, None, :]
    centre = flat[:, J.SPINE_MID : J.SPINE_MID + 1]
    sight = flat - sensor  # sensor → joint
    length = np.linalg.norm(sight, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        along = ((centre - sensor) * sight).sum(-1) / length  # the centre's depth on the line
        closest = np.linalg.norm(centre - sensor - sight * (along / length)[..., None], axis=-1)
        # The trunk spans SpineBase to SpineShoulder in height; the sensors stand about as high
        # as the trunk, so sight lines are close to horizontal and the height test suffices.
        high = joints[..., 1] <= joints[:, J.SPINE_SHOULDER : J.SPINE_SHOULDER + 1, 1]
        low = joints[..., 1] >= joints[:, J.SPINE_BASE : J.SPINE_BASE + 1, 1]
        hidden: npt.NDArray[np.bool_] = (
            (along < length) & (closest < TRUNK_RADIUS_M) & (along > 0) & high & low
        )
    hidden[:, list(TRUNK_JOINTS)] = False
    return hidden


def reliability_factors(
    joints: FloatArray,
    cosines: FloatArray,
    sensor_positions: FloatArray,
    starts: list[int],
    lean_fraction: float,
    errors_m: tuple[float, float, float],
    jitter_per_m2: float,
    occlusion_m: float,
    states: npt.NDArray[np.uint8] | None = None,
) -> FloatArray:
    """Each view's per-joint reliability relative to its person's best view (module docstring).

    Args:
        joints: (N, 25, 3) views, metres, world frame, labels corrected.
        cosines: (N,) facing cosines (NaN: unknown).
        sensor_positions: (N, 3) each view's sensor, metres, world.
        starts: (P + 1,) each person's first view index, then N.
        lean_fraction: share of the yaw relative to the sensor a view turns by.
        errors_m: the error floor of trunk, limb and extremity joints in a frontal view, metres.
        jitter_per_m2: jitter growth with the squared distance to the sensor, metres per m².
        occlusion_m: the extra error of a hidden joint (by the trunk, or reported Inferred),
            metres.
        states: (N, 25) TrackingState values; Inferred joints count as hidden. None: geometry
            alone.

    Returns:
        (N, 25) float64 in (0, 1]: 1 for the best view of each joint of each person.
    """
    floor2 = error_floor(errors_m)[None, :] ** 2
    lean = lean_errors(joints, cosines, lean_fraction)
    depth = np.linalg.norm(joints - np.asarray(sensor_positions)[:, None, :], axis=-1)
    jitter = np.nan_to_num(jitter_per_m2 * depth**2, nan=0.0)
    hidden = hidden_by_trunk(joints, sensor_positions)
    if states is not None:
        hidden |= np.asarray(states) == _INFERRED
    variance = floor2 + lean**2 + jitter**2 + np.where(hidden, occlusion_m**2, 0.0)
    raw = floor2 / variance
    counts = np.diff(starts)
    if not (counts > 1).any():
        return np.ones_like(raw)
    # Each person's best view per joint, all persons at once (a maximum: exact in any order);
    # a person seen by one view keeps 1.
    person_of = np.repeat(np.arange(len(counts)), counts)
    first = np.minimum(starts[:-1], len(raw) - 1)  # (a person without views gets no rows)
    best = np.maximum.reduceat(raw, first, axis=0)[person_of]
    factors: FloatArray = np.where((counts > 1)[person_of][:, None], raw / best, 1.0)
    return factors


# --- Ray weighting: a view's noise larger along its sensor's viewing ray than across it ----------


_RATIO_OF: Final = {name: p.depth_noise_ratio for name, p in PRIORS.items()}
_STRETCHED: Final = frozenset(name for name, ratio in _RATIO_OF.items() if ratio != 1.0)
"""The sensor types whose views have a ratio other than 1 (unknown types count as 1)."""


def depth_noise_ratios(sensor_types: Sequence[str]) -> FloatArray | None:
    """(N,) each view's ``depth_noise_ratio`` from its sensor type's prior, or None when every
    view's is 1 (nothing to do; unknown types count as Kinect v2: 1)."""
    if _STRETCHED.isdisjoint(sensor_types):  # the usual rig: a set test, not a loop (5 µs)
        return None
    return np.array([_RATIO_OF.get(t, 1.0) for t in sensor_types], dtype=np.float64)


def ray_weighted_mean(
    joints: FloatArray,
    weights: FloatArray,
    sensors: FloatArray,
    ratios: FloatArray,
    fused: FloatArray | None = None,
) -> FloatArray:
    """Each person's joints fused with each view's noise stretched along its sensor's ray.

    Args:
        joints: (P, S, J, 3) views; NaN where a view has no position.
        weights: (P, S, J) non-negative (inverse variance across the ray).
        sensors: (P, S, 3) where each view's sensor stands; NaN when unknown (that view then
            counts as the same in every direction).
        ratios: (P, S) each view's noise along the ray over across it, >= 1 (1: isotropic).
        fused: (P, J, 3) the plain weighted mean already computed, or None; persons without a
            ratio other than 1 keep its values unchanged (the same bits).

    Returns:
        (P, J, 3) float64; NaN where no view has a position with a positive weight.

    Raises:
        ValueError: on a ratio below 1 or not finite.
    """
    if not (np.isfinite(ratios).all() and (ratios >= 1.0).all()):
        raise ValueError(f"depth noise ratios must be finite and >= 1, got {ratios}")
    out = np.full(joints.shape[0:1] + joints.shape[2:], np.nan) if fused is None else fused.copy()
    persons = np.flatnonzero((ratios != 1.0).any(axis=1)) if fused is not None else None
    if persons is not None and len(persons) == 0:
        return out
    pick = slice(None) if persons is None else persons
    x, w, s, r = joints[pick], weights[pick], sensors[pick], ratios[pick]
    usable = finite_points(x) & (w > 0)
    w = np.where(usable, w, 0.0)
    x = np.where(usable[..., None], x, 0.0)
    ray = x - s[:, :, None, :]
    length = np.linalg.norm(ray, axis=-1, keepdims=True)
    known = np.isfinite(length) & (length > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(known, ray / length, 0.0)  # (P, S, J, 3) unit rays, 0 where unknown
    shrink = (1.0 / r**2 - 1.0)[:, :, None] * w  # (P, S, J): w·(1/ratio² − 1), <= 0
    total = w.sum(axis=1)  # (P, J)
    info = total[..., None, None] * np.eye(3) + np.einsum("psj,psja,psjb->pjab", shrink, d, d)
    along = (d * x).sum(axis=-1)  # (P, S, J) each view's position along its own ray
    rhs = (w[..., None] * x).sum(axis=1) + (shrink[..., None] * d * along[..., None]).sum(axis=1)
    seen = total > 0
    result = np.full(rhs.shape, np.nan)
    result[seen] = np.linalg.solve(info[seen], rhs[seen][..., None])[..., 0]
    out[pick] = result
    return out
