"""Every source kind, how to build one, and whether it can run on this PC (``skelfuse doctor``).

Nothing heavy is imported here: SDK modules are looked up with :func:`importlib.util.find_spec`
(which does not execute them) and imported only by the source that needs them.
"""

from __future__ import annotations

import ctypes.util
import importlib.util
import os
import platform
import struct
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from skelfuse.agent.sources.base import SensorError, SkeletonSource
from skelfuse.protocol.transform import Matrix4

SOURCE_KINDS: Final = ("sim", "replay", "ntu", "kinect_v2", "azure_kinect", "femto", "mono")

_K4A_DEFAULT_DIRS: Final = (
    r"C:\Program Files\Azure Kinect SDK v1.4.1\sdk\windows-desktop\amd64\release\bin",
    r"C:\Program Files\Azure Kinect SDK v1.4.2\sdk\windows-desktop\amd64\release\bin",
)
_K4ABT_DEFAULT_DIRS: Final = (r"C:\Program Files\Azure Kinect Body Tracking SDK\sdk\windows-desktop\amd64\release\bin",)  # fmt: skip  # noqa: E501


@dataclass(frozen=True, slots=True)
class SourceCheck:
    kind: str
    available: bool
    reason: str


def _has_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def _find_library(names: tuple[str, ...], dirs: tuple[str, ...], env: str) -> str | None:
    explicit = os.environ.get(env)
    if explicit and Path(explicit).exists():
        return explicit
    for directory in dirs:
        for name in names:
            candidate = Path(directory) / name
            if candidate.exists():
                return str(candidate)
    for name in names:
        found = ctypes.util.find_library(Path(name).stem.removeprefix("lib"))
        if found:
            return found
    return None


def _bits() -> int:
    return struct.calcsize("P") * 8


def check_kinect_v2() -> SourceCheck:
    kind = "kinect_v2"
    if platform.system() != "Windows":
        return SourceCheck(kind, False, f"the Kinect for Windows SDK 2.0 is Windows-only "
                                        f"(this is {platform.system()})")  # fmt: skip
    missing = [m for m in ("pykinect2", "comtypes") if not _has_module(m)]
    if missing:
        return SourceCheck(kind, False, f"missing {', '.join(missing)}: "
                                        "pip install 'skelfuse[kinect-v2]'")  # fmt: skip
    system = Path(os.environ.get("SYSTEMROOT", r"C:\Windows")) / "System32" / "Kinect20.dll"
    if not system.exists():
        return SourceCheck(kind, False, f"{system} not found: install the Kinect for Windows "
                                        "Runtime 2.0")  # fmt: skip
    note = " (64-bit Python: skelfuse patches pykinect2's tagSTATSTG check at import)"
    return SourceCheck(kind, True, "pykinect2, comtypes and Kinect20.dll found"
                       + (note if _bits() == 64 else ""))  # fmt: skip


def check_k4a(kind: str) -> SourceCheck:
    if sys.platform not in ("win32", "linux"):
        return SourceCheck(kind, False, "the Azure Kinect SDKs exist for Windows and Linux only")
    if _bits() != 64:
        return SourceCheck(kind, False, "the Body Tracking SDK needs 64-bit Python")
    if not _has_module("pykinect_azure"):
        return SourceCheck(kind, False, "missing pykinect_azure: pip install 'skelfuse[k4a]'")
    windows = sys.platform == "win32"
    k4a = _find_library(("k4a.dll",) if windows else ("libk4a.so",), _K4A_DEFAULT_DIRS,
                        "SKELFUSE_K4A_PATH")  # fmt: skip
    k4abt = _find_library(("k4abt.dll",) if windows else ("libk4abt.so",), _K4ABT_DEFAULT_DIRS,
                          "SKELFUSE_K4ABT_PATH")  # fmt: skip
    wrapper = (
        "Orbbec's K4A wrapper k4a library" if kind == "femto" else "the Azure Kinect Sensor SDK"
    )
    if k4a is None:
        return SourceCheck(kind, False, f"k4a library not found: install {wrapper} or set "
                                        "SKELFUSE_K4A_PATH / --k4a-path")  # fmt: skip
    if k4abt is None:
        return SourceCheck(kind, False, "k4abt library not found: install the Azure Kinect Body "
                                        "Tracking SDK 1.1 or set SKELFUSE_K4ABT_PATH")  # fmt: skip
    return SourceCheck(kind, True, f"pykinect_azure, {k4a} and {k4abt} found (device not probed)")


def check_sources() -> list[SourceCheck]:
    """Which source kinds can run here, and why not."""
    checks = [
        SourceCheck("sim", True, "built in (numpy only)"),
        SourceCheck("replay", True, "built in: plays a skelfuse recording (--file)"),
        SourceCheck("ntu", True, "built in: plays an NTU RGB+D .skeleton file (--file)"),
        check_kinect_v2(),
        check_k4a("azure_kinect"),
        check_k4a("femto"),
        check_mono_source(),
    ]
    return checks


def check_mono_source() -> SourceCheck:
    """One ordinary camera through MediaPipe Pose (agent/sources/mono.py): mediapipe 0.10.21
    with the models in its wheel, numpy<2 and OpenCV, looked up without importing them."""
    from skelfuse.agent.sources.mono_camera import check_mono

    available, reason = check_mono()
    return SourceCheck("mono", available, reason)


