"""What the Kalman filters share: their state per coordinate, started, stepped and stacked.

A filter keeps, per coordinate, a state ``x`` (position first), its covariance ``P`` and the
time of its last measurement ``t``; a subclass says how the state starts (:meth:`_init`) and how
one sample moves it (:meth:`_step`, written for any stack of states so that
:func:`skelfuse.fusion.filters.filter_all` can step several persons' filters in one pass).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


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
