"""SDK sources against fakes of their Python APIs (tests/fakes): no hardware here."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.registry import SOURCE_KINDS, check_sources, make_source
from skelfuse.protocol.constants import MAX_RESPONSE_BYTES
from skelfuse.protocol.skeleton import AZURE_JOINT_COUNT, azure_to_kinect_v2
from skelfuse.protocol.wire import Frame, Response, decode, encode

FAKES = Path(__file__).resolve().parents[1] / "fakes"


def _forget(prefix: str) -> None:
    for name in [m for m in sys.modules if m == prefix or m.startswith(prefix + ".")]:
        del sys.modules[name]


@pytest.fixture
def fake_pykinect2(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    from skelfuse.agent.sources.kinect_v2 import PyKinect2Fixer

    monkeypatch.syspath_prepend(str(FAKES))
    _forget("pykinect2")
    yield
    _forget("pykinect2")
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, PyKinect2Fixer)]


@pytest.fixture
def fake_k4a(monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    """The fake pykinect_azure package (tests/fakes/pykinect_azure), its ctypes layers reset;
    ``package.k4a`` / ``package.k4abt`` are the fake ``_k4a`` / ``_k4abt``."""
    monkeypatch.syspath_prepend(str(FAKES))
    _forget("pykinect_azure")
    module = importlib.import_module("pykinect_azure")
    module.k4a = importlib.import_module("pykinect_azure.k4a._k4a")
    module.k4abt = importlib.import_module("pykinect_azure.k4abt._k4abt")
    module.k4a.reset()
    module.k4abt.reset()
    module.CALLS.clear()
    yield module
    _forget("pykinect_azure")


class FakeClock:
    def __init__(self, start_ns: int = 1_800_000_000_000_000_000) -> None:
        self.now = start_ns

    def __call__(self) -> int:
        return self.now


# --- Kinect v2 ---------------------------------------------------------------------------------


def test_patch_fixes_each_known_line_and_leaves_others() -> None:
    from skelfuse.agent.sources.kinect_v2 import patch_pykinect_source

    source = (
        "assert sizeof(tagSTATSTG) == 72, sizeof(tagSTATSTG)\n"
        "from comtypes import _check_version; _check_version('')\nx = 1\n"
    )
    patched, applied = patch_pykinect_source("pykinect2.PyKinectV2", source)
    assert "in (72, 80)" in patched and "_check_version('')" not in patched
    assert "x = 1" in patched and len(applied) == 2
    runtime = "t = time.clock()\na = numpy.ndarray((6), dtype=numpy.object)\n"
    patched, applied = patch_pykinect_source("pykinect2.PyKinectRuntime", runtime)
    assert "time.perf_counter()" in patched and "dtype=object" in patched
    assert patch_pykinect_source("pykinect2.PyKinectV2", "fixed fork\n") == ("fixed fork\n", [])


def test_unpatched_fake_fails_like_the_real_pykinect2(fake_pykinect2: None) -> None:
    if sys.maxsize <= 2**32:
        pytest.skip("the tagSTATSTG size bug only shows on 64-bit Python")
    with pytest.raises(AssertionError, match="80"):
        importlib.import_module("pykinect2.PyKinectV2")


def _kinect_frame(runtime: Any, relative: int, floor: tuple[float, ...]) -> Any:
    joints = np.arange(75, dtype=np.float64).reshape(25, 3) / 100.0
    states = [2] * 25
    states[7] = 1
    states[21] = 0
    body = runtime.KinectBody(72057594037928141, joints, states)
    return runtime.KinectBodyFrameData([runtime.KinectBody(), body], floor, relative)


def test_kinect_v2_source_maps_joints_states_floor_and_time(fake_pykinect2: None) -> None:
    from skelfuse.agent.sources.kinect_v2 import KinectV2Source, import_pykinect2

    _, runtime = import_pykinect2()  # the fake, loaded through skelfuse's fixes
    clock = FakeClock()
    source = KinectV2Source(wall_clock_ns=clock, sleep=lambda s: None)
    runtime.SCRIPT[:] = [
        _kinect_frame(runtime, 10_000_000, (0.0, 0.99, 0.14, 1.0)),
        _kinect_frame(runtime, 10_333_333, (0.0, 0.0, 0.0, 0.0)),
    ]
    first = source.next_capture(0.1)
    clock.now += 40_000_000  # the PC saw it 40 ms later; the device says 33.3 ms
    second = source.next_capture(0.1)
    assert first is not None and second is not None
    assert len(first.bodies) == 1
    body = first.bodies[0]
    assert body.tracking_id == 72057594037928141
    np.testing.assert_allclose(body.joints_m[1], [0.03, 0.04, 0.05], atol=1e-6)
    assert body.states[7] == 1 and body.states[21] == 0 and body.states[0] == 2
    assert first.floor is not None and abs(np.linalg.norm(first.floor[:3]) - 1) < 1e-6
    assert second.floor is None  # (0, 0, 0, 0): the SDK has not found the floor
    assert second.t_capture_ns - first.t_capture_ns == 33_333_300  # device spacing kept
    assert source.last_relative_time == 10_333_333
    assert source.next_capture(0.0) is None
    source.close()
    assert runtime.OPENED[-1].closed
    encode(Frame(1, first.t_capture_ns, first.bodies, first.floor))  # wire-valid


def test_kinect_v2_depth_cloud_goes_through_the_coordinate_mapper(fake_pykinect2: None) -> None:
    """Depth image → the SDK's ICoordinateMapper (called with the ctypes types its COM
    signature demands) → our sensor frame, limited and packed as the server asks."""
    from skelfuse.agent.sources.kinect_v2 import KinectV2Source, import_pykinect2

    _, runtime = import_pykinect2()
    runtime.DEPTH.clear()
    source = KinectV2Source(sleep=lambda s: None)
    assert source.request_handlers()["depth_cloud"] == source.depth_cloud
    with pytest.raises(SensorError, match="no depth frame"):
        source.depth_cloud({})
    depth = np.zeros((runtime.DEPTH_HEIGHT, runtime.DEPTH_WIDTH), dtype=np.uint16)
    depth[:100] = 2500  # a wall 2.5 m away, at the top of the image
    depth[100:200, :256] = 6000  # beyond the request's range
    runtime.DEPTH.append(depth.ravel())  # the rest: no depth (the SDK maps it to -inf)
    result = source.depth_cloud({"max_points": 20_000, "max_range_m": 5.0})
    assert source._runtime._mapper.calls == 1
    points = np.frombuffer(result["points"], dtype="<f4").reshape(-1, 3)
    assert result["frame"] == "sensor" and result["count"] == points.shape[0]
    assert 10_000 <= points.shape[0] <= 20_000  # 51 200 wall points, thinned to the limit
    np.testing.assert_allclose(points[:, 2], 2.5, atol=1e-6)
    assert (points[:, 1] > 0).all(), "the top of the image is above the sensor: +Y up"
    message = encode(Response(1, True, result))
    decoded = decode(message, MAX_RESPONSE_BYTES)
    assert isinstance(decoded, Response) and decoded.result["count"] == result["count"]
    source.close()

    body_only = KinectV2Source(sleep=lambda s: None, depth=False)
    with pytest.raises(SensorError, match="without its depth stream"):
        body_only.depth_cloud({})
    body_only.close()


# --- Azure Kinect / Femto ----------------------------------------------------------------------


def _azure_body(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    joints = rng.uniform(-800, 800, size=(AZURE_JOINT_COUNT, 3))
    joints[:, 2] = rng.uniform(1500, 3000, size=AZURE_JOINT_COUNT)
    levels = rng.integers(0, 3, size=AZURE_JOINT_COUNT)
    return joints, levels


def _images(shape: tuple[int, int] = (8, 8)) -> tuple[np.ndarray, np.ndarray]:
    """A device capture's depth (a wall 2 m away) and IR, small where pixels do not matter."""
    return np.full(shape, 2000, dtype=np.uint16), np.full(shape, 100, dtype=np.uint16)


