"""The tracks' move after fusion as one compiled loop (numba).

:meth:`skelfuse.fusion.identity.PersonTracker.move_all` keeps each person's fused skeleton and
smooths its trunk velocity: fifteen numpy calls on (P, 25, 3) arrays, ~70 µs for 6 persons,
nearly all of it the calls' fixed cost. Here one loop does the same IEEE operations in the same
order (the velocity's difference quotient, its smoothing ``0.6 old + 0.4 new``, the speed
``√((x² + y²) + z²)`` and its clip, a joint kept where the fusion has none), so the same bits
(tests/unit/test_association_arrays.py).

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    joints = np.zeros((1, 25, 3))
    moved(joints, np.zeros(1), np.ones(1, bool), np.zeros((1, 3)), joints, 1.0, 3.0)
    warmed.done = True


def moved(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The tracks after a fusion at ``t_s``, as ``PersonTracker.move_all`` computes them.

    Args:
        joints: (P, 25, 3) each track's skeleton before (world, metres); last_seen_s: (P,)
            when each was last fused (s); fused_once: (P,) whether it has been;
            velocities: (P, 3) its trunk velocity (m/s); fused: (P, 25, 3) this fusion,
            NaN where it has no joint; t_s: the instant (s); max_speed_mps: the speed clip.

    Returns:
        (P, 25, 3) the skeletons kept (the fused joint, the old one where there is none),
        (P, 3) the new velocities (the old ones where a track does not move), (P,) which
        tracks moved (fused before, within 0.5 s, with a SpineBase then and now).
    """
    count = joints.shape[0]
    kept = np.empty((count, joints.shape[1], 3))
    velocity = np.empty((count, 3))
    moving = np.empty(count, dtype=np.bool_)
    _move_loop(
        plain(joints),
        plain(last_seen_s),
        plain(fused_once, np.bool_),
        plain(velocities),
        plain(fused),
        float(t_s),
        float(max_speed_mps),
        kept,
        velocity,
        moving,
    )
    return kept, velocity, moving


@jit
def _move_loop(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
    kept: FloatArray,
    velocity: FloatArray,
    moving: BoolArray,
) -> None:  # pragma: no cover - compiled; its numpy twin is the reference
    for p in range(joints.shape[0]):
        dt = t_s - last_seen_s[p]
        roots = True  # a SpineBase in both skeletons
        for k in range(3):
            roots = roots and np.isfinite(fused[p, 0, k]) and np.isfinite(joints[p, 0, k])
        moving[p] = fused_once[p] and dt > 0.0 and dt < 0.5 and roots
        if moving[p]:
            for k in range(3):
                new = 0.0 if k == 1 else (fused[p, 0, k] - joints[p, 0, k]) / dt
                velocity[p, k] = 0.6 * velocities[p, k] + 0.4 * new
            x, y, z = velocity[p, 0], velocity[p, 1], velocity[p, 2]
            speed = np.sqrt((x * x + y * y) + z * z)
            if speed > max_speed_mps:
                scale = max_speed_mps / speed
                for k in range(3):
                    velocity[p, k] = velocity[p, k] * scale
        else:
            for k in range(3):
                velocity[p, k] = velocities[p, k]
        for j in range(joints.shape[1]):
            for k in range(3):
                value = fused[p, j, k]
                kept[p, j, k] = value if np.isfinite(value) else joints[p, j, k]
