"""What the Kalman filters share: their state per coordinate, started, stepped and stacked.

A filter keeps, per coordinate, a state ``x`` (position first), its covariance ``P`` and the
time of its last measurement ``t``; a subclass says how the state starts (:meth:`_init`) and how
one sample moves it (:meth:`_update`: predict over ``h`` seconds, then correct with the
measurement). :meth:`_step` does the rest for both, on any stack of states, so that
:func:`skelfuse.fusion.filters.filter_all` can step several persons' filters in one pass: a
missing coordinate keeps its state, one missing longer than ``reset_gap_s`` (or never seen)
restarts from its next measurement.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
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
    def _update(
        self, z: FloatArray, last_x: FloatArray, last_p: FloatArray, h: FloatArray, step: BoolArray
    ) -> tuple[FloatArray, FloatArray]:
        """Predict ``h`` seconds ahead and correct with ``z`` where ``step``; new state and P."""

    @abstractmethod
    def _output(self, x: FloatArray) -> FloatArray:
        """The position the filter gives out from its state (with its lead, if any)."""

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
