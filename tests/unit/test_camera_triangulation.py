"""Cameras, calibration files and triangulation (calibration/camera*.py, triangulation.py).

``tests/data/pose2sim_single_calib.qca.txt`` is the Qualisys calibration of Pose2Sim's
single-person demo (``pose2sim==0.10.49``, BSD-3-Clause, perfanalytics), the clip whose
MediaPipe landmarks are ``tests/data/mono_landmarks.npz``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.camera import (
    SENSOR_FROM_OPENCV,
    Camera,
    CameraIntrinsics,
    pose_from_opencv_extrinsics,
    rodrigues,
)
from skelfuse.calibration.camera_files import read_camera_file
from skelfuse.calibration.errors import CameraFileError, InvalidInput
from skelfuse.calibration.triangulation import triangulate
from skelfuse.protocol.transform import look_at_pose

DATA = Path(__file__).resolve().parents[1] / "data"
QCA = DATA / "pose2sim_single_calib.qca.txt"
LANDMARKS = DATA / "mono_landmarks.npz"
LENS = (-0.05, 0.14, 0.0006, -0.0005, 0.0)


def real_clip(lag_frames: dict[str, int] | None = None) -> tuple[list[Camera], np.ndarray]:
    """The real clip's Qualisys cameras and their landmarks' pixels (cameras, frames, 33, 2),
    each camera's frames rolled back by its ``lag_frames`` (the rolled-over ones stay at the
    end); skips when the mono source's landmark fixture is missing."""
    if not LANDMARKS.exists():
        pytest.skip(f"{LANDMARKS} missing (the mono source's fixture)")
    cameras = read_camera_file(QCA, "qualisys").cameras
    data = np.load(LANDMARKS)
    lags = lag_frames or {}
    image = np.stack(
        [np.roll(data[f"{c.name}_image_px"][..., :2], -lags.get(c.name, 0), 0) for c in cameras]
    ).astype(np.float64)
    return cameras, image


def rig(distortion: tuple[float, ...] = LENS) -> list[Camera]:
    """Four portrait cameras 3-4 m around the origin at 1.8-2.1 m, aimed at a chest."""
    intrinsics = CameraIntrinsics(1088, 1920, 1680.0, 1679.0, 533.0, 950.0, distortion)
    spots = [(3.0, 1.9, 0.5), (-0.4, 2.0, 3.2), (-3.1, 2.1, -0.9), (0.8, 1.8, -3.4)]
    return [
        Camera(f"cam{i + 1:02d}", intrinsics, look_at_pose(spot, (0.0, 1.1, 0.0)))
        for i, spot in enumerate(spots)
    ]


