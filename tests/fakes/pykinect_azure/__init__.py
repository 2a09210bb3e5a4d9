# ruff: noqa
"""Fake of pykinect_azure 0.0.4's package level (pykinect_azure/pykinect.py, k4a/device.py,
k4a/capture.py, k4abt/tracker.py, k4abt/frame.py) on top of the fake ctypes layer
(k4a/_k4a.py, k4abt/_k4abt.py), so that it fails where the real one does:

- every SDK result goes through ``VERIFY``, which prints and ``sys.exit(1)``s on anything but
  success (pykinect_azure/k4a/_k4a.py and k4abt/_k4abt.py): a capture TIMEOUT in
  ``Device.update`` or ``Tracker.update`` ends the process, and so does a configuration the
  device refuses in ``start_device`` (WFOV unbinned at 30 fps);
- ``Device.update`` first releases the previous capture's handle (``Device.capture``, a class
  attribute) without forgetting it, so going on after a caught SystemExit releases it twice (the
  fake ctypes layer raises KeyError there; the real one frees freed memory).

skelfuse's sources use only ``initialize_libraries`` from here, then the ctypes layer."""

import sys

import numpy as np

from pykinect_azure.k4a import _k4a
from pykinect_azure.k4abt import _k4abt

K4A_COLOR_RESOLUTION_OFF = _k4a.K4A_COLOR_RESOLUTION_OFF
K4A_DEPTH_MODE_NFOV_2X2BINNED = _k4a.K4A_DEPTH_MODE_NFOV_2X2BINNED
K4A_DEPTH_MODE_NFOV_UNBINNED = _k4a.K4A_DEPTH_MODE_NFOV_UNBINNED
K4A_DEPTH_MODE_WFOV_2X2BINNED = _k4a.K4A_DEPTH_MODE_WFOV_2X2BINNED
K4A_DEPTH_MODE_WFOV_UNBINNED = _k4a.K4A_DEPTH_MODE_WFOV_UNBINNED
K4A_FRAMES_PER_SECOND_15 = _k4a.K4A_FRAMES_PER_SECOND_15
K4A_FRAMES_PER_SECOND_30 = _k4a.K4A_FRAMES_PER_SECOND_30

CALLS = []  # ("initialize_libraries", k4a path, k4abt path, track_body)


def VERIFY(result, error):
    if result != _k4a.K4A_RESULT_SUCCEEDED:
        print(error)
        sys.exit(1)


def initialize_libraries(module_k4a_path=None, module_k4abt_path=None, track_body=False):
    CALLS.append(("initialize_libraries", module_k4a_path, module_k4abt_path, track_body))


default_configuration = _k4a.k4a_device_configuration_t(
    color_resolution=1, depth_mode=K4A_DEPTH_MODE_WFOV_2X2BINNED, camera_fps=2
)


class _Wrapper:
    def __init__(self, handle):
        self._handle = handle

    def handle(self):
        return self._handle


class Capture(_Wrapper):
    def release_handle(self):
        if self._handle:
            _k4a.k4a_capture_release(self._handle)  # the handle is kept, as in 0.0.4

    def get_pointcloud(self):
        """(H·W, 3) mm through the lens (the SDK's transformation), (0, 0, 0) without depth."""
        image = _k4a.k4a_capture_get_depth_image(self._handle)
        depth = _k4a.image_pixels(image).astype(np.float64)
        _k4a.k4a_image_release(image)
        c = _k4a.CALIBRATION
        v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]].astype(np.float64)
        x, y = _k4a.undistort((u - c["cx"]) / c["fx"], (v - c["cy"]) / c["fy"], c["k1"])
        points = np.stack([x * depth, y * depth, depth], axis=-1).reshape(-1, 3)
        return True, points.astype(np.int16)


class Device:
    calibration = None
    capture = None

    def __init__(self, index=0):
        self._handle = _k4a.k4a_device_t()
        VERIFY(_k4a.k4a_device_open(index, self._handle), "Open K4A Device failed!")

    def start(self, configuration):
        Device.calibration = _k4a.k4a_calibration_t()
        VERIFY(
            _k4a.k4a_device_get_calibration(
                self._handle,
                configuration.depth_mode,
                configuration.color_resolution,
                Device.calibration,
            ),
            "Get calibration failed!",
        )
        VERIFY(
            _k4a.k4a_device_start_cameras(self._handle, configuration),
            "Start K4A cameras failed!",
        )

    def update(self, timeout_in_ms=-1):
        if Device.capture is not None:
            Device.capture.release_handle()
        capture_handle = _k4a.k4a_capture_t()
        VERIFY(
            _k4a.k4a_device_get_capture(self._handle, capture_handle, timeout_in_ms),
            "Get capture failed!",
        )
        if Device.capture is None:
            Device.capture = Capture(capture_handle)
        else:
            Device.capture._handle = capture_handle
        return Device.capture

    def close(self):
        if self._handle:
            _k4a.k4a_device_stop_cameras(self._handle)
            _k4a.k4a_device_close(self._handle)
            self._handle = None


class Frame(_Wrapper):
    def release(self):
        if self._handle:
            _k4abt.k4abt_frame_release(self._handle)

    def get_num_bodies(self):
        return _k4abt.k4abt_frame_get_num_bodies(self._handle)

    def get_body_id(self, index=0):
        return _k4abt.k4abt_frame_get_body_id(self._handle, index)

    def get_body_skeleton(self, index=0):
        skeleton = _k4abt.k4abt_skeleton_t()
        VERIFY(
            _k4abt.k4abt_frame_get_body_skeleton(self._handle, index, skeleton),
            "Body tracker get body skeleton failed!",
        )
        return skeleton


class Tracker:
    def __init__(self, calibration, model_type=0):
        self._handle = _k4abt.k4abt_tracker_t()
        VERIFY(
            _k4abt.k4abt_tracker_create(
                calibration, _k4abt.k4abt_tracker_default_configuration, self._handle
            ),
            "Body tracker initialization failed!",
        )
        self.frame = None

    def update(self, capture=None, timeout_in_ms=-1):
        capture = capture if capture else Device.capture
        VERIFY(
            _k4abt.k4abt_tracker_enqueue_capture(self._handle, capture.handle(), timeout_in_ms),
            "Body tracker capture enqueue failed!",
        )
        if self.frame is not None:
            self.frame.release()
            frame_handle = self.frame.handle()
        else:
            frame_handle = _k4abt.k4abt_frame_t()
        VERIFY(
            _k4abt.k4abt_tracker_pop_result(self._handle, frame_handle, timeout_in_ms),
            "Body tracker get body frame failed!",
        )
        if self.frame is None:
            self.frame = Frame(frame_handle)
        return self.frame

    def destroy(self):
        if self._handle:
            _k4abt.k4abt_tracker_destroy(self._handle)
            self._handle = None


def start_device(
    device_index=0, config=default_configuration, record=False, record_filepath="output.mkv"
):
    device = Device(device_index)
    device.start(config)
    return device


def start_body_tracker(model_type=0, calibration=None):
    return Tracker(calibration if calibration else Device.calibration, model_type)
