"""The seam between a tracker and the agent, and the mounting transform.

A pose source answers: where was the tracked body (a headset, a tracker puck, a simulated head)
at an instant of the agent's wall clock? The depth camera is fixed to that body, so its pose is
the body's pose times the mounting transform (:func:`mount_matrix`):
``T_space_from_sensor = T_space_from_body · T_body_from_sensor``.

Axes: every pose here uses the sensor convention of docs/protocol.md §8 for the *body* too
(+X the body's left, +Y its up, +Z where it looks, metres). A tracker with other axes (OpenVR:
+X right, +Y up, −Z forward) converts its body frame first (:data:`SENSOR_AXES_IN_OPENVR`), so
a mount of zero offset and identity rotation means "the camera looks where the body looks".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, Protocol

import numpy as np

from skelfuse.agent.sources.base import SensorError
from skelfuse.geometry.quaternion import quaternion_to_matrix
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.transform import Matrix4

# Sensor-convention axes (+X left, +Y up, +Z forward) in OpenVR's device axes (+X right, +Y up,
# −Z forward): a half turn about Y, ``p_openvr_device = R · p_sensor_convention``.
SENSOR_AXES_IN_OPENVR: Final = np.diag([-1.0, 1.0, -1.0, 1.0])


class PoseSource(Protocol):
    """Where the tracked body was at an instant.

    Optional, looked up with ``getattr``: ``last_miss`` (str), why the last :meth:`pose_at`
    answered None, for the agent's counts and logs.
    """

    def pose_at(self, t_ns: int) -> SensorPose | None:
        """``T_space_from_body`` (metres, sensor-convention body axes) at
        ``t_ns`` (ns since the Unix epoch on the agent's wall clock), or None when unknown
        (tracker lost, outside a recorded track, too far in the past to ask for)."""
        ...

    def close(self) -> None: ...


def mount_matrix(values: Sequence[float]) -> Matrix4:
    """``T_body_from_sensor`` from ``(x, y, z, qx, qy, qz, qw)``: the depth camera's origin in
    the body's frame (metres; +X the body's left, +Y up, +Z forward) and the quaternion turning
    camera axes into body axes (normalised here).

    Raises:
        SensorError: not 7 finite numbers, or a quaternion of norm outside 0.9..1.1 (a typo
            rather than rounding).
    """
    numbers = [float(v) for v in values]
    if len(numbers) != 7 or not all(math.isfinite(v) for v in numbers):
        raise SensorError(f"a mount is 7 finite numbers x,y,z,qx,qy,qz,qw, not {values!r}")
    q = np.asarray(numbers[3:], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if not 0.9 <= norm <= 1.1:
        raise SensorError(f"the mount's quaternion {numbers[3:]} has norm {norm:.3f}, not 1")
    transform = np.eye(4)
    transform[:3, :3] = quaternion_to_matrix(q / norm)
    transform[:3, 3] = numbers[:3]
    return transform


def compose(first: SensorPose, second: SensorPose) -> SensorPose:
    """``T_first · T_second`` of two rigid poses (e.g. ``T_space_from_body · T_body_from_sensor``),
    on plain floats: a few µs per capture, where the 4×4 route through
    :func:`~skelfuse.protocol.sensor_pose.pose_matrix` costs ~100× more. The quaternion is
    unit (from unit inputs) with w ≥ 0, as :func:`~skelfuse.protocol.sensor_pose.pose_from_matrix`
    gives it."""
    ax, ay, az, aw = first.rotation_xyzw
    bx, by, bz, bw = second.rotation_xyzw
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    w = aw * bw - ax * bx - ay * by - az * bz
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0:
        norm = -norm
    # second's origin rotated by first (q v q*: v + 2w(u × v) + 2u × (u × v)), then moved.
    vx, vy, vz = second.position_m
    tx, ty, tz = 2 * (ay * vz - az * vy), 2 * (az * vx - ax * vz), 2 * (ax * vy - ay * vx)
    px = vx + aw * tx + (ay * tz - az * ty) + first.position_m[0]
    py = vy + aw * ty + (az * tx - ax * tz) + first.position_m[1]
    pz = vz + aw * tz + (ax * ty - ay * tx) + first.position_m[2]
    return SensorPose((px, py, pz), (x / norm, y / norm, z / norm, w / norm))
