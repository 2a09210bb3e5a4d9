"""Camera calibration files as users have them → :class:`calibration.camera.Camera` s.

API::

    read_camera_file(path, fmt, *, up=None) -> CameraFile       fmt: qualisys | pose2sim | opencv
    CameraFile.cameras   list[Camera]  (name, intrinsics, T_world_from_sensor in the project's
                         world: +Y up, metres; sensor frame as in calibration.camera)
    CameraFile.residual_mm  {name: the file's own residual} where it states one
    CameraFile.warnings  list[str]  what was assumed (an image size guessed from the centre)
    as_sensor_calibrations(found, fmt, rename={}) -> {sensor id: SensorCalibration}  to store

Formats:

- **Qualisys** ``.qca.txt`` (XML): per ``camera``, ``transform`` holds the camera's position
  (``x y z``, millimetres) and a rotation ``r11..r33`` whose rows are the world → camera
  rotation of Qualisys' camera axes (+Y up, looking along −Z); ``intrinsic`` holds the focal
  lengths and principal point in 1/64 pixel of the sensor, ``fov_video`` the image window in
  pixels (the principal point is relative to its top-left corner), ``video_resolution`` (e.g.
  ``540p``) a scaled-down recording. Distortion coefficients are OpenCV's k1 k2 p1 p2 as they
  stand (Pose2Sim divides them by 64 as well; they are unit-free, and undivided they match the
  ~−0.05 / 0.15 a checkerboard gives for the same cameras). Cameras whose ``model`` is not a
  video model (marker-only cameras) are skipped, as Pose2Sim's ``calib_qca_fun`` does. The
  world is Z up.
- **Pose2Sim** ``.toml``: one table per camera (``[metadata]`` aside) with ``name``, ``size``
  [w, h], ``matrix`` (3×3), ``distortions`` [k1, k2, p1, p2], ``rotation`` (Rodrigues vector)
  and ``translation`` (metres) of the world → OpenCV camera transform, ``fisheye`` (only
  false is supported). World Z up.
- **OpenCV** FileStorage YAML or XML (:mod:`calibration.opencv_storage`).

``up``: the file's world up axis, ``"z"`` (default for Qualisys and Pose2Sim: the world is then
turned −90° about X, ``(x, y, z) → (x, z, −y)``) or ``"y"`` (kept as is; OpenCV's default).
"""

from __future__ import annotations

import contextlib
import math
import re
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import Camera, CameraIntrinsics, pose_from_opencv_extrinsics
from skelfuse.calibration.errors import CameraFileError, InvalidInput
from skelfuse.calibration.store import SensorCalibration
from skelfuse.protocol.transform import Matrix4

Format = Literal["qualisys", "pose2sim", "opencv"]
FORMATS: Final[tuple[Format, ...]] = ("qualisys", "pose2sim", "opencv")
Up = Literal["y", "z"]

YUP_FROM_ZUP: Final[Matrix4] = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""−90° about X: a Z-up world's +Z becomes +Y, its +Y becomes −Z."""

_QUALISYS_VIDEO_MODELS: Final = frozenset({"Miqus Video", "Miqus Video UnderWater", "none"})
_QUALISYS_TO_OPENCV_AXES: Final = np.diag([1.0, -1.0, -1.0])  # 180° about the camera's X
_QUALISYS_DISTORTION: Final = (
    "radialDistortion1",
    "radialDistortion2",
    "tangentalDistortion1",  # sic: Qualisys' spelling
    "tangentalDistortion2",
)


