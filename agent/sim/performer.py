"""Virtual performers: where every joint of every person is, as a pure function of time.

Separate agent processes simulate the same room independently, so the motion must be a
deterministic function of the shared clock (Unix seconds): two sensors asking for the same
instant see the same people. That function is also the ground truth for tests and benchmarks.

:class:`ProceduralPerformer` is built into the product (the demo needs no data files): each
person loops through a choreography of walking a circle around the origin, turning on the spot
(so every sensor sees their back at some point), arm raises and squats. :class:`ClipPerformer`
plays recorded human motion (e.g. CMU mocap loaded by :mod:`agent.sim.mocap`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.clip import MotionClip
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

J = JointId


class Performer(Protocol):
    """People moving in the room."""

    @property
    def person_count(self) -> int: ...

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        """(P, 25, 3) float64 true joint positions at ``t_s``, metres, world frame (+Y up)."""
        ...


# --- body model -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BodyShape:
    """Segment lengths in metres for a person of ``height_m`` (anthropometric proportions)."""

    height_m: float = 1.75

    def scaled(self, length_at_175: float) -> float:
        return length_at_175 * self.height_m / 1.75


@dataclass(frozen=True, slots=True)
class Pose:
    """Joint angles in radians; 0 everywhere is standing straight with arms down.

    Flexion is forward (hip, shoulder) or bending (knee, elbow); abduction raises a limb sideways.
    """

    hip_flex_l: float = 0.0
    hip_flex_r: float = 0.0
    knee_flex_l: float = 0.0
    knee_flex_r: float = 0.0
    shoulder_flex_l: float = 0.0
    shoulder_flex_r: float = 0.0
    shoulder_abd_l: float = 0.0
    shoulder_abd_r: float = 0.0
    elbow_flex_l: float = 0.0
    elbow_flex_r: float = 0.0
    torso_pitch: float = 0.0
    pelvis_drop_m: float = 0.0


def _rot_x(angle: float) -> npt.NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle: float) -> npt.NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(angle: float) -> npt.NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


_DOWN: Final = np.array([0.0, -1.0, 0.0])
_UP: Final = np.array([0.0, 1.0, 0.0])


def pose_joints(
    shape: BodyShape, pose: Pose, position_xz: tuple[float, float], heading: float
) -> npt.NDArray[np.float64]:
    """Forward kinematics of the procedural body.

    Body-local frame: the person faces +Z, their left is +X, +Y up. ``heading`` turns the body
    about world +Y (heading 0 faces +Z, π/2 faces +X); ``position_xz`` places the pelvis.

    Returns:
        (25, 3) float64 joints, metres, world frame, feet on the floor (y = 0).
    """
    s = shape.scaled
    thigh, shin, ankle_h = s(0.43), s(0.42), s(0.08)
    hip_drop, hip_half = s(0.05), s(0.09)
    out = np.zeros((JOINT_COUNT, 3))

    def leg(hip_flex: float, knee_flex: float) -> tuple[npt.NDArray[np.float64], ...]:
        r_thigh = _rot_x(-hip_flex)
        r_shin = r_thigh @ _rot_x(knee_flex)
        knee = r_thigh @ _DOWN * thigh
        ankle = knee + r_shin @ _DOWN * shin
        return knee, ankle

    legs = {
        "l": leg(pose.hip_flex_l, pose.knee_flex_l),
        "r": leg(pose.hip_flex_r, pose.knee_flex_r),
    }
    # Pelvis height keeps the lower foot on the floor.
    lowest_ankle = min(legs["l"][1][1], legs["r"][1][1])
    pelvis_y = hip_drop - lowest_ankle + ankle_h - pose.pelvis_drop_m

    for side, sign in (("l", 1.0), ("r", -1.0)):
        hip = np.array([sign * hip_half, -hip_drop, 0.0])
        knee, ankle = legs[side]
        ids = (
            (J.HIP_LEFT, J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT)
            if side == "l"
            else (J.HIP_RIGHT, J.KNEE_RIGHT, J.ANKLE_RIGHT, J.FOOT_RIGHT)
        )
        out[ids[0]] = hip
        out[ids[1]] = hip + knee
        out[ids[2]] = hip + ankle
        out[ids[3]] = hip + ankle + np.array([0.0, -s(0.05), s(0.12)])

    lean = _rot_x(pose.torso_pitch)  # positive pitch leans the trunk forward (+Z)

    def up(length: float) -> npt.NDArray[np.float64]:
        vector: npt.NDArray[np.float64] = lean @ np.array([0.0, length, 0.0])
        return vector

    out[J.SPINE_BASE] = 0.0
    out[J.SPINE_MID] = up(s(0.25))
    out[J.SPINE_SHOULDER] = up(s(0.48))
    out[J.NECK] = up(s(0.56))
    out[J.HEAD] = up(s(0.70))
    _place_arms(out, shape, pose, lean)

    world: npt.NDArray[np.float64] = out @ _rot_y(heading).T
    world[:, 0] += position_xz[0]
    world[:, 1] += pelvis_y
    world[:, 2] += position_xz[1]
    return world


def _place_arms(
    out: npt.NDArray[np.float64], shape: BodyShape, pose: Pose, lean: npt.NDArray[np.float64]
) -> None:
    """Set both arms' joints in ``out`` ((25, 3) body-local, metres) from the shoulders, which
    hang off the spine shoulder already in ``out``, turned by the trunk's ``lean`` (3, 3)."""
    s = shape.scaled
    upper_arm, forearm, hand, hand_tip = s(0.28), s(0.25), s(0.08), s(0.08)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        flex = pose.shoulder_flex_l if side == "l" else pose.shoulder_flex_r
        abd = pose.shoulder_abd_l if side == "l" else pose.shoulder_abd_r
        elbow_flex = pose.elbow_flex_l if side == "l" else pose.elbow_flex_r
        # Arm angles are relative to the world vertical, not the trunk: arms hang by gravity.
        r_upper = _rot_z(sign * abd) @ _rot_x(-flex)
        r_fore = r_upper @ _rot_x(-elbow_flex)
        shoulder = out[J.SPINE_SHOULDER] + lean @ np.array([sign * s(0.18), -s(0.02), 0.0])
        elbow = shoulder + r_upper @ _DOWN * upper_arm
        wrist = elbow + r_fore @ _DOWN * forearm
        hand_j = wrist + r_fore @ _DOWN * hand
        tip = hand_j + r_fore @ _DOWN * hand_tip
        thumb = wrist + r_fore @ np.array([0.0, -s(0.05), s(0.04)])
        if side == "l":
            ids = (J.SHOULDER_LEFT, J.ELBOW_LEFT, J.WRIST_LEFT, J.HAND_LEFT)
            out[J.HAND_TIP_LEFT], out[J.THUMB_LEFT] = tip, thumb
        else:
            ids = (J.SHOULDER_RIGHT, J.ELBOW_RIGHT, J.WRIST_RIGHT, J.HAND_RIGHT)
            out[J.HAND_TIP_RIGHT], out[J.THUMB_RIGHT] = tip, thumb
        out[ids[0]], out[ids[1]], out[ids[2]], out[ids[3]] = shoulder, elbow, wrist, hand_j