def _detect_in_turn(frames: list[list[Any]]) -> Callable[..., list[Any]]:
    """The fake tracker's DETECT: the bodies of each enqueued capture, in turn."""
    pending = iter(frames)
    return lambda depth, ir, calibration: next(pending)


def _live_captures(k4a: Any) -> int:
    return sum(1 for entry in k4a.LIVE.values() if entry["kind"] == "capture")


def test_azure_source_maps_32_joints_mm_ydown_and_confidence(fake_k4a: ModuleType) -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a, k4abt = fake_k4a.k4a, fake_k4a.k4abt
    joints, levels = _azure_body(np.random.default_rng(1))
    k4a.SCRIPT[:] = [(1_000_000, *_images()), (1_033_333, *_images())]
    k4abt.DETECT = _detect_in_turn([[(7, joints, levels)], []])
    clock = FakeClock()
    source = AzureKinectSource(wall_clock_ns=clock)
    assert ("initialize_libraries", None, None, True) in fake_k4a.CALLS
    assert k4a.STARTED[0] == (k4a.K4A_DEPTH_MODE_NFOV_UNBINNED, k4a.K4A_FRAMES_PER_SECOND_30, 0)
    assert source.fps == 30.0
    first = source.next_capture(0.1)
    clock.now += 50_000_000
    second = source.next_capture(0.1)
    assert first is not None and second is not None
    expected_joints, expected_states = azure_to_kinect_v2(joints.astype(np.float32), levels)
    np.testing.assert_allclose(first.bodies[0].joints_m, expected_joints, atol=1e-6)
    np.testing.assert_array_equal(first.bodies[0].states, expected_states)
    # Y down, mm -> Y up, m: the pelvis seen at +y (below the camera) comes out at -y.
    assert first.bodies[0].joints_m[0, 1] == pytest.approx(-joints[0, 1] / 1000, abs=1e-5)
    assert first.bodies[0].tracking_id == 7 and first.floor is None and second.bodies == ()
    assert second.t_capture_ns - first.t_capture_ns == 33_333_000
    assert source.last_device_timestamp_us == 1_033_333
    source.close()


