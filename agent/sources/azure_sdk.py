"""The Azure Kinect / Femto SDK calls of :mod:`skelfuse.agent.sources.azure_kinect` and
:mod:`skelfuse.agent.sources.azure_reprojected`.

Everything goes through pykinect_azure's ctypes layer (``pykinect_azure.k4a._k4a`` and
``pykinect_azure.k4abt._k4abt``: one Python function per C function of the Sensor SDK 1.4 and
the Body Tracking SDK 1.1, same names and argument order), not through its classes: those call
``VERIFY``, which ends the process (``sys.exit``) on any failed call, a capture timeout
included; here every result code is checked and turned into None or :class:`SensorError`.

Handles follow the SDKs' reference counting: every ``*_get_*_image``, ``*_create`` and
successful ``pop_result`` is balanced by a ``*_release``. A capture the application builds
(``k4a_capture_create`` + ``k4a_image_create`` + ``k4a_capture_set_depth_image`` /
``k4a_capture_set_ir_image``) is what the Body Tracking SDK accepts besides a device's own; it
needs the IR image as well as the depth image (Azure-Kinect-Sensor-SDK issue #1580: without IR,
``k4abt_tracker_enqueue_capture`` fails; with depth copied into IR it finds no bodies).

Not run on hardware or with the real libraries (docs/sensors.md): tested against a fake of
these two modules (tests/fakes/pykinect_azure).
"""

from __future__ import annotations

import ctypes
import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.depth_camera import DepthIntrinsics
from skelfuse.agent.sources.base import SensorError

U16 = npt.NDArray[np.uint16]

SUCCEEDED: Final = 0
"""``K4A_RESULT_SUCCEEDED`` / ``K4A_WAIT_RESULT_SUCCEEDED`` / ``K4ABT_RESULT_SUCCEEDED``."""
TIMEOUT: Final = 2
"""``K4A_WAIT_RESULT_TIMEOUT``: nothing within the call's timeout."""

DEPTH_RANGE_M: Final = {
    "NFOV_2X2BINNED": (0.5, 5.46),
    "NFOV_UNBINNED": (0.5, 3.86),
    "WFOV_2X2BINNED": (0.25, 2.88),
    "WFOV_UNBINNED": (0.25, 2.21),
}
"""Operating range of each depth mode (Azure Kinect DK hardware specification), metres."""
FPS: Final = {"NFOV_2X2BINNED": 30, "NFOV_UNBINNED": 30, "WFOV_2X2BINNED": 30, "WFOV_UNBINNED": 15}
"""Frame rate each depth mode is started at: its highest (WFOV unbinned allows 15 fps only)."""


@dataclass(frozen=True, slots=True)
class RawCapture:
    """One device capture's depth and IR images (copied out of the SDK's buffers).

    ``depth``: (H, W) uint16 mm, 0 = no reading; ``ir``: (H, W) uint16; ``device_us``: the
    depth image's device timestamp (µs); ``temperature_c``: the capture's sensor temperature.
    """

    depth: U16
    ir: U16
    device_us: int
    temperature_c: float


def sdk_layers(sdk: Any) -> tuple[Any, Any]:
    """``(k4a, k4abt)``: the ctypes modules of the ``pykinect_azure`` package ``sdk``."""
    base = sdk.__name__
    return (
        importlib.import_module(base + ".k4a._k4a"),
        importlib.import_module(base + ".k4abt._k4abt"),
    )


def waited(result: int, function: str, hint: str = "") -> bool:
    """A waiting SDK call's result (``k4a_wait_result_t``): True on success, False on a timeout.

    Raises:
        SensorError: on any other result, naming ``function`` (and ``hint``).
    """
    if result == TIMEOUT:
        return False
    if result != SUCCEEDED:
        raise SensorError(f"{function} failed ({result}){hint}")
    return True


def load_libraries(sdk: Any, k4a_path: str | None, k4abt_path: str | None) -> tuple[Any, Any]:
    """Point pykinect_azure's ctypes layer at the native libraries (``initialize_libraries``,
    body tracking included; None: its default search) and return :func:`sdk_layers`.

    Raises:
        SensorError: when a library cannot be loaded (pykinect_azure ``sys.exit()``s then).
    """
    try:
        sdk.initialize_libraries(
            module_k4a_path=k4a_path, module_k4abt_path=k4abt_path, track_body=True
        )
    except (Exception, SystemExit) as exc:  # SystemExit: pykinect_azure's own error path
        raise SensorError(f"cannot load the Azure Kinect SDK libraries: {exc!r}") from exc
    return sdk_layers(sdk)


def get_capture(k4a: Any, device: Any, timeout_ms: int) -> Any | None:
    """The device's next ``k4a_capture_t`` (the caller releases it), None when none came within
    ``timeout_ms``.

    Raises:
        SensorError: when ``k4a_device_get_capture`` fails (not on a timeout).
    """
    capture = k4a.k4a_capture_t()
    result = k4a.k4a_device_get_capture(device, capture, timeout_ms)
    return capture if waited(result, "k4a_device_get_capture", ": device unplugged?") else None