@dataclass(frozen=True, slots=True)
class CameraFile:
    """What :func:`read_camera_file` found (fields in the module docstring)."""

    cameras: list[Camera]
    residual_mm: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def read_camera_file(path: Path, fmt: Format, *, up: Up | None = None) -> CameraFile:
    """Read one calibration file of format ``fmt`` (see the module docstring).

    Raises:
        CameraFileError: the file cannot be read or parsed, a camera lacks a field or has an
            invalid one (the message names the file, the camera and the field), or no camera
            is in it.
    """
    if fmt not in FORMATS:
        raise CameraFileError(f"unknown calibration format {fmt!r}; one of {', '.join(FORMATS)}")
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise CameraFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    origin = str(path)
    try:
        if fmt == "qualisys":
            result = _read_qualisys(data, origin, up or "z")
        elif fmt == "pose2sim":
            result = _read_pose2sim(data, origin, up or "z")
        else:
            from skelfuse.calibration.opencv_storage import read_opencv_cameras

            cameras, warnings = read_opencv_cameras(data, origin, Path(path).stem)
            result = CameraFile([_in_world(c, up or "y") for c in cameras], warnings=warnings)
    except InvalidInput as exc:  # a value the Camera / CameraIntrinsics constructors refused
        raise CameraFileError(f"{origin}: {exc}") from exc
    if not result.cameras:
        raise CameraFileError(f"{origin}: no camera found in this {fmt} file")
    names = [c.name for c in result.cameras]
    if len(set(names)) != len(names):
        raise CameraFileError(f"{origin}: camera names repeat ({', '.join(names)})")
    return result


def as_sensor_calibrations(
    found: CameraFile, fmt: Format, *, rename: dict[str, str] | None = None
) -> dict[str, SensorCalibration]:
    """The cameras as entries of the project's calibration (``method`` ``"import:<fmt>"``),
    keyed by camera name or by ``rename[name]`` (the agent's sensor id).

    Raises:
        CameraFileError: ``rename`` names a camera the file does not have, or two cameras
            would get the same sensor id.
    """
    rename = rename or {}
    names = [c.name for c in found.cameras]
    unknown = sorted(set(rename) - set(names))
    if unknown:
        raise CameraFileError(
            f"no camera named {', '.join(unknown)} in the file (it has {', '.join(names)})"
        )
    ids = [rename.get(name, name) for name in names]
    if len(set(ids)) != len(ids):
        raise CameraFileError(f"two cameras would share a sensor id: {', '.join(ids)}")
    return {
        sensor_id: SensorCalibration(
            camera.T_world_from_sensor,
            f"import:{fmt}",
            found.residual_mm.get(camera.name),
            {"camera": camera.name},
            camera.intrinsics,
        )
        for sensor_id, camera in zip(ids, found.cameras, strict=True)
    }


def _in_world(camera: Camera, up: Up) -> Camera:
    if up not in ("y", "z"):
        raise CameraFileError(f"up must be 'y' or 'z', got {up!r}")
    if up == "y":
        return camera
    return Camera(camera.name, camera.intrinsics, YUP_FROM_ZUP @ camera.T_world_from_sensor)


def _read_qualisys(data: bytes, origin: str, up: Up) -> CameraFile:
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise CameraFileError(f"{origin}: not valid Qualisys XML ({exc})") from exc
    if root.tag != "calibration":
        raise CameraFileError(f"{origin}: the root element is <{root.tag}>, not <calibration>")
    cameras: list[Camera] = []
    residuals: dict[str, float] = {}
    for index, element in enumerate(root.findall("cameras/camera")):
        if element.get("model", "none") not in _QUALISYS_VIDEO_MODELS:
            continue
        name = element.get("serial") or f"camera{index + 1}"
        where = f"{origin}: camera {name!r}"
        fov = _child(element, "fov_video", where)
        intrinsic = _child(element, "intrinsic", where)
        transform = _child(element, "transform", where)
        scale = _qualisys_resolution_scale(element.get("video_resolution"), where)
        left, top = _number(fov, "left", where), _number(fov, "top", where)
        width = (_number(fov, "right", where) - left + 1) * scale
        height = (_number(fov, "bottom", where) - top + 1) * scale
        keys = [
            *_QUALISYS_DISTORTION,
            *(["radialDistortion3"] if "radialDistortion3" in intrinsic.attrib else []),
        ]  # k3 is optional
        distortion = tuple(_number(intrinsic, key, where) for key in keys)
        try:
            intrinsics = CameraIntrinsics(
                round(width),
                round(height),
                _number(intrinsic, "focalLengthU", where) / 64 * scale,
                _number(intrinsic, "focalLengthV", where) / 64 * scale,
                (_number(intrinsic, "centerPointU", where) / 64 - left) * scale,
                (_number(intrinsic, "centerPointV", where) / 64 - top) * scale,
                distortion,
            )
            rows = np.array(
                [[_number(transform, f"r{i}{j}", where) for j in (1, 2, 3)] for i in (1, 2, 3)]
            )
            position_m = np.array([_number(transform, k, where) for k in ("x", "y", "z")]) / 1000
        except InvalidInput as exc:
            raise CameraFileError(f"{where}: {exc}") from exc
        rotation = _QUALISYS_TO_OPENCV_AXES @ rows  # world → OpenCV camera axes
        try:
            pose = pose_from_opencv_extrinsics(rotation, -rotation @ position_m)
        except InvalidInput as exc:
            raise CameraFileError(f"{where}: transform: {exc}") from exc
        cameras.append(_in_world(Camera(name, intrinsics, pose), up))
        residual = element.get("avg-residual")
        if residual is not None:
            with contextlib.suppress(ValueError):  # informative only: never stops the import
                residuals[name] = float(residual)
    return CameraFile(cameras, residuals)


