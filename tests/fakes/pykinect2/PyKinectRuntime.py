# ruff: noqa
# fmt: off
# Fake of pykinect2/PyKinectRuntime.py: same public surface, frames from SCRIPT.
import ctypes
import time

import numpy

from pykinect2 import PyKinectV2

SCRIPT = []  # KinectBodyFrameData objects, consumed in order
OPENED = []


class _Point:
    def __init__(self, x, y, z):
        self.x, self.y, self.z = x, y, z


class _Joint:
    def __init__(self, x, y, z, state):
        self.Position = _Point(x, y, z)
        self.TrackingState = state


class _Vector4:
    def __init__(self, x, y, z, w):
        self.x, self.y, self.z, self.w = x, y, z, w


class KinectBody:
    def __init__(self, tracking_id=-1, joints=None, states=None):
        self.is_tracked = joints is not None
        self.tracking_id = tracking_id
        if joints is not None:
            self.joints = [_Joint(*joints[j], states[j]) for j in range(PyKinectV2.JointType_Count)]


class KinectBodyFrameData:
    def __init__(self, bodies, floor, relative_time):
        self.bodies = numpy.ndarray((6), dtype=numpy.object)
        for i in range(6):
            self.bodies[i] = bodies[i] if i < len(bodies) else KinectBody()
        self.floor_clip_plane = _Vector4(*floor)
        self.relative_time = relative_time


class PyKinectRuntime:
    def __init__(self, frame_source_types):
        self._PyObject_AsWriteBuffer = ctypes.pythonapi.PyObject_AsWriteBuffer
        self._PyObject_AsWriteBuffer.restype = ctypes.c_int
        self.frame_source_types = frame_source_types
        self._last_body_frame_time = time.clock()
        self.closed = False
        OPENED.append(self)

    def has_new_body_frame(self):
        return bool(SCRIPT)

    def get_last_body_frame(self):
        return SCRIPT.pop(0) if SCRIPT else None

    def close(self):
        self.closed = True
