"""The re-projected Azure Kinect source against a fake of pykinect_azure's ctypes layer.

The fake device sees a wall 3.5 m away and three small squares 0.5 m in front of it, through
a camera pitched, rolled and turned on a head; each square has its own IR value. The fake
tracker "detects" a body by finding each square in the IR image it was given and placing one
joint at its centre (centroid pixel, median depth, back-projected with the calibration the
tracker was created with). So the joints come back right only when the re-projected depth and
IR (not the raw ones) reached the tracker, with the tracker's intrinsics, and were mapped back
to the sensor frame with the capture's own pose.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.reproject import level_reference, reproject_depth
from skelfuse.agent.sim.depth_camera import DepthIntrinsics
from skelfuse.agent.sources.azure_lens import remap
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.skeleton import AZURE_JOINT_COUNT, AZURE_TO_KINECT_V2
from skelfuse.protocol.transform import apply, invert
from skelfuse.protocol.wire import Frame, encode

FAKES = Path(__file__).resolve().parents[1] / "fakes"
WALL_Z = 3.5
WALL_IR = 300
MARKERS = (  # azure joint, world centre (m), IR value
    (0, (-0.30, 1.20, 3.0), 2000),  # pelvis
    (26, (0.20, 1.90, 3.0), 2500),  # head
    (8, (0.05, 1.45, 3.0), 3000),  # left hand
)
HALF_SIZE_M = 0.07
LENS_K1 = 0.08  # the fake device's calibration (tests/fakes/pykinect_azure/k4a/_k4a.py)
BODY_ID = 7


def _rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> npt.NDArray[np.float64]:
    """World-from-sensor rotation: yaw about +Y, then pitch about the sensor's X, roll about Z."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    out: npt.NDArray[np.float64] = ry @ rx @ rz
    return out


def _pose(yaw: float, pitch: float, roll: float) -> npt.NDArray[np.float64]:
    pose = np.eye(4)
    pose[:3, :3] = _rotation(yaw, pitch, roll)
    pose[:3, 3] = (0.1, 1.65, 0.0)
    return pose


def _render(
    pose: npt.NDArray[np.float64], intr: DepthIntrinsics
) -> tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint16]]:
    """Depth (mm) and IR a camera at ``pose`` sees through the fake's lens: planes z = const
    in the world, ray cast."""
    lens = sys.modules["pykinect_azure.k4a._k4a"]
    rows, cols = np.indices((intr.height, intr.width), dtype=np.float64)
    x, y = lens.undistort((cols - intr.cx) / intr.fx, (rows - intr.cy) / intr.fy, LENS_K1)
    rays = np.stack([-x, -y, np.ones_like(cols)], axis=-1)  # k4a axes -> ours
    world = rays @ pose[:3, :3].T  # direction per pixel, world; the sensor-frame z is 1
    origin = pose[:3, 3]
    depth = np.zeros(rays.shape[:2])
    ir = np.zeros(rays.shape[:2])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = (WALL_Z - origin[2]) / world[..., 2]
        depth = np.where(t_wall > 0, t_wall, 0.0)
        ir[:] = WALL_IR
        for _, centre, value in MARKERS:
            t = (centre[2] - origin[2]) / world[..., 2]
            hit = origin + t[..., None] * world
            inside = (
                (t > 0)
                & (np.abs(hit[..., 0] - centre[0]) <= HALF_SIZE_M)
                & (np.abs(hit[..., 1] - centre[1]) <= HALF_SIZE_M)
                & (t < depth)
            )
            depth = np.where(inside, t, depth)
            ir = np.where(inside, value, ir)
    return np.rint(depth * 1000).astype(np.uint16), ir.astype(np.uint16)


def _detect(depth: Any, ir: Any, calibration: Any) -> list[tuple[int, Any, Any]]:
    """The fake tracker's "body": a joint at each IR square's centre (k4a axes, mm), read
    through the lens model of the calibration the tracker was created with."""
    lens = sys.modules["pykinect_azure.k4a._k4a"]
    param = calibration.depth_camera_calibration.intrinsics.parameters.param
    joints = np.zeros((AZURE_JOINT_COUNT, 3))
    levels = np.zeros(AZURE_JOINT_COUNT, dtype=int)
    for joint, _, value in MARKERS:
        rows, cols = np.nonzero((ir == value) & (depth > 0))
        if rows.size < 10:
            continue
        z = float(np.median(depth[rows, cols]))
        u, v = cols.mean(), rows.mean()
        x, y = lens.undistort((u - param.cx) / param.fx, (v - param.cy) / param.fy, param.k1)
        joints[joint] = (x * z, y * z, z)
        levels[joint] = 2
    if not levels.any():
        return []
    return [(BODY_ID, joints, levels)]