def test_a_capture_timeout_is_no_frame_and_the_source_goes_on(fake_k4a: ModuleType) -> None:
    """pykinect_azure 0.0.4's Device.update sys.exit()s on a timeout (VERIFY), the capture it
    held already released: the source asks the SDK itself, gets None, and goes on."""
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a, k4abt = fake_k4a.k4a, fake_k4a.k4abt
    source = AzureKinectSource(wall_clock_ns=FakeClock())
    assert source.next_capture(0.01) is None  # no capture yet
    k4a.SCRIPT[:] = [(1_000_000, *_images())]
    assert source.next_capture(0.1) is not None
    assert source.next_capture(0.01) is None  # a timeout after a capture
    k4a.SCRIPT[:] = [(2_000_000, *_images()), (2_033_333, *_images())]
    k4abt.LAG = 1  # the tracker a frame behind: its pop times out once
    assert source.next_capture(0.1) is None
    late = source.next_capture(0.1)
    assert late is not None and source.last_device_timestamp_us == 2_000_000
    assert _live_captures(k4a) == 0 and k4abt.FRAMES == {}, "released once each, not kept"
    source.close()
    assert k4a.LIVE == {} and k4abt.FRAMES == {}
    assert k4abt.TRACKERS[-1]["destroyed"] and k4a.STARTED[-2:] == ["stopped", "closed"]


def test_a_full_tracker_queue_drops_the_capture_and_still_pops(fake_k4a: ModuleType) -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a, k4abt = fake_k4a.k4a, fake_k4a.k4abt
    k4abt.QUEUE_LIMIT, k4abt.LAG = 1, 1  # one result waits; the tracker holds it back
    k4a.SCRIPT[:] = [(t, *_images()) for t in (1_000, 2_000, 3_000)]
    source = AzureKinectSource()
    assert source.next_capture(0.1) is None  # queued, its body frame not out yet
    assert source.next_capture(0.1) is None  # queue full: dropped
    k4abt.LAG = 0
    frame = source.next_capture(0.1)  # queue still full, but the pop gets the first one out
    assert frame is not None and source.last_device_timestamp_us == 1_000
    assert source.dropped["tracker queue full"] == 2
    source.close()
    assert k4a.LIVE == {} and k4abt.FRAMES == {}


