"""Mirrored views: detect a view whose left and right labels are swapped, before fusion.

A Kinect v2 assumes the person faces it. Seen from behind, it fits a front-facing body to the
person's back and reports it with left and right swapped, still Tracked, so tracking-state
weights cannot see it (docs/benchmarks.md, first version). Every view of one person therefore
gets a labelling, as reported (0) or swapped back with :data:`MIRROR_PERMUTATION` (1), chosen
jointly for all of the person's views by minimising

- **agreement between views**: Σ over pairs of the mean distance between their left/right joints
  under the two labellings (metres);
- **agreement with the track**: ``track_weight`` × the mean distance of each labelled view to the
  person's previous fused skeleton (when the person already has one): a sensor that flips its
  labels as the person turns away is caught by the jump;
- **geometry**: where the person faces (from the track, or from the candidate labelling itself
  at birth) against the direction to each sensor: a view kept as reported while its sensor is
  behind the person costs ``geometry_weight × (−cos θ)``, a view swapped while its sensor is in
  front ``geometry_weight × cos θ``. This also breaks the tie that pairwise agreement leaves
  (swapping every view agrees as well as swapping none) only when the person faces one sensor
  more than the others;
- **anatomy**: ``anatomy_weight_m`` × Σ over joints of (1 − the range-of-motion factor) of each
  labelled view: with left and right swapped, the body's forward axis is reversed, so bent knees
  look hyperextended and feet point backwards. This is what settles the labelling of a new
  person and of a person all sensors see from behind. It assumes, as the simulator does, that
  a sensor seeing the back reports where the knees and feet really are, only with swapped
  labels (the depth image shows them; the body-part classifier gets the side wrong);
- **hysteresis**: ``hysteresis`` for changing a view's labelling from the previous step, and a
  small prior for reporting a view as mirrored at all.

All 2^S combinations are scored at once (S ≤ 10 sensors per person; 3 views: 8 combinations).
Pure functions on arrays; the per-(sensor, body) memory for the hysteresis lives in the tracker.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION
from server.confidence import body_frame, facing_direction, range_of_motion_factors

FloatArray = npt.NDArray[np.float64]

PERMUTATION: Final = np.array(MIRROR_PERMUTATION)
LATERAL_JOINTS: Final = np.array([j for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] != j])
"""The 20 joints that have a left or right side."""
MAX_VIEWS: Final = 10
SWAP_PRIOR_M: Final = 0.01
"""Cost of calling a view mirrored at all: sensors are right more often than not."""


def labellings(views: npt.ArrayLike) -> FloatArray:
    """Both labellings of each view: (S, 2, 25, 3), index 1 with left and right swapped."""
    v = np.asarray(views, dtype=np.float64)
    return np.stack([v, v[:, PERMUTATION]], axis=1)


def _mean_distance(a: FloatArray, b: FloatArray) -> FloatArray:
    """Mean distance over the lateral joints both have; 0 where they share none.

    a, b: broadcastable (..., 25, 3) arrays. Returns (...).
    """
    d = np.linalg.norm(a[..., LATERAL_JOINTS, :] - b[..., LATERAL_JOINTS, :], axis=-1)
    finite = np.isfinite(d)
    count = finite.sum(-1)
    total = np.where(finite, d, 0.0).sum(-1)
    result: FloatArray = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return result


def choose_labelling(
    views: npt.ArrayLike,
    sensor_positions: npt.ArrayLike,
    reference: npt.ArrayLike | None = None,
    previous: npt.ArrayLike | None = None,
    *,
    geometry_weight_m: float = 0.15,
    hysteresis_m: float = 0.05,
    track_weight: float = 1.0,
    anatomy_weight_m: float = 0.1,
    rom_scale_deg: float = 15.0,
) -> npt.NDArray[np.bool_]:
    """Which views of one person are mirrored.

    Args:
        views: (S, 25, 3) one person's views, metres, world frame, NaN where unknown.
        sensor_positions: (S, 3) where each view's sensor stands (NaN rows: unknown).
        reference: (25, 3) the person's previous fused skeleton, or None for a new person.
        previous: (S,) previous decision per view: 1 mirrored, 0 not, −1 (or None) unknown.
        geometry_weight_m, hysteresis_m, track_weight, anatomy_weight_m: see the module
            docstring; ``rom_scale_deg`` as in :func:`range_of_motion_factors`.

    Returns:
        (S,) bool, True where the view should be swapped back before fusion.

    Raises:
        ValueError: on more than :data:`MAX_VIEWS` views or mismatched shapes.
    """
    v = np.asarray(views, dtype=np.float64)
    n = v.shape[0]
    if n == 0:
        return np.zeros(0, dtype=bool)
    if n > MAX_VIEWS or v.shape[1:] != (JOINT_COUNT, 3):
        raise ValueError(f"expected (S ≤ {MAX_VIEWS}, 25, 3) views, got {v.shape}")
    sensors = np.asarray(sensor_positions, dtype=np.float64).reshape(n, 3)
    both = labellings(v)  # (S, 2, 25, 3)
    combos = ((np.arange(2**n)[:, None] >> np.arange(n)[None, :]) & 1).astype(np.intp)  # (C, S)
    cost = np.zeros(len(combos))

    # Agreement between views: D[i, j, a, b].
    if n > 1:
        pair = _mean_distance(both[:, None, :, None], both[None, :, None, :])  # (S, S, 2, 2)
        for i in range(n):
            for j in range(i + 1, n):
                cost += pair[i, j, combos[:, i], combos[:, j]]

    # Agreement with the track.
    ref = None if reference is None else np.asarray(reference, dtype=np.float64)
    if ref is not None:
        to_ref = _mean_distance(both, ref[None, None])  # (S, 2)
        cost += track_weight * to_ref[np.arange(n)[None, :], combos].sum(axis=1)

    # Geometry: where the person faces against where each sensor is.
    body = np.nanmean(v[:, 0], axis=0) if np.isfinite(v[:, 0]).any() else np.full(3, np.nan)
    to_sensor = (sensors - body) * np.array([1.0, 0.0, 1.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        to_sensor /= np.linalg.norm(to_sensor, axis=-1, keepdims=True)
    facing_ref = None if ref is None else facing_direction(ref)
    if facing_ref is not None and np.isfinite(facing_ref).all():
        facing = np.broadcast_to(facing_ref, (len(combos), 3))
    else:
        # From the candidate labelling itself: the sum of the labelled views' forward axes.
        _, _, forward = body_frame(both.reshape(-1, JOINT_COUNT, 3))
        forward = np.nan_to_num(forward.reshape(n, 2, 3) * np.array([1.0, 0.0, 1.0]))
        facing = forward[np.arange(n)[None, :], combos].sum(axis=1)  # (C, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            facing = facing / np.linalg.norm(facing, axis=-1, keepdims=True)
    cos = np.nan_to_num(facing @ to_sensor.T)  # (C, S), 0 where unknown
    geometry = np.where(combos == 0, np.maximum(-cos, 0.0), np.maximum(cos, 0.0))
    cost += geometry_weight_m * geometry.sum(axis=1)

    # Anatomy: a labelling under which knees bend forwards and feet point backwards is wrong.
    if anatomy_weight_m > 0:
        factors = range_of_motion_factors(both.reshape(-1, JOINT_COUNT, 3), rom_scale_deg)
        anatomy = (1.0 - factors).sum(axis=1).reshape(n, 2)
        cost += anatomy_weight_m * anatomy[np.arange(n)[None, :], combos].sum(axis=1)

    # Hysteresis and the prior.
    cost += SWAP_PRIOR_M * combos.sum(axis=1)
    if previous is not None:
        prev = np.asarray(previous).reshape(n)
        known = prev >= 0
        cost += hysteresis_m * ((combos != prev[None, :]) & known[None, :]).sum(axis=1)

    best: npt.NDArray[np.bool_] = combos[int(np.argmin(cost))].astype(bool)
    return best
