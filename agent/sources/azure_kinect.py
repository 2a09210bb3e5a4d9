"""The ``azure_kinect`` and ``femto`` sources: Azure Kinect Body Tracking SDK via pykinect_azure.

Install: the Azure Kinect Sensor SDK 1.4 and Body Tracking SDK 1.1.x (native), then
``pip install 'skelfuse[k4a]'`` (``pykinect_azure``). Orbbec Femto Bolt / Mega: the same Body
Tracking SDK on top of Orbbec's K4A wrapper (OrbbecSDK-K4A-Wrapper), whose ``k4a`` library is
passed as ``k4a_path`` (``--k4a-path``), conventions.md §1.3. Not yet run on hardware
(docs/sensors.md).

The SDKs are called through pykinect_azure's ctypes layer
(:mod:`skelfuse.agent.sources.azure_sdk`), not its ``Device`` / ``Tracker``
classes: those pass every result to ``VERIFY``, which ``sys.exit()``s on a capture timeout as
on a real failure, having already released the capture it holds. Here a timeout is no frame
this time (None), a failure a :class:`SensorError` naming the SDK function, and every capture
and body frame is released once. The depth mode starts at its own highest rate
(:data:`~skelfuse.agent.sources.azure_sdk.FPS`: WFOV unbinned 15 fps, else 30).

Conversions (conventions.md §1.2, §1.7): the tracker's 32 joints (depth camera frame, mm,
+X right, +Y down) become our 25 (metres, +X left, +Y up) through
:func:`protocol.skeleton.azure_to_kinect_v2`, confidence levels become tracking states
(NONE → NotTracked, LOW → Inferred, MEDIUM/HIGH → Tracked). The body frame's device timestamp
(µs) spaces the capture stamps, anchored to this PC's clock (:class:`DeviceClock`) and kept in
:attr:`AzureKinectSource.last_device_timestamp_us`. The Body Tracking SDK 1.1 has no floor
plane, so ``floor`` is None, and no hand states (k4abt bodies have joints and confidence
levels only), so bodies carry no ``hands`` (docs/protocol.md §7.4).
:meth:`AzureKinectSource.depth_cloud` answers the server's depth requests for calibration: depth
points of the latest capture, in our sensor frame (through the calibration's lens).
"""

from __future__ import annotations

import importlib
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, Final

import numpy as np

from skelfuse.agent.sim.depth_camera import DepthIntrinsics
from skelfuse.agent.sources import azure_sdk as k4a_sdk
from skelfuse.agent.sources.azure_lens import LensMaps, lens_maps, sensor_points
from skelfuse.agent.sources.base import Capture, SensorError
from skelfuse.agent.sources.depth_reply import cloud_reply
from skelfuse.agent.sources.kinect_v2 import DeviceClock
from skelfuse.protocol.skeleton import AZURE_JOINT_COUNT, azure_to_kinect_v2
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body

logger = logging.getLogger(__name__)

DEPTH_MODES: Final = ("NFOV_2X2BINNED", "NFOV_UNBINNED", "WFOV_2X2BINNED", "WFOV_UNBINNED")
_US_NS = 1000


def import_pykinect_azure() -> Any:
    try:
        return importlib.import_module("pykinect_azure")
    except ImportError as exc:
        raise SensorError(
            f"Azure Kinect / Femto source needs pykinect_azure ({exc}): "
            "pip install 'skelfuse[k4a]' and install the Azure Kinect Sensor and Body Tracking SDKs"
        ) from exc


def _xyz(position: Any) -> tuple[float, float, float]:
    """A ``k4a_float3_t`` (a union: ``.xyz.x`` or ``.v[0]``) as a tuple."""
    inner = getattr(position, "xyz", position)
    return float(inner.x), float(inner.y), float(inner.z)


def body_from_skeleton(body_id: int, skeleton: Any) -> Body:
    """One ``k4abt_skeleton_t`` (32 joints, mm, Y down) as a wire body (25 joints, m, Y up)."""
    joints_mm = np.empty((AZURE_JOINT_COUNT, 3), dtype=np.float64)
    levels = np.empty(AZURE_JOINT_COUNT, dtype=np.int64)
    for k in range(AZURE_JOINT_COUNT):
        joint = skeleton.joints[k]
        joints_mm[k] = _xyz(joint.position)
        levels[k] = min(max(int(joint.confidence_level), 0), 3)
    joints_m, states = azure_to_kinect_v2(joints_mm, levels)
    bad = ~np.isfinite(joints_m).all(axis=1)
    joints_m[bad] = np.nan
    states[bad] = 0
    return Body(int(body_id), joints_m, states)


