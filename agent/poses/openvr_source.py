"""OpenVR poses (a SteamVR headset or tracker the depth camera is fixed to) via ``openvr``.

Written against pyopenvr 2.12 (the ``openvr`` wheel, which bundles ``libopenvr_api``), tested
against a fake of that API (``tests/fakes/openvr_api.py``); **it has not run with a headset**.

Each capture's pose is asked for at the capture instant: ``IVRSystem.
getDeviceToAbsoluteTrackingPose(TrackingUniverseStanding, dt, poses)`` with ``dt`` = capture
instant − now, negative for the past. Valve (ValveSoftware/openvr#206): the runtime keeps
100 ms of pose history and predicts at most ±100 ms from a real sample, so up to 200 ms back
is answered, the nearer the better; older captures get no pose (``max_lookback_s``).

Axes: OpenVR's standing universe and device frames are right-handed, +Y up, metres, the device
looking along −Z with +X to its right. The body pose handed on is in the sensor convention
(+X left, +Z forward: :data:`~skelfuse.agent.poses.base.SENSOR_AXES_IN_OPENVR`), in the
tracking space's own (OpenVR) axes; the mount then places the camera on the body.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.agent.poses.base import SENSOR_AXES_IN_OPENVR
from skelfuse.agent.sources.base import SensorError
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_from_matrix

_INIT_HINTS = {
    "InitError_Init_PathRegistryNotFound": "no OpenVR runtime is installed for this user "
    "(install SteamVR and run it once)",
    "InitError_Init_InstallationNotFound": "no OpenVR runtime is installed (install SteamVR)",
    "InitError_Init_NoServerForBackgroundApp": "SteamVR is not running (start it first: a "
    "background app does not start it)",
    "InitError_Init_HmdNotFound": "SteamVR runs but finds no headset",
}


def import_openvr() -> Any:
    """The ``openvr`` module (pyopenvr).

    Raises:
        SensorError: it is not installed.
    """
    try:
        return importlib.import_module("openvr")
    except ImportError as exc:
        raise SensorError(
            f"OpenVR poses need pyopenvr: pip install 'skelfuse[openvr]' ({exc})"
        ) from exc


def check_openvr(
    home: Path | None = None, environ: Mapping[str, str] | None = None
) -> tuple[bool, str]:
    """Whether OpenVR poses can run here, without starting OpenVR (``skelfuse doctor``).

    Looks for pyopenvr (not imported) and for the OpenVR path registry SteamVR writes when it
    first runs (``openvrpaths.vrpath``, where ``libopenvr_api`` looks for the runtime).
    ``home``/``environ``: the user's home and environment (injected in tests).
    """
    env = os.environ if environ is None else environ
    base = Path.home() if home is None else home
    try:
        found = importlib.util.find_spec("openvr") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        return False, "missing pyopenvr: pip install 'skelfuse[openvr]'"
    if sys.platform == "win32":
        folder = Path(env.get("LOCALAPPDATA", str(base / "AppData" / "Local"))) / "openvr"
    elif sys.platform == "darwin":
        folder = base / "Library" / "Application Support" / "OpenVR" / ".openvr"
    else:
        folder = Path(env.get("XDG_CONFIG_HOME", str(base / ".config"))) / "openvr"
    registry = folder / "openvrpaths.vrpath"
    if not registry.exists():
        return False, f"pyopenvr found, but no {registry}: install SteamVR and run it once"
    return True, f"pyopenvr and {registry} found (SteamVR must be running; headset not probed)"


def openvr_matrix(m34: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    """An ``HmdMatrix34_t`` (3 rows of 4: rotation | translation, metres) as a 4×4 float64."""
    transform = np.eye(4)
    transform[:3, :4] = [[float(m34[r][c]) for c in range(4)] for r in range(3)]
    return transform


class OpenVRPoseSource:
    """The pose of one OpenVR device at the agent's instants.

    Args:
        device: ``"hmd"`` (the headset) or a device's serial number
            (``Prop_SerialNumber_String``, e.g. a Vive tracker's ``LHR-1A2B3C4D``).
        vr: the ``openvr`` module (tests pass a fake); None imports it.
        clock_ns: the agent's wall clock, the capture stamps' clock.
        max_lookback_s: the oldest capture posed (at most 0.2 s: what the runtime answers).
        max_ahead_s: how far in the future a capture stamp may be (a clock step) and still be
            posed by OpenVR's prediction.

    Raises:
        SensorError: pyopenvr missing, no runtime (the message says which of the usual causes),
            or no such device (the message lists the serials found); ``max_lookback_s`` > 0.2.
    """

    def __init__(
        self,
        device: str = "hmd",
        *,
        vr: Any = None,
        clock_ns: Callable[[], int] = time.time_ns,
        max_lookback_s: float = 0.2,
        max_ahead_s: float = 0.05,
    ) -> None:
        if not 0.0 <= max_lookback_s <= 0.2:
            raise SensorError(f"max_lookback_s {max_lookback_s} must be within 0..0.2 s")
        self._vr = import_openvr() if vr is None else vr
        self._clock_ns = clock_ns
        self._max_back_ns = round(max_lookback_s * 1e9)
        self._max_ahead_ns = round(max_ahead_s * 1e9)
        self.last_miss = ""
        self._system = self._start()
        self._closed = False
        try:
            self.index = self._find(device)
        except SensorError:
            self.close()
            raise
        self._poses = (self._vr.TrackedDevicePose_t * self._vr.k_unMaxTrackedDeviceCount)()

    def _start(self) -> Any:
        vr = self._vr
        try:
            return vr.init(vr.VRApplication_Background)
        except vr.error_code.OpenVRError as exc:
            name = type(exc).__name__
            hint = _INIT_HINTS.get(name, "see SteamVR's own logs")
            raise SensorError(f"OpenVR did not start ({name}): {hint}") from exc

    def _find(self, device: str) -> int:
        vr, system = self._vr, self._system
        classes = [system.getTrackedDeviceClass(i) for i in range(vr.k_unMaxTrackedDeviceCount)]
        if device.lower() == "hmd":
            for index, kind in enumerate(classes):
                if kind == vr.TrackedDeviceClass_HMD:
                    return index
            raise SensorError("OpenVR reports no headset (--pose-device hmd)")
        serials: list[str] = []
        for index, kind in enumerate(classes):
            if kind == vr.TrackedDeviceClass_Invalid:
                continue
            try:
                serial = system.getStringTrackedDeviceProperty(index, vr.Prop_SerialNumber_String)
            except vr.error_code.OpenVRError:
                continue  # a slot without the property: not the device asked for
            if serial == device:
                return index
            serials.append(serial)
        found = ", ".join(serials) or "none"
        raise SensorError(f"OpenVR has no device with serial {device!r} (serials: {found})")

    def pose_at(self, t_ns: int) -> SensorPose | None:
        """The device's ``T_space_from_body`` at ``t_ns`` (sensor-convention body axes), or
        None (``last_miss`` says why): too far back or ahead, disconnected, pose not valid."""
        dt_ns = t_ns - self._clock_ns()
        if dt_ns < -self._max_back_ns:
            self.last_miss = f"capture older than {self._max_back_ns / 1e6:.0f} ms (OpenVR)"
            return None
        if dt_ns > self._max_ahead_ns:
            self.last_miss = f"capture stamped over {self._max_ahead_ns / 1e6:.0f} ms ahead"
            return None
        vr = self._vr
        poses = self._system.getDeviceToAbsoluteTrackingPose(
            vr.TrackingUniverseStanding, dt_ns / 1e9, self._poses
        )
        pose = poses[self.index]
        if not pose.bDeviceIsConnected:
            self.last_miss = "OpenVR device not connected"
            return None
        if not pose.bPoseIsValid:
            self.last_miss = "OpenVR pose not valid (tracking lost)"
            return None
        return pose_from_matrix(
            openvr_matrix(pose.mDeviceToAbsoluteTracking) @ SENSOR_AXES_IN_OPENVR
        )

    def close(self) -> None:
        """Shut OpenVR down (once)."""
        if not self._closed:
            self._closed = True
            self._vr.shutdown()