def standing_pose(height_m: float = 1.75) -> npt.NDArray[np.float64]:
    """(25, 3) a person standing at the origin facing +Z, arms relaxed (world frame, metres)."""
    relaxed = Pose(
        shoulder_abd_l=math.radians(6.0),
        shoulder_abd_r=math.radians(6.0),
        elbow_flex_l=math.radians(15.0),
        elbow_flex_r=math.radians(15.0),
    )
    return pose_joints(BodyShape(height_m), relaxed, (0.0, 0.0), 0.0)


# --- choreography ------------------------------------------------------------------------------

_HEIGHTS_M: Final = (1.75, 1.62, 1.85, 1.70, 1.58, 1.80)


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def _window(t: float, start: float, end: float, ramp: float = 0.6) -> float:
    """1 inside [start, end], easing to 0 over ``ramp`` seconds at both edges."""
    return _smoothstep((t - start) / ramp) * _smoothstep((end - t) / ramp)


@dataclass(frozen=True, slots=True)
class Choreography:
    """One person's looping routine (seconds).

    Walk a lap of the circle, turn one and a half times on the spot (every sensor sees the
    back), walk the lap back the other way, raise the arms, squat twice, turn back to face the
    starting direction. Half the loop is walking, so any 15 s window has people moving about.
    """

    radius_m: float = 1.0
    clockwise: bool = False
    walk_speed_mps: float = 0.9
    turn_s: float = 6.0
    arms_s: float = 5.0
    squat_s: float = 5.0
    turn_back_s: float = 2.0

    @property
    def walk_s(self) -> float:
        return 2.0 * math.pi * self.radius_m / self.walk_speed_mps

    @property
    def loop_s(self) -> float:
        return 2 * self.walk_s + self.turn_s + self.arms_s + self.squat_s + self.turn_back_s


def _tangent_heading(angle: float, direction: float) -> float:
    """Heading (0 faces +Z) of someone walking the circle at ``angle`` in ``direction``."""
    return math.atan2(-math.sin(angle) * direction, math.cos(angle) * direction)


