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

    def _update(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, h: FloatArray, step: BoolArray
    ) -> tuple[FloatArray, FloatArray]:
        if (h == h.flat[0]).all():
            # One step length for every coordinate (the usual case): one F and one Q, which
            # the products below broadcast, the same values as a stack of equal ones; the
            # frame period takes only a few distinct float values, so they are kept.
            one = h.reshape(-1)[:1]
            key = one.tobytes()
            transition = self._transitions.get(key)
            if transition is None:
                if len(self._transitions) >= _KEPT_TRANSITIONS:
                    self._transitions.clear()
                transition = self._transitions[key] = self._transition(one)
            f, q = transition
        else:
            f, q = self._transition(h)
        x_p = np.einsum("...ij,...j->...i", f, last_x)
        predicted_p = _sandwich(f, last_p)
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


def _sandwich(f: FloatArray, p: FloatArray) -> FloatArray:
    """``f @ p @ fᵀ`` for a stack of covariances ``p`` (..., 3, 3): the same floats.

    With one ``f`` (1, 3, 3) for all (the usual case), both products are two matrix products
    of all the stack's rows at once, ``(3K, 3) @ (3, 3)``, instead of 2K products of 3 × 3:
    each output element is the same dot product, taken in the same order (row by row, BLAS
    computes a product's rows alone), 83 → 35 µs for 6 persons. Any other ``f``: the stack.
    """
    if f.shape != (1, 3, 3):
        stacked: FloatArray = f @ p @ np.swapaxes(f, -1, -2)
        return stacked
    turn = f[0].T
    # Row j of p_kᵀ times fᵀ is column j of f·p_k: (f p_k)ᵀ, row by row.
    columns = np.swapaxes(p.reshape(-1, 3, 3), 1, 2).reshape(-1, 3) @ turn
    rows = np.swapaxes(columns.reshape(-1, 3, 3), 1, 2).reshape(-1, 3)
    result: FloatArray = (rows @ turn).reshape(p.shape)
    return result