@pytest.fixture
def fake_sdk(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[ModuleType, Any, Any]]:
    monkeypatch.syspath_prepend(str(FAKES))
    for name in [m for m in sys.modules if m.split(".")[0] == "pykinect_azure"]:
        del sys.modules[name]
    package = importlib.import_module("pykinect_azure")
    k4a = importlib.import_module("pykinect_azure.k4a._k4a")
    k4abt = importlib.import_module("pykinect_azure.k4abt._k4abt")
    k4a.reset()
    k4abt.reset()
    k4abt.DETECT = _detect
    yield package, k4a, k4abt
    for name in [m for m in sys.modules if m.split(".")[0] == "pykinect_azure"]:
        del sys.modules[name]


def _intrinsics(k4a: Any) -> DepthIntrinsics:
    c = k4a.CALIBRATION
    return DepthIntrinsics(c["width"], c["height"], c["fx"], c["fy"], c["cx"], c["cy"], 0.5, 3.86)


class _Clock:
    def __init__(self) -> None:
        self.now = 1_800_000_000_000_000_000

    def __call__(self) -> int:
        return self.now


def _source(package: ModuleType, poses: dict[int, SensorPose], **kwargs: Any) -> Any:
    from skelfuse.agent.sources.azure_reprojected import ReprojectedAzureKinectSource

    return ReprojectedAzureKinectSource(
        poses.get, pose_space="room", sdk=package, wall_clock_ns=_Clock(), **kwargs
    )


@pytest.mark.parametrize("reference_height_m", [None, 1.5])
def test_tracker_gets_the_level_image_and_joints_come_back_in_the_sensor_frame(
    fake_sdk: tuple[ModuleType, Any, Any], reference_height_m: float | None
) -> None:
    package, k4a, k4abt = fake_sdk
    intr = _intrinsics(k4a)
    T_world_from_sensor = _pose(yaw=10.0, pitch=-15.0, roll=20.0)
    depth, ir = _render(T_world_from_sensor, intr)
    for _, _, value in MARKERS:
        assert (ir == value).sum() > 100, "each square is seen by the tilted camera"
    k4a.SCRIPT.append((1_000_000, depth, ir))
    clock_now = 1_800_000_000_000_000_000
    pose = pose_from_matrix(T_world_from_sensor)
    closed: list[bool] = []
    source = _source(
        package,
        {clock_now: pose},
        reference_height_m=reference_height_m,
        close_with=lambda: closed.append(True),
    )
    assert source.pose_space == "room" and source.pose_hint() is None
    assert (source.intrinsics.fx, source.intrinsics.cy) == (intr.fx, intr.cy)

    capture = source.next_capture(0.1)

    assert capture is not None and capture.pose == pose and capture.t_capture_ns == clock_now
    # The tracker got the re-projection of the raw images into the level reference camera.
    (device_us, fed_depth, fed_ir) = k4abt.ENQUEUED[0]
    assert device_us == 1_000_000
    T_sensor = np.asarray(T_world_from_sensor)
    reference = level_reference(T_sensor, reference_height_m)
    lens = source.lens
    expected_depth, expected_ir = (
        remap(image, lens.to_device)
        for image in reproject_depth(
            remap(depth, lens.to_pinhole),
            remap(ir, lens.to_pinhole),
            intr,
            invert(reference) @ T_sensor,
        )
    )
    np.testing.assert_array_equal(fed_depth, expected_depth)
    np.testing.assert_array_equal(fed_ir, expected_ir)
    assert not np.array_equal(fed_depth, depth)
    # The joints are the squares' centres in the sensor frame (and in the world with the pose).
    (body,) = capture.bodies
    assert body.tracking_id == BODY_ID
    truth_world = np.array([centre for _, centre, _ in MARKERS])
    v2 = [AZURE_TO_KINECT_V2.index(joint) for joint, _, _ in MARKERS]
    found = body.joints_m[v2].astype(np.float64)
    assert (body.states[v2] == 2).all()
    np.testing.assert_allclose(found, apply(invert(T_sensor), truth_world), atol=0.005)
    np.testing.assert_allclose(apply(T_sensor, found), truth_world, atol=0.005)
    # The raw image in the tracker (or the joints left in the reference frame) would miss.
    raw_bodies = _detect(depth, ir, k4abt.TRACKERS[0]["calibration"])
    raw_joints = raw_bodies[0][1][[j for j, _, _ in MARKERS]] * np.array([-1e-3, -1e-3, 1e-3])
    left_in_reference = apply(reference, raw_joints)
    assert np.linalg.norm(left_in_reference - truth_world, axis=1).max() > 0.1
    encode(Frame(1, capture.t_capture_ns, capture.bodies, None, capture.pose))  # wire-valid
    source.close()
    assert k4a.LIVE == {} and k4abt.FRAMES == {}, "every capture, image and frame released"
    assert k4abt.TRACKERS[0]["shutdown"] and k4abt.TRACKERS[0]["destroyed"]
    assert k4a.STARTED[0] == (k4a.K4A_DEPTH_MODE_NFOV_UNBINNED, k4a.K4A_FRAMES_PER_SECOND_30, 0)
    assert k4a.STARTED[-2:] == ["stopped", "closed"] and closed == [True]