def choreography_state(
    routine: Choreography, t_s: float
) -> tuple[Pose, tuple[float, float], float]:
    """Pose, pelvis position (x, z) and heading of one person at ``t_s`` (loops forever)."""
    t = t_s % routine.loop_s
    direction = -1.0 if routine.clockwise else 1.0
    walk_s = routine.walk_s
    turn_end = walk_s + routine.turn_s
    walk2_end = turn_end + walk_s
    arms_end = walk2_end + routine.arms_s
    squat_end = arms_end + routine.squat_s
    start_heading = _tangent_heading(0.0, direction)

    if t < walk_s:  # lap one
        angle = direction * 2.0 * math.pi * t / walk_s
        heading = _tangent_heading(angle, direction)
    elif t < turn_end:  # one and a half turns on the spot
        angle = 0.0
        u = _smoothstep((t - walk_s) / routine.turn_s)
        heading = start_heading + direction * 3.0 * math.pi * u
    elif t < walk2_end:  # the lap back
        angle = -direction * 2.0 * math.pi * (t - turn_end) / walk_s
        heading = _tangent_heading(angle, -direction)
    elif t < squat_end:
        angle = 0.0
        heading = start_heading + math.pi
    else:  # turn back to the starting heading, closing the loop
        angle = 0.0
        u = _smoothstep((t - squat_end) / routine.turn_back_s)
        heading = start_heading + math.pi + direction * math.pi * u
    x = routine.radius_m * math.cos(angle)
    z = routine.radius_m * math.sin(angle)

    walking = _window(t, 0.0, walk_s) + _window(t, turn_end, walk2_end)
    cadence_hz = routine.walk_speed_mps / 1.3  # one gait cycle per 1.3 m (two steps)
    phase = 2.0 * math.pi * cadence_hz * t
    gait = math.sin(phase)
    hip_amp, arm_amp = math.radians(25.0) * walking, math.radians(20.0) * walking
    knee_l = math.radians(5.0 + 40.0 * max(0.0, math.sin(phase + 1.2))) * walking
    knee_r = math.radians(5.0 + 40.0 * max(0.0, math.sin(phase + 1.2 + math.pi))) * walking

    # Arm raises: sideways up above the head, then forwards.
    arms_t = t - walk2_end
    side_raise = _window(arms_t, 0.3, routine.arms_s / 2 - 0.3, ramp=1.2)
    front_raise = _window(arms_t, routine.arms_s / 2 + 0.3, routine.arms_s - 0.3, ramp=1.0)
    abd = math.radians(160.0) * side_raise
    flex_front = math.radians(90.0) * front_raise

    # Two squats.
    squat_t = t - arms_end
    half = routine.squat_s / 2
    squat = _window(squat_t, 0.4, half - 0.4, ramp=0.9) + _window(
        squat_t, half + 0.4, routine.squat_s - 0.4, ramp=0.9
    )
    squat_hip = math.radians(95.0) * squat
    squat_knee = math.radians(110.0) * squat

    pose = Pose(
        hip_flex_l=hip_amp * gait + squat_hip,
        hip_flex_r=-hip_amp * gait + squat_hip,
        knee_flex_l=knee_l + squat_knee,
        knee_flex_r=knee_r + squat_knee,
        shoulder_flex_l=-arm_amp * gait + flex_front + math.radians(60.0) * squat,
        shoulder_flex_r=arm_amp * gait + flex_front + math.radians(60.0) * squat,
        shoulder_abd_l=abd + math.radians(6.0),
        shoulder_abd_r=abd + math.radians(6.0),
        elbow_flex_l=math.radians(15.0) * (1.0 - side_raise),
        elbow_flex_r=math.radians(15.0) * (1.0 - side_raise),
        torso_pitch=math.radians(30.0) * squat + math.radians(4.0) * walking,
    )
    return pose, (x, z), heading


class ProceduralPerformer:
    """1 to 6 people looping a built-in routine around the origin.

    Person ``i`` walks a circle of radius ``0.9 + 0.55·i`` m (alternating direction) with its
    routine shifted in time so that people do different things at once.
    """

    def __init__(self, persons: int = 1) -> None:
        if not 1 <= persons <= 6:
            raise ValueError(f"persons must be 1..6, got {persons}")
        self._shapes = [BodyShape(_HEIGHTS_M[i]) for i in range(persons)]
        self._routines = [
            Choreography(radius_m=0.9 + 0.55 * i, clockwise=bool(i % 2)) for i in range(persons)
        ]

    @property
    def person_count(self) -> int:
        return len(self._shapes)

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        out = np.empty((self.person_count, JOINT_COUNT, 3))
        for i, (shape, routine) in enumerate(zip(self._shapes, self._routines, strict=True)):
            offset = i * routine.loop_s / max(self.person_count, 1) * 0.37
            pose, position, heading = choreography_state(routine, t_s + offset)
            out[i] = pose_joints(shape, pose, position, heading)
        return out


class ClipPerformer:
    """One person replaying a recorded clip, looped, placed at ``offset_xz`` and turned by
    ``heading_rad`` about +Y (the clip's own path is kept)."""

    def __init__(
        self,
        clip: MotionClip,
        offset_xz: tuple[float, float] = (0.0, 0.0),
        heading_rad: float = 0.0,
        t0_s: float = 0.0,
    ) -> None:
        self._clip = clip.centred()
        self._rotation = _rot_y(heading_rad)
        self._offset = np.array([offset_xz[0], 0.0, offset_xz[1]])
        self._t0 = t0_s

    @property
    def person_count(self) -> int:
        return 1

    @property
    def duration_s(self) -> float:
        return self._clip.duration_s

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        local = (t_s - self._t0) % self._clip.duration_s
        joints: npt.NDArray[np.float64] = self._clip.at(local) @ self._rotation.T + self._offset
        return joints[np.newaxis]
