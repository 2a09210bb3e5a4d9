# ruff: noqa
"""Fake of pykinect_azure.k4a._k4a (the Sensor SDK's ctypes layer): the calls skelfuse makes,
with the real names, argument order and handle types. Handles are ctypes pointers filled in
place as the C functions do; images and captures are reference counted, so a test can check
that every handle was released (LIVE). Device captures come from SCRIPT."""

import ctypes

import numpy as np

K4A_RESULT_SUCCEEDED = 0
K4A_RESULT_FAILED = 1
K4A_WAIT_RESULT_SUCCEEDED = 0
K4A_WAIT_RESULT_FAILED = 1
K4A_WAIT_RESULT_TIMEOUT = 2

K4A_DEPTH_MODE_OFF = 0
K4A_DEPTH_MODE_NFOV_2X2BINNED = 1
K4A_DEPTH_MODE_NFOV_UNBINNED = 2
K4A_DEPTH_MODE_WFOV_2X2BINNED = 3
K4A_DEPTH_MODE_WFOV_UNBINNED = 4
K4A_COLOR_RESOLUTION_OFF = 0
K4A_FRAMES_PER_SECOND_5 = 0
K4A_FRAMES_PER_SECOND_15 = 1
K4A_FRAMES_PER_SECOND_30 = 2
K4A_IMAGE_FORMAT_DEPTH16 = 4
K4A_IMAGE_FORMAT_IR16 = 5
K4A_CALIBRATION_TYPE_NUM = 4


class _handle_k4a_device_t(ctypes.Structure):
    _fields_ = [("_rsvd", ctypes.c_size_t)]


class _handle_k4a_capture_t(ctypes.Structure):
    _fields_ = [("_rsvd", ctypes.c_size_t)]


class _handle_k4a_image_t(ctypes.Structure):
    _fields_ = [("_rsvd", ctypes.c_size_t)]


k4a_device_t = ctypes.POINTER(_handle_k4a_device_t)
k4a_capture_t = ctypes.POINTER(_handle_k4a_capture_t)
k4a_image_t = ctypes.POINTER(_handle_k4a_image_t)


class k4a_device_configuration_t(ctypes.Structure):
    _fields_ = [
        ("color_format", ctypes.c_int),
        ("color_resolution", ctypes.c_int),
        ("depth_mode", ctypes.c_int),
        ("camera_fps", ctypes.c_int),
        ("synchronized_images_only", ctypes.c_bool),
        ("depth_delay_off_color_usec", ctypes.c_int32),
        ("wired_sync_mode", ctypes.c_int),
        ("subordinate_delay_off_master_usec", ctypes.c_uint32),
        ("disable_streaming_indicator", ctypes.c_bool),
    ]


class k4a_calibration_extrinsics_t(ctypes.Structure):
    _fields_ = [("rotation", ctypes.c_float * 9), ("translation", ctypes.c_float * 3)]


class _param(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_float)
        for name in (
            "cx",
            "cy",
            "fx",
            "fy",
            "k1",
            "k2",
            "k3",
            "k4",
            "k5",
            "k6",
            "codx",
            "cody",
            "p2",
            "p1",
            "metric_radius",
        )
    ]


class k4a_calibration_intrinsic_parameters_t(ctypes.Union):
    _fields_ = [("param", _param), ("v", ctypes.c_float * 15)]


class k4a_calibration_intrinsics_t(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_int),
        ("parameter_count", ctypes.c_uint),
        ("parameters", k4a_calibration_intrinsic_parameters_t),
    ]


class k4a_calibration_camera_t(ctypes.Structure):
    _fields_ = [
        ("extrinsics", k4a_calibration_extrinsics_t),
        ("intrinsics", k4a_calibration_intrinsics_t),
        ("resolution_width", ctypes.c_int),
        ("resolution_height", ctypes.c_int),
        ("metric_radius", ctypes.c_float),
    ]


