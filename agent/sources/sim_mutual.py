"""The ``sim`` source's mutual-capture scenario: one wearer's head-mounted sensor, moving.

Every agent process of the scene simulates the same people (:class:`RingWalkers` on the shared
wall clock) and one wearer's sensor (:class:`agent.sim.mutual.MutualCapture`): its captures
carry the bodies in the sensor frame and the pose the headset attaches (noise, mismatch), and
the source has a ``pose_space``, so the runner registers it as moving (docs/protocol.md §6.3).
The tracking space is the simulated room itself: the pose hint says its world transform is the
identity (``sim_truth``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skelfuse.agent.sim.head_mounted import AXES, Axis, HeadRig, PoseErrors
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.mutual import MutualCapture
from skelfuse.agent.sim.scenarios import RingWalkers
from skelfuse.agent.sources.base import Capture, SensorError, wait_for_due
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body

MUTUAL_SPACE = "room"
"""The tracking space every simulated headset reports its pose in."""


class MutualSimSource:
    """Wearer ``wearer`` of ``persons`` people on a 1.5 m ring, 30 fps in real time.

    Args:
        wearer: which person wears this sensor (0-based; every person is a wearer, each
            2π/persons round the ring and 9/persons s apart in report B's schedule).
        persons: people in the scene (2..6).
        axis: the head's turning axis (yaw, pitch, roll).
        errors: what is wrong with the poses the headset attaches.
        walk_m: how far everyone walks to and fro along their radius (0: standing).
        turn_speed: the schedule's rate (1: report B's, up to 20°/s).
        seed: the sensor's noise seed; params: the sensor model.
        wall_clock_ns, sleep: the clock and sleep (injected in tests).

    Raises:
        ValueError: ``wearer`` outside ``persons``, or fewer than 2 people.
    """

    pose_space = MUTUAL_SPACE

    def __init__(
        self,
        wearer: int,
        persons: int = 3,
        *,
        axis: Axis = "yaw",
        errors: PoseErrors | None = None,
        walk_m: float = 0.6,
        turn_speed: float = 1.0,
        seed: int = 0,
        params: KinectV2Params | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if persons < 2 or not 0 <= wearer < persons:
            raise ValueError(f"wearer {wearer} of {persons} people (2 or more)")
        offset = 9.0 / persons
        rigs = [
            HeadRig(axis=axis, schedule_offset_s=i * offset, turn_speed=turn_speed)
            for i in range(persons)
        ]
        self._capture = MutualCapture(
            RingWalkers(persons, 1.5, walk_m=walk_m), rigs, errors=errors, params=params, seed=seed
        )
        self._wearer = wearer
        self._fps = (params or KinectV2Params()).fps
        self._period_ns = round(1e9 / self._fps)
        self._wall_clock_ns = wall_clock_ns
        self._sleep = sleep
        self._next_ns: int | None = None

    @property
    def sensor_type(self) -> str:
        return "sim"

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def wearer(self) -> int:
        return self._wearer

    @property
    def capture(self) -> MutualCapture:
        """The simulated scene (ground truth for tests)."""
        return self._capture

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        """The tracking space's ``T_world_from_space``: the room is the world."""
        return np.eye(4), "sim_truth"

    def capture_at(self, true_ns: int) -> Capture:
        """The frame captured at ``true_ns`` (no pacing); frames must come in time order."""
        frame = self._capture.frame(self._wearer, true_ns / 1e9)
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in frame.bodies)
        return Capture(true_ns, bodies, frame.floor, frame.pose)

    def next_capture(self, timeout_s: float) -> Capture | None:
        now = self._wall_clock_ns()
        if self._next_ns is None or now - self._next_ns > 5 * self._period_ns:
            self._next_ns = now  # first frame, or we fell far behind: do not catch up
        if not wait_for_due(self._next_ns, now, timeout_s, self._sleep):
            return None
        true_ns = self._next_ns
        self._next_ns += self._period_ns
        return self.capture_at(true_ns)

    def close(self) -> None:
        return None


def mutual_source(options: dict[str, Any]) -> MutualSimSource:
    """The source ``make_source("sim", {"scenario": "mutual", ...})`` builds.

    Options (missing ones take defaults): ``wearer`` (0), ``persons`` (3), ``head_axis``
    (yaw), ``pose_mismatch_ms``, ``pose_noise_mm``, ``pose_noise_deg`` (0), ``walk_m`` (0.6),
    ``turn_speed`` (1), ``seed`` (0).

    Raises:
        SensorError: a bad wearer, person count or axis.
    """
    axis = str(options.get("head_axis") or "yaw")
    if axis not in AXES:
        raise SensorError(f"head axis {axis!r}: choose one of {', '.join(AXES)}")
    errors = PoseErrors(
        position_noise_mm=float(options.get("pose_noise_mm") or 0.0),
        rotation_noise_deg=float(options.get("pose_noise_deg") or 0.0),
        mismatch_ms=float(options.get("pose_mismatch_ms") or 0.0),
    )
    try:
        return MutualSimSource(
            int(options.get("wearer") or 0),
            int(options.get("persons") or 3),
            axis=axis,
            errors=errors,
            walk_m=float(options.get("walk_m", 0.6)),
            turn_speed=float(options.get("turn_speed") or 1.0),
            seed=int(options.get("seed") or 0),
        )
    except ValueError as exc:
        raise SensorError(str(exc)) from exc
