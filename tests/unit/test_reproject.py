"""Depth re-projection into a level reference camera (skelfuse.agent.reproject): identity, a known
plane, a person rendered by the simulator at 20° pitch + roll, ghosts across a depth step, the
numba loop against its numpy twin, and the joints' way back."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.reproject import (
    joints_to_sensor,
    joints_to_world,
    level_reference,
    reference_from_sensor,
    reproject_depth,
)
from skelfuse.agent.reproject_raster import raster_loop, raster_numpy, warm_up
from skelfuse.agent.sim.depth_camera import KINECT_V2_DEPTH, DepthIntrinsics, pixel_rays
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sim.room import default_room, render_depth
from skelfuse.protocol.transform import apply, invert, pose_from_position_yaw_pitch

K = KINECT_V2_DEPTH
FloatArray = npt.NDArray[np.float64]


def _rot_x(deg: float) -> FloatArray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    out = np.eye(4)
    out[1:3, 1:3] = [[c, -s], [s, c]]
    return out


def _rot_z(deg: float) -> FloatArray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    return out


def _head_pose(pitch_deg: float, roll_deg: float) -> FloatArray:
    """A head-mounted sensor 1.6 m up, heading 10°, pitched and rolled about a neck pivot
    8 cm behind and below it (so the rotation also moves it: parallax)."""
    neck = pose_from_position_yaw_pitch((0.0, 1.52, -2.08), 10.0)
    lever = np.eye(4)
    lever[:3, 3] = (0.0, 0.08, 0.08)
    return neck @ _rot_x(pitch_deg) @ _rot_z(roll_deg) @ lever


def test_identity_reproduces_the_image_and_fills_lone_dropouts() -> None:
    rng = np.random.default_rng(3)
    depth = render_depth(default_room(), standing_pose()[None], _head_pose(0, 0), rng=rng)
    depth_mm = np.rint(depth * 1000).astype(np.uint16)
    ir = rng.integers(1, 60000, size=depth.shape).astype(np.uint16)
    got_mm, got_ir = reproject_depth(depth_mm, ir, K, np.eye(4))
    assert got_mm.dtype == np.uint16 and got_ir.dtype == np.uint16
    read = depth_mm > 0
    np.testing.assert_array_equal(got_mm[read], depth_mm[read])
    np.testing.assert_array_equal(got_ir[read], ir[read])
    # A dropped pixel is filled only from a diamond of neighbours on one surface (< 10 cm): its
    # centre lies on the diamond's north-south edge, so its depth is between those two.
    filled = ~read & (got_mm > 0)
    rows, cols = np.nonzero(filled)
    assert 1000 < rows.size < (~read).sum()
    north, south = depth_mm[rows - 1, cols].astype(int), depth_mm[rows + 1, cols].astype(int)
    assert (north > 0).all() and (south > 0).all()
    assert (np.abs(north - south) <= 100).all()  # < 10 cm before rounding to mm
    assert (got_mm[filled] >= np.minimum(north, south) - 1).all()
    assert (got_mm[filled] <= np.maximum(north, south) + 1).all()
    got_m, _ = reproject_depth(depth, ir.astype(np.float32), K, np.eye(4))
    assert got_m.dtype == np.float32
    np.testing.assert_allclose(got_m[read], depth[read], atol=1e-6)
    # The same fills in metres, but for spreads at 10 cm that rounding to mm moved across it.
    assert ((got_m > 0) != (got_mm > 0)).sum() <= 5


def test_a_dropped_pixel_is_filled_within_a_surface_not_across_an_edge() -> None:
    small = dataclasses.replace(K, width=16, height=12, cx=8.0, cy=6.0, fx=12.0, fy=12.0)
    depth = np.full((12, 16), 2.0)
    depth[:, 8:] = 2.5  # a 50 cm step between columns 7 and 8
    depth[7:, :8] = 3.0  # and a 1 m step between rows 6 and 7 on the left
    depth[3, 3] = 0.0  # inside the near surface
    depth[7, 8] = 0.0  # beside a step, but its diamond's other half is on its own surface
    depth[6, 3] = 0.0  # on the step: north and south are across it
    for compiled in (True, False):
        got, _ = reproject_depth(depth, depth, small, np.eye(4), compiled=compiled)
        assert got[3, 3] == pytest.approx(2.0)
        assert got[7, 8] == pytest.approx(2.5)
        assert got[6, 3] == 0.0


def test_a_known_plane_reprojects_to_its_depth() -> None:
    # A wall 2 m in front of the reference camera, seen by a sensor pitched 8° and shifted.
    T_ref_from_sensor = _rot_x(8.0)
    T_ref_from_sensor[:3, 3] = (0.05, 0.04, 0.02)
    rays = pixel_rays(K)
    along = rays @ T_ref_from_sensor[2, :3]
    depth = (2.0 - T_ref_from_sensor[2, 3]) / along
    ir = np.full(depth.shape, 500.0)
    got, got_ir = reproject_depth(depth, ir, K, T_ref_from_sensor)
    seen = got > 0
    assert seen[150:-150, 100:-100].all()
    np.testing.assert_allclose(got[seen], 2.0, atol=1e-5)
    np.testing.assert_allclose(got_ir[seen], 500.0, atol=1e-6)


def _person_scene(pitch_deg: float, roll_deg: float) -> tuple[FloatArray, ...]:
    room, person = default_room(), standing_pose()[None]
    pose = _head_pose(pitch_deg, roll_deg)
    # The untilted head as the reference: 8 cm of parallax from the neck pivot, not only a turn.
    ref = level_reference(_head_pose(0.0, 0.0))
    depth = render_depth(room, person, pose).astype(np.float64)
    truth = render_depth(room, person, ref).astype(np.float64)
    silhouette = (np.abs(truth - render_depth(room, None, ref)) > 0.05) & (truth > 0)
    return pose, ref, depth, truth, silhouette


def test_a_person_at_20_degrees_pitch_and_roll() -> None:
    pose, ref, depth, truth, silhouette = _person_scene(20.0, 20.0)
    # IR as the world height of each surface point (mm): checks IR follows its surface.
    points = depth[..., None] * pixel_rays(K)
    ir = np.where(depth > 0, 1000.0 * apply(pose, points)[..., 1], 0.0)
    got, got_ir = reproject_depth(depth, ir, K, invert(ref) @ pose)
    holes = silhouette & (got == 0)
    assert silhouette.sum() > 5000
    assert holes.sum() / silhouette.sum() <= 0.03
    both = silhouette & (got > 0)
    assert np.median(np.abs(got[both] - truth[both])) <= 0.006
    height_mm = 1000.0 * apply(ref, truth[..., None] * pixel_rays(K))[..., 1]
    assert np.median(np.abs(got_ir[both] - height_mm[both])) <= 6.0


def _step_image(intrinsics: DepthIntrinsics) -> FloatArray:
    """A wall at 3 m with a square 1 m nearer in the middle (hard edges: no flying pixels)."""
    depth = np.full((intrinsics.height, intrinsics.width), 3.0)
    h, w = depth.shape
    depth[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3] = 2.0
    return depth


def test_no_ghosts_across_a_depth_step_with_the_edge_rule() -> None:
    depth = _step_image(K)
    # A sideways step keeps both surfaces at their depths and uncovers a strip beside the square.
    T_ref_from_sensor = invert(pose_from_position_yaw_pitch((0.15, 0.0, 0.0), 0.0))
    ghosts = []
    for max_edge_m in (0.10, np.inf):
        got, _ = reproject_depth(depth, depth, K, T_ref_from_sensor, max_edge_m=max_edge_m)
        between = (got > 2.1) & (got < 2.9)
        ghosts.append(int(between.sum()))
    assert ghosts[0] <= 0.0005 * depth.size
    assert ghosts[1] > 20 * max(ghosts[0], 10)


def test_the_numba_loop_and_numpy_agree() -> None:
    small = dataclasses.replace(K, width=64, height=48, cx=32.0, cy=24.0, fx=46.0, fy=46.0)
    rng = np.random.default_rng(7)
    depth = _step_image(small) + rng.normal(0.0, 0.004, size=(48, 64))
    depth[rng.random(depth.shape) < 0.05] = 0.0
    depth[5, 5:9] = (np.nan, np.inf, -1.0, 0.0)  # all no reading
    ir = rng.uniform(100.0, 900.0, size=depth.shape)
    T_ref_from_sensor = reference_from_sensor(_head_pose(20.0, -15.0))
    loop = reproject_depth(depth, ir, small, T_ref_from_sensor, compiled=True)
    vectorised = reproject_depth(depth, ir, small, T_ref_from_sensor, compiled=False)
    assert (loop[0] > 0).sum() > 1000
    np.testing.assert_allclose(vectorised[0], loop[0], atol=1e-6)
    np.testing.assert_allclose(vectorised[1], loop[1], atol=1e-4)
    assert raster_loop is not raster_numpy


def test_warm_up_draws_with_the_loop_the_frames_use() -> None:
    warm_up()  # compiles (or loads) the loop: the same signature as a frame's call
    out_z = np.full((2, 2), np.inf)
    grid = np.array([[0.0, 1.0], [0.0, 1.0]])
    ones = np.ones((2, 2))
    raster_loop(grid, grid.T.copy(), ones, ones, ones > 0, ones, 0.1, out_z, np.zeros((2, 2)))
    np.testing.assert_allclose(out_z, 1.0)


def test_level_reference_keeps_position_and_heading() -> None:
    pose = _head_pose(25.0, -30.0)
    ref = level_reference(pose)
    np.testing.assert_allclose(ref[:3, 3], pose[:3, 3])
    np.testing.assert_allclose(ref[:3, 1], (0.0, 1.0, 0.0), atol=1e-12)
    heading = pose[:3, 2].copy()
    heading[1] = 0.0
    np.testing.assert_allclose(ref[:3, 2], heading / np.linalg.norm(heading), atol=1e-12)
    at_eye_height = level_reference(pose, height_m=1.7)
    np.testing.assert_allclose(at_eye_height[:3, :3], ref[:3, :3])
    np.testing.assert_allclose(at_eye_height[:3, 3], (pose[0, 3], 1.7, pose[2, 3]))
    down = pose_from_position_yaw_pitch((1.0, 2.0, 0.0), 30.0, 90.0)
    np.testing.assert_allclose(
        level_reference(down), pose_from_position_yaw_pitch((1.0, 2.0, 0.0), 30.0), atol=1e-9
    )


def test_joints_map_back_to_the_sensor_and_the_world() -> None:
    pose = _head_pose(20.0, 20.0)
    world = standing_pose()
    world[3] = np.nan
    in_ref = apply(invert(level_reference(pose)), world)
    np.testing.assert_allclose(joints_to_world(in_ref, pose), world, atol=1e-12)
    in_sensor = joints_to_sensor(in_ref, reference_from_sensor(pose))
    np.testing.assert_allclose(apply(pose, in_sensor), world, atol=1e-12)
    assert np.isnan(in_sensor[3]).all()


def test_shapes_are_checked() -> None:
    with pytest.raises(ValueError, match="intrinsics"):
        reproject_depth(np.zeros((4, 4)), np.zeros((4, 4)), K, np.eye(4))
    with pytest.raises(ValueError, match="4, 4"):
        level_reference(np.eye(3))
