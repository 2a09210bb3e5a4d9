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
``filters.filter_all`` stacks are as in the constant-velocity Kalman. One compiled loop steps
every coordinate (:meth:`DampedAccelerationKalman._step`): its masks, the prediction ``F x``,
``F P Fᵀ`` (each element its three products summed in index order, ``(a + b) + c``: the same on
every machine, which a BLAS product is not), the process noise scaled by the coordinate's
speed, the correction and the led output. F and Q come from numpy (its ``exp`` and powers):
kept per step length for the usual step, where every coordinate steps by the same length.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kalman_state import BoolArray, KalmanState
from skelfuse.jit import jit, jit_inline, plain

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
        self._start_p = self._init(np.zeros(1))[1][0]  # (3, 3): a restart's covariance

    def _init(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = np.stack([z, np.zeros_like(z), np.zeros_like(z)], axis=-1)
        p = np.zeros((*z.shape, 3, 3))
        p[..., 0, 0], p[..., 1, 1], p[..., 2, 2] = self.r, 1.0, 100.0
        return x, p

    def _step(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, last_t: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """:meth:`KalmanState._step` in one loop (:func:`step_loop`): first with the one F and Q
        of the usual step (every coordinate measured, stepped, all by the same length), which
        gives up without writing anything when that does not hold; then with an F and a Q per
        coordinate."""
        h = t_s - float(last_t.flat[0]) if z.size else 0.0
        if 0.0 < h <= self.reset_gap_s:
            kept = self._kept_transition(np.array([h]))
            stepped = self._looped(z, last_x, last_p, last_t, t_s, kept, usual=True)
            if stepped is not None:
                return stepped
        dt = t_s - last_t
        present = np.isfinite(z)
        fresh = present & (~np.isfinite(last_x[..., 0]) | (dt > self.reset_gap_s))
        step = present & ~fresh & (dt > 0)
        f, q = self._transition(np.where(step, dt, 0.0))
        stepped = self._looped(z, last_x, last_p, last_t, t_s, (f, q), usual=False)
        assert stepped is not None  # with a transition per coordinate the loop always steps
        return stepped

    def _looped(
        self,
        z: FloatArray,
        last_x: FloatArray,
        last_p: FloatArray,
        last_t: FloatArray,
        t_s: float,
        transition: tuple[FloatArray, FloatArray],
        usual: bool,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
        """:func:`step_loop` on the stack's coordinates with ``transition`` (F, Q: (1, 3, 3)
        one for all when ``usual``, else (..., 3, 3) one each): output, state, covariance,
        times, or None when the usual step does not hold."""
        shape = z.shape
        out, new_t = np.empty(shape), np.empty(shape)
        new_x, new_p = np.empty((*shape, 3)), np.empty((*shape, 3, 3))
        f, q = transition
        lead = self.predict_s
        stepped = step_loop(
            (plain(z.reshape(-1)), plain(last_x.reshape(-1, 3)), plain(last_p.reshape(-1, 3, 3)),
             plain(last_t.reshape(-1))),
            float(t_s),
            (plain(f.reshape(-1, 3, 3)), plain(q.reshape(-1, 3, 3)), plain(self._start_p)),
            (float(self.jerk_std), float(self.jerk_per_speed), float(self.r),
             float(self.reset_gap_s), float(lead), float(lead * lead / 2)),
            usual,
            (out.reshape(-1), new_x.reshape(-1, 3), new_p.reshape(-1, 3, 3), new_t.reshape(-1)),
        )  # fmt: skip
        return (out, new_x, new_p, new_t) if stepped else None

    def _update(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, h: FloatArray, step: BoolArray
    ) -> tuple[FloatArray, FloatArray]:
        """Not used: :meth:`_step` predicts and corrects in its loop."""
        raise NotImplementedError("DampedAccelerationKalman steps in one loop: call _step")

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


def warm_up() -> None:
    """Compile (or load from numba's cache) the step's loop now, off any latency-bound path."""
    kalman = DampedAccelerationKalman()
    z = np.zeros(2)
    x, p = kalman._init(z)
    kalman._step(z, x, p, np.zeros(2), 1 / 30)  # the usual step
    kalman._step(np.array([0.0, np.nan]), x, p, np.zeros(2), 1 / 30)  # one coordinate missing


@jit
def step_loop(
    last: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    t_s: float,
    transition: tuple[FloatArray, FloatArray, FloatArray],
    params: tuple[float, float, float, float, float, float],
    usual: bool,
    into: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
) -> bool:
    """:meth:`KalmanState._step` of N coordinates: a measured one that has a state within the
    reset gap steps forward (predict, correct), a measured one without restarts from it
    (``(z, 0, 0)`` and the start covariance), an unmeasured one keeps its state; the output is
    the led position where measured, NaN elsewhere.

    Args:
        last: z (N,), x (N, 3), P (N, 3, 3), t (N,) (seconds); t_s: this sample's time.
        transition: F and the unscaled Q, (1, 3, 3) for all when ``usual``, else (N, 3, 3)
            one each; the start covariance (3, 3).
        params: jerk_std, jerk_per_speed, r, reset_gap_s, predict_s, predict_s² / 2.
        usual: every coordinate must step by ``t_s − t[0]``, or nothing is written and the
            answer is False.
        into: output (N,), x (N, 3), P (N, 3, 3), t (N,), written.
    """
    z, last_x, last_p, last_t = last
    f, q, start_p = transition
    jerk_std, jerk_per_speed, r, reset_gap_s, lead, half_lead_squared = params
    out, new_x, new_p, new_t = into
    if usual:  # the usual case or nothing: every coordinate steps by t_s − t[0]
        h = t_s - last_t[0]
        for c in range(z.shape[0]):
            dt = t_s - last_t[c]
            if not (np.isfinite(z[c]) and np.isfinite(last_x[c, 0])):
                return False  # missing, or never seen: a restart
            if dt > reset_gap_s or not dt > 0.0 or dt != h:
                return False  # a restart after a gap, no step forward, or another length
    scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3))
    for c in range(z.shape[0]):
        k = 0 if usual else c
        dt = t_s - last_t[c]
        present = np.isfinite(z[c])
        fresh = present and (not np.isfinite(last_x[c, 0]) or dt > reset_gap_s)
        if present and not fresh and dt > 0.0:
            jerk = jerk_std + jerk_per_speed * np.abs(last_x[c, 1])
            _predict_correct(z[c], last_x[c], last_p[c], f[k], q[k], jerk, r, scratch,
                             new_x[c], new_p[c])  # fmt: skip
        elif fresh:
            new_x[c, 0], new_x[c, 1], new_x[c, 2] = z[c], 0.0, 0.0
            new_p[c] = start_p
        else:
            new_x[c] = last_x[c]
            new_p[c] = last_p[c]
        new_t[c] = t_s if present else last_t[c]
        x = new_x[c]
        out[c] = x[0] + lead * x[1] + half_lead_squared * x[2] if present else np.nan
    return True


@jit_inline
def _predict_correct(
    z: float,
    x: FloatArray,
    p: FloatArray,
    f: FloatArray,
    q: FloatArray,
    jerk: float,
    r: float,
    scratch: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    new_x: FloatArray,
    new_p: FloatArray,
) -> None:
    """One coordinate's step: ``x_p = F x``, ``P_p = F P Fᵀ + jerk²·Q`` (each element's three
    products summed in index order), then the correction with the position measurement ``z``
    (H = [1, 0, 0], noise ``r``) into ``new_x`` (3,) and ``new_p`` (3, 3); ``scratch``: F P,
    P_p, x_p, the gain."""
    fp, p_p, x_p, gain = scratch
    for a in range(3):
        x_p[a] = f[a, 0] * x[0] + f[a, 1] * x[1] + f[a, 2] * x[2]
        for b in range(3):
            fp[a, b] = f[a, 0] * p[0, b] + f[a, 1] * p[1, b] + f[a, 2] * p[2, b]
    scale = jerk * jerk  # numpy's jerk**2
    for a in range(3):
        for b in range(3):
            predicted = fp[a, 0] * f[b, 0] + fp[a, 1] * f[b, 1] + fp[a, 2] * f[b, 2]
            p_p[a, b] = predicted + scale * q[a, b]
    s = p_p[0, 0] + r
    for a in range(3):
        gain[a] = p_p[a, 0] / s
    innovation = z - x_p[0]
    for a in range(3):
        new_x[a] = x_p[a] + gain[a] * innovation
        for b in range(3):
            new_p[a, b] = p_p[a, b] - gain[a] * p_p[0, b]