class AzureKinectSource:
    """Bodies from an Azure Kinect (or an Orbbec Femto through the K4A wrapper).

    Args:
        sensor_type: ``azure_kinect`` or ``femto`` (what the agent announces).
        device_index: which device on this PC.
        k4a_path / k4abt_path: the native libraries (``k4a.dll`` / ``libk4a.so`` of the Azure SDK
            or of Orbbec's K4A wrapper; ``k4abt.dll``); default: pykinect_azure's search.
        depth_mode: one of :data:`DEPTH_MODES` (NFOV_UNBINNED is the body tracker's best).
        pose: ``T_world_from_sensor`` to announce as a manual pose hint.
        sdk: the ``pykinect_azure`` module (tests pass a fake).
        wall_clock_ns: this PC's clock (injected in tests).

    Raises:
        SensorError: bad arguments, or the SDK, device or tracker cannot be started.
    """

    def __init__(
        self,
        sensor_type: str = "azure_kinect",
        *,
        device_index: int = 0,
        k4a_path: str | None = None,
        k4abt_path: str | None = None,
        depth_mode: str = "NFOV_UNBINNED",
        pose: Matrix4 | None = None,
        sdk: Any = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        if sensor_type not in ("azure_kinect", "femto"):
            raise SensorError(f"sensor type must be azure_kinect or femto, got {sensor_type!r}")
        if depth_mode not in DEPTH_MODES:
            raise SensorError(f"depth mode {depth_mode!r}: choose one of {', '.join(DEPTH_MODES)}")
        self._sensor_type = sensor_type
        self._depth_mode = depth_mode
        self._pose = pose
        self._clock = DeviceClock(_US_NS, wall_clock_ns)
        package = sdk if sdk is not None else import_pykinect_azure()
        self._k4a, self._bt = k4a_sdk.load_libraries(package, k4a_path, k4abt_path)
        self._opened = k4a_sdk.open_device(self._k4a, self._bt, device_index, depth_mode)
        self._last_depth: tuple[k4a_sdk.U16, int] | None = None
        self._lens: tuple[DepthIntrinsics, LensMaps] | None = None
        self.dropped: Counter[str] = Counter()
        """Device captures not given to the tracker, by reason (no depth or IR, queue full)."""

    @property
    def sensor_type(self) -> str:
        return self._sensor_type

    @property
    def fps(self) -> float:
        return float(k4a_sdk.FPS[self._depth_mode])

    @property
    def last_device_timestamp_us(self) -> int | None:
        """The last body frame's device timestamp (µs of the device clock)."""
        return self._clock.last_device_ticks

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose.copy(), "manual")

    def next_capture(self, timeout_s: float) -> Capture | None:
        """Give the device's next capture to the tracker, then return its next body frame.

        Returns:
            The bodies (our sensor frame) of the tracker's next body frame; None when no
            capture or no body frame came within ``timeout_s`` (each SDK call waits that long).

        Raises:
            SensorError: the device or the tracker failed (not on a timeout).
        """
        timeout_ms = max(int(timeout_s * 1000), 1)
        k4a = self._k4a
        capture = k4a_sdk.get_capture(k4a, self._opened.device, timeout_ms)
        if capture is None:
            return None
        try:
            depth = k4a_sdk.read_depth(k4a, capture)
            if depth is None:  # k4abt refuses a capture without both images
                self.dropped["capture without depth or IR"] += 1
                return None
            self._last_depth = depth
            if not k4a_sdk.enqueue(self._bt, self._opened.tracker, capture, timeout_ms):
                self.dropped["tracker queue full"] += 1  # still pop: that is what frees it
        finally:
            k4a.k4a_capture_release(capture)  # the tracker holds its own reference
        popped = k4a_sdk.pop_skeletons(self._bt, self._opened.tracker, timeout_ms)
        if popped is None:
            return None
        device_us, skeletons = popped
        bodies = tuple(body_from_skeleton(body_id, skeleton) for body_id, skeleton in skeletons)
        # k4abt 1.1 reports no floor plane; a depth + IMU floor estimate is future work.
        return Capture(self._clock.stamp(device_us), bodies, floor=None)

    def request_handlers(self) -> dict[str, Callable[[dict[str, Any]], Any]]:
        """Requests this source answers (docs/protocol.md §6.5)."""
        return {"depth_cloud": self.depth_cloud}

    def depth_cloud(self, params: dict[str, Any]) -> dict[str, Any]:
        """The ``depth_cloud`` request: points of the latest depth image, our sensor frame.

        Params: ``max_points`` (default 20 000, at most
        :data:`skelfuse.protocol.depth_cloud.MAX_POINTS`) and
        ``max_range_m`` (default 5.0). Result (docs/protocol.md §6.5): ``points``, one bin of
        float32 little-endian x, y, z triples (metres), ``count``, ``frame`` = ``"sensor"``,
        ``device_timestamp_us``.
        """
        if self._last_depth is None:
            raise SensorError("no depth capture yet")
        depth_mm, device_us = self._last_depth
        if self._lens is None:  # once, on the first request: 2 SDK calls per 8-px grid point
            calibration = self._opened.calibration
            intrinsics = k4a_sdk.depth_intrinsics(calibration, self._depth_mode)
            self._lens = (intrinsics, lens_maps(self._k4a, calibration, intrinsics))
        intrinsics, lens = self._lens
        if depth_mm.shape != (intrinsics.height, intrinsics.width):
            raise SensorError(
                f"depth image {depth_mm.shape}, calibration {(intrinsics.height, intrinsics.width)}"
            )
        points = sensor_points(depth_mm, lens, intrinsics)
        return cloud_reply(points, params, device_timestamp_us=device_us)

    def close(self) -> None:
        """Shut the tracker down, stop the cameras and close the device."""
        try:
            k4a_sdk.close_device(self._k4a, self._bt, self._opened)
        except Exception:
            logger.debug("closing the SDK failed", exc_info=True)