def _pose(options: dict[str, Any]) -> Matrix4 | None:
    pose = options.get("pose")
    return None if pose is None else np.asarray(pose, dtype=np.float64)


def make_source(kind: str, options: dict[str, Any]) -> SkeletonSource:
    """Build a source.

    Options by kind (missing ones take defaults):
        sim: ``performer``, ``pose`` (4×4), ``seed``, ``clock_offset_ns``, ``error_model``
        (``"kinect"`` or ``"tracker"``), ``random_sensor`` (a unit drawn from the seed); with
        ``scenario``
        ``"mutual"``: :func:`skelfuse.agent.sources.sim_mutual.mutual_source`'s options;
        replay: ``file``, ``sensor``, ``loop``, ``speed``;
        ntu: ``file``, ``pose``, ``loop``, ``start_unix_s``;
        kinect_v2: ``pose``;
        azure_kinect / femto: ``device_index``, ``k4a_path``, ``k4abt_path``, ``depth_mode``,
        ``pose``;
        mono: ``camera`` or ``video``, ``intrinsics`` (``"fx,fy,cx,cy"``) or ``lens``
        (:data:`skelfuse.agent.sources.mono.LensFor`), ``fov_deg``, ``pose``,
        ``loop``, ``speed``, ``start_unix_s``.

    Raises:
        SensorError: unknown kind, missing option, or the source cannot start.
    """
    if kind == "sim" and options.get("scenario") == "mutual":
        from skelfuse.agent.sources.sim_mutual import mutual_source

        return mutual_source(options)
    if kind == "sim":
        return _sim_source(options)
    if kind == "replay":
        from skelfuse.agent.sources.replay import ReplaySource

        if not options.get("file"):
            raise SensorError("the replay source needs --file RECORDING")
        return ReplaySource(
            options["file"],
            options.get("sensor"),
            loop=bool(options.get("loop", False)),
            speed=float(options.get("speed", 1.0)),
        )
    if kind == "ntu":
        from skelfuse.agent.sources.ntu import NtuSource

        if not options.get("file"):
            raise SensorError("the ntu source needs --file FILE.skeleton")
        return NtuSource(
            options["file"],
            _pose(options),
            loop=bool(options.get("loop", False)),
            start_unix_s=options.get("start_unix_s"),
        )
    if kind == "kinect_v2":
        from skelfuse.agent.sources.kinect_v2 import KinectV2Source

        return KinectV2Source(_pose(options))
    if kind in ("azure_kinect", "femto"):
        from skelfuse.agent.sources.azure_kinect import AzureKinectSource

        return AzureKinectSource(
            kind,
            device_index=int(options.get("device_index", 0)),
            k4a_path=options.get("k4a_path") or os.environ.get("SKELFUSE_K4A_PATH"),
            k4abt_path=options.get("k4abt_path") or os.environ.get("SKELFUSE_K4ABT_PATH"),
            depth_mode=str(options.get("depth_mode", "NFOV_UNBINNED")),
            pose=_pose(options),
        )
    if kind == "mono":
        return _mono_source(options)
    raise SensorError(f"unknown source {kind!r}: choose one of {', '.join(SOURCE_KINDS)}")


def _mono_source(options: dict[str, Any]) -> SkeletonSource:
    from skelfuse.agent.sources.mono import DEFAULT_FOV_DEG, MonoSource
    from skelfuse.geometry.pinhole import Intrinsics

    text = options.get("intrinsics")
    try:
        intrinsics = None if not text else Intrinsics.parse(str(text))
    except ValueError as exc:
        raise SensorError(f"--intrinsics: {exc}") from exc
    camera, video = options.get("camera"), options.get("video")
    fov = options.get("fov_deg")
    return MonoSource(
        camera=None if camera is None else int(camera),
        video=video or None,
        intrinsics=intrinsics,
        lens=options.get("lens"),
        fov_deg=DEFAULT_FOV_DEG if fov is None else float(fov),
        pose=_pose(options),
        loop=bool(options.get("loop", False)),
        speed=float(options.get("speed", 1.0)),
        start_unix_s=options.get("start_unix_s"),
    )


def _sim_source(options: dict[str, Any]) -> SkeletonSource:
    """The ``sim`` source from :func:`make_source`'s options (see there)."""
    from skelfuse.agent.sim.performer import ProceduralPerformer
    from skelfuse.agent.sim.sensor_units import ErrorModel
    from skelfuse.agent.sources.sim import SimSource

    if options.get("pose") is None:
        raise SensorError("the sim source needs a pose")
    return SimSource(
        options.get("performer") or ProceduralPerformer(int(options.get("persons", 2))),
        options["pose"],
        seed=int(options.get("seed", 0)),
        clock_offset_ns=int(options.get("clock_offset_ns", 0)),
        clock_drift_ppm=float(options.get("clock_drift_ppm", 0.0)),
        send_pose_hint=bool(options.get("send_pose_hint", True)),
        error_model=ErrorModel(
            options.get("error_model", "kinect"), bool(options.get("random_sensor", False))
        ),
    )
