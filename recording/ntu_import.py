"""NTU RGB+D ``.skeleton`` files → a skelfuse recording, for offline replay and fusion.

Each file becomes one simulated Kinect v2 sensor (``ntu-C001``...), its frames stamped at the
dataset's 30 fps from a common start, so the three cameras of one performance line up exactly.
The cameras' poses are not in the dataset: give one ``T_world_from_sensor`` per file (``--pose``)
or fusion has nothing to place them with (calibration from skeletons is a later issue).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from skelfuse.protocol.ntu import NTU_FPS, parse_ntu_name, read_ntu_skeleton
from skelfuse.protocol.recording_file import Header, Record, SensorPose
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Frame, Hello, encode

_T0_NS = 1_700_000_000_000_000_000
_NETWORK_DELAY_NS = 2_000_000


def ntu_recording(
    paths: Sequence[str | Path], poses: Sequence[Matrix4 | None]
) -> tuple[Header, list[Record]]:
    """A recording of ``paths`` played together; ``poses[i]`` calibrates file i (or None)."""
    if len(poses) != len(paths):
        raise ValueError(f"{len(paths)} NTU files but {len(poses)} poses")
    calibration: dict[str, SensorPose] = {}
    sensors: dict[str, dict[str, object]] = {}
    records: list[tuple[int, int, Record]] = []
    for k, (path, pose) in enumerate(zip(paths, poses, strict=True)):
        name = parse_ntu_name(path)
        sensor_id = f"ntu-C{name.camera:03d}" if name else f"ntu-{k + 1}"
        if sensor_id in sensors:
            sensor_id = f"{sensor_id}-{k + 1}"
        frames = read_ntu_skeleton(path)
        sensors[sensor_id] = {"type": "kinect_v2", "pose_state": "stored" if pose is not None
                              else "uncalibrated", "source": Path(path).name}  # fmt: skip
        if pose is not None:
            calibration[sensor_id] = SensorPose(pose, "manual", "stored")
        hello = Hello(sensor_id, "kinect_v2", "ntu-import", NTU_FPS, _T0_NS)
        records.append((_T0_NS, k, Record(_T0_NS, sensor_id, "hello", encode(hello))))
        for i, bodies in enumerate(frames):
            t_ns = _T0_NS + round(i * 1e9 / NTU_FPS) + k  # +k: unique, stable order
            payload = encode(Frame(i + 1, t_ns, bodies))
            t_arrival = t_ns + _NETWORK_DELAY_NS
            records.append((t_arrival, k, Record(t_arrival, sensor_id, "frame", payload)))
    records.sort(key=lambda r: (r[0], r[1]))
    header = Header(_T0_NS / 1e9, "ntu-import", "NTU RGB+D", calibration, sensors)
    return header, [r[2] for r in records]
