"""``skelfuse agent --source mono --calibration FILE``: a calibration file's camera as the
``mono`` source's lens (intrinsics fitted to the frames, undistortion) and pose hint.

The agent package may not import the calibration layer (they are independent layers), so the
command line joins them: it reads the file with :mod:`skelfuse.calibration.camera_files` and
hands the source a :data:`skelfuse.agent.sources.mono.LensFor`. Nothing here imports a server
library (the calibration file readers need numpy and the standard library only).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.mono import LensFor, Undistort
from skelfuse.cli.values import UsageError
from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.protocol.transform import Matrix4

_log = logging.getLogger("skelfuse.agent")

_FORMAT_OF_SUFFIX = {
    ".txt": "qualisys", ".qca": "qualisys", ".toml": "pose2sim",
    ".yml": "opencv", ".yaml": "opencv", ".xml": "opencv",
}  # fmt: skip


def calibrated_lens(path: Path, fmt: str | None, camera: str | None) -> tuple[LensFor, Matrix4]:
    """The lens of camera ``camera`` (or the file's only one) and its ``T_world_from_sensor``.

    Raises:
        UsageError: the file does not read, its format cannot be told from its extension, or
            the camera is not in it (or several are and none is named).
    """
    from skelfuse.calibration.camera_files import read_camera_file
    from skelfuse.calibration.errors import CameraFileError, InvalidInput

    chosen = fmt or _FORMAT_OF_SUFFIX.get(path.suffix.lower())
    if chosen is None:
        raise UsageError(f"{path}: say --calibration-format (qualisys, pose2sim or opencv)")
    try:
        cameras = read_camera_file(path, chosen).cameras  # type: ignore[arg-type]
    except CameraFileError as exc:
        raise UsageError(str(exc)) from exc
    names = [c.name for c in cameras]
    if camera is None and len(cameras) > 1:
        raise UsageError(f"{path} holds cameras {', '.join(names)}: say --calibration-camera")
    found = cameras[0] if camera is None else next((c for c in cameras if c.name == camera), None)
    if found is None:
        raise UsageError(f"{path}: no camera {camera!r} (it holds {', '.join(names)})")
    calibrated = found.intrinsics

    def lens(width: int, height: int) -> tuple[Intrinsics, Undistort | None]:
        try:
            fitted, warning = calibrated.for_frames(width, height)
        except InvalidInput as exc:
            raise SensorError(f"--calibration camera {found.name}: {exc}") from exc
        if warning:
            _log.warning("mono: --calibration camera %s: %s", found.name, warning)
        k = Intrinsics(fitted.fx, fitted.fy, fitted.cx, fitted.cy)
        if not fitted.distortion:
            return k, None

        def undistort(pixels: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            normal = np.stack([(pixels[:, 0] - k.cx) / k.fx, (pixels[:, 1] - k.cy) / k.fy], -1)
            ideal = fitted.undistort(normal)
            out: npt.NDArray[np.float64] = np.stack(
                [ideal[:, 0] * k.fx + k.cx, ideal[:, 1] * k.fy + k.cy], axis=-1
            )
            return out

        return k, undistort

    return lens, found.T_world_from_sensor.copy()
