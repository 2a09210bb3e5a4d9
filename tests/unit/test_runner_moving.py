"""The agent's runner registers a source with a ``pose_space`` as moving and sends its poses."""

from __future__ import annotations

from skelfuse.agent.runner import make_hello
from skelfuse.agent.sources.base import Capture
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.transform import Matrix4

POSE = SensorPose((0.0, 1.6, 0.0), (0.0, 0.0, 0.0, 1.0))


class _Source:
    sensor_type = "sim"
    fps = 30.0

    def __init__(self, pose_space: str | None) -> None:
        if pose_space is not None:
            self.pose_space = pose_space

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None

    def next_capture(self, timeout_s: float) -> Capture | None:
        return Capture(1, (), None, POSE)

    def close(self) -> None:
        pass


def test_a_source_with_a_pose_space_registers_as_moving() -> None:
    hello = make_hello("head0", _Source("room"))
    assert hello.moving and hello.pose_space == "room"


def test_a_source_without_one_registers_as_fixed() -> None:
    hello = make_hello("k0", _Source(None))
    assert not hello.moving and hello.pose_space is None