class k4a_calibration_t(ctypes.Structure):
    _fields_ = [
        ("depth_camera_calibration", k4a_calibration_camera_t),
        ("color_camera_calibration", k4a_calibration_camera_t),
        (
            "extrinsics",
            (k4a_calibration_extrinsics_t * K4A_CALIBRATION_TYPE_NUM) * K4A_CALIBRATION_TYPE_NUM,
        ),
        ("depth_mode", ctypes.c_int),
        ("color_resolution", ctypes.c_int),
    ]


class _xy(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float)]


class k4a_float2_t(ctypes.Union):
    _fields_ = [("xy", _xy), ("v", ctypes.c_float * 2)]


class _xyz(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class k4a_float3_t(ctypes.Union):
    _fields_ = [("xyz", _xyz), ("v", ctypes.c_float * 3)]


# --- test state -------------------------------------------------------------------------------

CALIBRATION = {
    "width": 640,
    "height": 576,
    "fx": 504.0,
    "fy": 503.0,
    "cx": 321.5,
    "cy": 286.0,
    "k1": 0.08,  # a radial lens: the corners move ~25 px (real units have a 6-term model)
}
SCRIPT = []  # device captures: (device_us, depth (H, W) uint16 or None, ir (H, W) uint16 or None)
STARTED = []  # the configurations k4a_device_start_cameras was given (depth_mode, camera_fps)
LIVE = {}  # address -> {"kind", "refs", ...} for every capture and image not yet released
STRIDE_PAD = 16  # device images have rows padded by this many bytes, as an SDK may


def reset():
    SCRIPT.clear()
    STARTED.clear()
    LIVE.clear()


def _check(value, kind):
    if not isinstance(value, kind):
        raise ctypes.ArgumentError(f"expected {kind.__name__}, got {type(value).__name__}")


def _fill(handle, struct_type, **entry):
    """Point ``handle`` at a new object (the C function writing the out-parameter)."""
    handle.contents = struct_type()
    LIVE[ctypes.addressof(handle.contents)] = {"refs": 1, **entry}


def _entry(handle):
    if not handle:
        raise ctypes.ArgumentError("NULL handle")
    return LIVE[ctypes.addressof(handle.contents)]


def _release(handle):
    address = ctypes.addressof(handle.contents)
    entry = LIVE[address]
    entry["refs"] -= 1
    if entry["refs"] == 0:
        del LIVE[address]
        for image in entry.get("images", {}).values():
            _release(image)


def _new_image(image_format, width, height, stride):
    handle = k4a_image_t()
    k4a_image_create(image_format, width, height, stride, handle)
    return handle


def image_pixels(handle):
    """Test helper: a 16-bit image's pixels (H, W) as the tracker would read them."""
    entry = _entry(handle)
    raw = np.frombuffer(entry["buffer"], dtype=np.uint8).reshape(entry["height"], entry["stride"])
    return raw[:, : 2 * entry["width"]].copy().view("<u2")


# --- device -----------------------------------------------------------------------------------


def k4a_device_open(device_id, device_handle):
    _check(device_handle, k4a_device_t)
    if device_id != 0:
        return K4A_RESULT_FAILED
    device_handle.contents = _handle_k4a_device_t()
    return K4A_RESULT_SUCCEEDED


def k4a_device_get_calibration(device_handle, depth_mode, color_resolution, calibration):
    _check(device_handle, k4a_device_t)
    _check(calibration, k4a_calibration_t)
    camera = calibration.depth_camera_calibration
    camera.resolution_width = CALIBRATION["width"]
    camera.resolution_height = CALIBRATION["height"]
    param = camera.intrinsics.parameters.param
    for name in ("fx", "fy", "cx", "cy"):
        setattr(param, name, CALIBRATION[name])
    param.k1 = CALIBRATION["k1"]
    calibration.depth_mode = depth_mode
    calibration.color_resolution = color_resolution
    return K4A_RESULT_SUCCEEDED


def k4a_device_start_cameras(device_handle, config):
    _check(device_handle, k4a_device_t)
    _check(config, k4a_device_configuration_t)
    STARTED.append((config.depth_mode, config.camera_fps, config.color_resolution))
    if config.depth_mode == K4A_DEPTH_MODE_WFOV_UNBINNED and config.camera_fps > 1:
        return K4A_RESULT_FAILED  # as the real device: WFOV unbinned runs at 15 fps at most
    return K4A_RESULT_SUCCEEDED


def k4a_device_stop_cameras(device_handle):
    _check(device_handle, k4a_device_t)
    STARTED.append("stopped")


def k4a_device_close(device_handle):
    _check(device_handle, k4a_device_t)
    STARTED.append("closed")


def k4a_device_get_capture(device_handle, capture_handle, timeout):
    _check(device_handle, k4a_device_t)
    _check(capture_handle, k4a_capture_t)
    if not SCRIPT:
        return K4A_WAIT_RESULT_TIMEOUT
    device_us, depth, ir = SCRIPT.pop(0)
    k4a_capture_create(capture_handle)
    for image_format, pixels, setter in (
        (K4A_IMAGE_FORMAT_DEPTH16, depth, k4a_capture_set_depth_image),
        (K4A_IMAGE_FORMAT_IR16, ir, k4a_capture_set_ir_image),
    ):
        if pixels is None:
            continue
        height, width = pixels.shape
        image = _new_image(image_format, width, height, 2 * width + STRIDE_PAD)
        rows = np.frombuffer(_entry(image)["buffer"], dtype=np.uint8).reshape(height, -1)
        rows[:, : 2 * width] = np.ascontiguousarray(pixels, dtype="<u2").view(np.uint8)
        k4a_image_set_device_timestamp_usec(image, device_us)
        setter(capture_handle, image)
        k4a_image_release(image)
    k4a_capture_set_temperature_c(capture_handle, 31.5)
    return K4A_WAIT_RESULT_SUCCEEDED


# --- captures ---------------------------------------------------------------------------------


def k4a_capture_create(capture_handle):
    _check(capture_handle, k4a_capture_t)
    _fill(capture_handle, _handle_k4a_capture_t, kind="capture", images={}, temperature=0.0)
    return K4A_RESULT_SUCCEEDED


def k4a_capture_release(capture_handle):
    _check(capture_handle, k4a_capture_t)
    _release(capture_handle)


def k4a_capture_reference(capture_handle):
    _check(capture_handle, k4a_capture_t)
    _entry(capture_handle)["refs"] += 1


def _get_image(capture_handle, which):
    _check(capture_handle, k4a_capture_t)
    image = _entry(capture_handle)["images"].get(which)
    if image is None:
        return k4a_image_t()  # NULL
    _entry(image)["refs"] += 1
    return image


def _set_image(capture_handle, image_handle, which):
    _check(capture_handle, k4a_capture_t)
    _check(image_handle, k4a_image_t)
    images = _entry(capture_handle)["images"]
    if which in images:
        _release(images[which])
    _entry(image_handle)["refs"] += 1
    images[which] = k4a_image_t(image_handle.contents)


def k4a_capture_get_depth_image(capture_handle):
    return _get_image(capture_handle, "depth")


def k4a_capture_get_ir_image(capture_handle):
    return _get_image(capture_handle, "ir")


def k4a_capture_set_depth_image(capture_handle, image_handle):
    _set_image(capture_handle, image_handle, "depth")


def k4a_capture_set_ir_image(capture_handle, image_handle):
    _set_image(capture_handle, image_handle, "ir")


def k4a_capture_set_temperature_c(capture_handle, temperature):
    _check(capture_handle, k4a_capture_t)
    _entry(capture_handle)["temperature"] = float(temperature)


def k4a_capture_get_temperature_c(capture_handle):
    _check(capture_handle, k4a_capture_t)
    return _entry(capture_handle)["temperature"]


# --- images -----------------------------------------------------------------------------------


def k4a_image_create(image_format, width, height, stride, image_handle):
    _check(image_handle, k4a_image_t)
    if stride < 2 * width:
        return K4A_RESULT_FAILED
    buffer = (ctypes.c_uint8 * (height * stride))()
    _fill(
        image_handle,
        _handle_k4a_image_t,
        kind="image",
        format=image_format,
        width=width,
        height=height,
        stride=stride,
        buffer=buffer,
        device_us=0,
    )
    return K4A_RESULT_SUCCEEDED


def k4a_image_get_buffer(image_handle):
    _check(image_handle, k4a_image_t)
    return ctypes.cast(_entry(image_handle)["buffer"], ctypes.POINTER(ctypes.c_uint8))


def k4a_image_get_size(image_handle):
    entry = _entry(image_handle)
    return entry["height"] * entry["stride"]


def k4a_image_get_format(image_handle):
    return _entry(image_handle)["format"]


def k4a_image_get_width_pixels(image_handle):
    return _entry(image_handle)["width"]


def k4a_image_get_height_pixels(image_handle):
    return _entry(image_handle)["height"]


def k4a_image_get_stride_bytes(image_handle):
    return _entry(image_handle)["stride"]


def k4a_image_get_device_timestamp_usec(image_handle):
    return _entry(image_handle)["device_us"]


def k4a_image_set_device_timestamp_usec(image_handle, timestamp_usec):
    _check(image_handle, k4a_image_t)
    _entry(image_handle)["device_us"] = int(timestamp_usec)


def k4a_image_release(image_handle):
    _check(image_handle, k4a_image_t)
    _release(image_handle)


# --- the lens (radial, k1 only: x_d = x (1 + k1 r^2) on the z = 1 plane) ----------------------


def distort(x, y, k1):
    """Test helper: normalised ray (x, y) -> normalised image point, arrays."""
    scale = 1.0 + k1 * (x * x + y * y)
    return x * scale, y * scale


def undistort(xd, yd, k1):
    """Test helper: the inverse of distort (fixed-point iterations)."""
    x, y = xd, yd
    for _ in range(30):
        scale = 1.0 + k1 * (x * x + y * y)
        x, y = xd / scale, yd / scale
    return x, y


def _param(calibration):
    return calibration.depth_camera_calibration.intrinsics.parameters.param


def k4a_calibration_3d_to_2d(
    calibration, source_point3d_mm, source_camera, target_camera, target_point2d, valid
):
    _check(calibration, k4a_calibration_t)
    _check(source_point3d_mm, k4a_float3_t)
    _check(target_point2d, k4a_float2_t)
    _check(valid, ctypes.c_int)
    p, q = _param(calibration), source_point3d_mm.xyz
    if source_camera != 0 or target_camera != 0:
        return K4A_RESULT_FAILED  # the fake has the depth camera only
    if q.z <= 0:
        valid.value = 0
        return K4A_RESULT_SUCCEEDED
    x, y = distort(q.x / q.z, q.y / q.z, p.k1)
    valid.value = int(x * x + y * y < 1.0)  # inside the lens's valid radius
    target_point2d.xy.x = p.cx + p.fx * x
    target_point2d.xy.y = p.cy + p.fy * y
    return K4A_RESULT_SUCCEEDED


def k4a_calibration_2d_to_3d(
    calibration,
    source_point2d,
    source_depth_mm,
    source_camera,
    target_camera,
    target_point3d_mm,
    valid,
):
    _check(calibration, k4a_calibration_t)
    _check(source_point2d, k4a_float2_t)
    _check(target_point3d_mm, k4a_float3_t)
    _check(valid, ctypes.c_int)
    if source_camera != 0 or target_camera != 0:
        return K4A_RESULT_FAILED
    p = _param(calibration)
    xd = (source_point2d.xy.x - p.cx) / p.fx
    yd = (source_point2d.xy.y - p.cy) / p.fy
    valid.value = int(xd * xd + yd * yd < 1.0)
    x, y = undistort(xd, yd, p.k1)
    z = float(source_depth_mm)
    target_point3d_mm.xyz.x, target_point3d_mm.xyz.y, target_point3d_mm.xyz.z = x * z, y * z, z
    return K4A_RESULT_SUCCEEDED
