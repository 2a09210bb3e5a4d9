"""The seam between sensors and the agent's sender.

Every source (simulator, recording, Kinect v2 SDK, Azure/Femto body tracking) delivers captures
in the Kinect v2 joint set, metres, in its own camera frame: the conversion from an SDK's native
skeleton happens inside the source, so the rest of the agent and the server see one format.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body


class SensorError(Exception):
    """A source failed (device unplugged, SDK missing, recording unreadable...)."""


@dataclass(frozen=True, slots=True)
class Capture:
    """One sensor frame: bodies in the sensor frame, capture time on this PC's wall clock.

    ``pose``: a moving sensor's ``T_space_from_sensor`` at ``t_capture_ns`` (docs/protocol.md
    §6.3); None for a fixed sensor, or for a moving one whose tracker lost it at that instant.
    """

    t_capture_ns: int
    bodies: tuple[Body, ...]
    floor: tuple[float, float, float, float] | None = None
    pose: SensorPose | None = None


def wait_for_due(
    due_ns: int, now_ns: int, timeout_s: float, sleep: Callable[[float], None]
) -> bool:
    """Sleep until a frame is due, when that is within the caller's timeout.

    Args:
        due_ns: when the frame is due on the source's clock; now_ns: that clock now;
        timeout_s: the longest ``next_capture`` may block; sleep: sleeps seconds (injected).

    Returns:
        True once the frame is due (at once when it already is); False after sleeping
        ``timeout_s`` when it is due later (``next_capture`` then returns None).
    """
    wait_s = (due_ns - now_ns) / 1e9
    if wait_s > timeout_s:
        sleep(timeout_s)
        return False
    if wait_s > 0:
        sleep(wait_s)
    return True


class SkeletonSource(Protocol):
    """What the agent needs from a sensor.

    Optional, looked up by the runner with ``getattr``: ``request_handlers()`` (requests the
    source answers, e.g. ``depth_cloud``), ``wall_clock_ns`` (a source with its own clock),
    ``waits_for_server`` (True: start reading only once registered, for recordings) and
    ``pose_space`` (a moving sensor's tracking space id: its hello says ``moving`` and its
    captures carry poses; None or absent for a fixed sensor).
    """

    @property
    def sensor_type(self) -> str:
        """Wire ``sensor_type``: kinect_v2, azure_kinect, femto, sim or replay."""
        ...

    @property
    def fps(self) -> float: ...

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        """A ``T_world_from_sensor`` the source knows (and its source tag), or None."""
        ...

    def next_capture(self, timeout_s: float) -> Capture | None:
        """Block until the next frame (None if none came within ``timeout_s``)."""
        ...

    def close(self) -> None: ...
