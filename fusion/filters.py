"""Temporal filters for fused skeletons: vectorised One Euro and constant-velocity Kalman.

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

Added latency of both, measured on ramps and steps, is in docs/fusion.md
(``python -m bench accuracy --latency``).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.filters_ca import DampedAccelerationKalman
from skelfuse.fusion.kalman_state import BoolArray, KalmanState

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
