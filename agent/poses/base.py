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
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.quaternion import quaternion_to_matrix
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
