"""Temporal filters for fused skeletons: One Euro and two Kalman filters, vectorised.

One filter object per person track, created at the track's birth (so a new person never
inherits another's state); each call filters all 25×3 coordinates at once. Timestamps are the
fusion instants (seconds, server clock), so irregular steps are handled.

A joint that is NaN in the input is NaN in the output (nothing is invented) and its state is
kept; when it comes back after more than ``reset_gap_s``, that joint restarts from the new
measurement instead of being pulled towards where it was.

- **One Euro** (Casiez, Roussel & Vogel, CHI 2012): a first-order low-pass whose cut-off rises
  with speed, ``f_c = min_cutoff + beta·|dx/dt|``: smooth when still, little lag when moving.
  Per coordinate, exactly as the authors' reference implementation (``OneEuroFilter`` 0.2.1),
  which the unit tests use as an oracle in scalar form.
- **Constant-velocity Kalman**: per coordinate, state (position, velocity), white-acceleration
  process noise ``accel_std`` (m/s²), measurement noise ``meas_std_m``; optionally outputs the
  state extrapolated ``predict_s`` ahead to cancel its own lag (and the pipeline's).
- **Damped-acceleration Kalman** (the default): see below.

What the Kalman filters share (:class:`KalmanState`): per coordinate, a state ``x`` (position
first), its covariance ``P`` and the time of its last measurement ``t``; a subclass says how the
state starts (:meth:`_init`) and how one sample moves a stack of states (:meth:`_step`), so
that :func:`filter_all` can step several persons' filters in one pass: a missing coordinate
keeps its state, one missing longer than ``reset_gap_s`` (or never seen) restarts from its next
measurement. The constant-velocity filter steps in numpy (predict over ``h`` seconds, then
correct); the damped-acceleration one in one compiled loop.

Constant-acceleration Kalman with a damped acceleration (Singer model). Why: a
constant-velocity Kalman has no lag on a ramp but lags whenever the joint accelerates, which a
limb does all the time (an arm swinging while walking lags 15 ms even with a 12 ms lead,
docs/benchmarks.md "Lag against the truth"). Modelling the acceleration as well removes that
lag; letting it decay towards zero with time constant ``accel_tau_s`` (Singer, 1970) keeps the
acceleration from running away when a joint stops, so the lead it allows overshoots less.
Per coordinate, state (position, velocity, acceleration), transition over ``h`` seconds
``F = [[1, h, h²/2], [0, 1, h], [0, 0, e^(−h/τ)]]``, process noise from white jerk of spectral
density ``jerk_std²`` (m²/s⁵), measurement noise ``meas_std_m``. The output is the state
extrapolated ``predict_s`` ahead (``p + v·L + a·L²/2``), which also cancels the pipeline's own
delay. One compiled loop steps every coordinate (:meth:`DampedAccelerationKalman._step`): its
masks, the prediction ``F x``, ``F P Fᵀ`` (each element its three products summed in index
order, ``(a + b) + c``: the same on every machine, which a BLAS product is not), the process
noise scaled by the coordinate's speed, the correction and the led output. F and Q come from
numpy (its ``exp`` and powers): kept per step length for the usual step, where every coordinate
steps by the same length.

Added latency of the filters, measured on ramps and steps, is in docs/fusion.md
(``python -m bench accuracy --latency``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit, jit_inline, plain

FloatArray = npt.NDArray[np.float64]


class JointFilter(Protocol):
    """Filters one person's joints over time."""

    def __call__(self, joints: FloatArray, t_s: float) -> FloatArray:
        """Filter one sample: (..., 3) positions (NaN where unknown) at ``t_s`` seconds."""
        ...


class PassThrough:
    """No filtering."""

    def __call__(self, joints: FloatArray, t_s: float) -> FloatArray:
        return np.array(joints, dtype=np.float64, copy=True)