def body_points(frames: int = 5, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal([0.0, 1.0, 0.0], [0.3, 0.5, 0.3], size=(frames, 33, 3))


def test_distortion_round_trip_and_projection_frame() -> None:
    camera = rig()[0]
    xy = np.random.default_rng(1).uniform(-0.3, 0.3, size=(200, 2))
    k = camera.intrinsics
    np.testing.assert_allclose(k.undistort(k.distort(xy)), xy, atol=1e-9)
    # A point straight ahead along the sensor's +Z lands on the principal point.
    ahead = camera.T_world_from_sensor @ np.array([0.0, 0.0, 2.0, 1.0])
    np.testing.assert_allclose(camera.project(ahead[:3]), [k.cx, k.cy], atol=1e-9)
    # The sensor's +Y (up) is image up: smaller v.
    up = camera.T_world_from_sensor @ np.array([0.0, 0.3, 2.0, 1.0])
    assert camera.project(up[:3])[1] < k.cy
    behind = camera.T_world_from_sensor @ np.array([0.0, 0.0, -2.0, 1.0])
    assert np.isnan(camera.project(behind[:3])).all()
    np.testing.assert_array_equal(SENSOR_FROM_OPENCV @ SENSOR_FROM_OPENCV, np.eye(4))


def test_intrinsics_refuse_bad_values() -> None:
    with pytest.raises(InvalidInput, match="outside"):
        CameraIntrinsics(1920, 1080, 1000.0, 1000.0, 540.0, 1500.0)  # a portrait centre
    with pytest.raises(InvalidInput, match="0, 4, 5 or 8"):
        CameraIntrinsics(640, 480, 500.0, 500.0, 320.0, 240.0, (0.1, 0.2))
    with pytest.raises(InvalidInput, match="focal"):
        CameraIntrinsics(640, 480, 0.0, 500.0, 320.0, 240.0)
    with pytest.raises(InvalidInput, match="NaN"):
        CameraIntrinsics(640, 480, float("nan"), 500.0, 320.0, 240.0)
    k = CameraIntrinsics(640, 480, 500.0, 501.0, 320.0, 240.0, (0.1, 0.0, 0.0, 0.0))
    assert CameraIntrinsics.from_json(k.to_json(), "test") == k
    with pytest.raises(InvalidInput, match="test: bad intrinsics"):
        CameraIntrinsics.from_json({"width": 640}, "test")


def test_triangulation_recovers_points_with_distortion() -> None:
    cameras = rig()
    points = body_points()
    image = np.stack([c.project(points) for c in cameras])
    result = triangulate(cameras, image)
    np.testing.assert_allclose(result.points_world, points, atol=1e-6)
    assert np.nanmax(result.reprojection_px) < 1e-4
    assert result.views_used.all()


def test_triangulation_weights_gaps_and_outliers() -> None:
    cameras = rig()
    points = body_points(frames=3, seed=2)
    rng = np.random.default_rng(3)
    image = np.stack([c.project(points) for c in cameras]) + rng.normal(0, 1.0, (4, 3, 33, 2))
    image[2, 0, 5] = np.nan  # cam03 missed one landmark
    image[0, 1, :] += 60.0  # cam01 is 60 px off on frame 1
    weights = np.ones((4, 3, 33))
    weights[3, 2, 7] = 0.0  # cam04 gives no weight to one landmark
    image[1, :, 9] = np.nan
    image[2, :, 9] = np.nan
    image[3, :, 9] = np.nan  # landmark 9 seen by cam01 only
    plain = triangulate(cameras, image, weights)
    robust = triangulate(cameras, image, weights, max_error_px=10.0)
    assert not plain.views_used[2, 0, 5] and not plain.views_used[3, 2, 7]
    assert np.isnan(plain.points_world[:, 9]).all() and not plain.views_used[:, :, 9].any()
    err_plain = np.linalg.norm(plain.points_world[1] - points[1], axis=-1)
    err_robust = np.linalg.norm(robust.points_world[1] - points[1], axis=-1)
    assert np.nanmedian(err_robust) < 0.01 < np.nanmedian(err_plain)
    assert not robust.views_used[0, 1, :9].any()  # the 60 px view was dropped
    assert robust.views_used[:, 0, :5].all()  # the good frame kept every view
    assert np.isfinite(robust.reprojection_px[0, 1, 0])  # a dropped view still gets its error


def test_triangulation_refuses_bad_input() -> None:
    cameras = rig()
    with pytest.raises(InvalidInput, match="at least 2 cameras"):
        triangulate(cameras[:1], np.zeros((1, 5, 2)))
    with pytest.raises(InvalidInput, match="image_px"):
        triangulate(cameras, np.zeros((3, 5, 2)))
    with pytest.raises(InvalidInput, match="weights"):
        triangulate(cameras, np.zeros((4, 5, 2)), -np.ones((4, 5)))
    with pytest.raises(InvalidInput, match="max_error_px"):
        triangulate(cameras, np.zeros((4, 5, 2)), max_error_px=0.0)


def test_opencv_extrinsics_and_rodrigues() -> None:
    camera = rig()[1]
    transform = camera.T_opencv_from_world
    pose = pose_from_opencv_extrinsics(transform[:3, :3], transform[:3, 3])
    np.testing.assert_allclose(pose, camera.T_world_from_sensor, atol=1e-12)
    axis = np.array([0.2, -0.5, 0.3])
    rotation = rodrigues(axis)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rotation @ axis, axis, atol=1e-12)  # the axis stays put
    np.testing.assert_allclose(np.trace(rotation), 1 + 2 * np.cos(np.linalg.norm(axis)))
    with pytest.raises(InvalidInput, match="proper rotation"):
        pose_from_opencv_extrinsics(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def test_qualisys_file_of_the_real_clip() -> None:
    found = read_camera_file(QCA, "qualisys")
    names = [c.name for c in found.cameras]
    assert names == ["cam01", "cam02", "cam03", "cam04"]
    for camera in found.cameras:
        k = camera.intrinsics
        assert (k.width, k.height) == (1088, 1920)  # portrait, like the videos
        assert 1670 < k.fx < 1685 and 500 < k.cx < 560 and 940 < k.cy < 970
        assert 1.6 < camera.T_world_from_sensor[1, 3] < 2.2  # mounted 1.7-2.1 m up (Y up)
        forward = camera.T_world_from_sensor[:3, 2]
        assert forward[1] < -0.2  # looking down at the person
    assert found.residual_mm["cam01"] == pytest.approx(0.402)


def test_qualisys_reprojection_on_the_real_landmarks() -> None:
    """Triangulated from the four views, the landmarks reproject to each within the
    landmarks' own consistency (MediaPipe's, about 13-18 px median here; with a wrong
    convention it is 50-400 px), and the body stands on the floor, about 1.7 m tall."""
    cameras, image = real_clip({"cam03": 2})  # cam03 lags the others (motion_sync finds it)
    result = triangulate(cameras, image[:, 5:95])
    medians = np.nanmedian(result.reprojection_px.reshape(4, -1), axis=1)
    assert (medians < 20.0).all(), medians
    heights = result.points_world[..., 1]
    assert -0.15 < np.nanpercentile(heights, 1) < 0.15  # feet on the floor (y = 0)
    assert 1.5 < np.nanpercentile(heights, 99) < 1.9


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not xml at all <", "not valid Qualisys XML"),
        ("<other/>", "not <calibration>"),
        ("<calibration><cameras/></calibration>", "no camera found"),
        (
            "<calibration><cameras><camera serial='a'/></cameras></calibration>",
            "missing <fov_video>",
        ),
    ],
)
def test_qualisys_broken_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "broken.qca.txt"
    path.write_text(text)
    with pytest.raises(CameraFileError, match=message):
        read_camera_file(path, "qualisys")


