"""An Azure Kinect / Femto on a moving head, its body tracker fed level, re-projected captures.

Report B (issue 15): a body tracker trained on level cameras sees a head-mounted camera pitch
and roll with its wearer. This source feeds it instead what a level camera at the same floor
position and heading would have seen. For each device capture:

1. depth and IR are copied out of the SDK (:mod:`skelfuse.agent.sources.azure_sdk`);
   the depth image's device timestamp, anchored to this PC's clock, is the capture instant;
2. ``pose_at(t_capture_ns)`` gives the sensor's ``T_space_from_sensor`` then (a plain callable:
   e.g. ``PosedSource.sensor_pose_at`` of :mod:`skelfuse.agent.poses.posed`, which adds the
   mount and the clock offset; the space must be +Y up, as OpenVR's standing universe is). No
   pose: the capture is not tracked, it is counted (``unposed``) and returned with
   ``pose=None`` and no bodies, so the runner skips it and its ``seq`` gap shows the loss;
3. :func:`skelfuse.agent.reproject.reproject_depth` re-renders depth and IR as the level
   reference camera (:func:`skelfuse.agent.reproject.level_reference`: floor position and
   heading only, at the sensor's height or ``reference_height_m``) sees them. The reference
   camera is the device's own: the calibration the tracker was created with, lens included.
   ``reproject_depth`` models a pinhole, so the images go through it as pinhole images (the
   calibration's fx, fy, cx, cy) and are taken into and out of the lens by nearest-pixel maps
   built from the SDK's lens model (:mod:`skelfuse.agent.sources.azure_lens`): the
   tracker's 3-D joints are then consistent with the re-projected pixels;
4. a new ``k4a_capture_t`` holding the two images (DEPTH16, IR16, the device timestamp) is
   enqueued in the tracker; its body frames are popped and matched to their capture by that
   timestamp (the tracker may lag a frame behind);
5. the joints, found in the reference camera, are mapped back to the sensor's own frame
   (:func:`skelfuse.agent.reproject.joints_to_sensor`) and sent with the sensor's pose.

Why back to the sensor frame rather than sending the reference frame with the reference pose
(the same world points either way): a frame then means exactly what docs/protocol.md §6.3 says
(joints in the sensor frame, ``pose`` = the pose the pose source measured), so the server
treats this source like any other moving sensor; its per-ray depth error and view direction
are those of the physical camera; the ``depth_cloud`` reply (raw depth, sensor frame) agrees
with the bodies; and a reference at a fixed height (``reference_height_m``), which is not where
the camera is, never reaches the wire.

No floor plane (``floor`` None) and no hand states, as the fixed Azure source. Not run on
hardware or with a real body tracker: tested against a fake of the SDK's ctypes layer; the
effect of re-projection on a real body tracker cannot be measured here (docs/sensors.md).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from skelfuse.agent.reproject import MAX_EDGE_M, joints_to_sensor, level_reference, reproject_depth
from skelfuse.agent.reproject_raster import warm_up
from skelfuse.agent.sources.azure_kinect import (
    DEPTH_MODES,
    body_from_skeleton,
    import_pykinect_azure,
)
from skelfuse.agent.sources.azure_lens import lens_maps, remap, sensor_points
from skelfuse.agent.sources.azure_sdk import (
    FPS,
    build_capture,
    close_device,
    depth_intrinsics,
    enqueue,
    get_capture,
    load_libraries,
    open_device,
    pop_skeletons,
    read_capture,
)
from skelfuse.agent.sources.base import Capture, SensorError
from skelfuse.agent.sources.depth_reply import cloud_reply
from skelfuse.agent.sources.kinect_v2 import DeviceClock
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.transform import Matrix4, invert
from skelfuse.protocol.wire import Body

logger = logging.getLogger(__name__)

_US_NS: Final = 1000
NO_POSE: Final = "no pose at the capture instant"
"""The reason :attr:`ReprojectedAzureKinectSource.unposed` counts."""
MAX_PENDING: Final = 8
"""Captures in the tracker awaiting their body frame; older ones are forgotten (lost frames)."""


@dataclass(frozen=True, slots=True)
class _Pending:
    """A capture in the tracker: its stamp, the sensor's pose and the re-projection used."""

    t_capture_ns: int
    pose: SensorPose
    T_ref_from_sensor: Matrix4


