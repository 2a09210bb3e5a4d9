"""The ``azure_kinect`` and ``femto`` sources: Azure Kinect Body Tracking SDK via pykinect_azure.

Install: the Azure Kinect Sensor SDK 1.4 and Body Tracking SDK 1.1.x (native), then
``pip install 'skelfuse[k4a]'`` (``pykinect_azure``). Orbbec Femto Bolt / Mega: the same Body
Tracking SDK on top of Orbbec's K4A wrapper (OrbbecSDK-K4A-Wrapper), whose ``k4a`` library is
passed as ``k4a_path`` (``--k4a-path``), conventions.md §1.3. Not yet run on hardware
(docs/sensors.md).

Conversions (conventions.md §1.2, §1.7): the tracker's 32 joints (depth camera frame, mm,
+X right, +Y down) become our 25 (metres, +X left, +Y up) through
:func:`protocol.skeleton.azure_to_kinect_v2`, confidence levels become tracking states
(NONE → NotTracked, LOW → Inferred, MEDIUM/HIGH → Tracked). The body frame's device timestamp
(µs) spaces the capture stamps, anchored to this PC's clock (:class:`DeviceClock`) and kept in
:attr:`AzureKinectSource.last_device_timestamp_us`. The Body Tracking SDK 1.1 has no floor
plane, so ``floor`` is None, and no hand states (k4abt bodies have joints and confidence
levels only), so bodies carry no ``hands`` (docs/protocol.md §7.4).
:meth:`AzureKinectSource.depth_cloud` answers the server's depth requests for calibration: depth
points of the latest capture, in our sensor frame.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable
from typing import Any, Final

import numpy as np
import numpy.typing as npt

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


def cloud_to_sensor_frame(points_mm: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """(N, 3) depth-camera points (mm, +X right, +Y down) → our sensor frame (m, +X left, +Y up);
    points with z = 0 (no depth) are dropped."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    points = points[points[:, 2] > 0]
    out: npt.NDArray[np.float32] = (points * np.array([-1e-3, -1e-3, 1e-3])).astype(np.float32)
    return out


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
        self._pose = pose
        self._clock = DeviceClock(_US_NS, wall_clock_ns)
        self._k4a = sdk if sdk is not None else import_pykinect_azure()
        k4a = self._k4a
        try:
            k4a.initialize_libraries(
                module_k4a_path=k4a_path, module_k4abt_path=k4abt_path, track_body=True
            )
            config = k4a.default_configuration
            config.color_resolution = k4a.K4A_COLOR_RESOLUTION_OFF
            config.depth_mode = getattr(k4a, f"K4A_DEPTH_MODE_{depth_mode}")
            self._fps = 30.0
            config.camera_fps = k4a.K4A_FRAMES_PER_SECOND_30
            self._device = k4a.start_device(device_index=device_index, config=config)
            self._tracker = k4a.start_body_tracker()
        except (OSError, AttributeError, RuntimeError, Exception) as exc:  # ctypes/SDK failures
            raise SensorError(
                f"cannot start {sensor_type} device {device_index} with body tracking: {exc}"
            ) from exc
        self._bt = importlib.import_module(k4a.__name__ + ".k4abt._k4abt")
        self._last_capture: Any = None

    @property
    def sensor_type(self) -> str:
        return self._sensor_type

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def last_device_timestamp_us(self) -> int | None:
        """The last body frame's device timestamp (µs of the device clock)."""
        return self._clock.last_device_ticks

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose.copy(), "manual")

    def next_capture(self, timeout_s: float) -> Capture | None:
        timeout_ms = max(int(timeout_s * 1000), 1)
        try:
            capture = self._device.update(timeout_in_ms=timeout_ms)
            if capture is None:
                return None
            frame = self._tracker.update(capture=capture, timeout_in_ms=timeout_ms)
        except Exception as exc:  # pykinect_azure raises bare Exception from VERIFY
            logger.debug("no body frame within %d ms: %s", timeout_ms, exc)
            return None
        if frame is None:
            return None
        self._last_capture = capture
        device_us = int(self._bt.k4abt_frame_get_device_timestamp_usec(frame.handle()))
        bodies = []
        for index in range(int(frame.get_num_bodies())):
            skeleton = frame.get_body_skeleton(index)
            bodies.append(body_from_skeleton(int(frame.get_body_id(index)), skeleton))
        # k4abt 1.1 reports no floor plane; a depth + IMU floor estimate is future work.
        return Capture(self._clock.stamp(device_us), tuple(bodies), floor=None)

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
        if self._last_capture is None:
            raise SensorError("no depth capture yet")
        ok, points_mm = self._last_capture.get_pointcloud()
        if not ok:
            raise SensorError("the SDK returned no point cloud for the latest capture")
        return cloud_reply(
            cloud_to_sensor_frame(points_mm),
            params,
            device_timestamp_us=self._clock.last_device_ticks,
        )

    def close(self) -> None:
        for closer in (
            getattr(self._tracker, "destroy", None),
            getattr(self._device, "close", None),
        ):
            if closer is not None:
                try:
                    closer()
                except Exception:
                    logger.debug("closing the SDK failed", exc_info=True)