def test_qualisys_broken_attribute(tmp_path: Path) -> None:
    good = QCA.read_text()
    for old, new, message in [
        ('focalLengthU="107599.671875"', 'focalLengthU="abc"', "cam01.*focalLengthU.*not a number"),
        ('r11="0.5536380477336265"', 'r11="5.5"', "cam01.*not a proper rotation"),
        (' x="1460.2323709212087"', "", "cam01.*lacks the attribute x"),
        ('<fov_video bottom="1919"', '<fov_video bottom="9"', "cam01.*outside"),
    ]:
        assert old in good
        path = tmp_path / "broken.qca.txt"
        path.write_text(good.replace(old, new, 1))
        with pytest.raises(CameraFileError, match=message):
            read_camera_file(path, "qualisys")
    with pytest.raises(CameraFileError, match="cannot read"):
        read_camera_file(tmp_path / "absent.qca.txt", "qualisys")


def test_qualisys_optional_k3_and_video_resolution(tmp_path: Path) -> None:
    """A camera filming at 540p has its calibration at 1080 lines: everything halves; k3 is
    optional; a resolution that is not like '1080p' is refused."""
    text = QCA.read_text().replace(' radialDistortion3="0.000000"', "")
    text = text.replace('serial="cam01"', 'serial="cam01" video_resolution="540p"')
    path = tmp_path / "binned.qca.txt"
    path.write_text(text)
    cameras = {c.name: c for c in read_camera_file(path, "qualisys").cameras}
    full = {c.name: c for c in read_camera_file(QCA, "qualisys").cameras}
    half, whole = cameras["cam01"].intrinsics, full["cam01"].intrinsics
    assert (half.width, half.height) == (544, 960)
    assert half.fx == pytest.approx(whole.fx / 2) and half.cy == pytest.approx(whole.cy / 2)
    assert half.distortion == whole.distortion[:4]
    np.testing.assert_allclose(
        cameras["cam01"].T_world_from_sensor, full["cam01"].T_world_from_sensor
    )
    path.write_text(text.replace('video_resolution="540p"', 'video_resolution="big"'))
    with pytest.raises(CameraFileError, match=r"cam01.*not like '1080p'"):
        read_camera_file(path, "qualisys")


def test_intrinsics_for_other_frame_sizes() -> None:
    k = CameraIntrinsics(1088, 1920, 1680.0, 1679.0, 533.0, 950.0, LENS)
    assert k.for_frames(1088, 1920) == (k, None)
    half, warning = k.for_frames(544, 960)
    assert warning is None and half.fx == 840.0 and half.cx == pytest.approx(266.25)
    cropped, warning = k.for_frames(1080, 1920)  # the clip's cam01 and cam02
    assert cropped.cx == 529.0 and cropped.fx == k.fx and warning and "centred crop" in warning
    with pytest.raises(InvalidInput, match="portrait, the other landscape"):
        k.for_frames(1920, 1088)
    with pytest.raises(InvalidInput, match="not a resize"):
        k.for_frames(1000, 1920)
