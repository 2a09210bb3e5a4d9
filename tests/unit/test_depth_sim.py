"""The simulated depth camera (agent/sim/room.py, agent/sim/depth_camera.py): image format, noise,
geometry, imports."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from skelfuse.agent.sim.depth_camera import KINECT_V2_DEPTH, depth_to_points, voxel_downsample
from skelfuse.agent.sim.kinect_model import SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.room import Room, capture_point_cloud, default_room, render_depth
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import apply, invert, look_at_pose

POSE = look_at_pose((0.5, 1.2, 2.5), (0.0, 0.9, 0.0))


def test_image_format_and_missing_pixels() -> None:
    depth = render_depth(default_room(), None, POSE, rng=np.random.default_rng(0))
    assert depth.shape == (424, 512) and depth.dtype == np.float32
    valid = depth > 0
    assert 0.02 < (~valid).mean() < 0.9  # missing pixels exist, most of the image is not empty
    assert depth[valid].min() >= KINECT_V2_DEPTH.min_m and depth.max() <= KINECT_V2_DEPTH.max_m


def test_noise_grows_with_depth() -> None:
    # A sensor looking straight at a wall from 1 m and from 3.5 m: per-pixel noise vs ideal.
    stds = []
    for distance in (1.0, 3.5):
        pose = look_at_pose((0.0, 1.3, 4.0 - distance), (0.0, 1.3, 4.0))
        ideal = render_depth(Room(), None, pose)
        noisy = render_depth(Room(), None, pose, rng=np.random.default_rng(1))
        both = (ideal > 0) & (noisy > 0)
        stds.append(float(np.std((noisy - ideal)[both])))
    assert stds[1] > 3 * stds[0]


def test_back_projection_round_trip_lands_on_room_surfaces() -> None:
    room = default_room()
    world = apply(POSE, depth_to_points(render_depth(room, None, POSE), KINECT_V2_DEPTH))
    on_floor = np.abs(world[:, 1]) < 1e-3
    on_wall = np.abs(np.abs(world[:, [0, 2]]).max(axis=1) - room.wall_half_m) < 1e-3
    on_box = np.zeros(len(world), dtype=bool)
    for box in room.boxes:
        lo, hi = np.asarray(box.min_m) - 1e-3, np.asarray(box.max_m) + 1e-3
        on_box |= ((world >= lo) & (world <= hi)).all(axis=1)
    assert (on_floor | on_wall | on_box).all()
    assert on_floor.mean() > 0.3


def test_kinect_convention_matches_skeleton_model() -> None:
    """A joint SimulatedKinect reports at (x, y, z) is seen at pixel u = cx − fx·x/z."""
    person = ProceduralPerformer(1).joints_at(0.0)
    kinect = SimulatedKinect(POSE)
    joint_sensor = apply(invert(kinect.T_world_from_sensor), person[0, JointId.SPINE_MID])
    x, y, z = joint_sensor
    k = KINECT_V2_DEPTH
    u = round(k.cx - k.fx * x / z)
    v = round(k.cy - k.fy * y / z)
    with_person = render_depth(default_room(), person, POSE)
    without = render_depth(default_room(), None, POSE)
    # The person's trunk surface is in front of the joint (trunk radius 13 cm), the room behind.
    assert z - 0.2 < with_person[v, u] < z
    assert without[v, u] == 0 or without[v, u] > z + 0.5  # out of range, or the room
    # Back-projecting that pixel gives a point near the joint, in the same camera frame.
    image = np.zeros_like(with_person)
    image[v, u] = with_person[v, u]
    point = depth_to_points(image, k)[0]
    assert np.linalg.norm(point - joint_sensor) < 0.2


def test_person_appears_in_depth() -> None:
    person = ProceduralPerformer(1).joints_at(0.0)
    with_person = render_depth(default_room(), person, POSE)
    without = render_depth(default_room(), None, POSE)
    closer = (with_person > 0) & (without > 0) & (with_person < without - 0.3)
    assert closer.sum() > 1000


def test_capture_point_cloud_is_capped_and_downsampled() -> None:
    cloud = capture_point_cloud(
        default_room(), None, POSE, np.random.default_rng(2), max_points=5000
    )
    assert cloud.shape == (5000, 3) and cloud.dtype == np.float32
    grid = voxel_downsample(np.array([[0.0, 0, 0], [0.01, 0, 0], [0.5, 0, 0]]), 0.1)
    assert len(grid) == 2


def test_depth_to_points_rejects_wrong_size() -> None:
    with pytest.raises(ValueError, match="does not match"):
        depth_to_points(np.zeros((10, 10)), KINECT_V2_DEPTH)


def test_room_module_imports_numpy_only() -> None:
    code = (
        "import sys, skelfuse.agent.sim.room; "
        "bad = [m for m in ('scipy', 'open3d') if m in sys.modules]; "
        "print(','.join(bad))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == ""