def enqueue(k4abt: Any, tracker: Any, capture: Any, timeout_ms: int) -> bool:
    """Put ``capture`` in the tracker's queue (the tracker takes its own reference: the caller
    still releases it); False when the queue stayed full for ``timeout_ms``.

    Raises:
        SensorError: when ``k4abt_tracker_enqueue_capture`` fails (not on a timeout).
    """
    result = k4abt.k4abt_tracker_enqueue_capture(tracker, capture, timeout_ms)
    return waited(result, "k4abt_tracker_enqueue_capture")


def depth_intrinsics(calibration: Any, depth_mode: str) -> DepthIntrinsics:
    """The pinhole part of a ``k4a_calibration_t``'s depth camera (fx, fy, cx, cy, pixels;
    image size) and the depth mode's range. The lens distortion (k1..k6, p1, p2) is left out:
    :func:`skelfuse.agent.reproject.reproject_depth` models a pinhole camera.

    Raises:
        SensorError: when the calibration has no image size or focal length.
    """
    camera = calibration.depth_camera_calibration
    param = camera.intrinsics.parameters.param
    width, height = int(camera.resolution_width), int(camera.resolution_height)
    if width <= 0 or height <= 0 or param.fx <= 0 or param.fy <= 0:
        raise SensorError(
            f"depth calibration without image size or focal length ({width}x{height})"
        )
    low, high = DEPTH_RANGE_M[depth_mode]
    return DepthIntrinsics(
        width, height, float(param.fx), float(param.fy), float(param.cx), float(param.cy), low, high
    )


def _image_array(k4a: Any, image: Any) -> U16:
    """A 16-bit image's pixels (H, W) copied out of its buffer, honouring its stride."""
    width = int(k4a.k4a_image_get_width_pixels(image))
    height = int(k4a.k4a_image_get_height_pixels(image))
    stride = int(k4a.k4a_image_get_stride_bytes(image))
    size = int(k4a.k4a_image_get_size(image))
    if width <= 0 or height <= 0 or stride < 2 * width or size < height * stride:
        raise SensorError(f"unexpected image layout {width}x{height}, stride {stride}, {size} B")
    raw = np.ctypeslib.as_array(k4a.k4a_image_get_buffer(image), shape=(size,))
    rows = raw[: height * stride].reshape(height, stride)[:, : 2 * width]
    pixels: U16 = np.ascontiguousarray(rows).view("<u2").astype(np.uint16)
    return pixels


@contextmanager
def _depth_and_ir(k4a: Any, capture: Any) -> Iterator[tuple[Any, Any] | None]:
    """A capture's depth and IR image handles, None when it lacks either (k4abt needs both);
    their references are released on exit, the capture stays the caller's."""
    depth = k4a.k4a_capture_get_depth_image(capture)
    ir = k4a.k4a_capture_get_ir_image(capture)
    try:
        yield (depth, ir) if depth and ir else None
    finally:
        for image in (depth, ir):
            if image:
                k4a.k4a_image_release(image)


def read_capture(k4a: Any, capture: Any) -> RawCapture | None:
    """Depth and IR of a device capture, or None when it lacks either."""
    with _depth_and_ir(k4a, capture) as images:
        if images is None:
            return None
        depth, ir = images
        return RawCapture(
            _image_array(k4a, depth),
            _image_array(k4a, ir),
            int(k4a.k4a_image_get_device_timestamp_usec(depth)),
            float(k4a.k4a_capture_get_temperature_c(capture)),
        )


def read_depth(k4a: Any, capture: Any) -> tuple[U16, int] | None:
    """A device capture's depth image ((H, W) uint16 mm, copied) and its device timestamp (µs),
    or None when it lacks depth or IR (the IR image is not copied)."""
    with _depth_and_ir(k4a, capture) as images:
        if images is None:
            return None
        depth = images[0]
        return _image_array(k4a, depth), int(k4a.k4a_image_get_device_timestamp_usec(depth))


def _new_image(k4a: Any, image_format: int, pixels: U16, device_us: int) -> Any:
    """A new SDK-owned 16-bit image holding a copy of ``pixels`` (stride = 2·width)."""
    height, width = pixels.shape
    image = k4a.k4a_image_t()
    if k4a.k4a_image_create(image_format, width, height, 2 * width, image) != SUCCEEDED:
        raise SensorError(f"k4a_image_create failed for a {width}x{height} image")
    data = np.ascontiguousarray(pixels, dtype="<u2")
    if int(k4a.k4a_image_get_size(image)) < data.nbytes:
        k4a.k4a_image_release(image)
        raise SensorError("k4a_image_create gave a buffer smaller than the image")
    ctypes.memmove(k4a.k4a_image_get_buffer(image), data.ctypes.data, data.nbytes)
    k4a.k4a_image_set_device_timestamp_usec(image, device_us)
    return image