class OneEuroFilter:
    """Vectorised One Euro filter over arrays of any fixed shape.

    Args:
        min_cutoff_hz: cut-off when still (Hz); lower is smoother and laggier.
        beta: cut-off increase per unit of speed (Hz per m/s); higher follows fast moves better.
        d_cutoff_hz: cut-off of the speed estimate (Hz).
        reset_gap_s: a coordinate missing for longer than this restarts from its next sample.
    """

    def __init__(
        self,
        min_cutoff_hz: float = 1.0,
        beta: float = 4.0,
        d_cutoff_hz: float = 1.0,
        reset_gap_s: float = 0.5,
    ) -> None:
        self.min_cutoff_hz = min_cutoff_hz
        self.beta = beta
        self.d_cutoff_hz = d_cutoff_hz
        self.reset_gap_s = reset_gap_s
        self._x: FloatArray | None = None
        self._dx: FloatArray | None = None
        self._t: FloatArray | None = None

    def __call__(self, joints: FloatArray, t_s: float) -> FloatArray:
        x = np.asarray(joints, dtype=np.float64)
        if self._x is None or self._dx is None or self._t is None:
            self._x, self._dx = x.copy(), np.zeros_like(x)
            self._t = np.where(np.isfinite(x), t_s, -np.inf)
            return x.copy()
        out, self._x, self._dx, self._t = self._step(x, self._x, self._dx, self._t, t_s)
        return out

    def _step(
        self, x: FloatArray, last_x: FloatArray, last_dx: FloatArray, last_t: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """One sample on any stack of states: output, new x, new dx, new t."""
        present = np.isfinite(x)
        dt = t_s - last_t
        fresh = present & (~np.isfinite(last_x) | (dt > self.reset_gap_s))
        step = present & ~fresh & (dt > 0)
        safe_dt = np.where(step, dt, 1.0)
        previous = np.where(step, last_x, 0.0)
        dx = np.where(step, (x - previous) / safe_dt, 0.0)
        alpha_d = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * self.d_cutoff_hz * safe_dt))
        dx_hat = alpha_d * dx + (1.0 - alpha_d) * last_dx
        cutoff = self.min_cutoff_hz + self.beta * np.abs(dx_hat)
        alpha = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * safe_dt))
        x_hat = alpha * np.where(step, x, 0.0) + (1.0 - alpha) * previous
        new_x = np.where(step, x_hat, np.where(fresh, x, last_x))
        new_dx = np.where(step, dx_hat, np.where(fresh, 0.0, last_dx))
        new_t = np.where(present, t_s, last_t)
        return np.where(present, new_x, np.nan), new_x, new_dx, new_t

    def _params(self) -> tuple[float, float, float, float]:
        return (self.min_cutoff_hz, self.beta, self.d_cutoff_hz, self.reset_gap_s)

    def _state(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """x, dx, t of a started filter (``filter_all`` stacks them)."""
        assert self._x is not None
        assert self._dx is not None
        assert self._t is not None
        return self._x, self._dx, self._t

    def _set_state(self, x: FloatArray, dx: FloatArray, t: FloatArray) -> None:
        self._x, self._dx, self._t = x, dx, t


StateRows = tuple[FloatArray, FloatArray, FloatArray]
"""One filter's state arrays, as ``_state()`` gives them."""
Stacks = dict[tuple[type, tuple[float, ...]], tuple[list[StateRows], StateRows]]
"""Per group of filters stepped together, each member's state rows after the last step and the
stacked arrays they are rows of (:func:`filter_all`'s ``stacks``)."""


def filter_all(
    filters: list[JointFilter], joints: FloatArray, t_s: float, stacks: Stacks | None = None
) -> list[FloatArray]:
    """Filter one sample per filter (``filters[i]`` gets ``joints[i]``), as separate calls would.

    One Euro or Kalman filters of the same kind and parameters, already started, are stepped
    together in one vectorised pass (the same element-wise arithmetic, so the same results);
    others one by one.

    Args:
        joints: (P, ...) one sample per filter.
        stacks: the caller's memory of the last call's stacked states, or None. With it, a
            group whose members' states are still the very rows the last call gave them (the
            same filters, in the same order, none restarted: the usual step) steps the arrays
            those rows came from instead of stacking the rows again (the same values, without
            ~2 × P copies of each person's covariances).
    """
    out: list[FloatArray | None] = [None] * len(filters)
    groups: dict[tuple[type, tuple[float, ...]], list[int]] = {}
    stackable = _STACKABLE
    same = _same_group(filters, joints, stacks)
    if same:  # the usual step: no regrouping
        assert stacks is not None
        groups[next(iter(stacks))] = list(range(len(filters)))
    else:
        for i, f in enumerate(filters):
            if isinstance(f, stackable) and f._t is not None and f._t.shape == joints.shape[1:]:
                groups.setdefault((type(f), f._params()), []).append(i)
            else:
                out[i] = f(joints[i], t_s)
    kept: Stacks = {}
    for key, members in groups.items():
        chosen = [f for i in members if isinstance(f := filters[i], stackable)]
        first = chosen[0]
        last = None if stacks is None else stacks.get(key)
        if same and last is not None:  # every state still the rows of those very arrays
            x, second, t = last[1]
        else:
            states = [f._state() for f in chosen]
            if last is not None and _same_rows(last[0], states):
                x, second, t = last[1]
            else:
                x, second, t = (np.stack([s[k] for s in states]) for k in range(3))
        # Every filter in one group (the usual step): the samples as they are, not a gathered
        # copy (_step only reads them).
        whole = len(members) == len(joints)
        z = joints if whole else joints[members]
        result, *new = first._step(np.asarray(z, dtype=np.float64), x, second, t, t_s)
        rows: list[StateRows] = []
        for k, (i, f) in enumerate(zip(members, chosen, strict=True)):
            row = (new[0][k], new[1][k], new[2][k])
            f._set_state(*row)
            rows.append(row)
            out[i] = result[k]
        kept[key] = (rows, (new[0], new[1], new[2]))
    if stacks is not None:  # only this call's groups: the others' states are gone
        stacks.clear()
        stacks.update(kept)
    return [o for o in out if o is not None]


def _same_group(filters: list[JointFilter], joints: FloatArray, stacks: Stacks | None) -> bool:
    """Whether the last call stepped one group, the very filters of this call in this order,
    none stepped alone or restarted since (each one's time array is still the row that call
    gave it, so its kind and parameters are that group's): then they are that group again, and
    their states are still that call's rows (a filter's three state arrays are only ever set
    together: a step alone or ``_set_state``, and a restart is a new filter)."""
    if stacks is None or len(stacks) != 1 or len(filters) != len(joints):
        return False
    last_rows, stacked = next(iter(stacks.values()))
    return (
        len(last_rows) == len(filters)
        and stacked[2].shape[1:] == joints.shape[1:]
        and all(
            isinstance(f, _STACKABLE) and f._t is row[2]
            for f, row in zip(filters, last_rows, strict=True)
        )
    )


def _same_rows(last: list[StateRows], states: list[StateRows]) -> bool:
    """Whether each filter's state arrays are the very ones ``last`` holds, in the same order
    (a filter stepped alone or restarted since has new ones)."""
    return len(last) == len(states) and all(
        a is b for old, now in zip(last, states, strict=True) for a, b in zip(old, now, strict=True)
    )


# --- Kalman state: what the Kalman filters share -------------------------------------------------


BoolArray = npt.NDArray[np.bool_]


class KalmanState(ABC):
    """State handling of a per-coordinate Kalman filter (see the module docstring).

    Args:
        meas_std_m: measurement noise standard deviation (metres).
        reset_gap_s: a coordinate missing for longer than this restarts from its next sample.
    """

    def __init__(self, meas_std_m: float, reset_gap_s: float) -> None:
        self.r = meas_std_m**2
        self.reset_gap_s = reset_gap_s
        self._x: FloatArray | None = None
        self._p: FloatArray | None = None
        self._t: FloatArray | None = None

    @abstractmethod
    def _init(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The state and covariance a filter starts from at its first sample ``z``."""

    @abstractmethod
    def _output(self, x: FloatArray) -> FloatArray:
        """The position the filter gives out from its state (with its lead, if any)."""

    @abstractmethod
    def _step(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, last_t: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """One sample on any stack of states: output, new state, new covariance, new t."""

    @abstractmethod
    def _params(self) -> tuple[float, ...]:
        """The parameters: filters with equal ones can be stepped together."""

    def __call__(self, joints: FloatArray, t_s: float) -> FloatArray:
        z = np.asarray(joints, dtype=np.float64)
        if self._x is None or self._p is None or self._t is None:
            self._x, self._p = self._init(z)
            self._t = np.where(np.isfinite(z), t_s, -np.inf)
            return z.copy()
        out, self._x, self._p, self._t = self._step(z, self._x, self._p, self._t, t_s)
        return out

    def _state(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """x, P, t of a started filter (``filter_all`` stacks them)."""
        assert self._x is not None
        assert self._p is not None
        assert self._t is not None
        return self._x, self._p, self._t

    def _set_state(self, x: FloatArray, p: FloatArray, t: FloatArray) -> None:
        self._x, self._p, self._t = x, p, t


def _per(mask: BoolArray, values: FloatArray) -> BoolArray:
    """A per-coordinate mask shaped to broadcast over per-coordinate state ``values``."""
    return mask.reshape(mask.shape + (1,) * (values.ndim - mask.ndim))


# --- Constant-velocity Kalman --------------------------------------------------------------------


class ConstantVelocityKalman(KalmanState):
    """Per-coordinate constant-velocity Kalman filter, vectorised over arrays of any shape.

    Args:
        accel_std: process noise, standard deviation of the white acceleration (m/s²).
        meas_std_m: measurement noise standard deviation (metres).
        predict_s: output the state extrapolated this far ahead (0: the filtered position).
        reset_gap_s: a coordinate missing for longer than this restarts from its next sample.
    """

    def __init__(
        self,
        accel_std: float = 8.0,
        meas_std_m: float = 0.03,
        predict_s: float = 0.0,
        reset_gap_s: float = 0.5,
    ) -> None:
        super().__init__(meas_std_m, reset_gap_s)  # x: (..., 2) position, velocity; P: (..., 3)
        self.q = accel_std**2
        self.predict_s = predict_s

    def _init(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = np.stack([z, np.zeros_like(z)], axis=-1)
        p = np.stack([np.full_like(z, self.r), np.zeros_like(z), np.full_like(z, 1.0)], axis=-1)
        return x, p

    def _step(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, last_t: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """One sample on any stack of states: output, new state, new covariance, new t."""
        present = np.isfinite(z)
        dt = t_s - last_t
        fresh = present & (~np.isfinite(last_x[..., 0]) | (dt > self.reset_gap_s))
        step = present & ~fresh & (dt > 0)
        if step.all():
            # The usual case, every coordinate steps: the masks below would pick the update
            # everywhere. The same values with a dozen fewer array operations.
            new_x, new_p = self._update(z, last_x, last_p, dt, step)
            return self._output(new_x), new_x, new_p, np.full(z.shape, t_s)
        new_x, new_p = self._update(
            np.where(step, z, 0.0), last_x, last_p, np.where(step, dt, 0.0), step
        )
        if fresh.any():
            init_x, init_p = self._init(np.where(fresh, z, 0.0))
            last_x = np.where(_per(fresh, init_x), init_x, last_x)
            last_p = np.where(_per(fresh, init_p), init_p, last_p)
        x = np.where(_per(step, new_x), new_x, last_x)
        p = np.where(_per(step, new_p), new_p, last_p)
        t = np.where(present, t_s, last_t)
        return np.where(present, self._output(x), np.nan), x, p, t

    def _update(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, h: FloatArray, step: BoolArray
    ) -> tuple[FloatArray, FloatArray]:
        pos, vel = last_x[..., 0], last_x[..., 1]
        p00, p01, p11 = last_p[..., 0], last_p[..., 1], last_p[..., 2]
        # Predict: F = [[1, h], [0, 1]], Q from white acceleration.
        pos_p = pos + h * vel
        q = self.q
        p00_p = p00 + 2 * h * p01 + h * h * p11 + q * h**4 / 4
        p01_p = p01 + h * p11 + q * h**3 / 2
        p11_p = p11 + q * h**2
        # Update with the position measurement.
        s = p00_p + self.r
        k0, k1 = p00_p / s, p01_p / s
        innovation = z - np.where(step, pos_p, 0.0)
        new_p = np.stack([(1 - k0) * p00_p, (1 - k0) * p01_p, p11_p - k1 * p01_p], axis=-1)
        return np.stack([pos_p + k0 * innovation, vel + k1 * innovation], axis=-1), new_p

    def _output(self, x: FloatArray) -> FloatArray:
        out: FloatArray = x[..., 0] + self.predict_s * x[..., 1]
        return out

    def _params(self) -> tuple[float, float, float, float]:
        return (self.q, self.r, self.predict_s, self.reset_gap_s)


# --- Damped-acceleration (Singer) Kalman ---------------------------------------------------------


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


# --- Choosing and stacking the filters -----------------------------------------------------------


_STACKABLE = (OneEuroFilter, ConstantVelocityKalman, DampedAccelerationKalman)
"""The filters :func:`filter_all` steps together (their ``_step`` takes any stack of states)."""


def make_filter(
    kind: str,
    *,
    min_cutoff_hz: float = 1.0,
    beta: float = 4.0,
    d_cutoff_hz: float = 1.0,
    accel_std: float = 8.0,
    meas_std_m: float = 0.03,
    predict_s: float = 0.0,
    jerk_std: float = 3.0,
    accel_tau_s: float = 0.1,
    ca_meas_std_m: float = 0.03,
    ca_predict_s: float = 0.006,
    jerk_per_speed: float = 30.0,
) -> JointFilter:
    """A new filter by name: ``none``, ``one_euro``, ``kalman`` or ``kalman_ca``.

    Raises:
        ValueError: for any other name.
    """
    if kind == "none":
        return PassThrough()
    if kind == "one_euro":
        return OneEuroFilter(min_cutoff_hz, beta, d_cutoff_hz)
    if kind == "kalman":
        return ConstantVelocityKalman(accel_std, meas_std_m, predict_s)
    if kind == "kalman_ca":
        return DampedAccelerationKalman(
            jerk_std, ca_meas_std_m, accel_tau_s, ca_predict_s, jerk_per_speed=jerk_per_speed
        )
    raise ValueError(f"unknown filter {kind!r}: use 'none', 'one_euro', 'kalman' or 'kalman_ca'")
