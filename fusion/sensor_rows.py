"""The sensors table of ``GET /api/sensors``: one JSON-ready row per known sensor."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from skelfuse.fusion.drift import DriftMonitor
from skelfuse.fusion.sensors import SensorState
from skelfuse.protocol.transform import Matrix4


def sensor_rows(
    sensors: Iterable[SensorState],
    pose_of: Callable[[str], tuple[Matrix4 | None, str]],
    drift: DriftMonitor | None,
    now_mono: float,
) -> list[dict[str, object]]:
    """Session, health counters, clock, calibration and drift of each sensor, sorted by id.

    ``pose_of`` gives a sensor's ``T_world_from_sensor`` and where it comes from (the engine's
    :meth:`~skelfuse.fusion.engine.FusionEngine.pose_of`; a moving sensor's is its tracking
    space's, and its row names the space: ``pose_space``); ``now_mono``: monotonic seconds.
    """
    rows: list[dict[str, object]] = []
    for sensor in sorted(sensors, key=lambda x: x.sensor_id):
        pose, state = pose_of(sensor.sensor_id)
        age = None if sensor.last_frame_mono is None else now_mono - sensor.last_frame_mono
        rows.append(
            {
                "id": sensor.sensor_id,
                "type": sensor.sensor_type,
                "agent_version": sensor.agent_version,
                "connected": sensor.connected,
                "fps": round(sensor.fps(now_mono), 2) if sensor.connected else 0.0,
                "last_frame_age_s": None if age is None else round(age, 4),
                "bodies": sensor.bodies_last if sensor.connected else 0,
                "frames_received": sensor.frames_received,
                "frames_rejected": dict(sensor.frames_rejected),
                "sequence_gaps": sensor.sequence_gaps,
                "clock_offset_s": sensor.clock_offset_s,
                "clock_source": sensor.clock_source,
                "clock_lag_s": sensor.lag_s,
                "round_trip_ms": None
                if sensor.round_trip.rtt_s is None
                else round(sensor.round_trip.rtt_s * 1000, 3),
                "calibration": {
                    "state": state,
                    "T_world_from_sensor": None if pose is None else pose.tolist(),
                },
                "drift": None
                if drift is None or (status := drift.status(sensor.sensor_id)) is None
                else status.to_json(),
            }
        )
        if sensor.moving:  # only then, so fixed sensors' rows are as before
            rows[-1]["pose_space"] = sensor.pose_space
    return rows
