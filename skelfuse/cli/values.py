"""Command-line values -> typed values, and the error for one that cannot be used.

Every command module imports these; none imports another command module.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from skelfuse.fusion.settings import FusionSettings
    from skelfuse.protocol.transform import Matrix4


class UsageError(Exception):
    """A command-line value that cannot be used; the message says what to type instead."""


def parse_pose(text: str) -> tuple[tuple[float, float, float], float, float]:
    """``X,Y,Z,YAW_DEG[,PITCH_DEG]`` -> position (m), yaw (deg), pitch (deg, 0 if not given).

    Raises:
        UsageError: not 4 or 5 finite numbers, or a pitch outside -90..90 degrees.
    """
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise UsageError(f"--pose {text!r}: expected numbers X,Y,Z,YAW_DEG[,PITCH_DEG]") from exc
    if len(values) not in (4, 5) or not all(map(math.isfinite, values)):
        raise UsageError(
            f"--pose {text!r}: expected 4 or 5 finite numbers X,Y,Z,YAW_DEG[,PITCH_DEG]"
        )
    pitch = values[4] if len(values) == 5 else 0.0
    if not -90.0 <= pitch <= 90.0:
        raise UsageError(f"--pose pitch {pitch} must be within -90..90 degrees")
    return (values[0], values[1], values[2]), values[3], pitch


def pose_matrix(text: str) -> Matrix4:
    """``X,Y,Z,YAW_DEG[,PITCH_DEG]`` -> (4, 4) ``T_world_from_sensor`` (metres, Y up).

    Raises:
        UsageError: as :func:`parse_pose`.
    """
    from skelfuse.protocol.transform import pose_from_position_yaw_pitch

    position, yaw, pitch = parse_pose(text)
    return pose_from_position_yaw_pitch(position, yaw, pitch)


def parse_host_port(text: str, default_port: int) -> tuple[str, int]:
    """``HOST:PORT``, ``HOST`` or ``:PORT`` (host 127.0.0.1) -> (host, port); IPv6 in brackets.

    Raises:
        UsageError: the port is not a number in 1..65535.
    """
    host, sep, port = text.rpartition(":")
    if not sep:
        return text, default_port
    try:
        number = int(port)
    except ValueError as exc:
        raise UsageError(f"{text!r}: the port must be a number") from exc
    if not 0 < number < 65536:
        raise UsageError(f"{text!r}: port out of range")
    return host.strip("[]") or "127.0.0.1", number


def fusion_settings(path: str | None) -> FusionSettings:
    """Defaults, or the deployment's ``--fusion-config`` TOML file.

    Raises:
        UsageError: the file cannot be read or holds invalid settings (every problem listed).
    """
    from skelfuse.fusion.config import FusionConfigError, load_fusion_settings
    from skelfuse.fusion.settings import FusionSettings

    if path is None:
        return FusionSettings()
    try:
        return load_fusion_settings(path)
    except FusionConfigError as exc:
        raise UsageError(str(exc)) from exc
