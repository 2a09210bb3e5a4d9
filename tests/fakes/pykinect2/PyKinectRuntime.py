# ruff: noqa
# fmt: off
# Fake of pykinect2/PyKinectRuntime.py: same public surface, frames from SCRIPT.
import ctypes
import time

import numpy

from pykinect2 import PyKinectV2

SCRIPT = []  # KinectBodyFrameData objects, consumed in order
OPENED = []
DEPTH = []  # flat uint16 depth images (mm); the last one is the current frame
DEPTH_WIDTH, DEPTH_HEIGHT = 512, 424
FOCAL_PX = 365.0  # a pinhole stand-in for the device's lens calibration


class _CoordinateMapper:
    """ICoordinateMapper as comtypes exposes it: checks the ctypes argument types as the real
    COM method's argtypes would."""

    def __init__(self):
        self.calls = 0

    def MapDepthFrameToCameraSpace(self, depth_count, depth_data, point_count, camera_points):
        assert isinstance(depth_count, ctypes.c_uint) and isinstance(point_count, ctypes.c_uint)
        assert isinstance(depth_data, ctypes.POINTER(ctypes.c_ushort)), type(depth_data)
        assert isinstance(camera_points, ctypes.Array), type(camera_points)
        assert camera_points._type_ is PyKinectV2._CameraSpacePoint
        assert len(camera_points) == point_count.value
        self.calls += 1
        n = depth_count.value
        depth = numpy.ctypeslib.as_array(depth_data, shape=(n,)).astype(numpy.float64) / 1000.0
        v, u = numpy.divmod(numpy.arange(n), DEPTH_WIDTH)
        out = numpy.frombuffer(camera_points, dtype=numpy.float32).reshape(n, 3)
        out[:, 0] = (DEPTH_WIDTH / 2 - u) * depth / FOCAL_PX  # camera space: +X to the left
        out[:, 1] = (DEPTH_HEIGHT / 2 - v) * depth / FOCAL_PX
        out[:, 2] = depth
        out[depth == 0] = -numpy.inf  # what the SDK gives pixels without depth
        return 0


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
    # The real KinectBody copies these from IBody only for a tracked body (HandState values
    # 0 Unknown .. 4 Lasso, TrackingConfidence 0 Low / 1 High).
    def __init__(self, tracking_id=-1, joints=None, states=None, hands=(0, 0, 0, 0)):
        self.is_tracked = joints is not None
        self.tracking_id = tracking_id
        if joints is not None:
            self.hand_left_state, self.hand_right_state = hands[0], hands[1]
            self.hand_left_confidence, self.hand_right_confidence = hands[2], hands[3]
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
        self._mapper = _CoordinateMapper()
        self._last_body_frame_time = time.clock()
        self.closed = False
        OPENED.append(self)

    def has_new_body_frame(self):
        return bool(SCRIPT)

    def get_last_body_frame(self):
        return SCRIPT.pop(0) if SCRIPT else None

    def get_last_depth_frame(self):
        if not self.frame_source_types & PyKinectV2.FrameSourceTypes_Depth:
            return None  # the real runtime's _depth_frame_data is None then
        if not DEPTH:
            return numpy.zeros(DEPTH_WIDTH * DEPTH_HEIGHT, dtype=numpy.uint16)
        return numpy.copy(DEPTH[-1])

    def close(self):
        self.closed = True
