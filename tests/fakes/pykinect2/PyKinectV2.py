# ruff: noqa
# fmt: off
# Fake of pykinect2/PyKinectV2.py (PyPI 0.1.0): the few names skelfuse uses, and the lines that
# break the real module on 64-bit Python / comtypes >= 1.2.
from ctypes import POINTER, Structure, c_float, c_uint32, c_ulonglong, c_void_p, c_wchar_p, sizeof

FrameSourceTypes_Depth = 8
FrameSourceTypes_Body = 32
JointType_Count = 25


class _CameraSpacePoint(Structure):
    _fields_ = [("x", c_float), ("y", c_float), ("z", c_float)]


class tagSTATSTG(Structure):
    _fields_ = [
        ("pwcsName", c_wchar_p),
        ("type", c_uint32),
        ("cbSize", c_ulonglong),
        ("mtime", c_uint32 * 2),
        ("ctime", c_uint32 * 2),
        ("atime", c_uint32 * 2),
        ("grfMode", c_uint32),
        ("grfLocksSupported", c_uint32),
        ("clsid", c_uint32 * 4),
        ("grfStateBits", c_uint32),
        ("reserved", c_uint32),
    ]


assert sizeof(tagSTATSTG) == 72, sizeof(tagSTATSTG)
UNUSED = POINTER(c_void_p)
from comtypes import _check_version; _check_version('')
