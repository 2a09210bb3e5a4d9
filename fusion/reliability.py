"""Per-joint view reliability: how well each view sees each joint, from the view's geometry.

The body terms (:mod:`skelfuse.fusion.confidence`) judge a joint by its own view's anatomy and
the facing term judges a whole view; neither knows that a side view's *legs and hands* are the
worst part of it. A Kinect-style tracker fits a front-facing body and turns it towards its
sensor by a fraction ``lean_fraction`` of the person's yaw relative to the sensor (the
simulator's ``KinectV2Params.facing_bias`` = 0.5, measured on NTU RGB+D; docs/fusion.md §7).
The turn is about the vertical through SpineBase, so a joint at horizontal distance ``r`` from
SpineBase moves by ``2·r·sin(turn / 2)``: nothing at the pelvis, 100–140 mm at a striding ankle
or a hand swung forward in a side view (turn 45°), nothing in a view from straight in front or
behind. That lean, the depth-dependent jitter and self-occlusion by the trunk add to each joint's
own error; each view's joint is then weighed by the inverse of its expected error variance::

    factor = σ_j² / (σ_j² + lean² + jitter(z)² + hidden·σ_occ²)

relative to the most reliable view of the same person for that joint (the best view gets 1), so
that the confidence apps receive (``joint_confidence``) keeps its scale and a person seen once is
unaffected. ``σ_j`` is the joint's error floor in a frontal view (trunk, limb, extremity).

Shapes: N views (of P persons, ``starts`` giving each person's slice), 25 joints. Positions in
metres, world frame (+Y up). Every factor is in (0, 1]; NaN inputs give 1.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState

J = JointId
FloatArray = npt.NDArray[np.float64]

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
