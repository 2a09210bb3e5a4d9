"""The lead / lag against the views (bench/accuracy/view_shift.py) on takes of known shift."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.accuracy.view_shift import Take, shift_against_views
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState
from skelfuse.protocol.wire import Body, Frame

TOLERANCE_MS = 0.5
"""The refined shift's error on smooth motion sampled at 30 fps (the grid is 2 ms)."""


def motion(t: float, phase: float) -> np.ndarray:
    """Every joint swinging on its own phase (25, 3), metres, plus a constant per-joint pose."""
    joints = np.arange(JOINT_COUNT, dtype=np.float64)
    angle = 2 * math.pi * 1.3 * t + joints * 0.4 + phase
    out = np.stack([0.3 * np.sin(angle), 1.0 + 0.02 * joints, 0.2 * np.cos(1.7 * angle)], axis=-1)
    return out


def take_of(fused_behind_s: float, view_bias_m: float = 0.05, depth_ahead_s: float = 0.0,
            sensor_type: str = "kinect_v2") -> Take:  # fmt: skip
    """Two sensors (3 m in front of the motion, unrotated) whose views are the motion at their
    capture times plus a constant bias (and, along each line of sight, the motion
    ``depth_ahead_s`` ahead: a depth error that follows the pose), and a fused output that is
    the motion ``fused_behind_s`` late."""
    take = Take()
    pose = np.eye(4)
    pose[:3, 3] = (0.0, 1.2, -3.0)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
    for k, sensor in enumerate(("a", "b")):
        for n in range(120):
            t = n / 30 + k * 0.013
            joints = motion(t, 0.0) + view_bias_m * (k + 1)
            sight = joints - pose[:3, 3]
            sight /= np.linalg.norm(sight, axis=-1, keepdims=True)
            ahead = motion(t + depth_ahead_s, 0.0) - motion(t, 0.0)
            joints = joints + np.sum(ahead * sight, axis=-1, keepdims=True) * sight
            local = (joints - pose[:3, 3]).astype(np.float32)  # the sensor frame
            frame = Frame(n + 1, int(t * 1e9), (Body(7, local, states),))
            take.add_view(sensor, t, frame, pose, sensor_type)
    for n in range(120):
        t = n / 30 + 0.005
        take.fused_t.append(t)
        take.person.append(1)
        take.fused.append(motion(t - fused_behind_s, 0.0))
        take.members.append({"a": (7, False), "b": (7, False)})
    return take


@pytest.mark.parametrize("behind_s", [0.0, 0.010, -0.008])
def test_the_shift_is_the_fused_delay_whatever_the_views_bias(behind_s: float) -> None:
    shifts = shift_against_views(take_of(behind_s))
    for group, shift_ms in shifts.items():
        assert abs(shift_ms - 1000 * behind_s) < TOLERANCE_MS, (group, shifts)


def test_a_view_swapped_back_is_compared_swapped() -> None:
    take = take_of(0.010)
    # Sensor b reports left and right the other way round; fusion swapped it back.
    swapped = [
        (t, {i: joints[list(MIRROR_PERMUTATION)] for i, joints in bodies.items()})
        for t, bodies in take.views["b"]
    ]
    take.views["b"] = swapped
    take.members = [{"a": (7, False), "b": (7, True)} for _ in take.members]
    shifts = shift_against_views(take)
    assert all(abs(s - 10.0) < TOLERANCE_MS for s in shifts.values()), shifts


def test_a_camera_is_judged_across_its_lines_of_sight_only() -> None:
    # A monocular camera's depth running 40 ms ahead of the motion is not read as a lead.
    shifts = shift_against_views(take_of(0.010, depth_ahead_s=0.040, sensor_type="rgb"))
    assert all(abs(s - 10.0) < TOLERANCE_MS for s in shifts.values()), shifts
    # The same views judged whole (a depth sensor's) do read it: the measure can fail.
    whole = shift_against_views(take_of(0.010, depth_ahead_s=0.040))
    assert any(abs(s - 10.0) > 5 * TOLERANCE_MS for s in whole.values()), whole
