"""A real server with a moving sensor: the real agent link streams to it (its welcome announces
``moving_sensors``), each frame carries the head-mounted sensor's pose, and the fused person
stands where the truth is although the sensor's head turns all the while. With no fixed sensor
and one tracking space, the space is the world (``floor``)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx
import numpy as np
import pytest

from skelfuse.agent.runner import run_agent
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sources.base import Capture
from skelfuse.protocol.depth_cloud import encode_reply
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import (
    Matrix4,
    apply,
    invert,
    look_at_pose,
    pose_from_position_yaw_pitch,
)
from skelfuse.protocol.wire import Body
from tests.integration.conftest import LiveServer, collect_feed
from tests.support import wait_until

pytestmark = pytest.mark.timeout(90)

TRUTH = standing_pose() * [-1.0, 1.0, -1.0] + [0.0, 0.0, 3.0]  # 3 m away, facing the sensor
ROOM = np.random.default_rng(2).uniform([-3.0, 0.0, 1.0], [3.0, 2.5, 5.0], (2000, 3))


def head_pose(t_s: float) -> Matrix4:
    """A head at 1.6 m looking at the person, turning ±20° in yaw (up to 80°/s)."""
    aim = look_at_pose((0.0, 1.6, 0.0), (0.0, 1.2, 3.0))
    return aim @ pose_from_position_yaw_pitch((0.0, 0.0, 0.0), 20.0 * math.sin(4.0 * t_s))


class HeadSource:
    """A head-mounted sensor seeing one standing person, at 30 fps on the wall clock."""

    sensor_type = "sim"
    fps = 30.0
    pose_space = "room"

    def __init__(self) -> None:
        self._next_ns = time.time_ns()
        self._sent: list[tuple[int, Matrix4]] = []  # (capture stamp, pose) of the newest two

    def request_handlers(self) -> dict[str, Callable[[dict[str, Any]], Any]]:
        return {"depth_cloud": self.depth_cloud}

    def depth_cloud(self, params: dict[str, Any]) -> dict[str, object]:
        """The room's points as the sensor saw them at the frame before its newest (that frame's
        stamp): a frame surely at the server already."""
        captured_ns, pose = self._sent[0]
        return encode_reply(apply(invert(pose), ROOM), t_capture_ns=captured_ns)

    def pose_hint(self) -> None:
        return None

    def next_capture(self, timeout_s: float) -> Capture | None:
        wait_s = (self._next_ns - time.time_ns()) / 1e9
        if wait_s > timeout_s:
            time.sleep(timeout_s)
            return None
        time.sleep(max(wait_s, 0.0))
        now_ns = self._next_ns
        self._next_ns += round(1e9 / self.fps)
        pose = head_pose(now_ns / 1e9)
        self._sent = [*self._sent[-1:], (now_ns, pose)]
        joints = apply(invert(pose), TRUTH).astype(np.float32)
        body = Body(7, joints, np.full(JOINT_COUNT, 2, dtype=np.uint8))
        return Capture(now_ns, (body,), None, pose_from_matrix(pose))

    def close(self) -> None:
        pass


def fused_errors(live_server: LiveServer, truth: np.ndarray) -> list[float]:
    """Median joint error (metres) of each person in the feed's newest 5 messages."""
    feed = collect_feed(live_server.ws_url, 10)
    return [
        float(np.median(np.linalg.norm(np.array(person["joints"])[:, :3] - truth, axis=1)))
        for message in list(feed.values())[-5:]
        for person in message["persons"]
    ]


def test_a_moving_agent_streams_and_its_person_is_fused_where_the_truth_is(
    live_server: LiveServer,
) -> None:
    stop = threading.Event()
    thread = threading.Thread(
        target=run_agent, args=("head-a", HeadSource(), live_server.zmq_url),
        kwargs={"stop": stop}, daemon=True,
    )  # fmt: skip
    thread.start()
    try:

        def row() -> dict[str, object]:
            rows = httpx.get(live_server.http_url + "/api/sensors", timeout=5).json()["sensors"]
            return next((r for r in rows if r["id"] == "head-a"), {})

        assert wait_until(lambda: row().get("frames_received", 0) > 10, 20), row()
        assert row()["calibration"]["state"] == "floor"  # type: ignore[index]
        assert row()["pose_space"] == "room"
        errors = fused_errors(live_server, TRUTH)
        assert errors and max(errors) < 0.03, errors
        assert row()["frames_rejected"] == {}
        # The viewer's depth cloud of a moving camera lands in the world too.
        cloud = httpx.get(live_server.http_url + "/api/sensors/head-a/cloud", timeout=10).json()
        assert cloud["frame"] == "world" and cloud["pose"] == "floor", cloud.get("detail")
        shown = np.array(cloud["points"])
        assert np.abs(shown - ROOM[: len(shown)]).max() < 0.01
        # The space's transform set by hand: an exported calibration with a "spaces" entry.
        world_from_space = pose_from_position_yaw_pitch((1.0, 0.0, 2.0), 90.0)
        file = {
            "format": 1,
            "sensors": {},
            "spaces": {"room": {"T_world_from_space": world_from_space.tolist(), "method": "tape"}},
        }
        url = live_server.http_url + "/api/calibration"
        imported = httpx.post(url + "/import", json=file, timeout=10)
        assert imported.status_code == 200, imported.text
        assert imported.json()["spaces"]["room"]["method"] == "tape"
        assert row()["calibration"]["state"] == "stored"  # type: ignore[index]
        assert httpx.get(url + "/export", timeout=5).json()["spaces"]["room"]["method"] == "tape"
        moved = apply(world_from_space, TRUTH)
        assert wait_until(lambda: max(fused_errors(live_server, moved) or [1.0]) < 0.03, 10)
    finally:
        stop.set()
        thread.join(timeout=10)