class ReprojectedAzureKinectSource:
    """Bodies from a moving Azure Kinect (or Femto via the K4A wrapper), tracked level.

    Args:
        pose_at: ``T_space_from_sensor`` at a capture instant (ns on this PC's wall clock), or
            None when unknown. The space must be +Y up.
        pose_space: the tracking space's id (the hello says ``moving``).
        sensor_type: ``azure_kinect`` or ``femto``.
        device_index, k4a_path, k4abt_path, depth_mode: as
            :class:`~skelfuse.agent.sources.azure_kinect.AzureKinectSource`.
        reference_height_m: the reference camera's height in the space (None: the sensor's own
            at each capture: no parallax, only turned).
        max_edge_m: the re-projection's mesh edge rule (metres).
        sdk: the ``pykinect_azure`` package (tests pass a fake).
        wall_clock_ns: this PC's clock (injected in tests).
        close_with: called by :meth:`close` after the device is closed (the pose source's
            ``close``, so one ``close`` ends both).

    Raises:
        SensorError: bad arguments, or the SDK, device or tracker cannot be started.
    """

    def __init__(
        self,
        pose_at: Callable[[int], SensorPose | None],
        *,
        pose_space: str,
        sensor_type: str = "azure_kinect",
        device_index: int = 0,
        k4a_path: str | None = None,
        k4abt_path: str | None = None,
        depth_mode: str = "NFOV_UNBINNED",
        reference_height_m: float | None = None,
        max_edge_m: float = MAX_EDGE_M,
        sdk: Any = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        close_with: Callable[[], None] | None = None,
    ) -> None:
        if sensor_type not in ("azure_kinect", "femto"):
            raise SensorError(f"sensor type must be azure_kinect or femto, got {sensor_type!r}")
        if depth_mode not in DEPTH_MODES:
            raise SensorError(f"depth mode {depth_mode!r}: choose one of {', '.join(DEPTH_MODES)}")
        if not pose_space:
            raise SensorError("a moving sensor needs a pose space id")
        self._sensor_type = sensor_type
        self._depth_mode = depth_mode
        self._pose_at = pose_at
        self._close_with = close_with
        self.pose_space = pose_space
        self._height = reference_height_m
        self._max_edge_m = max_edge_m
        self._clock = DeviceClock(_US_NS, wall_clock_ns)
        package = sdk if sdk is not None else import_pykinect_azure()
        self._k4a, self._bt = load_libraries(package, k4a_path, k4abt_path)
        self._opened = open_device(self._k4a, self._bt, device_index, depth_mode)
        self.intrinsics = depth_intrinsics(self._opened.calibration, depth_mode)
        """The depth camera's (and the reference camera's) pinhole intrinsics."""
        self.lens = lens_maps(self._k4a, self._opened.calibration, self.intrinsics)
        """Device image ↔ pinhole image of :attr:`intrinsics`, through the calibration's lens."""
        warm_up()  # compile the re-projection before the first frame, not during it
        self._pending: dict[int, _Pending] = {}
        self._last_depth: tuple[Any, int] | None = None
        self.unposed: Counter[str] = Counter()
        """Captures not tracked because ``pose_at`` had no pose for them, by reason (one
        reason here; a Counter like :class:`~skelfuse.agent.poses.posed.PosedSource`'s, which
        ``skelfuse agent`` reports at exit)."""
        self.dropped: Counter[str] = Counter()
        """Captures lost after posing, by reason (tracker queue full, frame never matched)."""

    @property
    def sensor_type(self) -> str:
        return self._sensor_type

    @property
    def fps(self) -> float:
        return float(FPS[self._depth_mode])

    @property
    def last_device_timestamp_us(self) -> int | None:
        """The last device capture's depth timestamp (µs of the device clock)."""
        return self._clock.last_device_ticks

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        """None: a moving sensor has no one world pose (its space is calibrated instead)."""
        return None

    def next_capture(self, timeout_s: float) -> Capture | None:
        """Feed the next device capture to the tracker, then return the next body frame.

        Returns:
            The bodies (sensor frame) with the sensor's pose at their capture instant; a
            capture with ``pose=None`` and no bodies when its pose was unknown; None when no
            body frame came within ``timeout_s``.

        Raises:
            SensorError: the device or the tracker failed (not on a timeout).
        """
        timeout_ms = max(int(timeout_s * 1000), 1)
        unposed = self._feed(timeout_ms)
        if unposed is not None:
            return unposed
        if not self._pending:
            return None
        return self._result(timeout_ms)

    def _feed(self, timeout_ms: int) -> Capture | None:
        """One device capture, re-projected, into the tracker; the pose-less capture to
        return when its pose is unknown, else None."""
        k4a = self._k4a
        device_capture = get_capture(k4a, self._opened.device, timeout_ms)
        if device_capture is None:
            return None
        try:
            raw = read_capture(k4a, device_capture)
        finally:
            k4a.k4a_capture_release(device_capture)
        if raw is None:
            self.dropped["capture without depth or IR"] += 1
            return None
        shape = (self.intrinsics.height, self.intrinsics.width)
        if raw.depth.shape != shape or raw.ir.shape != shape:
            raise SensorError(
                f"depth {raw.depth.shape} / IR {raw.ir.shape} images, calibration {shape}"
            )
        t_ns = self._clock.stamp(raw.device_us)
        self._last_depth = (raw.depth, raw.device_us)
        pose = self._pose_at(t_ns)
        if pose is None:
            if not self.unposed:
                logger.warning("captures without a sensor pose are not tracked nor sent")
            self.unposed[NO_POSE] += 1
            return Capture(t_ns, (), floor=None, pose=None)
        T_space_from_sensor = pose_matrix(pose)
        T_ref_from_sensor = invert(level_reference(T_space_from_sensor, self._height)) @ (
            T_space_from_sensor
        )
        depth_ref, ir_ref = reproject_depth(
            remap(raw.depth, self.lens.to_pinhole),
            remap(raw.ir, self.lens.to_pinhole),
            self.intrinsics,
            T_ref_from_sensor,
            self._max_edge_m,
        )
        built = build_capture(
            k4a,
            remap(depth_ref, self.lens.to_device),
            remap(ir_ref, self.lens.to_device),
            raw.device_us,
            raw.temperature_c,
        )
        try:
            queued = enqueue(self._bt, self._opened.tracker, built, timeout_ms)
        finally:
            k4a.k4a_capture_release(built)  # the tracker holds its own reference
        if not queued:
            self.dropped["tracker queue full"] += 1
            return None
        self._pending[raw.device_us] = _Pending(t_ns, pose, T_ref_from_sensor)
        while len(self._pending) > MAX_PENDING:
            del self._pending[min(self._pending)]
            self.dropped["no body frame"] += 1
        return None

    def _result(self, timeout_ms: int) -> Capture | None:
        """The tracker's next body frame, matched to its pending capture, in the sensor frame."""
        popped = pop_skeletons(self._bt, self._opened.tracker, timeout_ms)
        if popped is None:
            return None
        device_us, skeletons = popped
        for older in [t for t in self._pending if t < device_us]:
            del self._pending[older]  # the tracker skipped them
            self.dropped["no body frame"] += 1
        pending = self._pending.pop(device_us, None)
        if pending is None:
            self.dropped["body frame of an unknown capture"] += 1
            return None
        bodies = []
        for body_id, skeleton in skeletons:
            in_reference = body_from_skeleton(body_id, skeleton)
            joints = joints_to_sensor(in_reference.joints_m, pending.T_ref_from_sensor)
            bodies.append(Body(body_id, joints.astype(np.float32), in_reference.states))
        return Capture(pending.t_capture_ns, tuple(bodies), floor=None, pose=pending.pose)

    def request_handlers(self) -> dict[str, Callable[[dict[str, Any]], Any]]:
        """Requests this source answers (docs/protocol.md §6.5)."""
        return {"depth_cloud": self.depth_cloud}

    def depth_cloud(self, params: dict[str, Any]) -> dict[str, Any]:
        """The ``depth_cloud`` request: the latest raw (not re-projected) depth image's points
        in the sensor frame (through the lens maps), as
        :meth:`~skelfuse.agent.sources.azure_kinect.AzureKinectSource.depth_cloud` replies."""
        if self._last_depth is None:
            raise SensorError("no depth capture yet")
        depth_mm, device_us = self._last_depth
        points = sensor_points(depth_mm, self.lens, self.intrinsics)
        return cloud_reply(points, params, device_timestamp_us=device_us)

    def close(self) -> None:
        try:
            close_device(self._k4a, self._bt, self._opened)
        except Exception:
            logger.debug("closing the SDK failed", exc_info=True)
        finally:
            if self._close_with is not None:
                self._close_with()
