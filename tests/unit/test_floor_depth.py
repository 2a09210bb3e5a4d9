"""calibration.floor_depth: a body's distance from the foot on the floor, on exact geometry."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.calibration.errors import InvalidInput
from skelfuse.calibration.floor import FloorFit
from skelfuse.calibration.floor_depth import (
    FloorDepthSettings,
    contact_points,
    floor_in_camera,
    floor_scales,
    level_camera_height,
    place_on_floor,
    smooth_scales,
)
from skelfuse.protocol.transform import look_at_pose

FloatArray = npt.NDArray[np.float64]
FLOOR_Y_UP = FloorFit(np.array([0.0, 1.0, 0.0]), 0.0, 0.0, 0)
"""skelfuse's world: +Y up, floor at y = 0."""
FEET = (2, 3)
EXACT = FloorDepthSettings(contact_height_m=0.0, window_frames=1)


def _camera() -> FloatArray:
    """A camera 2 m high, 4 m back, looking down at the origin, as T_world_from_camera with the
    OpenCV camera frame (x right, y down, z forward)."""
    pose = np.asarray(look_at_pose((0.0, 2.0, -4.0), (0.0, 1.0, 0.0)), dtype=np.float64)
    # look_at_pose gives the Kinect frame (+X left, +Y up): turn it to OpenCV's.
    result: FloatArray = pose @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return result


def _body_world(frames: int) -> FloatArray:
    """Four points per frame: head, hip, left heel on the floor, right foot 10 cm up; walking."""
    x = np.linspace(-0.5, 0.5, frames)[:, None]
    pts = np.array([[0.0, 1.7, 0.0], [0.0, 1.0, 0.0], [-0.1, 0.0, 0.0], [0.1, 0.1, 0.2]])
    out: FloatArray = pts[None] + np.concatenate([x, np.zeros((frames, 2))], axis=1)[:, None]
    return out


def _to_camera(T_world_from_camera: FloatArray, pts_world: FloatArray) -> FloatArray:
    inv = np.linalg.inv(T_world_from_camera)
    out: FloatArray = pts_world @ inv[:3, :3].T + inv[:3, 3]
    return out


def test_the_camera_sees_the_floor_below_it() -> None:
    pose = _camera()
    floor = floor_in_camera(pose, FLOOR_Y_UP)
    assert floor.d == pytest.approx(2.0)
    body = _to_camera(pose, _body_world(3))
    np.testing.assert_allclose(floor.height_of(body)[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(floor.height_of(body)[:, 0], 1.7, atol=1e-12)


def test_a_body_placed_too_far_comes_back_onto_the_floor() -> None:
    pose = _camera()
    truth = _to_camera(pose, _body_world(5))
    # A PnP distance 25 % too long: the same image, the body scaled about the camera centre.
    placed = truth * 1.25
    floor = floor_in_camera(pose, FLOOR_Y_UP)
    assert (contact_points(placed, floor, FEET) == 2).all()  # the heel, not the lifted foot
    scales = floor_scales(placed, floor, feet=FEET, settings=EXACT)
    np.testing.assert_allclose(scales, 1 / 1.25, rtol=1e-12)
    fixed, applied = place_on_floor(placed, pose, FLOOR_Y_UP, feet=FEET, settings=EXACT)
    np.testing.assert_allclose(fixed, truth, atol=1e-9)
    np.testing.assert_allclose(applied, 1 / 1.25, rtol=1e-12)


def test_the_contact_height_raises_the_floor_the_feet_stand_on() -> None:
    pose = _camera()
    truth = _to_camera(pose, _body_world(1) + np.array([0.0, 0.03, 0.0]))  # landmarks 3 cm up
    settings = FloorDepthSettings(contact_height_m=0.03, window_frames=1)
    fixed, _ = place_on_floor(truth * 0.8, pose, FLOOR_Y_UP, feet=FEET, settings=settings)
    np.testing.assert_allclose(fixed, truth, atol=1e-9)


def test_a_hidden_foot_or_an_implausible_scale_fixes_nothing() -> None:
    pose = _camera()
    floor = floor_in_camera(pose, FLOOR_Y_UP)
    placed = _to_camera(pose, _body_world(4)) * np.array([1.0, 1.0, 3.0, 1.0])[:, None, None]
    visibility = np.ones((4, 4))
    visibility[1, 2] = 0.2  # frame 1: the contact heel is hidden
    scales = floor_scales(placed, floor, visibility=visibility, feet=FEET, settings=EXACT)
    assert np.isfinite(scales[[0, 3]]).all()
    assert np.isnan(scales[1])  # hidden
    assert np.isnan(scales[2])  # 1/3 is outside the accepted range


def test_a_foot_above_the_cameras_horizon_fixes_nothing() -> None:
    pose = _camera()
    floor = floor_in_camera(pose, FLOOR_Y_UP)
    placed = _to_camera(pose, _body_world(1) + np.array([0.0, 2.5, 0.0]))  # feet above the camera
    assert np.isnan(floor_scales(placed, floor, feet=FEET, settings=EXACT)).all()


def test_smoothing_is_a_running_median_carried_across_frames_without_a_foot() -> None:
    raw = np.array([np.nan, 0.9, 0.8, 5.0, 0.85, np.nan, np.nan, np.nan, np.nan])
    smooth = smooth_scales(raw, 3)
    np.testing.assert_allclose(smooth, [0.9, 0.85, 0.9, 0.85, 2.925, 0.85, 0.85, 0.85, 0.85])
    np.testing.assert_allclose(smooth_scales(raw, 1)[[0, 5, 8]], [0.9, 0.85, 0.85])  # held
    gap = np.array([0.8, np.nan, np.nan, np.nan, 1.2])
    np.testing.assert_allclose(smooth_scales(gap, 1), [0.8, 0.9, 1.0, 1.1, 1.2])  # linear
    # "pnp": frames with no scale nearby keep the placement's distance
    np.testing.assert_allclose(smooth_scales(raw, 3, "pnp")[5:], [0.85, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(smooth_scales(np.full(4, np.nan), 3), 1.0)  # no foot ever
    with pytest.raises(InvalidInput):
        smooth_scales(raw, 4)


def test_bad_shapes_are_refused() -> None:
    floor = floor_in_camera(_camera(), FLOOR_Y_UP)
    with pytest.raises(InvalidInput):
        floor_scales(np.zeros((4, 3)), floor)
    with pytest.raises(InvalidInput):
        floor_scales(np.zeros((2, 4, 3)), floor, visibility=np.ones(4), feet=FEET)
    with pytest.raises(InvalidInput):
        floor_in_camera(np.eye(3), FLOOR_Y_UP)


def test_a_level_cameras_height_comes_from_the_lowest_feet() -> None:
    # Level camera 1.4 m up (OpenCV frame: +Y down), heel on the floor, the other foot lifted.
    pose = np.eye(4)
    pose[:3, :3] = np.diag([-1.0, -1.0, 1.0])  # world +Y up from the camera's +Y down
    pose[1, 3] = 1.4
    body = _to_camera(pose, _body_world(5) + np.array([0.0, 0.0, 3.0]))
    body[2] = np.nan  # a frame without a body is ignored
    assert level_camera_height(body, feet=FEET, contact_height_m=0.0) == pytest.approx(1.4)
    assert level_camera_height(body, feet=FEET, contact_height_m=0.03) == pytest.approx(1.43)
    with pytest.raises(InvalidInput):
        level_camera_height(np.full((2, 4, 3), np.nan), feet=FEET)
