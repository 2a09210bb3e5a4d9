"""The walking check: a person who walks backwards for long is taken as mirrored as a whole.

A person born mirrored (every sensor seeing them from the side or behind) stays mirrored, since
each view is labelled to agree with them and their own facing, reversed, makes the back views
look like front ones. People walk forwards (docs/fusion.md §5). The check for every person at
once is one loop compiled with numba (:func:`walking_backwards_now`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_direction
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]


def walking_backwards(
    joints: FloatArray,
    velocity: FloatArray,
    t_s: float,
    backward_since_s: float | None,
    settings: FusionSettings,
    facing: FloatArray | None = None,
) -> tuple[bool, float | None]:
    """Whether a person has walked backwards long enough to be taken as mirrored as a whole:
    at ``mirror.walk_min_speed_mps`` or more for ``mirror.walk_check_s``.

    Args:
        joints: (25, 3) the person's fused skeleton, metres, world; velocity: (3,) m/s.
        backward_since_s: when the current stretch of walking backwards began, or None.
        facing: the skeleton's ``facing_direction`` (3,) if the caller has it (one batched
            call for every person is cheaper); None: worked out here.

    Returns:
        (swap now, when the stretch began or None): after a swap the stretch starts over.
    """
    s = settings
    if s.mirror.walk_check_s <= 0 or not s.mirror.enabled:
        return False, backward_since_s
    if facing is None:
        facing = facing_direction(joints)
    velocities = np.asarray(velocity, dtype=np.float64).reshape(1, 3)
    facings = np.asarray(facing, dtype=np.float64).reshape(1, 3)
    if not walking_backwards_now(velocities, facings, s.mirror.walk_min_speed_mps)[0]:
        return False, None
    if backward_since_s is None:
        return False, t_s
    if t_s - backward_since_s < s.mirror.walk_check_s:
        return False, backward_since_s
    return True, None


def walking_backwards_now(
    velocities: FloatArray, facings: FloatArray, min_speed: float
) -> npt.NDArray[np.bool_]:
    """(P,) whether each of P persons walks backwards now, before :func:`walking_backwards`'s
    timing: at least ``min_speed`` (m/s) with a finite facing against the velocity by more than
    half the speed. velocities, facings: (P, 3), m/s and unit vectors, world frame."""
    out = np.empty(len(velocities), dtype=np.bool_)
    _backwards_loop(plain(velocities), plain(facings), float(min_speed), out)
    return out


@jit
def _backwards_loop(
    velocities: FloatArray, facings: FloatArray, min_speed: float, out: npt.NDArray[np.bool_]
) -> None:
    """Fill ``out`` (P,) for :func:`walking_backwards_now` (``np.linalg.norm`` and ``np.dot``
    of three components as (a₀b₀ + a₁b₁) + a₂b₂)."""
    for p in range(len(out)):
        v0, v1, v2 = velocities[p, 0], velocities[p, 1], velocities[p, 2]
        speed = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        backwards = False
        if speed >= min_speed:
            f0, f1, f2 = facings[p, 0], facings[p, 1], facings[p, 2]
            finite = math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)
            backwards = finite and f0 * v0 + f1 * v1 + f2 * v2 < -0.5 * speed
        out[p] = backwards


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now, for the argument types every call
    passes (:func:`~skelfuse.jit.plain`), so no frame waits for it."""
    walking_backwards_now(np.ones((2, 3)), np.ones((2, 3)), 0.3)
