"""The ``sim`` source: a virtual sensor (the Kinect v2 model or the depth body tracker model)
watching virtual performers, paced in real time."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skelfuse.agent.sim.depth_camera import KINECT_V2_DEPTH
from skelfuse.agent.sim.hands import simulated_hands
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.performer import Performer
from skelfuse.agent.sim.room import Room, capture_point_cloud, default_room
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel, SimulatedSensor
from skelfuse.agent.sources.base import Capture, wait_for_due
from skelfuse.protocol.depth_cloud import decode_request, encode_reply
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body


class SimSource:
    """Frames at the sensor's own 30 fps clock; each shows the performers at that instant.

    ``clock_offset_ns`` and ``clock_drift_ppm`` make this "PC" clock wrong (to exercise the
    server's clock alignment): capture stamps and heartbeats use the wrong clock, the scene is
    rendered at the true time. ``hand_states`` adds made-up Kinect v2 hand states to each body
    (:mod:`agent.sim.hands`; they change nothing else in the frames). ``error_model`` picks the
    sensor's error model (default: the Kinect v2 model with ``params``; a random unit is drawn
    from ``seed``).
    """

    def __init__(
        self,
        performer: Performer,
        T_world_from_sensor: Matrix4,
        *,
        params: KinectV2Params | None = None,
        error_model: ErrorModel = DEFAULT_ERROR_MODEL,
        seed: int = 0,
        clock_offset_ns: int = 0,
        clock_drift_ppm: float = 0.0,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
        room: Room | None = None,
        send_pose_hint: bool = True,
        hand_states: bool = True,
    ) -> None:
        self._performer = performer
        self._room = room or default_room()
        self._depth_rng = np.random.default_rng(seed + 7919)
        self._send_pose_hint = send_pose_hint
        self._hand_states = hand_states
        self._sensor = error_model.sensors([T_world_from_sensor], [seed], seed, params)[0]
        self._clock_offset_ns = clock_offset_ns
        self._clock_drift = clock_drift_ppm * 1e-6
        self._wall_clock_ns = wall_clock_ns
        self._clock_epoch_ns = wall_clock_ns()
        self._sleep = sleep
        self._period_ns = round(1e9 / self._sensor.params.fps)
        self._next_ns: int | None = None

    @property
    def sensor_type(self) -> str:
        return "sim"

    @property
    def fps(self) -> float:
        return self._sensor.params.fps

    @property
    def sensor(self) -> SimulatedSensor:
        """The simulated sensor's error model (its pose, parameters and processes)."""
        return self._sensor

    def agent_clock_ns(self, true_ns: int | None = None) -> int:
        """This simulated PC's (wrong) wall clock at true time ``true_ns`` (default: now)."""
        true = self._wall_clock_ns() if true_ns is None else true_ns
        drift = round((true - self._clock_epoch_ns) * self._clock_drift)
        return true + self._clock_offset_ns + drift

    def wall_clock_ns(self) -> int:
        """The clock the agent stamps everything with (frames and heartbeats)."""
        return self.agent_clock_ns()

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        if not self._send_pose_hint:
            return None
        return self._sensor.T_world_from_sensor.copy(), "sim_truth"

    def request_handlers(self) -> dict[str, Callable[[dict[str, Any]], Any]]:
        """What the server may ask this sensor for (see docs/protocol.md, requests)."""
        return {"depth_cloud": self.depth_cloud}

    def depth_cloud(self, params: dict[str, Any]) -> dict[str, object]:
        """Render one depth frame of the room and the performers now, back-projected.

        Blocks the capture loop for the rendering time (a few hundred ms): frames due meanwhile
        are skipped, as a real agent busy with a depth capture would.
        """
        request = decode_request(params)  # DecodeError: the agent answers with a refusal
        true_ns = self._wall_clock_ns()
        persons = self._performer.joints_at(true_ns / 1e9)
        points = capture_point_cloud(
            self._room,
            persons,
            self._sensor.T_world_from_sensor,
            self._depth_rng,
            max_points=request.max_points,
        )
        intrinsics = KINECT_V2_DEPTH
        return encode_reply(
            points,
            t_capture_ns=self.agent_clock_ns(true_ns),
            intrinsics={
                "width": intrinsics.width,
                "height": intrinsics.height,
                "fx": intrinsics.fx,
                "fy": intrinsics.fy,
                "cx": intrinsics.cx,
                "cy": intrinsics.cy,
            },
        )

    def capture_at(self, true_ns: int) -> Capture:
        """Render the frame captured at true time ``true_ns`` (no pacing)."""
        t_s = true_ns / 1e9
        observations = self._sensor.observe(self._performer.joints_at(t_s), t_s)
        bodies = tuple(
            Body(
                o.tracking_id,
                o.joints_m,
                o.states,
                simulated_hands(o.joints_m, o.states, o.tracking_id, t_s)
                if self._hand_states
                else None,
            )
            for o in observations
        )
        return Capture(
            t_capture_ns=self.agent_clock_ns(true_ns),
            bodies=bodies,
            floor=self._sensor.floor_plane(),
        )

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
