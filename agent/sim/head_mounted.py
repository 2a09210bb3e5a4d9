"""A depth sensor worn on the head: report B's head-turn schedule, the rig, the pose it reports.

Report B (``shared/papers.md``, B) turned a headset by hand about one axis at a time:
still 1 s, 10° left 1 s, still 1 s, 20° right 1 s, still 1 s, 10° left 1 s, still 3 s
(:data:`REPORT_B_SCHEDULE`, 9 s, looped here). :func:`head_turn_deg` reads the turn angle at any
instant (each move at a constant rate over its second, so 10°/s and 20°/s).

:class:`HeadRig` places the sensor: the head turns about a pivot at the wearer's neck joint;
the sensor is mounted rigidly ``mount_offset_m`` from that pivot in head axes (default 12 cm up,
8 cm forward). Head axes, like the Kinect's camera axes: +X the wearer's left, +Y up, +Z
forward. The head looks horizontally along ``heading_rad`` (about world +Y, 0 looks along +Z),
pitched down ``look_down_deg``, then turned by the schedule about one axis:

- ``yaw``: about head +Y, positive to the left (report B's "left");
- ``pitch``: about head +X, positive looks down;
- ``roll``: about head +Z, positive lifts the left side.

:class:`PoseReport` is what the wearer's tracker says: the pose at ``t + mismatch_ms`` (a pose
attached to the wrong instant) with white noise on position (mm, per axis) and rotation (deg,
per axis of a small rotation vector).

Frames: world +Y up, metres; ``T_world_from_sensor`` maps Kinect camera-frame points into it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.transform import Matrix4, axis_rotation

Axis = Literal["yaw", "pitch", "roll"]
AXES: Final[tuple[Axis, ...]] = ("yaw", "pitch", "roll")
_HEAD_AXIS: Final = {"yaw": "y", "pitch": "x", "roll": "z"}

#: (duration s, turn during it in degrees): report B's test, positive = its "left".
REPORT_B_SCHEDULE: Final[tuple[tuple[float, float], ...]] = (
    (1.0, 0.0),
    (1.0, 10.0),
    (1.0, 0.0),
    (1.0, -20.0),
    (1.0, 0.0),
    (1.0, 10.0),
    (3.0, 0.0),
)


def schedule_duration_s(schedule: tuple[tuple[float, float], ...] = REPORT_B_SCHEDULE) -> float:
    """The length of one pass of ``schedule``, seconds."""
    return float(sum(d for d, _ in schedule))


def head_turn_deg(
    t_s: float,
    schedule: tuple[tuple[float, float], ...] = REPORT_B_SCHEDULE,
    *,
    speed: float = 1.0,
) -> float:
    """The head's turn (degrees) ``t_s`` seconds into ``schedule``, looped.

    Each segment turns by its angle at a constant rate over its duration. ``speed`` > 1 plays
    the schedule faster (same angles, shorter segments): 5 gives up to 100°/s.

    Raises:
        ValueError: ``speed`` not positive or the schedule has no duration.
    """
    if speed <= 0:
        raise ValueError(f"speed must be positive, got {speed}")
    total = schedule_duration_s(schedule)
    if total <= 0:
        raise ValueError("the schedule has no duration")
    t = (t_s * speed) % total
    angle = 0.0
    for duration, turn in schedule:
        if t < duration:
            return angle + turn * t / duration
        t -= duration
        angle += turn
    return angle


@dataclass(frozen=True, slots=True)
class HeadRig:
    """How one wearer's head turns and where the sensor sits on it (see module docstring).

    ``schedule_offset_s`` shifts this wearer in the schedule (wearers need not turn together);
    ``turn_speed`` scales the schedule's rate (:func:`head_turn_deg`).
    """

    axis: Axis = "yaw"
    mount_offset_m: tuple[float, float, float] = (0.0, 0.12, 0.08)
    look_down_deg: float = 10.0
    schedule_offset_s: float = 0.0
    turn_speed: float = 1.0
    schedule: tuple[tuple[float, float], ...] = REPORT_B_SCHEDULE

    def turn_deg(self, t_s: float) -> float:
        """The schedule's turn at ``t_s`` (degrees, about :attr:`axis`)."""
        return head_turn_deg(t_s + self.schedule_offset_s, self.schedule, speed=self.turn_speed)

    def sensor_pose(self, neck_m: npt.ArrayLike, heading_rad: float, t_s: float) -> Matrix4:
        """``T_world_from_sensor`` (4×4, metres) with the head pivot at ``neck_m`` (3,).

        Raises:
            KeyError: :attr:`axis` is not yaw, pitch or roll.
        """
        rotation = (
            axis_rotation("y", heading_rad)
            @ axis_rotation("x", math.radians(self.look_down_deg))
            @ axis_rotation(_HEAD_AXIS[self.axis], math.radians(self.turn_deg(t_s)))
        )
        transform = np.eye(4)
        transform[:3, :3] = rotation
        transform[:3, 3] = np.asarray(neck_m, dtype=np.float64) + rotation @ np.asarray(
            self.mount_offset_m
        )
        return transform


@dataclass(frozen=True, slots=True)
class PoseErrors:
    """What is wrong with a tracker's poses: white noise and a time mismatch.

    position_noise_mm: σ per axis of the position, mm; rotation_noise_deg: σ per axis of a
    small rotation vector applied in sensor axes, degrees; mismatch_ms: the pose attached to a
    frame captured at t is the true pose at t + mismatch_ms (positive: a later pose).
    """

    position_noise_mm: float = 0.0
    rotation_noise_deg: float = 0.0
    mismatch_ms: float = 0.0


def rotation_vector_matrix(rotvec: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(3, 3) rotation by the angle ‖rotvec‖ (radians) about its direction (Rodrigues)."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle < 1e-15:
        return np.eye(3)
    k = v / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    result: npt.NDArray[np.float64] = (
        np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross
    )
    return result


def noisy_pose(transform: Matrix4, errors: PoseErrors, rng: np.random.Generator) -> SensorPose:
    """The :class:`SensorPose` of ``transform`` with ``errors``' white noise added.

    The noise draws use ``rng`` even when σ is 0, so runs with and without noise stay aligned.
    """
    noisy = np.array(transform, dtype=np.float64)
    shift = rng.normal(size=3) * errors.position_noise_mm * 1e-3
    turn = rng.normal(size=3) * math.radians(errors.rotation_noise_deg)
    noisy[:3, :3] = noisy[:3, :3] @ rotation_vector_matrix(turn)
    noisy[:3, 3] += shift
    return pose_from_matrix(noisy)
