"""Small performers for benchmark scenarios: people walking lines, crossing and occluding.

Same contract as :mod:`agent.sim.performer` (a pure function of time, the ground truth), built
on its forward-kinematics body (:func:`pose_joints`) and gait.

- :class:`LineWalkers`: each person walks back and forth between two points (turning round at
  each end), so two people on crossing lines pass close to each other, and a person walking in
  front of another hides them from some sensors.
- :class:`Standing`: one person standing still, facing a given heading (the paper's
  pre-measurement pose: standing in front of one sensor for a few seconds).
- :class:`Segment`: a time window of another performer, looped (e.g. only the turning part of
  the built-in routine).
- :class:`RingWalkers`: people on a circle facing its centre (mutual capture: each looks at the
  others), optionally walking to and fro along their radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.performer import BodyShape, Performer, Pose, pose_joints
from skelfuse.protocol.skeleton import JOINT_COUNT


@dataclass(frozen=True, slots=True)
class Line:
    """One person's walk: from ``start`` to ``end`` (x, z metres) and back, looped.

    ``pause_s`` standing at each end (arms raised sideways during it when ``arms``), ``t0_s``
    shifts the person's loop in time.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    speed_mps: float = 1.0
    pause_s: float = 1.0
    t0_s: float = 0.0
    height_m: float = 1.75
    arms: bool = False