def _qualisys_resolution_scale(resolution: str | None, where: str) -> float:
    """A camera recording at ``540p`` has its calibration at 1080 lines: scale by 540/1080."""
    if resolution is None:
        return 1.0
    match = re.fullmatch(r"(\d+)p", resolution.strip())
    if not match or int(match.group(1)) == 0:
        raise CameraFileError(f"{where}: video_resolution {resolution!r} is not like '1080p'")
    return int(match.group(1)) / 1080


def _child(element: ET.Element, tag: str, where: str) -> ET.Element:
    child = element.find(tag)
    if child is None:
        raise CameraFileError(f"{where}: missing <{tag}>")
    return child


def _number(element: ET.Element, key: str, where: str) -> float:
    raw = element.get(key)
    if raw is None:
        raise CameraFileError(f"{where}: <{element.tag}> lacks the attribute {key}")
    try:
        value = float(raw)
    except ValueError as exc:
        raise CameraFileError(f"{where}: <{element.tag} {key}={raw!r}> is not a number") from exc
    if not math.isfinite(value):
        raise CameraFileError(f"{where}: <{element.tag} {key}={raw!r}> is not finite")
    return value


def _read_pose2sim(data: bytes, origin: str, up: Up) -> CameraFile:
    try:
        document = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise CameraFileError(f"{origin}: not valid TOML ({exc})") from exc
    cameras: list[Camera] = []
    for key, table in document.items():
        if key == "metadata":
            continue
        where = f"{origin}: [{key}]"
        if not isinstance(table, dict):
            raise CameraFileError(f"{where}: expected a table of camera fields")
        if table.get("fisheye", False):
            raise CameraFileError(f"{where}: fisheye cameras are not supported")
        name = table.get("name", key)
        size = _floats(table, "size", (2,), where)
        matrix = _floats(table, "matrix", (3, 3), where)
        distortion = _floats(table, "distortions", None, where).reshape(-1)
        try:
            intrinsics = CameraIntrinsics(
                round(size[0]),
                round(size[1]),
                matrix[0, 0],
                matrix[1, 1],
                matrix[0, 2],
                matrix[1, 2],
                tuple(float(v) for v in distortion),
            )
            pose = pose_from_opencv_extrinsics(
                _floats(table, "rotation", (3,), where), _floats(table, "translation", (3,), where)
            )
        except InvalidInput as exc:
            raise CameraFileError(f"{where}: {exc}") from exc
        cameras.append(_in_world(Camera(str(name), intrinsics, pose), up))
    return CameraFile(cameras)


def _floats(
    table: dict[str, Any], key: str, shape: tuple[int, ...] | None, where: str
) -> npt.NDArray[np.float64]:
    if key not in table:
        raise CameraFileError(f"{where}: missing {key}")
    try:
        array = np.asarray(table[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CameraFileError(f"{where}: {key} is not an array of numbers") from exc
    if shape is not None and array.shape != shape:
        raise CameraFileError(f"{where}: {key} must have shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise CameraFileError(f"{where}: {key} holds NaN or inf")
    return array
