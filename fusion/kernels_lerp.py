"""The pending interpolations of one step as one compiled loop (numba).

:func:`skelfuse.fusion.world_views.resolve` interpolates every sensor's bodies to the instant
in one element-wise pass, ``(1 − α)·a + α·b`` in float64 with each row's own ``α``, float32
out; where a frame misses a joint the nearer frame decides, and the lower tracking state wins
(:func:`~skelfuse.fusion.sensors.body_arrays_at`'s rule). In numpy that is a dozen calls on
(rows, 25, 3) arrays, 59–94 µs a step at 4–16 sensors. Here one loop does the same IEEE
operations per coordinate (the products and the sum in that order, the float32 rounding
numpy's cast does), so the same bits (tests/unit/test_kernels_lerp.py).

As :mod:`skelfuse.fusion.kernels_observe`: the loop runs only once :func:`warm_up` has compiled
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
    interpolated_rows(joints, joints, states, states, np.full(1, 0.5))
    warmed.done = True


def interpolated_rows(
    first: Float32Array,
    second: Float32Array,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
) -> tuple[Float32Array, StateArray]:
    """Every row ``alpha`` of the way from ``first`` to ``second``.

    Args:
        first, second: (N, 25, 3) float32 metres, the earlier and the later frame's bodies.
        first_states, second_states: (N, 25) their tracking states.
        alpha: (N,) each row's fraction (its sensor's), in [0, 1].

    Returns:
        (N, 25, 3) float32 joints and (N, 25) states: where both frames have a joint (all
        three coordinates finite) the float64 interpolation rounded to float32 and the lower
        state; elsewhere the nearer frame's joint and state (the later one from α = 0.5); a
        joint left with an unknown coordinate is NOT_TRACKED.
    """
    joints = np.empty(first.shape, np.float32)
    states = np.empty(first_states.shape, np.uint8)
    _lerp_loop(
        plain(first, np.float32),
        plain(second, np.float32),
        plain(first_states, np.uint8),
        plain(second_states, np.uint8),
        plain(alpha),
        _NOT_TRACKED,
        joints,
        states,
    )
    return joints, states


@jit
def _lerp_loop(  # pragma: no cover
    first: Float32Array,
    second: Float32Array,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
    not_tracked: int,
    joints: Float32Array,
    states: StateArray,
) -> None:
    value = np.empty(3)
    for n in range(first.shape[0]):
        fraction = alpha[n]
        rest = 1.0 - fraction
        later = fraction >= 0.5
        for j in range(first.shape[1]):
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
