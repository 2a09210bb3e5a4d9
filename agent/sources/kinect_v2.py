"""The ``kinect_v2`` source: Kinect for Windows SDK 2.0 through PyKinect2 (Windows only).

Install: the Kinect for Windows Runtime (or SDK) 2.0, then ``pip install 'skelfuse[kinect-v2]'``
(``pykinect2`` and ``comtypes``). Not yet run on hardware (docs/sensors.md).

PyKinect2 0.1.0 from PyPI does not import on today's Pythons (conventions.md §2, Kinect/PyKinect2
#17 #37 #88). Rather than asking users to edit site-packages, :func:`import_pykinect2` installs
an import hook that patches the two modules' source text as they load, only where the known
faulty line is present (so a fixed fork loads untouched):

- ``assert sizeof(tagSTATSTG) == 72``: the struct is 80 bytes on 64-bit Python → accept both;
- ``from comtypes import _check_version; _check_version('')``: raises with comtypes ≥ 1.2 → drop;
- ``time.clock()`` (removed in Python 3.8) → ``time.perf_counter()``;
- ``numpy.object`` (removed in numpy 1.24) → ``object``;
- ``ctypes.pythonapi.PyObject_AsWriteBuffer`` (removed in Python 3.10; only used for pygame
  surfaces) → a stub, so the runtime object can be created.

Frames: the SDK's camera space is our sensor frame (metres, +X sensor-left, +Y up, +Z forward),
its ``JointType`` order is our joint order and ``TrackingState`` our states: joints pass as is.
``FloorClipPlane`` (x, y, z, w) is the floor plane. ``RelativeTime`` (100 ns ticks, the sensor's
clock) spaces the capture stamps; they are anchored to this PC's clock at the first frame and
re-anchored if the two drift apart by more than 50 ms. Hand states pass as the SDK reports
them (``hand_left_state``, ``hand_left_confidence`` and the right ones; docs/protocol.md §7.4).
"""

from __future__ import annotations

import ctypes
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import logging
import re
import sys
import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sources.base import Capture, SensorError
from skelfuse.agent.sources.depth_reply import cloud_reply
from skelfuse.protocol.hands import hands_from_sdk
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body

logger = logging.getLogger(__name__)

KINECT_V2_FPS = 30.0
_TICK_NS = 100
_REANCHOR_NS = 50_000_000

_PATCHES: dict[str, tuple[tuple[str, str, str], ...]] = {
    "pykinect2.PyKinectV2": (
        ("tagSTATSTG size on 64-bit Python",
         r"assert sizeof\(tagSTATSTG\) == 72, sizeof\(tagSTATSTG\)",
         "assert sizeof(tagSTATSTG) in (72, 80), sizeof(tagSTATSTG)"),
        ("comtypes >= 1.2 _check_version",
         r"from comtypes import _check_version; _check_version\(''\)",
         "pass  # skelfuse: comtypes >= 1.2 refuses an empty version check"),
    ),
    "pykinect2.PyKinectRuntime": (
        ("time.clock removed in Python 3.8", r"\btime\.clock\(\)", "time.perf_counter()"),
        ("numpy.object removed in numpy 1.24", r"\bnumpy\.object\b", "object"),
        ("PyObject_AsWriteBuffer removed in Python 3.10",
         r"ctypes\.pythonapi\.PyObject_AsWriteBuffer\b",
         "(getattr(ctypes.pythonapi, 'PyObject_AsWriteBuffer', None) "
         "or __import__('types').SimpleNamespace())"),
    ),
}  # fmt: skip


def patch_pykinect_source(module: str, source: str) -> tuple[str, list[str]]:
    """Apply the known fixes to one PyKinect2 module's source; returns it and what was fixed."""
    applied = []
    for label, pattern, replacement in _PATCHES.get(module, ()):
        source, count = re.subn(pattern, replacement, source)
        if count:
            applied.append(label)
    return source, applied


