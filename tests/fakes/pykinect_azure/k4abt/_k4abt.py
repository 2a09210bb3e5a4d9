# ruff: noqa
"""Fake of pykinect_azure.k4abt._k4abt (the Body Tracking SDK's ctypes layer): the real names,
argument order and handle types. The tracker reads the depth and IR images of each enqueued
capture through the fake Sensor SDK (it fails without IR, as the real one does) and "detects"
bodies with DETECT(depth, ir, calibration) -> [(body_id, joints_mm (32, 3), levels (32,))],
set by a test; its queue gives results LAG captures late."""

import ctypes

import numpy as np

from pykinect_azure.k4a import _k4a
from pykinect_azure.k4a._k4a import k4a_calibration_t, k4a_capture_t

K4ABT_RESULT_SUCCEEDED = 0
K4ABT_RESULT_FAILED = 1
K4ABT_JOINT_COUNT = 32


class _handle_k4abt_tracker_t(ctypes.Structure):
    _fields_ = [("_rsvd", ctypes.c_size_t)]


class _handle_k4abt_frame_t(ctypes.Structure):
    _fields_ = [("_rsvd", ctypes.c_size_t)]


k4abt_tracker_t = ctypes.POINTER(_handle_k4abt_tracker_t)
k4abt_frame_t = ctypes.POINTER(_handle_k4abt_frame_t)


class k4abt_tracker_configuration_t(ctypes.Structure):
    _fields_ = [
        ("sensor_orientation", ctypes.c_int),
        ("processing_mode", ctypes.c_int),
        ("gpu_device_id", ctypes.c_int32),
        ("model_path", ctypes.c_char_p),
    ]


k4abt_tracker_default_configuration = k4abt_tracker_configuration_t()


class _xyz(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class k4a_float3_t(ctypes.Union):
    _fields_ = [("xyz", _xyz), ("v", ctypes.c_float * 3)]


class _k4abt_joint_t(ctypes.Structure):
    _fields_ = [
        ("position", k4a_float3_t),
        ("orientation", ctypes.c_float * 4),
        ("confidence_level", ctypes.c_int),
    ]


class k4abt_skeleton_t(ctypes.Structure):
    _fields_ = [("joints", _k4abt_joint_t * K4ABT_JOINT_COUNT)]


# --- test state -------------------------------------------------------------------------------

DETECT = None  # (depth, ir, calibration) -> bodies; None: no bodies
LAG = 0  # results wait until this many later captures are enqueued
QUEUE_LIMIT = 3  # enqueue times out with this many results waiting
TRACKERS = []  # {"calibration": k4a_calibration_t copy, "config", "shutdown", "destroyed"}
ENQUEUED = []  # (device_us, depth, ir) of every capture the tracker accepted
FRAMES = {}  # address -> {"refs", "device_us", "bodies"} for body frames not yet released
_queue = []


def reset():
    global DETECT, LAG
    DETECT, LAG = None, 0
    TRACKERS.clear()
    ENQUEUED.clear()
    FRAMES.clear()
    _queue.clear()


def _check(value, kind):
    if not isinstance(value, kind):
        raise ctypes.ArgumentError(f"expected {kind.__name__}, got {type(value).__name__}")


def k4abt_tracker_create(sensor_calibration, config, tracker_handle):
    _check(sensor_calibration, k4a_calibration_t)
    _check(config, k4abt_tracker_configuration_t)
    _check(tracker_handle, k4abt_tracker_t)
    copy = k4a_calibration_t()
    ctypes.pointer(copy)[0] = sensor_calibration
    tracker_handle.contents = _handle_k4abt_tracker_t()
    TRACKERS.append({"calibration": copy, "shutdown": False, "destroyed": False})
    return K4ABT_RESULT_SUCCEEDED


def k4abt_tracker_enqueue_capture(tracker_handle, sensor_capture_handle, timeout_in_ms):
    _check(tracker_handle, k4abt_tracker_t)
    _check(sensor_capture_handle, k4a_capture_t)
    if len(_queue) >= QUEUE_LIMIT:
        return _k4a.K4A_WAIT_RESULT_TIMEOUT
    depth_image = _k4a.k4a_capture_get_depth_image(sensor_capture_handle)
    ir_image = _k4a.k4a_capture_get_ir_image(sensor_capture_handle)
    try:
        if not depth_image or not ir_image:
            return _k4a.K4A_WAIT_RESULT_FAILED  # "Get IR buffer from the capture handle failed!"
        depth = _k4a.image_pixels(depth_image)
        ir = _k4a.image_pixels(ir_image)
        device_us = _k4a.k4a_image_get_device_timestamp_usec(depth_image)
    finally:
        for image in (depth_image, ir_image):
            if image:
                _k4a.k4a_image_release(image)
    ENQUEUED.append((device_us, depth, ir))
    calibration = TRACKERS[-1]["calibration"]
    bodies = [] if DETECT is None else DETECT(depth, ir, calibration)
    _queue.append((device_us, bodies))
    return _k4a.K4A_WAIT_RESULT_SUCCEEDED


def k4abt_tracker_pop_result(tracker_handle, body_frame_handle, timeout_in_ms):
    _check(tracker_handle, k4abt_tracker_t)
    _check(body_frame_handle, k4abt_frame_t)
    if len(_queue) <= LAG:
        return _k4a.K4A_WAIT_RESULT_TIMEOUT
    device_us, bodies = _queue.pop(0)
    body_frame_handle.contents = _handle_k4abt_frame_t()
    FRAMES[ctypes.addressof(body_frame_handle.contents)] = {
        "refs": 1,
        "device_us": device_us,
        "bodies": bodies,
    }
    return _k4a.K4A_WAIT_RESULT_SUCCEEDED


def _frame(body_frame_handle):
    _check(body_frame_handle, k4abt_frame_t)
    return FRAMES[ctypes.addressof(body_frame_handle.contents)]


def k4abt_frame_release(body_frame_handle):
    frame = _frame(body_frame_handle)
    frame["refs"] -= 1
    if frame["refs"] == 0:
        del FRAMES[ctypes.addressof(body_frame_handle.contents)]


def k4abt_frame_get_num_bodies(body_frame_handle):
    return len(_frame(body_frame_handle)["bodies"])


def k4abt_frame_get_body_id(body_frame_handle, index):
    return _frame(body_frame_handle)["bodies"][index][0]


def k4abt_frame_get_body_skeleton(body_frame_handle, index, skeleton):
    _check(skeleton, k4abt_skeleton_t)
    _, joints, levels = _frame(body_frame_handle)["bodies"][index]
    for k in range(K4ABT_JOINT_COUNT):
        skeleton.joints[k].position.xyz = _xyz(*(float(c) for c in joints[k]))
        skeleton.joints[k].confidence_level = int(levels[k])
    return K4ABT_RESULT_SUCCEEDED


def k4abt_frame_get_device_timestamp_usec(body_frame_handle):
    return _frame(body_frame_handle)["device_us"]


def k4abt_tracker_shutdown(tracker_handle):
    _check(tracker_handle, k4abt_tracker_t)
    TRACKERS[-1]["shutdown"] = True


def k4abt_tracker_destroy(tracker_handle):
    _check(tracker_handle, k4abt_tracker_t)
    TRACKERS[-1]["destroyed"] = True
