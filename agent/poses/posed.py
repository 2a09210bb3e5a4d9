"""Any skeleton source made a moving sensor: each capture carries its pose at capture time.

``PosedSource(inner, poses, pose_space)`` reads ``inner``'s captures and attaches
``T_space_from_sensor`` at ``t_capture_ns`` (+ ``offset_ns``): the pose source's body pose
times the mount (:func:`~skelfuse.agent.poses.base.mount_matrix`). A capture whose pose is
unknown keeps ``pose=None``; the agent's runner does not send it (the server could not place
it) but counts its ``seq``, so the gap shows the loss; the reasons are counted here and logged
(the first of each reason at once, then a summary at most every ``report_s``).
:class:`SensorPoses` is that pose part alone, for a source that needs each pose before it
tracks (the re-projected Azure Kinect source takes its ``at`` as ``pose_at``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, Final

import numpy as np

from skelfuse.agent.poses.base import PoseSource, compose
from skelfuse.agent.sources.base import Capture, SkeletonSource
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.transform import Matrix4

logger = logging.getLogger(__name__)

# What the runner looks up with getattr on a source, passed through from the inner one.
_PASSED_THROUGH: Final = frozenset({"request_handlers", "wall_clock_ns", "waits_for_server"})


class SensorPoses:
    """The sensor's pose at capture instants: a pose source's body pose times the mount.

    Args:
        poses: where the body carrying the sensor is (:class:`PoseSource`), on the capture
            stamps' clock.
        mount: ``T_body_from_sensor`` (4×4); None: the sensor is the tracked body.
        offset_ns: a capture stamped t is posed at t + offset_ns (the pose clock runs this far
            ahead of the capture stamps, or the stamps are late by it).
        report_s: the least time between two logged summaries of unposed captures.
        monotonic: seconds clock for those summaries (injected in tests).
    """

    def __init__(
        self,
        poses: PoseSource,
        *,
        mount: Matrix4 | None = None,
        offset_ns: int = 0,
        report_s: float = 10.0,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.poses = poses
        identity = mount is None or np.array_equal(np.asarray(mount), np.eye(4))
        self._mount = None if identity else pose_from_matrix(np.asarray(mount, dtype=np.float64))
        self._offset_ns = offset_ns
        self._report_s = report_s
        self._monotonic = monotonic
        self._last_report = monotonic()
        self.posed = 0
        self.unposed: Counter[str] = Counter()

    def at(self, t_capture_ns: int) -> SensorPose | None:
        """``T_space_from_sensor`` for a capture stamped ``t_capture_ns``, or None (counted)."""
        body = self.poses.pose_at(t_capture_ns + self._offset_ns)
        if body is None:
            self._miss(getattr(self.poses, "last_miss", "") or "no pose")
            return None
        self.posed += 1
        if self._mount is None:
            return body
        return compose(body, self._mount)

    def _miss(self, reason: str) -> None:
        first = reason not in self.unposed
        self.unposed[reason] += 1
        if first:
            logger.warning("captures without a pose are not sent: %s", reason)
        now = self._monotonic()
        if now - self._last_report >= self._report_s:
            self._last_report = now
            counts = ", ".join(f"{n} {why}" for why, n in self.unposed.most_common())
            logger.warning("%d captures posed, unposed: %s", self.posed, counts)

    def close(self) -> None:
        """Close the pose source."""
        self.poses.close()


class PosedSource:
    """``inner``'s captures with poses from ``poses``; registers as moving in ``pose_space``.

    Args:
        inner: the skeleton source (its captures in its sensor frame, stamped on its clock).
        poses: where the body carrying the sensor is (:class:`PoseSource`), on that clock.
        pose_space: the tracking space's id in ``hello`` (one per tracking system and room).
        mount, offset_ns, report_s, monotonic: as :class:`SensorPoses`.
    """

    def __init__(
        self,
        inner: SkeletonSource,
        poses: PoseSource,
        pose_space: str,
        *,
        mount: Matrix4 | None = None,
        offset_ns: int = 0,
        report_s: float = 10.0,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.inner = inner
        self.poses = SensorPoses(
            poses, mount=mount, offset_ns=offset_ns, report_s=report_s, monotonic=monotonic
        )
        self.pose_space = pose_space

    def __getattr__(self, name: str) -> Any:
        # Only the runner's optional hooks; anything else is a real AttributeError.
        if name in _PASSED_THROUGH:
            return getattr(self.inner, name)
        raise AttributeError(name)

    @property
    def sensor_type(self) -> str:
        return self.inner.sensor_type

    @property
    def fps(self) -> float:
        return self.inner.fps

    @property
    def posed(self) -> int:
        """Captures posed so far."""
        return self.poses.posed

    @property
    def unposed(self) -> Counter[str]:
        """Captures without a pose, by reason."""
        return self.poses.unposed

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        """None: a moving sensor has no one world pose (its space is calibrated instead)."""
        return None

    def sensor_pose_at(self, t_capture_ns: int) -> SensorPose | None:
        """``T_space_from_sensor`` for a capture stamped ``t_capture_ns``, or None (counted)."""
        return self.poses.at(t_capture_ns)

    def next_capture(self, timeout_s: float) -> Capture | None:
        """The inner source's next capture with its pose (``pose=None`` when unknown)."""
        capture = self.inner.next_capture(timeout_s)
        if capture is None:
            return None
        return dataclasses.replace(capture, pose=self.poses.at(capture.t_capture_ns))

    def close(self) -> None:
        """Close the inner source and the pose source."""
        try:
            self.inner.close()
        finally:
            self.poses.close()
