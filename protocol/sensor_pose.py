"""A moving sensor's pose (:class:`~skelfuse.protocol.messages.SensorPose`): matrix, time.

A frame of a moving sensor carries ``T_space_from_sensor``: the sensor's pose in its tracking
space (a headset's play area, a motion-capture volume) at the frame's capture instant
(docs/protocol.md §6.3). Agents read poses from a tracker at its own instants; the server may
need a pose between two frames. Both interpolate here: position linearly, rotation by slerp
on the shorter arc, the same rule in both places so that an agent and the server agree.

Frames: ``T_space_from_sensor`` maps sensor-frame points (metres, Kinect v2 camera axes) into
the tracking space (metres; the space's own axes, +Y up for OpenVR's standing universe).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.geometry.quaternion import (
    matrix_to_quaternion,
    quaternion_slerp,
    quaternion_to_matrix,
)
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.transform import Matrix4

F64 = npt.NDArray[np.float64]

__all__ = ["PoseTrack", "interpolate_pose", "pose_from_matrix", "pose_matrix"]


def pose_matrix(pose: SensorPose) -> Matrix4:
    """``T_space_from_sensor`` (4×4 float64, metres) of ``pose``; its quaternion is normalised."""
    transform = np.eye(4)
    transform[:3, :3] = quaternion_to_matrix(np.asarray(pose.rotation_xyzw, dtype=np.float64))
    transform[:3, 3] = pose.position_m
    return transform


def pose_from_matrix(transform: Matrix4) -> SensorPose:
    """The :class:`SensorPose` of a rigid ``T_space_from_sensor`` (4×4, metres); w ≥ 0."""
    matrix = np.asarray(transform, dtype=np.float64)
    x, y, z, w = (float(v) for v in matrix_to_quaternion(matrix[:3, :3]))
    px, py, pz = (float(v) for v in matrix[:3, 3])
    return SensorPose((px, py, pz), (x, y, z, w))


def interpolate_pose(first: SensorPose, second: SensorPose, alpha: float) -> SensorPose:
    """The pose a fraction ``alpha`` of the way from ``first`` to ``second`` (0 → first, 1 →
    second; outside [0, 1] extrapolates): position linear, rotation slerp on the shorter arc."""
    a, b = np.asarray(first.position_m), np.asarray(second.position_m)
    px, py, pz = (float(v) for v in a + alpha * (b - a))
    q = quaternion_slerp(
        np.asarray(first.rotation_xyzw, dtype=np.float64),
        np.asarray(second.rotation_xyzw, dtype=np.float64),
        alpha,
    )
    x, y, z, w = (float(v) for v in q)
    return SensorPose((px, py, pz), (x, y, z, w))


class PoseTrack:
    """Timed poses of one sensor, read at any instant between them.

    Args:
        times_s: (N,) increasing sample instants, seconds on one clock (N ≥ 1).
        poses: the N poses at those instants.
        max_gap_s: two samples further apart than this are not interpolated between (a lost
            tracker): :meth:`at` answers None inside such a gap.
        max_extrapolation_s: how far beyond the first/last sample :meth:`at` still answers,
            holding the end pose (never predicting a motion it has not seen).

    Raises:
        ValueError: lengths differ, no samples, or times not strictly increasing / not finite.
    """

    def __init__(
        self,
        times_s: npt.ArrayLike,
        poses: Sequence[SensorPose],
        *,
        max_gap_s: float = 0.25,
        max_extrapolation_s: float = 0.05,
    ) -> None:
        times = np.asarray(times_s, dtype=np.float64).reshape(-1)
        if len(times) != len(poses):
            raise ValueError(f"{len(times)} times for {len(poses)} poses")
        if len(times) == 0:
            raise ValueError("a pose track needs at least one sample")
        if not np.isfinite(times).all() or (len(times) > 1 and np.any(np.diff(times) <= 0)):
            raise ValueError("pose times must be finite and strictly increasing")
        self.times_s = times
        self.poses = tuple(poses)
        self.max_gap_s = max_gap_s
        self.max_extrapolation_s = max_extrapolation_s

    def at(self, t_s: float) -> SensorPose | None:
        """The pose at ``t_s`` (same clock as ``times_s``), or None outside the track or in a
        gap wider than ``max_gap_s``."""
        times = self.times_s
        if t_s <= times[0]:
            return self.poses[0] if times[0] - t_s <= self.max_extrapolation_s else None
        if t_s >= times[-1]:
            return self.poses[-1] if t_s - times[-1] <= self.max_extrapolation_s else None
        after = int(np.searchsorted(times, t_s, side="right"))
        t0, t1 = times[after - 1], times[after]
        if t1 - t0 > self.max_gap_s:
            return None
        alpha = float((t_s - t0) / (t1 - t0))
        return interpolate_pose(self.poses[after - 1], self.poses[after], alpha)
