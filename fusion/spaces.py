"""Where fusion takes each sensor's pose from: a fixed sensor's own, a moving sensor's space's.

A fixed sensor's ``T_world_from_sensor`` is its stored calibration, else its agent's
``pose_hint``. A moving sensor's frames are placed in its tracking space as they arrive
(:func:`skelfuse.fusion.sensors.placed_in_space`), so what fusion needs of it is the space's
``T_world_from_space``, one per space, shared by all its sensors (docs/calibration.md "Tracking
spaces"), taken from the first of:

1. ``stored``: the calibration's ``spaces`` entry;
2. ``sim_truth`` / ``manual``: a ``pose_hint`` of one of the space's moving sensors (for a moving
   sensor the hint is its space's pose, the only thing about it that stands still), the first by
   sensor id;
3. ``floor``: the identity, when the space is the only frame of reference there is: no stored
   sensor or other stored space, no fixed sensor with a hint, no moving sensor in another space.
   OpenVR's standing space (and any space with +Y up and the floor at y = 0) then *is* the world;
4. otherwise none: the space's sensors stay ``uncalibrated`` until it is calibrated.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.store import Calibration, SensorCalibration, SpaceCalibration
from skelfuse.fusion.sensors import SensorState, sensor_pose_at
from skelfuse.protocol.constants import MOVING_SENSORS
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.transform import Matrix4, apply

SERVER_FEATURES: tuple[str, ...] = (MOVING_SENSORS,)
"""What the hub's ``welcome`` announces (docs/protocol.md §6.2)."""

CLOUD_POSE_SLACK_S = 0.1
"""A moving sensor's depth cloud is placed by its frames' poses only if it was captured within
this long of a frame (seconds): beyond, where the sensor looked is not known."""

_IDENTITY = np.eye(4)
_IDENTITY.flags.writeable = False


def resolve_pose(
    calibration: Calibration | None, sensors: Mapping[str, SensorState], sensor_id: str
) -> tuple[Matrix4 | None, str]:
    """The pose fusion uses for ``sensor_id`` and where it comes from.

    Returns:
        ``T_world_from_sensor`` (a fixed sensor) or ``T_world_from_space`` (a moving one), 4×4
        float64 metres, or None; and its source: ``stored``, ``sim_truth``, ``manual``,
        ``floor`` (moving sensors only) or ``uncalibrated``.
    """
    sensor = sensors.get(sensor_id)
    if sensor is not None and sensor.moving and sensor.pose_space is not None:
        return space_pose(calibration, sensors, sensor.pose_space)
    if calibration is not None and sensor_id in calibration.sensors:
        return calibration.sensors[sensor_id].T_world_from_sensor, "stored"
    if sensor is not None and sensor.pose_hint is not None:
        return sensor.pose_hint, sensor.pose_hint_source or "manual"
    return None, "uncalibrated"


def space_pose(
    calibration: Calibration | None, sensors: Mapping[str, SensorState], space_id: str
) -> tuple[Matrix4 | None, str]:
    """``T_world_from_space`` of tracking space ``space_id`` and where it comes from (the
    module's rules, in order)."""
    if calibration is not None and space_id in calibration.spaces:
        return calibration.spaces[space_id].T_world_from_space, "stored"
    hinted = sorted(
        (s.sensor_id, s)
        for s in sensors.values()
        if s.moving and s.pose_space == space_id and s.pose_hint is not None
    )
    if hinted:
        sensor = hinted[0][1]
        assert sensor.pose_hint is not None
        return sensor.pose_hint, sensor.pose_hint_source or "manual"
    if _only_frame_of_reference(calibration, sensors, space_id):
        return _IDENTITY, "floor"
    return None, "uncalibrated"


def _only_frame_of_reference(
    calibration: Calibration | None, sensors: Mapping[str, SensorState], space_id: str
) -> bool:
    if calibration is not None and (calibration.sensors or calibration.spaces):
        return False
    for sensor in sensors.values():
        if sensor.moving:
            if sensor.pose_space != space_id:
                return False
        elif sensor.pose_hint is not None:
            return False
    return True


def split_by_space(
    sensors: Mapping[str, SensorState], updates: Mapping[str, SensorCalibration]
) -> tuple[dict[str, SensorCalibration], dict[str, SpaceCalibration]]:
    """A calibration run's results as stored: fixed sensors' poses by sensor id, and a moving
    sensor's (solved from its bodies in its space: ``T_world_from_space``) as its space's.

    Two moving sensors of one space solved in one run give that space the first by sensor id
    (both solve the same transform)."""
    fixed: dict[str, SensorCalibration] = {}
    spaces: dict[str, SpaceCalibration] = {}
    for sensor_id, result in sorted(updates.items()):
        sensor = sensors.get(sensor_id)
        if sensor is None or not sensor.moving or sensor.pose_space is None:
            fixed[sensor_id] = result
        elif sensor.pose_space not in spaces:
            details = {**result.details, "sensor": sensor_id}
            spaces[sensor.pose_space] = SpaceCalibration(
                result.T_world_from_sensor, result.method, result.residual_mm, details
            )
    return fixed, spaces


def cloud_in_space(
    sensor: SensorState | None, t_capture_ns: object, points: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """A depth cloud (N, 3) metres in the sensor's frame, as the calibration's ICP must see it:
    a moving sensor's moved into its tracking space by its pose at the cloud's capture instant
    (``t_capture_ns`` on the agent's clock, mapped like its frames'); anyone else's unchanged.

    Raises:
        ValueError: a moving sensor's cloud without a capture time, or captured further than
            :data:`CLOUD_POSE_SLACK_S` from its frames (its pose then is not known).
    """
    if sensor is None or not sensor.moving:
        return points
    offset = sensor.clock_offset_s
    if not isinstance(t_capture_ns, int) or offset is None or not sensor.frames:
        raise ValueError(
            "a moving sensor's depth cloud needs its capture time and the sensor's frames"
        )
    return cloud_at(sensor, t_capture_ns / 1e9 + offset - sensor.lag_s, points)


def cloud_at(
    sensor: SensorState, t_s: float, points: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """A moving sensor's cloud (N, 3) metres captured at server time ``t_s``, moved from its
    camera frame into its tracking space by its frames' pose then.

    Raises:
        ValueError: ``t_s`` is further than :data:`CLOUD_POSE_SLACK_S` from its frames.
    """
    pose = sensor_pose_at(sensor.frames, t_s)
    near = bool(sensor.frames) and (
        sensor.frames[0].t_server_s - CLOUD_POSE_SLACK_S
        <= t_s
        <= sensor.frames[-1].t_server_s + CLOUD_POSE_SLACK_S
    )
    if pose is None or not near:
        raise ValueError("its depth cloud was captured where no frame says where the sensor was")
    return apply(pose_matrix(pose), points)