class _PatchingLoader(importlib.abc.SourceLoader):
    def __init__(self, fullname: str, path: str) -> None:
        self.fullname = fullname
        self.path = path

    def get_filename(self, fullname: str) -> str:
        return self.path

    def get_data(self, path: str) -> bytes:
        with open(path, "rb") as handle:
            raw = handle.read()
        if path != self.path:
            return raw
        text, applied = patch_pykinect_source(self.fullname, raw.decode("utf-8", "replace"))
        if applied:
            logger.info("patched %s while importing: %s", self.fullname, "; ".join(applied))
        return text.encode("utf-8")

    def path_stats(self, path: str) -> Any:
        raise OSError("no bytecode cache for patched modules")  # always compile the patched text


class PyKinect2Fixer(importlib.abc.MetaPathFinder):
    """Import hook: loads ``pykinect2.PyKinectV2`` / ``PyKinectRuntime`` with the fixes."""

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in _PATCHES:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
            return spec
        return importlib.util.spec_from_file_location(
            fullname, spec.origin, loader=_PatchingLoader(fullname, spec.origin)
        )


def import_pykinect2() -> tuple[Any, Any]:
    """``(PyKinectV2, PyKinectRuntime)`` with the packaging bugs worked around.

    Raises:
        SensorError: not Windows, or pykinect2/comtypes missing, or the SDK runtime not loadable.
    """
    if not any(isinstance(f, PyKinect2Fixer) for f in sys.meta_path):
        sys.meta_path.insert(0, PyKinect2Fixer())
    try:
        v2 = importlib.import_module("pykinect2.PyKinectV2")
        runtime = importlib.import_module("pykinect2.PyKinectRuntime")
    except ImportError as exc:
        raise SensorError(
            f"Kinect v2 source needs pykinect2 and comtypes ({exc}): "
            "pip install 'skelfuse[kinect-v2]' on Windows with the Kinect for Windows Runtime 2.0"
        ) from exc
    except (AssertionError, AttributeError, OSError) as exc:
        raise SensorError(f"pykinect2 failed to load even with skelfuse's fixes: {exc!r}") from exc
    return v2, runtime


def bodies_from_frame(frame: Any, joint_count: int = JOINT_COUNT) -> tuple[Body, ...]:
    """Tracked bodies of a PyKinect2 ``KinectBodyFrameData`` as wire bodies (sensor frame),
    with their hand states (PyKinect2's ``KinectBody`` copies them from the SDK's ``IBody``)."""
    bodies = []
    for body in frame.bodies if frame.bodies is not None else ():
        if not body.is_tracked:
            continue
        joints = np.empty((JOINT_COUNT, 3), dtype=np.float32)
        states = np.empty(JOINT_COUNT, dtype=np.uint8)
        for j in range(joint_count):
            joint = body.joints[j]
            position = joint.Position
            joints[j] = (position.x, position.y, position.z)
            states[j] = min(max(int(joint.TrackingState), 0), 2)
        bad = ~np.isfinite(joints).all(axis=1)
        joints[bad] = np.nan
        states[bad] = 0
        hands = hands_from_sdk(
            int(body.hand_left_state),
            int(body.hand_right_state),
            int(body.hand_left_confidence),
            int(body.hand_right_confidence),
        )
        bodies.append(Body(int(body.tracking_id) % 2**64, joints, states, hands))
    return tuple(bodies)


def floor_from_frame(frame: Any) -> tuple[float, float, float, float] | None:
    """``FloorClipPlane`` as (a, b, c, d); None when the SDK has not found the floor (0,0,0,0)."""
    plane = frame.floor_clip_plane
    if plane is None:
        return None
    values = (float(plane.x), float(plane.y), float(plane.z), float(plane.w))
    norm = float(np.linalg.norm(values[:3]))
    if not np.isfinite(values).all() or norm < 0.5:
        return None
    a, b, c, d = (v / norm for v in values)
    return (a, b, c, d)


class DeviceClock:
    """Capture stamps on this PC's clock, spaced by the device's own timestamps."""

    def __init__(self, tick_ns: int, wall_clock_ns: Callable[[], int] = time.time_ns) -> None:
        self._tick_ns = tick_ns
        self._clock = wall_clock_ns
        self._anchor_ns: int | None = None
        self.last_device_ticks: int | None = None

    def stamp(self, device_ticks: int) -> int:
        now = self._clock()
        device_ns = int(device_ticks) * self._tick_ns
        if self._anchor_ns is None or abs(self._anchor_ns + device_ns - now) > _REANCHOR_NS:
            self._anchor_ns = now - device_ns
        self.last_device_ticks = int(device_ticks)
        return self._anchor_ns + device_ns


