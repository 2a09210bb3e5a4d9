"""OpenCV FileStorage calibration files (YAML or XML) → :class:`calibration.camera.Camera` s.

Without OpenCV or a YAML library: FileStorage writes a small, regular subset of each, read
here. YAML: a ``%YAML:1.0`` header, ``key: value`` mappings nested by indentation, scalars,
flow lists ``[a, b]`` that may wrap lines, block lists (``- item``) and matrices tagged
``!!opencv-matrix`` (``rows``, ``cols``, ``dt``, ``data``). XML: ``<opencv_storage>`` with one
element per key, matrices marked ``type_id="opencv-matrix"``, other values as text.

Keys, one camera per file (its name is the file's stem), or several as EasyMocap/Pose2Sim
write them (``names`` listing them, keys suffixed ``_<name>``):

- intrinsics: ``camera_matrix`` | ``cameraMatrix`` | ``K`` (3×3); ``distortion_coefficients``
  | ``dist_coeffs`` | ``distCoeffs`` | ``dist`` | ``D`` (4, 5 or 8); the image size from
  ``image_width`` + ``image_height`` or ``image_size`` | ``imageSize`` [w, h], else twice the
  principal point (a warning says so);
- extrinsics, world → OpenCV camera, metres: ``rvec`` | ``R`` (Rodrigues 3-vector) or
  ``rotation_matrix`` | ``Rot`` | ``R`` (3×3), and ``tvec`` | ``T`` | ``t``. Without them the
  camera stands at the world origin (a warning says so).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import Camera, CameraIntrinsics, pose_from_opencv_extrinsics
from skelfuse.calibration.errors import CameraFileError, InvalidInput

_MATRIX_KEYS: Final = ("camera_matrix", "cameraMatrix", "K")
_DIST_KEYS: Final = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "dist", "D")
_ROTATION_KEYS: Final = ("rvec", "rotation_matrix", "Rot", "R")
_TRANSLATION_KEYS: Final = ("tvec", "T", "t")
_SIZE_KEYS: Final = ("image_size", "imageSize")


def read_opencv_cameras(data: bytes, origin: str, stem: str) -> tuple[list[Camera], list[str]]:
    """The cameras of a FileStorage file and the warnings of what was assumed.

    Raises:
        CameraFileError: not parseable as FileStorage YAML/XML, or a camera lacks its camera
            matrix or has a field of the wrong shape (the message names it).
    """
    text = data.decode("utf-8", errors="replace")
    stripped = text.lstrip()
    document = _parse_xml(text, origin) if stripped.startswith("<") else _parse_yaml(text, origin)
    names = document.get("names")
    if isinstance(names, list) and names:
        cameras, warnings = [], []
        for name in names:
            keys = {k[: -len(f"_{name}")]: v for k, v in document.items() if k.endswith(f"_{name}")}
            camera, camera_warnings = _camera(keys, str(name), f"{origin}: camera {name!r}")
            cameras.append(camera)
            warnings.extend(camera_warnings)
        return cameras, warnings
    camera, warnings = _camera(document, stem, origin)
    return [camera], warnings


def _camera(keys: dict[str, Any], name: str, where: str) -> tuple[Camera, list[str]]:
    warnings: list[str] = []
    matrix = _array(
        _first(keys, _MATRIX_KEYS, where, required=True), (3, 3), "camera matrix", where
    )
    raw_dist = _first(keys, _DIST_KEYS, where, required=False)
    dist = np.zeros(0) if raw_dist is None else _array(raw_dist, None, "distortion", where)
    width, height = _size(keys, matrix, where, warnings)
    rotation = _rotation(keys, where)
    translation = _first(keys, _TRANSLATION_KEYS, where, required=False)
    try:
        intrinsics = CameraIntrinsics(
            width,
            height,
            matrix[0, 0],
            matrix[1, 1],
            matrix[0, 2],
            matrix[1, 2],
            tuple(float(v) for v in dist.reshape(-1)),
        )
        if rotation is None or translation is None:
            warnings.append(f"{where}: no extrinsics (rvec/R and tvec/T): placed at the origin")
            pose = np.eye(4)
            pose[:3, :3] = np.diag([-1.0, -1.0, 1.0])  # OpenCV's axes = the world's
        else:
            pose = pose_from_opencv_extrinsics(
                rotation, _array(translation, None, "translation", where).reshape(-1)
            )
        return Camera(name, intrinsics, pose), warnings
    except InvalidInput as exc:
        raise CameraFileError(f"{where}: {exc}") from exc


def _first(keys: dict[str, Any], options: tuple[str, ...], where: str, *, required: bool) -> Any:
    for key in options:
        if key in keys:
            return keys[key]
    if required:
        raise CameraFileError(f"{where}: none of the keys {', '.join(options)} is present")
    return None


def _rotation(keys: dict[str, Any], where: str) -> npt.NDArray[np.float64] | None:
    raw = _first(keys, _ROTATION_KEYS, where, required=False)
    if raw is None:
        return None
    rotation = _array(raw, None, "rotation", where)
    if rotation.size not in (3, 9):
        raise CameraFileError(f"{where}: rotation must be a 3-vector or 3×3, got {rotation.shape}")
    return rotation.reshape(3) if rotation.size == 3 else rotation.reshape(3, 3)


def _size(
    keys: dict[str, Any], matrix: npt.NDArray[np.float64], where: str, warnings: list[str]
) -> tuple[int, int]:
    if "image_width" in keys and "image_height" in keys:
        size = _array([keys["image_width"], keys["image_height"]], (2,), "image size", where)
    elif (raw := _first(keys, _SIZE_KEYS, where, required=False)) is not None:
        size = _array(raw, None, "image size", where).reshape(-1)
        if size.shape != (2,):
            raise CameraFileError(f"{where}: image size must be [width, height]")
    else:
        size = 2 * matrix[:2, 2]
        warnings.append(
            f"{where}: no image size in the file: assumed {size[0]:.0f}×{size[1]:.0f} (twice "
            "the principal point)"
        )
    return round(float(size[0])), round(float(size[1]))


def _array(
    value: Any, shape: tuple[int, ...] | None, what: str, where: str
) -> npt.NDArray[np.float64]:
    if isinstance(value, dict):  # an opencv-matrix
        try:
            rows, cols = int(value["rows"]), int(value["cols"])
            flat = np.asarray(value["data"], dtype=np.float64).reshape(-1)
        except (KeyError, TypeError, ValueError) as exc:
            raise CameraFileError(f"{where}: {what}: a malformed opencv-matrix ({exc})") from exc
        if flat.size != rows * cols:
            raise CameraFileError(f"{where}: {what}: {flat.size} values for a {rows}×{cols} matrix")
        array = flat.reshape(rows, cols)
    else:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CameraFileError(f"{where}: {what} is not numbers") from exc
    if shape is not None and array.shape != shape:
        if array.size == int(np.prod(shape)):
            array = array.reshape(shape)
        else:
            raise CameraFileError(f"{where}: {what} must have shape {shape}, got {array.shape}")
    if not np.isfinite(array).all():
        raise CameraFileError(f"{where}: {what} holds NaN or inf")
    return array


def _scalar(text: str) -> Any:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _flow(text: str, where: str) -> list[Any]:
    inner = text.strip()
    if not (inner.startswith("[") and inner.endswith("]")):
        raise CameraFileError(f"{where}: unbalanced [ ] in a list")
    body = inner[1:-1].strip()
    return [] if not body else [_scalar(v) for v in body.split(",") if v.strip()]


def _parse_yaml(text: str, origin: str) -> dict[str, Any]:
    """FileStorage's YAML subset (module docstring) → nested dicts and lists."""
    lines: list[tuple[int, str, int]] = []  # (indent, content, line number)
    pending = ""
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].rstrip() if not raw.lstrip().startswith("%") else ""
        if not line.strip() or line.strip() == "---":
            continue
        if pending:
            pending += " " + line.strip()
        else:
            indent, pending, start = len(line) - len(line.lstrip()), line.strip(), number
        if pending.count("[") == pending.count("]"):
            lines.append((indent, pending, start))
            pending = ""
    if pending:
        raise CameraFileError(f"{origin}: line {start}: a list that never closes")
    if not lines:
        raise CameraFileError(f"{origin}: empty file")
    root: dict[str, Any] = {}
    stack: list[tuple[int, Any]] = [(-1, root)]
    for i, (indent, content, number) in enumerate(lines):
        where = f"{origin}: line {number}"
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1]
        if content.startswith("- "):
            if not isinstance(parent, list):
                raise CameraFileError(f"{where}: a list item outside a list")
            parent.append(_scalar(content[2:]))
            continue
        match = re.fullmatch(r"([A-Za-z_][\w.-]*)\s*:\s*(.*)", content)
        if match is None or not isinstance(parent, dict):
            raise CameraFileError(f"{where}: expected 'key: value', got {content[:60]!r}")
        key, value = match.group(1), match.group(2).replace("!!opencv-matrix", "").strip()
        if value.startswith("["):
            parent[key] = _flow(value, where)
        elif value:
            parent[key] = _scalar(value)
        else:
            child_is_list = i + 1 < len(lines) and lines[i + 1][1].startswith("- ")
            child: Any = [] if child_is_list else {}
            parent[key] = child
            stack.append((indent, child))
    return root


def _parse_xml(text: str, origin: str) -> dict[str, Any]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise CameraFileError(f"{origin}: not valid XML ({exc})") from exc
    if root.tag != "opencv_storage":
        raise CameraFileError(f"{origin}: the root element is <{root.tag}>, not <opencv_storage>")
    document: dict[str, Any] = {}
    for element in root:
        if element.get("type_id") == "opencv-matrix":
            document[element.tag] = {
                child.tag: (child.text or "").split() if child.tag == "data" else child.text
                for child in element
            }
        elif len(element):
            document[element.tag] = [_scalar(child.text or "") for child in element]
        else:
            values = (element.text or "").split()
            document[element.tag] = (
                _scalar(values[0]) if len(values) == 1 else [_scalar(v) for v in values]
            )
    return document
