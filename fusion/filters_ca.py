"""Constant-acceleration Kalman filter with a damped acceleration (Singer model), vectorised.

Why: a constant-velocity Kalman (fusion/filters.py) has no lag on a ramp but lags whenever the
joint accelerates, which a limb does all the time (an arm swinging while walking lags 15 ms
even with a 12 ms lead, docs/benchmarks.md "Lag against the truth"). Modelling the
acceleration as well removes that lag; letting it decay towards zero with time constant
``accel_tau_s`` (Singer, 1970) keeps the acceleration from running away when a joint stops,
so the lead it allows overshoots less.

Per coordinate, state (position, velocity, acceleration), transition over ``h`` seconds
``F = [[1, h, h²/2], [0, 1, h], [0, 0, e^(−h/τ)]]``, process noise from white jerk of spectral
density ``jerk_std²`` (m²/s⁵), measurement noise ``meas_std_m``. The output is the state
extrapolated ``predict_s`` ahead (``p + v·L + a·L²/2``), which also cancels the pipeline's own
delay.

NaN handling, reset after ``reset_gap_s`` and the ``_step``/``_state`` protocol that
``filters.filter_all`` stacks are as in the constant-velocity Kalman.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_filter
from skelfuse.fusion.kalman_state import BoolArray, KalmanState

FloatArray = npt.NDArray[np.float64]
_KEPT_TRANSITIONS = 16
"""F and Q kept per step length (seconds, to the bit), for this many step lengths."""


class DampedAccelerationKalman(KalmanState):
    """Per-coordinate constant-acceleration Kalman with decaying acceleration.

    Args:
        jerk_std: process noise, square root of the white jerk's spectral density (m/s^2.5).
        meas_std_m: measurement noise standard deviation (metres).
        accel_tau_s: time constant (seconds) with which the acceleration decays to zero.
        predict_s: output the state extrapolated this far ahead (0: the filtered position).
        reset_gap_s: a coordinate missing for longer than this restarts from its next sample.
        jerk_per_speed: jerk added per unit of the coordinate's estimated speed (m/s^2.5 per
            m/s): as One Euro's ``beta``, smooth when still, quick when moving.
    """

    def __init__(
        self,
        jerk_std: float = 3.0,
        meas_std_m: float = 0.03,
        accel_tau_s: float = 0.3,
        predict_s: float = 0.0,
        reset_gap_s: float = 0.5,
        jerk_per_speed: float = 0.0,
    ) -> None:
        super().__init__(meas_std_m, reset_gap_s)  # x: (..., 3) position, velocity, accel.
        self.jerk_std = jerk_std
        self.jerk_per_speed = jerk_per_speed
        self.accel_tau_s = accel_tau_s
        self.predict_s = predict_s
        self._transitions: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def _init(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = np.stack([z, np.zeros_like(z), np.zeros_like(z)], axis=-1)
        p = np.zeros((*z.shape, 3, 3))
        p[..., 0, 0], p[..., 1, 1], p[..., 2, 2] = self.r, 1.0, 100.0
        return x, p

    def _step(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, last_t: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """:meth:`KalmanState._step`; with the kernels on and warmed, its usual case (every
        coordinate measured, stepped, all by the same length) as one compiled loop, which
        gives up without writing anything when the case does not hold (the same bits,
        tests/unit/test_kernels_filter.py)."""
        if z.size and kernels.enabled() and kernels_filter.warmed():
            h = t_s - float(last_t.flat[0])
            if 0.0 < h <= self.reset_gap_s:
                f, q = self._kept_transition(np.array([h]))
                noise = (self.jerk_std, self.jerk_per_speed, self.r)
                lead = (self.predict_s, self.predict_s * self.predict_s / 2)
                stepped = kernels_filter.step_all(
                    z, last_x, last_p, last_t, t_s, (f, q), noise, self.reset_gap_s, lead
                )
                if stepped is not None:
                    out, new_x, new_p = stepped
                    return out, new_x, new_p, np.full(z.shape, t_s)
        return super()._step(z, last_x, last_p, last_t, t_s)

    def _update(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, h: FloatArray, step: BoolArray
    ) -> tuple[FloatArray, FloatArray]:
        if (h == h.flat[0]).all():
            # One step length for every coordinate (the usual case): one F and one Q, which
            # the products below broadcast, the same values as a stack of equal ones.
            f, q = self._kept_transition(h.reshape(-1)[:1])
        else:
            f, q = self._transition(h)
        x_p, predicted_p = predicted(f, last_x, last_p)
        if kernels.enabled() and kernels_filter.warmed():  # the same bits in one loop
            noise = (self.jerk_std, self.jerk_per_speed, self.r)
            return kernels_filter.correct(predicted_p, q, last_x, z, x_p, step, noise)
        jerk = self.jerk_std + self.jerk_per_speed * np.abs(last_x[..., 1])
        p_p = predicted_p + (jerk**2)[..., None, None] * q
        # Update with the position measurement (H = [1, 0, 0]).
        s = p_p[..., 0, 0] + self.r
        gain = p_p[..., :, 0] / s[..., None]
        innovation = z - np.where(step, x_p[..., 0], 0.0)
        new_x: FloatArray = x_p + gain * innovation[..., None]
        new_p: FloatArray = p_p - gain[..., :, None] * p_p[..., 0, None, :]
        return new_x, new_p

    def _kept_transition(self, one: FloatArray) -> tuple[FloatArray, FloatArray]:
        """F and Q (1, 3, 3) for the one step length ``one`` (1,): the frame period takes
        only a few distinct float values, so they are kept."""
        key = one.tobytes()
        transition = self._transitions.get(key)
        if transition is None:
            if len(self._transitions) >= _KEPT_TRANSITIONS:
                self._transitions.clear()
            transition = self._transitions[key] = self._transition(one)
        return transition

    def _transition(self, h: FloatArray) -> tuple[FloatArray, FloatArray]:
        """F and the unscaled Q over ``h`` seconds: (..., 3, 3) each for ``h`` (...)."""
        f = np.zeros((*h.shape, 3, 3))
        f[..., 0, 0] = f[..., 1, 1] = 1.0
        f[..., 0, 1] = f[..., 1, 2] = h
        f[..., 0, 2] = h * h / 2
        f[..., 2, 2] = np.exp(-h / self.accel_tau_s)
        # White-jerk process noise (exact for the undamped model; the damping is slow
        # against one frame, so its effect on Q is negligible).
        q = np.empty_like(f)
        q[..., 0, 0] = h**5 / 20
        q[..., 0, 1] = q[..., 1, 0] = h**4 / 8
        q[..., 0, 2] = q[..., 2, 0] = h**3 / 6
        q[..., 1, 1] = h**3 / 3
        q[..., 1, 2] = q[..., 2, 1] = h**2 / 2
        q[..., 2, 2] = h
        return f, q

    def _output(self, x: FloatArray) -> FloatArray:
        lead = self.predict_s
        out: FloatArray = x[..., 0] + lead * x[..., 1] + lead * lead / 2 * x[..., 2]
        return out

    def _params(self) -> tuple[float, ...]:
        return (self.jerk_std, self.jerk_per_speed, self.r, self.accel_tau_s, self.predict_s,
                self.reset_gap_s)  # fmt: skip


def predicted(f: FloatArray, x: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The predicted state ``F x`` (..., 3) and covariance ``F P Fᵀ`` (..., 3, 3) of a stack
    of coordinates, for one ``f`` (1, 3, 3) for all or one each (..., 3, 3).

    Each element is its three products summed in index order, ``(a + b) + c``, element-wise:
    the floats of :mod:`skelfuse.fusion.kernels_filter`'s loop, and the same on every machine
    (a BLAS product's floats are its kernel's: with fused multiply-adds or not, in its order).
    """
    x_p = (
        f[..., :, 0] * x[..., 0, None]
        + f[..., :, 1] * x[..., 1, None]
        + f[..., :, 2] * x[..., 2, None]
    )
    fp = (  # F P: row a, column b is sum over k of F[a, k] P[k, b]
        f[..., :, 0, None] * p[..., 0, None, :]
        + f[..., :, 1, None] * p[..., 1, None, :]
        + f[..., :, 2, None] * p[..., 2, None, :]
    )
    p_p = (  # (F P) Fᵀ: row a, column b is sum over k of (F P)[a, k] F[b, k]
        fp[..., :, 0, None] * f[..., None, :, 0]
        + fp[..., :, 1, None] * f[..., None, :, 1]
        + fp[..., :, 2, None] * f[..., None, :, 2]
    )
    return x_p, p_p
