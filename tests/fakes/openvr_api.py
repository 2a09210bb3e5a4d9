"""A fake of pyopenvr's ``openvr`` module (2.12): the names, structures and call shapes that
``agent/poses/openvr_source.py`` uses, with scripted devices instead of a runtime.

The structures are real ctypes ones with pyopenvr's field names (``TrackedDevicePose_t`` with
``mDeviceToAbsoluteTracking`` (``HmdMatrix34_t``: 3 rows of 4 floats), ``bPoseIsValid``,
``bDeviceIsConnected``); ``IVRSystem.getDeviceToAbsoluteTrackingPose(origin, seconds, array)``
fills and returns the array as the real binding does; the errors are ``error_code`` classes
named like the real ones. Build one with :func:`make_openvr`.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from ctypes import Structure, c_bool, c_float, c_int32
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt


class HmdMatrix34_t(Structure):
    _fields_ = [("m", (c_float * 4) * 3)]

    def __getitem__(self, key: int) -> object:
        return self.m[key]


class HmdVector3_t(Structure):
    _fields_ = [("v", c_float * 3)]


class TrackedDevicePose_t(Structure):
    _fields_ = [
        ("mDeviceToAbsoluteTracking", HmdMatrix34_t),
        ("vVelocity", HmdVector3_t),
        ("vAngularVelocity", HmdVector3_t),
        ("eTrackingResult", c_int32),
        ("bPoseIsValid", c_bool),
        ("bDeviceIsConnected", c_bool),
    ]


class OpenVRError(Exception):
    pass


class InitError(OpenVRError):
    pass


class TrackedPropertyError(OpenVRError):
    pass


def _error(name: str, base: type[OpenVRError]) -> type[OpenVRError]:
    return type(name, (base,), {})


# Device → space pose at (seconds relative to the call): a 3×4 matrix, or None (not valid).
PoseScript = Callable[[float], npt.NDArray[np.float64] | None]


@dataclass
class FakeDevice:
    device_class: int
    serial: str
    pose: PoseScript = field(default=lambda dt: np.eye(4)[:3])
    connected: bool = True


@dataclass
class FakeSystem:
    """``IVRSystem``: scripted devices; ``calls`` records (origin, predicted seconds)."""

    devices: list[FakeDevice]
    calls: list[tuple[int, float]] = field(default_factory=list)

    def getTrackedDeviceClass(self, index: int) -> int:
        return self.devices[index].device_class if index < len(self.devices) else 0

    def getStringTrackedDeviceProperty(self, index: int, prop: int) -> str:
        if prop != 1002:
            raise _error("TrackedProp_UnknownProperty", TrackedPropertyError)()
        if index >= len(self.devices) or not self.devices[index].serial:
            raise _error("TrackedProp_InvalidDevice", TrackedPropertyError)()
        return self.devices[index].serial

    def getDeviceToAbsoluteTrackingPose(
        self, origin: int, predictedSecondsToPhotonsFromNow: float, array: object
    ) -> object:
        self.calls.append((origin, predictedSecondsToPhotonsFromNow))
        for index, slot in enumerate(array):  # type: ignore[call-overload]
            device = self.devices[index] if index < len(self.devices) else None
            matrix = None if device is None else device.pose(predictedSecondsToPhotonsFromNow)
            slot.bDeviceIsConnected = device is not None and device.connected
            slot.bPoseIsValid = matrix is not None
            slot.eTrackingResult = 200 if matrix is not None else 100
            if matrix is not None:
                for r in range(3):
                    for c in range(4):
                        slot.mDeviceToAbsoluteTracking.m[r][c] = float(matrix[r][c])
        return array


def make_openvr(
    devices: list[FakeDevice] | None = None, init_error: str | None = None
) -> types.SimpleNamespace:
    """A fake ``openvr`` module: ``init`` returns a :class:`FakeSystem` of ``devices`` (default:
    one headset) or raises ``error_code.<init_error>`` (e.g. the real message's
    ``InitError_Init_PathRegistryNotFound``); ``shutdowns`` counts ``shutdown()`` calls."""
    system = FakeSystem(devices if devices is not None else [FakeDevice(1, "HMD-1")])
    error_code = types.SimpleNamespace(
        OpenVRError=OpenVRError, InitError=InitError, TrackedPropertyError=TrackedPropertyError
    )
    vr = types.SimpleNamespace(
        k_unMaxTrackedDeviceCount=64,
        k_unTrackedDeviceIndex_Hmd=0,
        TrackedDeviceClass_Invalid=0,
        TrackedDeviceClass_HMD=1,
        TrackedDeviceClass_Controller=2,
        TrackedDeviceClass_GenericTracker=3,
        TrackingUniverseSeated=0,
        TrackingUniverseStanding=1,
        Prop_SerialNumber_String=1002,
        VRApplication_Other=0,
        VRApplication_Background=3,
        HmdMatrix34_t=HmdMatrix34_t,
        TrackedDevicePose_t=TrackedDevicePose_t,
        error_code=error_code,
        system=system,
        app_types=[],
        shutdowns=0,
    )

    def init(application_type: int, startup_info: str | None = None) -> FakeSystem:
        vr.app_types.append(application_type)
        if init_error is not None:
            raise _error(init_error, InitError)()
        return system

    def shutdown() -> None:
        vr.shutdowns += 1

    vr.init = init
    vr.shutdown = shutdown
    return vr
