"""The damped-acceleration Kalman's step as compiled loops (numba).

:meth:`skelfuse.fusion.filters_ca.DampedAccelerationKalman._step` in numpy is two dozen
element-wise operations on the persons' (P, 25, 3, 3, 3) covariances: the masks of which
coordinates step, the prediction (:func:`~skelfuse.fusion.filters_ca.predicted`), the process
noise scaled by each coordinate's speed, the gain, the corrected state and covariance, the led
output. :func:`step_all` does the usual step (every coordinate measured and stepped by the same
length) in one loop; :func:`correct` does the correction of any other step, after numpy's
masks and prediction. Each does the same IEEE operations in the same order per element (no
fused multiply-add: numba without fastmath), so the same bits
(tests/unit/test_kernels_filter.py).

As the other kernel modules: they run only once :func:`warm_up` has compiled
them, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
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
    """Compile (or load from numba's cache) the loops now; a no-op with the kernels off."""
    one = np.zeros((1, 3))
    correct(np.zeros((1, 3, 3)), np.zeros((1, 3, 3)), one, np.zeros(1), one, np.ones(1, bool),
            (1.0, 1.0, 1.0))  # fmt: skip
    transition = (np.eye(3)[None], np.eye(3)[None])
    step_all(np.zeros(1), one, np.zeros((1, 3, 3)), np.zeros(1), 1.0, transition, (1.0, 1.0, 1.0),
             2.0, (0.0, 0.0))  # fmt: skip
    warmed.done = True


def step_all(
    z: FloatArray,
    last_x: FloatArray,
    last_p: FloatArray,
    last_t: FloatArray,
    t_s: float,
    transition: tuple[FloatArray, FloatArray],
    noise: tuple[float, float, float],
    reset_gap_s: float,
    lead: tuple[float, float],
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """The damped-acceleration Kalman's usual step, as ``KalmanState._step`` computes it when
    every coordinate steps by the same length: predict (:func:`~skelfuse.fusion.filters_ca.
    predicted`'s sums), correct (:func:`correct`'s), give out the led position.

    Args:
        z: (...) the measurements; last_x: (..., 3) the states, last_p: (..., 3, 3) their
            covariances, last_t: (...) their last measurement's times (s);
        t_s: this sample's time (s);
        transition: F and the unscaled Q, (1, 3, 3) each, for the step length
            ``t_s - last_t.flat[0]``;
        noise: (jerk_std, jerk_per_speed, r); reset_gap_s: the filter's;
        lead: (predict_s, predict_s² / 2) as the filter's output takes them.

    Returns:
        (output (...), new_x (..., 3), new_p (..., 3, 3)), or None, with nothing computed
        that the caller keeps, when some coordinate is missing, restarts, does not step
        forward or steps by another length (numpy's path then takes the step).
    """
    shape = z.shape
    out = np.empty(shape)
    new_x = np.empty((*shape, 3))
    new_p = np.empty((*shape, 3, 3))
    f, q = transition
    jerk_std, jerk_per_speed, r = noise
    stepped = _step_loop(
        plain(z.reshape(-1)),
        plain(last_x.reshape(-1, 3)),
        plain(last_p.reshape(-1, 3, 3)),
        plain(last_t.reshape(-1)),
        float(t_s),
        plain(f.reshape(3, 3)),
        plain(q.reshape(3, 3)),
        float(jerk_std),
        float(jerk_per_speed),
        float(r),
        float(reset_gap_s),
        float(lead[0]),
        float(lead[1]),
        out.reshape(-1),
        new_x.reshape(-1, 3),
        new_p.reshape(-1, 3, 3),
    )
    return (out, new_x, new_p) if stepped else None


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


@jit
def _step_loop(
    z: FloatArray,
    last_x: FloatArray,
    last_p: FloatArray,
    last_t: FloatArray,
    t_s: float,
    f: FloatArray,
    q: FloatArray,
    jerk_std: float,
    jerk_per_speed: float,
    r: float,
    reset_gap_s: float,
    lead: float,
    half_lead_squared: float,
    out: FloatArray,
    new_x: FloatArray,
    new_p: FloatArray,
) -> bool:  # pragma: no cover - compiled; its numpy twin is the reference
    # The usual case or nothing: KalmanState._step's masks, every coordinate stepping.
    h = t_s - last_t[0]
    for c in range(z.shape[0]):
        dt = t_s - last_t[c]
        if not (np.isfinite(z[c]) and np.isfinite(last_x[c, 0])):
            return False  # missing, or never seen: a restart
        if dt > reset_gap_s or not dt > 0.0 or dt != h:
            return False  # a restart after a gap, no step forward, or another length
    fp = np.empty((3, 3))
    p_p = np.empty((3, 3))
    x_p = np.empty(3)
    gain = np.empty(3)
    for c in range(z.shape[0]):
        x, p = last_x[c], last_p[c]
        for a in range(3):  # filters_ca.predicted's sums: (a + b) + c, element by element
            x_p[a] = f[a, 0] * x[0] + f[a, 1] * x[1] + f[a, 2] * x[2]
            for b in range(3):
                fp[a, b] = f[a, 0] * p[0, b] + f[a, 1] * p[1, b] + f[a, 2] * p[2, b]
        jerk = jerk_std + jerk_per_speed * np.abs(last_x[c, 1])
        scale = jerk * jerk
        for a in range(3):
            for b in range(3):
                predicted = fp[a, 0] * f[b, 0] + fp[a, 1] * f[b, 1] + fp[a, 2] * f[b, 2]
                p_p[a, b] = predicted + scale * q[a, b]
        s = p_p[0, 0] + r
        for a in range(3):
            gain[a] = p_p[a, 0] / s
        innovation = z[c] - x_p[0]
        for a in range(3):
            new_x[c, a] = x_p[a] + gain[a] * innovation
            for b in range(3):
                new_p[c, a, b] = p_p[a, b] - gain[a] * p_p[0, b]
        out[c] = new_x[c, 0] + lead * new_x[c, 1] + half_lead_squared * new_x[c, 2]
    return True