def test_a_capture_without_a_pose_is_counted_and_not_tracked(
    fake_sdk: tuple[ModuleType, Any, Any],
) -> None:
    package, k4a, k4abt = fake_sdk
    intr = _intrinsics(k4a)
    T = _pose(0.0, -10.0, 5.0)
    depth, ir = _render(T, intr)
    k4a.SCRIPT.extend([(1_000_000, depth, ir), (1_033_333, depth, ir)])
    start = 1_800_000_000_000_000_000
    pose = pose_from_matrix(T)
    source = _source(package, {start + 33_333_000: pose})  # only the second instant is posed

    first = source.next_capture(0.1)
    assert first is not None and first.pose is None and first.bodies == ()
    assert sum(source.unposed.values()) == 1 and k4abt.ENQUEUED == []
    second = source.next_capture(0.1)
    assert second is not None and second.pose == pose and len(second.bodies) == 1
    assert second.t_capture_ns == start + 33_333_000  # device spacing kept
    assert source.next_capture(0.1) is None  # the device has nothing more: a timeout
    source.close()
    assert k4a.LIVE == {}


def test_body_frames_that_come_late_are_matched_to_their_own_capture(
    fake_sdk: tuple[ModuleType, Any, Any],
) -> None:
    """The tracker lags one capture: each body frame gets the pose of the capture it was
    tracked from (by device timestamp), not the pose of the capture just fed."""
    package, k4a, k4abt = fake_sdk
    k4abt.LAG = 1
    intr = _intrinsics(k4a)
    start = 1_800_000_000_000_000_000
    T_first, T_second = _pose(0.0, -15.0, 20.0), _pose(8.0, -5.0, -10.0)
    poses = {start: pose_from_matrix(T_first), start + 33_333_000: pose_from_matrix(T_second)}
    k4a.SCRIPT.extend([(1_000_000, *_render(T_first, intr)), (1_033_333, *_render(T_second, intr))])
    source = _source(package, poses)

    assert source.next_capture(0.1) is None  # fed, nothing out yet
    late = source.next_capture(0.1)
    assert late is not None and late.t_capture_ns == start and late.pose == poses[start]
    truth = np.array([centre for _, centre, _ in MARKERS])
    v2 = [AZURE_TO_KINECT_V2.index(joint) for joint, _, _ in MARKERS]
    found = late.bodies[0].joints_m[v2].astype(np.float64)
    np.testing.assert_allclose(apply(T_first, found), truth, atol=0.005)
    source.close()


