# ruff: noqa
"""Fake of pykinect_azure 0.0.4: the calls skelfuse makes; frames come from SCRIPT."""

import ctypes

from pykinect_azure.k4abt import _k4abt

K4A_COLOR_RESOLUTION_OFF = 0
K4A_DEPTH_MODE_NFOV_2X2BINNED = 1
K4A_DEPTH_MODE_NFOV_UNBINNED = 2
K4A_DEPTH_MODE_WFOV_2X2BINNED = 3
K4A_DEPTH_MODE_WFOV_UNBINNED = 4
K4A_FRAMES_PER_SECOND_30 = 2

SCRIPT = []  # (device_timestamp_us, [(body_id, joints_mm (32,3), levels (32,))], cloud_mm)
CALLS = []


class _xyz(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class k4a_float3_t(ctypes.Union):
    _fields_ = [("xyz", _xyz), ("v", ctypes.c_float * 3)]


class k4abt_joint_t(ctypes.Structure):
    _fields_ = [
        ("position", k4a_float3_t),
        ("orientation", ctypes.c_float * 4),
        ("confidence_level", ctypes.c_int),
    ]


class k4abt_skeleton_t(ctypes.Structure):
    _fields_ = [("joints", k4abt_joint_t * 32)]


class _Config:
    color_resolution = 1
    depth_mode = 0
    camera_fps = 0


default_configuration = _Config()


def initialize_libraries(module_k4a_path=None, module_k4abt_path=None, track_body=False):
    CALLS.append(("initialize_libraries", module_k4a_path, module_k4abt_path, track_body))


class Capture:
    def __init__(self, cloud_mm):
        self._cloud = cloud_mm

    def get_pointcloud(self):
        return self._cloud is not None, self._cloud


class Frame:
    def __init__(self, timestamp_us, bodies):
        self._timestamp_us = timestamp_us
        self._bodies = bodies

    def handle(self):
        return self

    def get_num_bodies(self):
        return len(self._bodies)

    def get_body_id(self, index):
        return self._bodies[index][0]

    def get_body_skeleton(self, index):
        skeleton = k4abt_skeleton_t()
        _, joints, levels = self._bodies[index]
        for k in range(32):
            skeleton.joints[k].position.xyz = _xyz(*joints[k])
            skeleton.joints[k].confidence_level = int(levels[k])
        return skeleton


class Device:
    def __init__(self):
        self.current = None
        self.closed = False

    def update(self, timeout_in_ms=-1):
        if not SCRIPT:
            raise Exception("Get capture failed!")
        self.current = SCRIPT.pop(0)
        return Capture(self.current[2])

    def close(self):
        self.closed = True


class Tracker:
    def __init__(self, device):
        self._device = device
        self.destroyed = False

    def update(self, capture=None, timeout_in_ms=-1):
        timestamp_us, bodies, _ = self._device.current
        return Frame(timestamp_us, bodies)

    def destroy(self):
        self.destroyed = True


_DEVICES = []


def start_device(
    device_index=0, config=default_configuration, record=False, record_filepath="output.mkv"
):
    CALLS.append(("start_device", device_index, config.depth_mode, config.color_resolution))
    device = Device()
    _DEVICES.append(device)
    return device


def start_body_tracker(model_type=0, calibration=None):
    return Tracker(_DEVICES[-1])
