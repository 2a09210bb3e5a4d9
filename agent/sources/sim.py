"""The ``sim`` source: a virtual Kinect v2 watching virtual performers, paced in real time."""

from __future__ import annotations

import time
from collections.abc import Callable

from agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from agent.sim.performer import Performer
from agent.sources.base import Capture
from protocol.transform import Matrix4
from protocol.wire import Body


class SimSource:
    """Frames at the sensor's own 30 fps clock; each shows the performers at that instant.

    ``clock_offset_ns`` makes this "PC" clock wrong by a fixed amount (to exercise the server's
    clock alignment): capture stamps carry the offset, the scene is rendered at the true time.
    """

    def __init__(
        self,
        performer: Performer,
        T_world_from_sensor: Matrix4,
        *,
        params: KinectV2Params | None = None,
        seed: int = 0,
        clock_offset_ns: int = 0,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self._performer = performer
        self._kinect = SimulatedKinect(T_world_from_sensor, params, seed=seed)
        self._clock_offset_ns = clock_offset_ns
        self._wall_clock_ns = wall_clock_ns
        self._sleep = sleep
        self._period_ns = round(1e9 / self._kinect.params.fps)
        self._next_ns: int | None = None

    @property
    def sensor_type(self) -> str:
        return "sim"

    @property
    def fps(self) -> float:
        return self._kinect.params.fps

    @property
    def kinect(self) -> SimulatedKinect:
        return self._kinect

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return self._kinect.T_world_from_sensor.copy(), "sim_truth"

    def capture_at(self, true_ns: int) -> Capture:
        """Render the frame captured at true time ``true_ns`` (no pacing)."""
        t_s = true_ns / 1e9
        observations = self._kinect.observe(self._performer.joints_at(t_s), t_s)
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
        return Capture(
            t_capture_ns=true_ns + self._clock_offset_ns,
            bodies=bodies,
            floor=self._kinect.floor_plane(),
        )

    def next_capture(self, timeout_s: float) -> Capture | None:
        now = self._wall_clock_ns()
        if self._next_ns is None or now - self._next_ns > 5 * self._period_ns:
            self._next_ns = now  # first frame, or we fell far behind: do not catch up
        wait_s = (self._next_ns - now) / 1e9
        if wait_s > timeout_s:
            self._sleep(timeout_s)
            return None
        if wait_s > 0:
            self._sleep(wait_s)
        true_ns = self._next_ns
        self._next_ns += self._period_ns
        return self.capture_at(true_ns)

    def close(self) -> None:
        return None
