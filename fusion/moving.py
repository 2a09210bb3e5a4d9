"""A moving sensor's frames placed in its tracking space, and where the sensor is at an instant.

A moving sensor (a depth camera on a headset, ``hello.moving``) sends its bodies in its own
camera frame, which moves, with the frame's pose ``T_space_from_sensor`` at the capture instant
(docs/protocol.md §6.3). The server places every such frame in the sensor's tracking space as it
arrives (:func:`placed_in_space`): from then on the sensor's "own frame" is the space, which does
not move, so everything downstream treats it like a fixed sensor whose pose is the space's
``T_world_from_space`` (:mod:`skelfuse.fusion.spaces`): time interpolation between frames (of
bodies that moved in the space, not in a turning camera), association, filters, and the
calibration solvers that work on a sensor's bodies.

What stays the sensor's own is where it is: each placed frame keeps its pose, and
:func:`world_position` gives the sensor's origin in the world at any instant between frames (the
mirror labels and the ray weighting look from there), interpolated by the rule agents use
(:func:`skelfuse.protocol.sensor_pose.interpolate_pose`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.messages import checked_body, checked_frame
from skelfuse.protocol.sensor_pose import interpolate_pose, pose_matrix
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body, Frame, SensorPose

FloatArray = npt.NDArray[np.float64]


class TimedPose(Protocol):
    """A frame at its time on the server's clock (:class:`skelfuse.fusion.sensors.TimedFrame`,
    which imports this module)."""

    t_server_s: float
    frame: Frame


NO_POSE = "no_pose"
"""The rejection reason of a moving sensor's frame that carries no pose (it cannot be placed)."""


def placed_in_space(frame: Frame) -> Frame:
    """``frame`` with its bodies and floor moved from the sensor's frame into its tracking space
    by the frame's own pose (``T_space_from_sensor``); the pose is kept.

    Joints (25, 3) float32 metres, computed in float64 (NaN stays NaN); the floor plane
    ``a·x + b·y + c·z + d = 0`` keeps a unit normal.

    Raises:
        ValueError: the frame has no pose.
    """
    if frame.pose is None:
        raise ValueError("a frame without a pose cannot be placed in a tracking space")
    transform = pose_matrix(frame.pose)
    rotation_t, shift = transform[:3, :3].T, transform[:3, 3]
    bodies = frame.bodies
    if bodies:
        joints = np.array([body.joints_m for body in bodies], dtype=np.float64)
        placed = (joints @ rotation_t + shift).astype(np.float32)
        bodies = tuple(map(_moved, bodies, placed))
    floor = frame.floor
    if floor is not None:
        normal = transform[:3, :3] @ np.asarray(floor[:3], dtype=np.float64)
        a, b, c = (float(v) for v in normal)
        floor = (a, b, c, float(floor[3] - normal @ shift))
    return checked_frame(frame.seq, frame.t_capture_ns, bodies, floor, frame.pose)


def _moved(body: Body, joints_m: npt.NDArray[np.float32]) -> Body:
    return checked_body(body.tracking_id, joints_m, body.states, body.hands)


def position_in_space(frames: Sequence[TimedPose], t_s: float) -> tuple[float, float, float] | None:
    """Where a moving sensor's origin is in its space at ``t_s`` (metres), by
    :func:`sensor_pose_at`'s rule; None without a posed frame."""
    pose = sensor_pose_at(frames, t_s)
    return None if pose is None else pose.position_m


def world_position(
    frames: Sequence[TimedPose], t_s: float, world_from_space: Matrix4
) -> FloatArray | None:
    """A moving sensor's origin in the world at ``t_s``: (3,) float64 metres, or None when no
    frame says where it is."""
    origin = position_in_space(frames, t_s)
    if origin is None:
        return None
    moved: FloatArray = world_from_space[:3, :3] @ np.asarray(origin) + world_from_space[:3, 3]
    return moved


def sensor_pose_at(frames: Sequence[TimedPose], t_s: float) -> SensorPose | None:
    """A moving sensor's pose in its space at server time ``t_s``: interpolated between the two
    frames around it (position linear, rotation slerp), before the first or after the newest
    held at that frame's (its bodies are held the same way); None without a posed frame."""
    if not frames:
        return None
    index = len(frames)
    while index > 0 and frames[index - 1].t_server_s >= t_s:
        index -= 1
    if index == len(frames) or index == 0:
        return frames[-1 if index else 0].frame.pose
    before, after = frames[index - 1], frames[index]
    first, second = before.frame.pose, after.frame.pose
    if first is None or second is None:
        return first or second
    gap = after.t_server_s - before.t_server_s
    return interpolate_pose(first, second, (t_s - before.t_server_s) / gap if gap > 0 else 1.0)