def _smooth(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def line_state(line: Line, t_s: float) -> tuple[Pose, tuple[float, float], float]:
    """Pose, pelvis position (x, z) and heading of a :class:`Line` walker at ``t_s``."""
    sx, sz = line.start
    ex, ez = line.end
    length = math.hypot(ex - sx, ez - sz)
    walk_s = length / line.speed_mps
    loop = 2 * (walk_s + line.pause_s)
    t = (t_s + line.t0_s) % loop
    out_heading = math.atan2(ex - sx, ez - sz)
    leg_t = t % (walk_s + line.pause_s)
    outbound = t < walk_s + line.pause_s
    walking = leg_t < walk_s
    frac = min(leg_t / walk_s, 1.0)
    if outbound:
        x, z = sx + (ex - sx) * frac, sz + (ez - sz) * frac
        heading = out_heading
    else:
        x, z = ex + (sx - ex) * frac, ez + (sz - ez) * frac
        heading = out_heading + math.pi
    pause = 0.0
    if not walking:
        # Turn round during the pause, ready for the way back.
        pause = _smooth((leg_t - walk_s) / max(line.pause_s, 1e-6))
        heading += math.pi * pause
    ramp = 0.0 if not walking else min(1.0, leg_t / 0.4, (walk_s - leg_t) / 0.4)
    cadence_hz = line.speed_mps / 1.3
    phase = 2 * math.pi * cadence_hz * t_s
    gait = math.sin(phase)
    hip_amp, arm_amp = math.radians(25.0) * ramp, math.radians(20.0) * ramp
    knee_l = math.radians(5.0 + 40.0 * max(0.0, math.sin(phase + 1.2))) * ramp
    knee_r = math.radians(5.0 + 40.0 * max(0.0, math.sin(phase + 1.2 + math.pi))) * ramp
    raise_arms = math.radians(150.0) * math.sin(math.pi * pause) if line.arms else 0.0
    pose = Pose(
        hip_flex_l=hip_amp * gait,
        hip_flex_r=-hip_amp * gait,
        knee_flex_l=knee_l,
        knee_flex_r=knee_r,
        shoulder_flex_l=-arm_amp * gait,
        shoulder_flex_r=arm_amp * gait,
        shoulder_abd_l=math.radians(6.0) + raise_arms,
        shoulder_abd_r=math.radians(6.0) + raise_arms,
        elbow_flex_l=math.radians(15.0),
        elbow_flex_r=math.radians(15.0),
        torso_pitch=math.radians(4.0) * ramp,
    )
    return pose, (x, z), heading


class LineWalkers:
    """People walking back and forth along lines (:class:`Line`)."""

    def __init__(self, lines: list[Line]) -> None:
        if not 1 <= len(lines) <= 6:
            raise ValueError(f"1..6 people, got {len(lines)}")
        self._lines = list(lines)

    @property
    def person_count(self) -> int:
        return len(self._lines)

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        out = np.empty((self.person_count, JOINT_COUNT, 3))
        for i, line in enumerate(self._lines):
            pose, position, heading = line_state(line, t_s)
            out[i] = pose_joints(BodyShape(line.height_m), pose, position, heading)
        return out


class Standing:
    """One person standing still at ``position_xz`` facing ``heading_rad`` (0 faces +Z)."""

    def __init__(
        self, position_xz: tuple[float, float], heading_rad: float, height_m: float = 1.75
    ) -> None:
        self._joints = pose_joints(BodyShape(height_m), Pose(), position_xz, heading_rad)

    @property
    def person_count(self) -> int:
        return 1

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        return self._joints[np.newaxis].copy()


class Segment:
    """``performer`` from ``start_s`` for ``duration_s``, looped."""

    def __init__(self, performer: Performer, start_s: float, duration_s: float) -> None:
        self._performer = performer
        self._start = start_s
        self._duration = duration_s

    @property
    def person_count(self) -> int:
        return self._performer.person_count

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        return self._performer.joints_at(self._start + t_s % self._duration)


class RingWalkers:
    """``count`` people evenly spaced on a circle of ``radius_m`` round ``center_xz``, facing it.

    With ``walk_m`` > 0 each walks towards the centre and back (forwards, then backwards) over
    ``walk_m`` metres every ``walk_period_s``, people a fraction of a period apart, with a gait
    whose size follows their speed. Person i stands at angle 2πi/count (0 on the +Z side).

    Raises:
        ValueError: not 1..6 people, or a radius the walk would cross.
    """

    def __init__(
        self,
        count: int = 2,
        radius_m: float = 1.5,
        *,
        center_xz: tuple[float, float] = (0.0, 0.0),
        walk_m: float = 0.0,
        walk_period_s: float = 6.0,
        height_m: float = 1.75,
    ) -> None:
        if not 1 <= count <= 6:
            raise ValueError(f"1..6 people, got {count}")
        if radius_m - walk_m / 2 < 0.3:
            raise ValueError("the walk would take people into the centre")
        self._count = count
        self._radius = radius_m
        self._center = center_xz
        self._walk = walk_m
        self._period = walk_period_s
        self._shape = BodyShape(height_m)

    @property
    def person_count(self) -> int:
        return self._count

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        out = np.empty((self._count, JOINT_COUNT, 3))
        omega = 2 * math.pi / self._period
        top_speed = max(self._walk / 2 * omega, 1e-9)
        for i in range(self._count):
            angle = 2 * math.pi * i / self._count
            phase = omega * t_s + angle
            radius = self._radius + self._walk / 2 * math.sin(phase)
            speed = abs(self._walk / 2 * omega * math.cos(phase))
            ramp = min(1.0, speed / top_speed) if self._walk > 0 else 0.0
            gait = math.sin(2 * math.pi * 0.8 * t_s)
            hip, arm = math.radians(20.0) * ramp, math.radians(15.0) * ramp
            pose = Pose(
                hip_flex_l=hip * gait,
                hip_flex_r=-hip * gait,
                knee_flex_l=math.radians(5.0 + 30.0 * max(0.0, gait)) * ramp,
                knee_flex_r=math.radians(5.0 + 30.0 * max(0.0, -gait)) * ramp,
                shoulder_flex_l=-arm * gait,
                shoulder_flex_r=arm * gait,
                shoulder_abd_l=math.radians(6.0),
                shoulder_abd_r=math.radians(6.0),
                elbow_flex_l=math.radians(15.0),
                elbow_flex_r=math.radians(15.0),
            )
            position = (
                self._center[0] + radius * math.sin(angle),
                self._center[1] + radius * math.cos(angle),
            )
            out[i] = pose_joints(self._shape, pose, position, angle + math.pi)
        return out
