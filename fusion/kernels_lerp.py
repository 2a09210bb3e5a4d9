"""The pending interpolations of one step and every body's move to the world, as one compiled
loop (numba).

:func:`skelfuse.fusion.world_views.resolve` interpolates every sensor's bodies to the instant
in one element-wise pass, ``(1 − α)·a + α·b`` in float64 with each row's own ``α``, float32
out; where a frame misses a joint the nearer frame decides, and the lower tracking state wins
(:func:`~skelfuse.fusion.sensors.body_arrays_at`'s rule). It then moves every body to the world
by its sensor's pose (:func:`~skelfuse.fusion.world_views.bodies_to_world`, each coordinate
``((x·r₀ + y·r₁) + z·r₂) + t`` as :func:`~skelfuse.protocol.transform.apply`). In numpy that is
two dozen calls on (rows, 25, 3) arrays, ~90 µs a step at 4 sensors. :func:`to_world` does
both in one loop: the same IEEE operations per coordinate (the products and the sums in that
order, the float32 rounding numpy's cast does), so the same bits (tests/unit/test_kernels_lerp.py;
a NaN's sign aside where +inf and −inf meet, which no frame holds: the wire refuses ±inf).

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]
StateArray = npt.NDArray[np.uint8]

_NOT_TRACKED = int(TrackingState.NOT_TRACKED)

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    joints = np.zeros((1, JOINT_COUNT, 3), np.float32)
    states = np.zeros((1, JOINT_COUNT), np.uint8)
    rows = (np.full(1, 0.5), np.ones(1, bool), np.zeros(1, np.intp))
    to_world(joints, joints, states, states, *rows, np.eye(4)[None])
    warmed.done = True


def to_world(
    first: Float32Array,
    second: Float32Array,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
    interpolate: npt.NDArray[np.bool_],
    pose_of_row: npt.NDArray[np.intp],
    poses: FloatArray,
) -> tuple[Float32Array, StateArray, FloatArray]:
    """Every row interpolated (where ``interpolate``) and moved to the world by its pose.

    Args:
        first, second: (N, 25, 3) float32 metres, the earlier and the later frame's bodies;
        first_states, second_states: (N, 25) their tracking states; alpha: (N,) each row's
            fraction (its sensor's), in [0, 1]; a row not to interpolate is ``first`` as it
            is (``second`` and ``alpha`` unread);
        interpolate: (N,) which rows to interpolate; pose_of_row: (N,) each row's pose;
        poses: (S, 4, 4) ``T_world_from_sensor`` (metres).

    Returns:
        (N, 25, 3) float32 joints and (N, 25) states: where both frames have a joint (all
        three coordinates finite) the float64 interpolation rounded to float32 and the lower
        state; elsewhere the nearer frame's joint and state (the later one from α = 0.5); a
        joint left with an unknown coordinate is NOT_TRACKED; a row not interpolated is
        ``first``'s. And (N, 25, 3) float64 world metres, the joints moved as
        :func:`~skelfuse.protocol.transform.apply` moves them.
    """
    joints = np.empty(first.shape, np.float32)
    states = np.empty(first_states.shape, np.uint8)
    world = np.empty(first.shape)
    _to_world_loop(
        plain(first, np.float32),
        plain(second, np.float32),
        plain(first_states, np.uint8),
        plain(second_states, np.uint8),
        plain(alpha),
        plain(interpolate, np.bool_),
        plain(pose_of_row, np.intp),
        plain(poses),
        _NOT_TRACKED,
        joints,
        states,
        world,
    )
    return joints, states, world


@jit
def _to_world_loop(  # pragma: no cover
    first: Float32Array,
    second: Float32Array,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
    interpolate: npt.NDArray[np.bool_],
    pose_of_row: npt.NDArray[np.intp],
    poses: FloatArray,
    not_tracked: int,
    joints: Float32Array,
    states: StateArray,
    world: FloatArray,
) -> None:
    value = np.empty(3)
    for n in range(first.shape[0]):
        fraction = alpha[n]
        rest = 1.0 - fraction
        later = fraction >= 0.5
        pose = poses[pose_of_row[n]]
        for j in range(first.shape[1]):
            if not interpolate[n]:
                for c in range(3):
                    joints[n, j, c] = first[n, j, c]
                states[n, j] = first_states[n, j]
            else:  # sensors._lerp's rule, joint by joint
                both = True
                for c in range(3):
                    if not (np.isfinite(first[n, j, c]) and np.isfinite(second[n, j, c])):
                        both = False
                if both:
                    for c in range(3):
                        value[c] = rest * np.float64(first[n, j, c]) + fraction * np.float64(
                            second[n, j, c]
                        )
                    state = min(first_states[n, j], second_states[n, j])
                else:
                    for c in range(3):
                        value[c] = np.float64(second[n, j, c] if later else first[n, j, c])
                    state = second_states[n, j] if later else first_states[n, j]
                known = True
                for c in range(3):
                    joints[n, j, c] = np.float32(value[c])
                    if not np.isfinite(value[c]):
                        known = False
                states[n, j] = state if known else not_tracked
            x = np.float64(joints[n, j, 0])
            y = np.float64(joints[n, j, 1])
            z = np.float64(joints[n, j, 2])
            for i in range(3):  # protocol.transform.apply's sums
                world[n, j, i] = ((x * pose[i, 0] + y * pose[i, 1]) + z * pose[i, 2]) + pose[i, 3]