def build_capture(k4a: Any, depth: U16, ir: U16, device_us: int, temperature_c: float) -> Any:
    """A new ``k4a_capture_t`` holding ``depth`` (DEPTH16, mm) and ``ir`` (IR16), both stamped
    ``device_us``: what the body tracker is fed. The caller releases it.

    Raises:
        SensorError: when the SDK cannot create the capture or an image.
    """
    capture = k4a.k4a_capture_t()
    if k4a.k4a_capture_create(capture) != SUCCEEDED:
        raise SensorError("k4a_capture_create failed")
    try:
        for image_format, pixels, setter in (
            (k4a.K4A_IMAGE_FORMAT_DEPTH16, depth, k4a.k4a_capture_set_depth_image),
            (k4a.K4A_IMAGE_FORMAT_IR16, ir, k4a.k4a_capture_set_ir_image),
        ):
            image = _new_image(k4a, image_format, pixels, device_us)
            setter(capture, image)  # the capture takes its own reference
            k4a.k4a_image_release(image)
        k4a.k4a_capture_set_temperature_c(capture, temperature_c)
    except BaseException:
        k4a.k4a_capture_release(capture)
        raise
    return capture


def pop_skeletons(
    k4abt: Any, tracker: Any, timeout_ms: int
) -> tuple[int, list[tuple[int, Any]]] | None:
    """The tracker's next body frame: its device timestamp (µs) and each body's id and
    ``k4abt_skeleton_t`` (joints in the depth camera frame of the tracker's calibration, mm),
    or None when none is ready within ``timeout_ms``. The frame is released.

    Raises:
        SensorError: when the tracker fails (not on a timeout).
    """
    frame = k4abt.k4abt_frame_t()
    if not waited(
        k4abt.k4abt_tracker_pop_result(tracker, frame, timeout_ms), "k4abt_tracker_pop_result"
    ):
        return None
    try:
        device_us = int(k4abt.k4abt_frame_get_device_timestamp_usec(frame))
        bodies = []
        for index in range(int(k4abt.k4abt_frame_get_num_bodies(frame))):
            skeleton = k4abt.k4abt_skeleton_t()
            if k4abt.k4abt_frame_get_body_skeleton(frame, index, skeleton) != SUCCEEDED:
                continue
            bodies.append((int(k4abt.k4abt_frame_get_body_id(frame, index)), skeleton))
        return device_us, bodies
    finally:
        k4abt.k4abt_frame_release(frame)


@dataclass(frozen=True, slots=True)
class OpenDevice:
    """A started device and its body tracker: the handles and the ``k4a_calibration_t`` the
    tracker was created with (the re-projected captures use its depth intrinsics)."""

    device: Any
    calibration: Any
    tracker: Any


def open_device(k4a: Any, k4abt: Any, device_index: int, depth_mode: str) -> OpenDevice:
    """Open device ``device_index``, start its depth camera (``depth_mode`` at :data:`FPS`, no
    colour)
    and create a body tracker (pykinect_azure's default configuration: its processing mode is
    what ``initialize_libraries`` found) from the device's calibration for that mode.

    Raises:
        SensorError: when any step fails (what was opened is closed again).
    """
    device = k4a.k4a_device_t()
    if k4a.k4a_device_open(device_index, device) != SUCCEEDED:
        raise SensorError(f"k4a_device_open({device_index}) failed: no such device, or in use")
    config = k4a.k4a_device_configuration_t()
    config.color_resolution = k4a.K4A_COLOR_RESOLUTION_OFF
    config.depth_mode = getattr(k4a, f"K4A_DEPTH_MODE_{depth_mode}")
    config.camera_fps = getattr(k4a, f"K4A_FRAMES_PER_SECOND_{FPS[depth_mode]}")
    calibration = k4a.k4a_calibration_t()
    started = False
    try:
        if (
            k4a.k4a_device_get_calibration(
                device, config.depth_mode, config.color_resolution, calibration
            )
            != SUCCEEDED
        ):
            raise SensorError("k4a_device_get_calibration failed")
        if k4a.k4a_device_start_cameras(device, config) != SUCCEEDED:
            raise SensorError("k4a_device_start_cameras failed")
        started = True
        tracker = k4abt.k4abt_tracker_t()
        configuration = k4abt.k4abt_tracker_default_configuration
        if k4abt.k4abt_tracker_create(calibration, configuration, tracker) != SUCCEEDED:
            raise SensorError("k4abt_tracker_create failed (GPU/ONNX runtime, or the model)")
    except BaseException:
        if started:
            k4a.k4a_device_stop_cameras(device)
        k4a.k4a_device_close(device)
        raise
    return OpenDevice(device, calibration, tracker)


def close_device(k4a: Any, k4abt: Any, opened: OpenDevice) -> None:
    """Shut the tracker down and destroy it, stop the cameras, close the device."""
    k4abt.k4abt_tracker_shutdown(opened.tracker)
    k4abt.k4abt_tracker_destroy(opened.tracker)
    k4a.k4a_device_stop_cameras(opened.device)
    k4a.k4a_device_close(opened.device)