def test_a_capture_without_ir_is_dropped_and_a_bad_setup_refused(
    fake_sdk: tuple[ModuleType, Any, Any],
) -> None:
    from skelfuse.agent.sources.azure_reprojected import ReprojectedAzureKinectSource
    from skelfuse.agent.sources.base import SensorError

    package, k4a, k4abt = fake_sdk
    depth, _ = _render(_pose(0, 0, 0), _intrinsics(k4a))
    k4a.SCRIPT.append((1_000_000, depth, None))
    source = _source(package, {})
    assert source.next_capture(0.1) is None
    assert source.dropped["capture without depth or IR"] == 1 and k4abt.ENQUEUED == []
    source.close()
    assert k4a.LIVE == {}
    k4a.SCRIPT.append((1_000_000, depth[:-2], depth[:-2]))  # not the calibration's size
    source = _source(package, {})
    with pytest.raises(SensorError, match="calibration"):
        source.next_capture(0.1)
    source.close()
    with pytest.raises(SensorError, match="k4a_device_open"):
        ReprojectedAzureKinectSource(lambda t: None, pose_space="room", sdk=package, device_index=3)
    with pytest.raises(SensorError, match="pose space"):
        ReprojectedAzureKinectSource(lambda t: None, pose_space="", sdk=package)


def test_lens_maps_take_a_pixel_to_its_ray_and_back(fake_sdk: tuple[ModuleType, Any, Any]) -> None:
    """Device pixel → pinhole pixel on the same ray (the fake lens, inverted analytically) and
    back again, to the nearest pixel, from the grid-interpolated SDK samples."""
    from skelfuse.agent.sources.azure_lens import lens_maps

    _, k4a, _ = fake_sdk
    calibration = k4a.k4a_calibration_t()
    k4a.k4a_device_get_calibration(k4a.k4a_device_t(), 2, 0, calibration)
    intr = _intrinsics(k4a)
    maps = lens_maps(k4a, calibration, intr)
    rows, cols = np.indices((intr.height, intr.width))
    xd, yd = k4a.distort((cols - intr.cx) / intr.fx, (rows - intr.cy) / intr.fy, LENS_K1)
    truth_col, truth_row = np.rint(intr.cx + intr.fx * xd), np.rint(intr.cy + intr.fy * yd)
    none = intr.width * intr.height
    has = maps.to_pinhole < none
    assert 0.85 < has.mean() < 1.0, "the pinhole image's corners lie outside the lens's image"
    found_row, found_col = np.divmod(maps.to_pinhole[has], intr.width)
    assert np.abs(found_col - truth_col[has]).max() <= 1
    assert np.abs(found_row - truth_row[has]).max() <= 1
    assert (maps.to_device < none).all()  # every device pixel's ray is inside the pinhole image
    back = maps.to_device.reshape(-1)[maps.to_pinhole[has]]
    back_row, back_col = np.divmod(back, intr.width)
    assert np.abs(back_col - cols[has]).max() <= 1 and np.abs(back_row - rows[has]).max() <= 1


def test_depth_cloud_is_the_raw_depth_in_the_sensor_frame(
    fake_sdk: tuple[ModuleType, Any, Any],
) -> None:
    """The calibration's depth request gets the device's own (not re-projected) depth, through
    the lens: every point lies on the wall or a square once posed in the world."""
    from skelfuse.agent.sources.base import SensorError

    package, k4a, _ = fake_sdk
    T = _pose(10.0, -15.0, 20.0)
    k4a.SCRIPT.append((1_000_000, *_render(T, _intrinsics(k4a))))
    source = _source(package, {1_800_000_000_000_000_000: pose_from_matrix(T)})
    with pytest.raises(SensorError, match="no depth capture"):
        source.request_handlers()["depth_cloud"]({})
    source.next_capture(0.1)
    reply = source.depth_cloud({"max_points": 5000, "max_range_m": 5.0})
    points = np.frombuffer(reply["points"], dtype="<f4").reshape(-1, 3).astype(np.float64)
    assert reply["frame"] == "sensor" and reply["device_timestamp_us"] == 1_000_000
    assert 4000 <= len(points) <= 5000
    world_z = apply(T, points)[:, 2]
    off = np.minimum(np.abs(world_z - WALL_Z), np.abs(world_z - 3.0))
    assert np.percentile(off, 99) < 0.01
    source.close()


def test_wide_unbinned_depth_starts_at_15_fps(fake_sdk: tuple[ModuleType, Any, Any]) -> None:
    package, k4a, _ = fake_sdk
    source = _source(package, {}, depth_mode="WFOV_UNBINNED")
    assert source.fps == 15.0
    assert k4a.STARTED[0][:2] == (k4a.K4A_DEPTH_MODE_WFOV_UNBINNED, k4a.K4A_FRAMES_PER_SECOND_15)
    source.close()
    narrow = _source(package, {})
    assert narrow.fps == 30.0
    narrow.close()