class KinectV2Source:
    """Bodies from the Kinect v2 attached to this PC (the SDK allows one per PC)."""

    def __init__(
        self,
        pose: Matrix4 | None = None,
        *,
        runtime_factory: Callable[[], Any] | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
        depth: bool = True,
    ) -> None:
        if runtime_factory is None:
            v2, runtime = import_pykinect2()
            # Depth too: calibration asks for clouds (depth_cloud); the SDK streams both at once.
            streams = v2.FrameSourceTypes_Body | (v2.FrameSourceTypes_Depth if depth else 0)

            def runtime_factory() -> Any:
                return runtime.PyKinectRuntime(streams)

        try:
            self._runtime = runtime_factory()
        except OSError as exc:
            raise SensorError(
                f"cannot open the Kinect v2 (is the runtime installed?): {exc}"
            ) from exc
        self._pose = pose
        self._clock = DeviceClock(_TICK_NS, wall_clock_ns)
        self._sleep = sleep
        self._last_relative: int | None = None
        self._point_type: Any = None

    @property
    def sensor_type(self) -> str:
        return "kinect_v2"

    @property
    def fps(self) -> float:
        return KINECT_V2_FPS

    @property
    def last_relative_time(self) -> int | None:
        """The last frame's ``RelativeTime`` (100 ns ticks of the sensor's clock)."""
        return self._clock.last_device_ticks

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose.copy(), "manual")

    def next_capture(self, timeout_s: float) -> Capture | None:
        deadline = time.monotonic() + timeout_s
        while True:
            if self._runtime.has_new_body_frame():
                frame = self._runtime.get_last_body_frame()
                if frame is not None:
                    relative = int(frame.relative_time)
                    if relative != self._last_relative:  # the same frame, read twice
                        self._last_relative = relative
                        return Capture(
                            t_capture_ns=self._clock.stamp(relative),
                            bodies=bodies_from_frame(frame),
                            floor=floor_from_frame(frame),
                        )
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self._sleep(min(0.002, remaining))

    def request_handlers(self) -> dict[str, Callable[[dict[str, Any]], Any]]:
        """Requests this source answers (docs/protocol.md §6.5)."""
        return {"depth_cloud": self.depth_cloud}

    def depth_cloud(self, params: dict[str, Any]) -> dict[str, object]:
        """The ``depth_cloud`` request: the latest depth image as points in our sensor frame.

        The SDK's coordinate mapper turns the 512×424 depth image (mm) into camera space, which
        is our sensor frame already (metres, +X to the sensor's left, +Y up, +Z forward), with
        the device's own lens calibration. Pixels without depth map to −inf and are dropped.
        Params and reply as :func:`agent.sources.depth_reply.cloud_reply`.

        Raises:
            SensorError: no depth stream, or no depth frame yet.
        """
        depth = self._runtime.get_last_depth_frame()
        if depth is None:
            raise SensorError("the Kinect v2 was opened without its depth stream")
        depth = np.ascontiguousarray(depth, dtype=np.uint16)
        if not depth.any():
            raise SensorError("no depth frame from the Kinect v2 yet")
        return cloud_reply(
            self._camera_points(depth),
            params,
            device_relative_time=self._clock.last_device_ticks,
        )

    def _camera_points(self, depth: npt.NDArray[np.uint16]) -> npt.NDArray[np.float32]:
        """(N, 3) camera-space points of a flat depth image, through ICoordinateMapper."""
        if self._point_type is None:
            v2, _ = import_pykinect2()
            self._point_type = v2._CameraSpacePoint
        count = int(depth.size)
        out = (self._point_type * count)()
        # PyKinect2 exposes the sensor's ICoordinateMapper only as this attribute.
        self._runtime._mapper.MapDepthFrameToCameraSpace(
            ctypes.c_uint(count),
            depth.ctypes.data_as(ctypes.POINTER(ctypes.c_ushort)),
            ctypes.c_uint(count),
            out,
        )
        points: npt.NDArray[np.float32] = np.frombuffer(out, dtype=np.float32).reshape(count, 3)
        return points

    def close(self) -> None:
        self._runtime.close()
