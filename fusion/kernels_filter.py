"""The damped-acceleration Kalman's correction step as one compiled loop (numba).

:meth:`skelfuse.fusion.filters_ca.DampedAccelerationKalman._update`, once the predicted state
and the covariance product ``F P Fᵀ`` are known (numpy computes both: their sums are BLAS's and
einsum's), is a dozen element-wise numpy operations on the persons' (P, 25, 3, 3, 3)
covariances: the process noise scaled by each coordinate's speed, the gain, the corrected state
and covariance. Here one loop does the same IEEE operations in the same order per element (no
fused multiply-add: numba without fastmath), so the same bits
(tests/unit/test_kernels_filter.py).

As :mod:`skelfuse.fusion.kernels_observe`: it runs only once :func:`warm_up` has compiled it,
so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
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
    one = np.zeros((1, 3))
    correct(np.zeros((1, 3, 3)), np.zeros((1, 3, 3)), one, np.zeros(1), one, np.ones(1, bool),
            (1.0, 1.0, 1.0))  # fmt: skip
    warmed.done = True


def correct(
    predicted_p: FloatArray,
    q: FloatArray,
    last_x: FloatArray,
    z: FloatArray,
    x_p: FloatArray,
    step: BoolArray,
    noise: tuple[float, float, float],
) -> tuple[FloatArray, FloatArray]:
    """The new state and covariance, as ``DampedAccelerationKalman._update`` computes them.

    Args:
        predicted_p: (..., 3, 3) ``F P Fᵀ`` per coordinate; q: the unscaled process noise,
            (1, 3, 3) one for all coordinates or (..., 3, 3) one each; last_x: (..., 3) the
            state before the step; z: (...) the measurements; x_p: (..., 3) the predicted
            state; step: (...) where a coordinate is measured (elsewhere the innovation is
            taken against 0, as numpy does);
        noise: (jerk_std, jerk_per_speed, r) the filter's parameters.

    Returns:
        new_x (..., 3), new_p (..., 3, 3) float64.
    """
    shape = z.shape
    new_x = np.empty((*shape, 3))
    new_p = np.empty((*shape, 3, 3))
    jerk_std, jerk_per_speed, r = noise
    _correct_loop(
        plain(predicted_p.reshape(-1, 3, 3)),
        plain(q.reshape(-1, 3, 3)),
        plain(last_x.reshape(-1, 3)),
        plain(z.reshape(-1)),
        plain(x_p.reshape(-1, 3)),
        plain(step.reshape(-1), np.bool_),
        float(jerk_std),
        float(jerk_per_speed),
        float(r),
        new_x.reshape(-1, 3),
        new_p.reshape(-1, 3, 3),
    )
    return new_x, new_p


@jit
def _correct_loop(
    predicted_p: FloatArray,
    q: FloatArray,
    last_x: FloatArray,
    z: FloatArray,
    x_p: FloatArray,
    step: BoolArray,
    jerk_std: float,
    jerk_per_speed: float,
    r: float,
    new_x: FloatArray,
    new_p: FloatArray,
) -> None:  # pragma: no cover - compiled; its numpy twin is the reference
    p_p = np.empty((3, 3))
    gain = np.empty(3)
    each = q.shape[0] > 1  # one q per coordinate, or one for all
    for c in range(z.shape[0]):
        k = c if each else 0
        jerk = jerk_std + jerk_per_speed * np.abs(last_x[c, 1])
        scale = jerk * jerk  # numpy's jerk**2
        for a in range(3):
            for b in range(3):
                p_p[a, b] = predicted_p[c, a, b] + scale * q[k, a, b]
        s = p_p[0, 0] + r
        for a in range(3):
            gain[a] = p_p[a, 0] / s
        innovation = z[c] - (x_p[c, 0] if step[c] else 0.0)
        for a in range(3):
            new_x[c, a] = x_p[c, a] + gain[a] * innovation
            for b in range(3):
                new_p[c, a, b] = p_p[a, b] - gain[a] * p_p[0, b]