def test_sdk_failures_are_sensor_errors_naming_the_call(
    fake_k4a: ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a, k4abt = fake_k4a.k4a, fake_k4a.k4abt
    with pytest.raises(SensorError, match="k4a_device_open"):
        AzureKinectSource(device_index=1)
    source = AzureKinectSource()
    depth, _ = _images()
    k4a.SCRIPT[:] = [(1_000, depth, None), (2_000, *_images()), (3_000, *_images())]
    assert source.next_capture(0.1) is None  # no IR: the tracker would refuse it; dropped
    assert source.dropped["capture without depth or IR"] == 1
    failed = k4a.K4A_WAIT_RESULT_FAILED
    monkeypatch.setattr(k4abt, "k4abt_tracker_enqueue_capture", lambda *args: failed)
    with pytest.raises(SensorError, match="k4abt_tracker_enqueue_capture"):
        source.next_capture(0.1)
    monkeypatch.undo()
    monkeypatch.setattr(k4abt, "k4abt_tracker_pop_result", lambda *args: failed)
    with pytest.raises(SensorError, match="k4abt_tracker_pop_result"):
        source.next_capture(0.1)
    monkeypatch.setattr(k4a, "k4a_device_get_capture", lambda *args: failed)
    with pytest.raises(SensorError, match="k4a_device_get_capture"):
        source.next_capture(0.1)
    source.close()
    assert _live_captures(k4a) == 0 and k4abt.FRAMES == {}

    def exits(**kwargs: Any) -> None:
        sys.exit(1)  # what pykinect_azure does when a native library is missing

    monkeypatch.setattr(fake_k4a, "initialize_libraries", exits)
    with pytest.raises(SensorError, match="libraries"):
        AzureKinectSource()


def test_wide_unbinned_depth_starts_at_15_fps(fake_k4a: ModuleType) -> None:
    """The device refuses 30 fps in WFOV unbinned (the fake too): the mode's own rate."""
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a = fake_k4a.k4a
    source = AzureKinectSource(depth_mode="WFOV_UNBINNED")
    assert source.fps == 15.0
    assert k4a.STARTED[0][:2] == (k4a.K4A_DEPTH_MODE_WFOV_UNBINNED, k4a.K4A_FRAMES_PER_SECOND_15)
    source.close()


def test_femto_passes_the_orbbec_wrapper_library(fake_k4a: ModuleType) -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    source = AzureKinectSource(
        "femto", k4a_path="/opt/orbbec/libk4a.so", depth_mode="WFOV_2X2BINNED"
    )
    assert source.sensor_type == "femto"
    assert ("initialize_libraries", "/opt/orbbec/libk4a.so", None, True) in fake_k4a.CALLS
    assert fake_k4a.k4a.STARTED[0][0] == fake_k4a.k4a.K4A_DEPTH_MODE_WFOV_2X2BINNED
    source.close()
    with pytest.raises(SensorError, match="depth mode"):
        AzureKinectSource(depth_mode="HUGE")


def test_depth_cloud_is_in_our_sensor_frame_and_fits_one_message(fake_k4a: ModuleType) -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    k4a = fake_k4a.k4a
    shape = (k4a.CALIBRATION["height"], k4a.CALIBRATION["width"])
    depth, ir = _images(shape)
    depth[:, 320:] = 3000  # the image's right half 3 m away, its left half 2 m
    depth[400:] = 0  # no depth in the bottom rows
    k4a.SCRIPT[:] = [(5, depth, ir)]
    source = AzureKinectSource()
    with pytest.raises(SensorError, match="no depth"):
        source.depth_cloud({})
    source.next_capture(0.1)
    result = source.depth_cloud({})
    points = np.frombuffer(result["points"], dtype="<f4").reshape(-1, 3)
    assert result["frame"] == "sensor" and result["device_timestamp_us"] == 5
    assert result["count"] == points.shape[0] and 10_000 <= points.shape[0] <= 20_000
    near = np.isclose(points[:, 2], 2.0)
    assert (near | np.isclose(points[:, 2], 3.0)).all()
    # Azure's +X right, +Y down, mm -> ours +X left, +Y up, m.
    assert (points[near, 0] > 0).mean() > 0.99 and (points[~near, 0] < 0).mean() > 0.99
    assert points[:, 1].max() > 1.0 and points[:, 1].min() > -0.7  # depth above, none low
    assert source.request_handlers()["depth_cloud"] == source.depth_cloud
    message = encode(Response(1, True, result))
    decoded = decode(message, MAX_RESPONSE_BYTES)  # the server's limit while it waits
    assert isinstance(decoded, Response) and decoded.result["count"] == result["count"]
    source.close()


# --- registry ----------------------------------------------------------------------------------


def test_check_sources_says_why_each_sdk_source_cannot_run_here() -> None:
    checks = {c.kind: c for c in check_sources()}
    assert tuple(checks) == SOURCE_KINDS
    assert checks["sim"].available and checks["replay"].available
    for kind in ("kinect_v2", "azure_kinect", "femto"):
        assert checks[kind].reason
    if sys.platform != "win32":
        assert not checks["kinect_v2"].available and "Windows" in checks["kinect_v2"].reason


def test_make_source_refuses_unknown_kinds_and_missing_files() -> None:
    with pytest.raises(SensorError, match="unknown source"):
        make_source("kinect_v3", {})
    with pytest.raises(SensorError, match="--file"):
        make_source("replay", {})
