"""CMU ASF skeletons driven by AMC motions: the reader and its forward kinematics.

Per bone, C from ``axis`` (the i-th angle is about the i-th letter of the order, applied in that
order, so ``XYZ`` gives C = Rz(az)·Ry(ay)·Rx(ax)), M = Rz(rz)·Ry(ry)·Rx(rx) from the frame's dof
values (missing = 0), L = C·M·Cᵀ, R_bone = R_parent·L, bone end = parent end +
R_bone·(direction·length). The root takes its values in its ``order`` (TX TY TZ RX RY RZ) and
composes RX RY RZ in its ``axis`` order, with ``orientation`` as its C and ``position`` added to
the translation. Lengths are converted with ``:units length`` (CMU: 1 unit = 1/length inch;
0.45 → 0.05644 m).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.clip import MocapFormatError, PointTracks
from skelfuse.protocol.transform import compose_rotations

F64 = npt.NDArray[np.float64]

_INCH_M: Final = 0.0254


def _read_text(path: Path) -> str:
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MocapFormatError(f"{path}: not a text file ({exc})") from None


def _float(token: str, where: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise MocapFormatError(f"{where}: expected a number, got {token!r}") from None
    if not math.isfinite(value):
        raise MocapFormatError(f"{where}: non-finite number {token!r}")
    return value


@dataclass(slots=True)
class _AsfBone:
    name: str
    line: int
    direction: F64 | None = None
    length: float | None = None
    axis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis_order: str = "xyz"
    dof: tuple[str, ...] = ()


@dataclass(slots=True)
class _Asf:
    length_m_per_unit: float = _INCH_M
    angles_in_degrees: bool = True
    root_order: tuple[str, ...] = ("tx", "ty", "tz", "rx", "ry", "rz")
    root_axis: str = "xyz"
    root_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    root_orientation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bones: dict[str, _AsfBone] = field(default_factory=dict)
    children: dict[str, list[str]] = field(default_factory=dict)


_ROOT_CHANNELS: Final = frozenset({"tx", "ty", "tz", "rx", "ry", "rz"})


def _axis_order(token: str, where: str) -> str:
    order = token.lower()
    if sorted(order) != ["x", "y", "z"]:
        raise MocapFormatError(f"{where}: axis order must be a permutation of XYZ, got {token!r}")
    return order


def _three(tokens: Sequence[str], where: str) -> tuple[float, float, float]:
    if len(tokens) < 3:
        raise MocapFormatError(f"{where}: expected 3 numbers, got {' '.join(tokens)!r}")
    x, y, z = (_float(tok, where) for tok in tokens[:3])
    return (x, y, z)


def _parse_asf(path: Path) -> _Asf:
    asf = _Asf()
    section = ""
    bone: _AsfBone | None = None
    in_hierarchy_block = False
    seen_bonedata = seen_hierarchy = False
    for lineno, raw in enumerate(_read_text(path).splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"{path}:{lineno}"
        tokens = line.split()
        key = tokens[0].lower()
        if key.startswith(":"):
            section = key
            seen_bonedata |= section == ":bonedata"
            seen_hierarchy |= section == ":hierarchy"
            if bone is not None:
                raise MocapFormatError(f"{where}: bone {bone.name!r} has no 'end'")
            continue
        args = tokens[1:]
        if section == ":units":
            _units_line(asf, key, args, where)
        elif section == ":root":
            _root_line(asf, key, args, where)
        elif section == ":bonedata":
            if key == "begin":
                bone = _AsfBone(name="", line=lineno)
            elif key == "end":
                if bone is None:
                    raise MocapFormatError(f"{where}: 'end' without 'begin'")
                _check_bone(path, bone)
                if bone.name in asf.bones or bone.name == "root":
                    raise MocapFormatError(f"{where}: duplicate bone {bone.name!r}")
                asf.bones[bone.name] = bone
                bone = None
            elif bone is None:
                raise MocapFormatError(f"{where}: {tokens[0]!r} outside a begin/end bone block")
            else:
                _bone_line(bone, key, args, where)
        elif section == ":hierarchy":
            if key == "begin":
                in_hierarchy_block = True
            elif key == "end":
                in_hierarchy_block = False
            elif in_hierarchy_block:
                parent = tokens[0]
                if parent != "root" and parent not in asf.bones:
                    raise MocapFormatError(f"{where}: unknown parent bone {parent!r}")
                for child in args:
                    if child not in asf.bones:
                        raise MocapFormatError(f"{where}: unknown bone {child!r}")
                asf.children.setdefault(parent, []).extend(args)
    if bone is not None:
        raise MocapFormatError(f"{path}: bone {bone.name!r} has no 'end'")
    if not seen_bonedata or not seen_hierarchy:
        raise MocapFormatError(f"{path}: missing :bonedata or :hierarchy; not an ASF file?")
    _check_hierarchy(path, asf)
    return asf


def _units_line(asf: _Asf, key: str, args: list[str], where: str) -> None:
    """A line of ``:units``: the length unit (``asf.length_m_per_unit``) or the angle unit."""
    if key == "length":
        scale = _float(args[0] if args else "", where)
        if scale <= 0:
            raise MocapFormatError(f"{where}: length unit must be > 0")
        asf.length_m_per_unit = _INCH_M / scale
    elif key == "angle":
        unit = args[0].lower() if args else ""
        if unit not in ("deg", "rad"):
            raise MocapFormatError(f"{where}: angle unit must be deg or rad, got {unit!r}")
        asf.angles_in_degrees = unit == "deg"


def _root_line(asf: _Asf, key: str, args: list[str], where: str) -> None:
    """A line of ``:root``: its channel order, axis order, position or orientation."""
    if key == "order":
        order = tuple(a.lower() for a in args)
        if not set(order) <= _ROOT_CHANNELS or len(set(order)) != len(order):
            raise MocapFormatError(f"{where}: unsupported root order {' '.join(args)!r}")
        asf.root_order = order
    elif key == "axis":
        asf.root_axis = _axis_order(args[0] if args else "", where)
    elif key == "position":
        asf.root_position = _three(args, where)
    elif key == "orientation":
        asf.root_orientation = _three(args, where)


def _bone_line(bone: _AsfBone, key: str, args: list[str], where: str) -> None:
    """A line inside a ``:bonedata`` begin/end block: the bone's name, direction, length,
    axis or rotation channels (``dof``)."""
    if key == "name":
        bone.name = args[0] if args else ""
    elif key == "direction":
        bone.direction = np.array(_three(args, where))
    elif key == "length":
        bone.length = _float(args[0] if args else "", where)
    elif key == "axis":
        bone.axis = _three(args, where)
        bone.axis_order = _axis_order(args[3] if len(args) > 3 else "XYZ", where)
    elif key == "dof":
        dof = tuple(a.lower() for a in args)
        bad = [d for d in dof if d not in ("rx", "ry", "rz")]
        if bad or len(set(dof)) != len(dof):
            raise MocapFormatError(
                f"{where}: unsupported dof {' '.join(args)!r} "
                "(only rotations rx ry rz, each at most once)"
            )
        bone.dof = dof
    # id, limits and their continuation lines, bodymass, cofmass: not needed


def _check_hierarchy(path: Path, asf: _Asf) -> None:
    """Every bone has one parent and hangs from the root."""
    parented = [c for kids in asf.children.values() for c in kids]
    duplicates = sorted({c for c in parented if parented.count(c) > 1})
    if duplicates:
        raise MocapFormatError(f"{path}: bones with several parents: {duplicates}")
    reachable = _asf_order(asf)
    missing = sorted(set(asf.bones) - set(reachable))
    if missing:
        raise MocapFormatError(f"{path}: bones not connected to root in :hierarchy: {missing}")


def _check_bone(path: Path, bone: _AsfBone) -> None:
    where = f"{path}:{bone.line}"
    if not bone.name:
        raise MocapFormatError(f"{where}: bone without a name")
    if bone.direction is None or bone.length is None:
        raise MocapFormatError(f"{where}: bone {bone.name!r} lacks a direction or length")
    norm = float(np.linalg.norm(bone.direction))
    if bone.length < 0 or (bone.length > 0 and norm < 1e-9):
        raise MocapFormatError(f"{where}: bone {bone.name!r} has a bad direction or length")
    if norm > 0:
        bone.direction = bone.direction / norm


def _asf_order(asf: _Asf) -> list[str]:
    """Bones parents-first (breadth-first from root)."""
    order: list[str] = []
    queue = list(asf.children.get("root", []))
    while queue:
        name = queue.pop(0)
        order.append(name)
        queue.extend(asf.children.get(name, []))
    return order


def _parse_amc(path: Path, asf: _Asf) -> tuple[dict[str, F64], bool]:
    """Per bone (and 'root') a (T, len(dof)) array of raw values; and whether in degrees."""
    degrees = asf.angles_in_degrees
    frames: list[dict[str, list[float]]] = []
    last_number: int | None = None
    for lineno, raw in enumerate(_read_text(path).splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{path}:{lineno}"
        if line.startswith(":"):
            if line.upper().startswith(":RADIANS"):
                degrees = False
            elif line.upper().startswith(":DEGREES"):
                degrees = True
            continue
        tokens = line.split()
        if len(tokens) == 1 and tokens[0].lstrip("-").isdigit():
            number = int(tokens[0])
            if last_number is not None and number != last_number + 1:
                raise MocapFormatError(
                    f"{where}: frame {number} follows frame {last_number}; frames must be "
                    "numbered consecutively"
                )
            last_number = number
            frames.append({})
            continue
        if not frames:
            raise MocapFormatError(f"{where}: bone values before the first frame number")
        name = tokens[0]
        if name == "root":
            expected = len(asf.root_order)
        elif name in asf.bones:
            expected = len(asf.bones[name].dof)
        else:
            raise MocapFormatError(f"{where}: bone {name!r} is not in the ASF skeleton")
        if len(tokens) - 1 != expected:
            raise MocapFormatError(
                f"{where}: {name!r} has {len(tokens) - 1} values, expected {expected}"
            )
        if name in frames[-1]:
            raise MocapFormatError(f"{where}: {name!r} given twice in frame {last_number}")
        frames[-1][name] = [_float(tok, where) for tok in tokens[1:]]
    if not frames:
        raise MocapFormatError(f"{path}: no frames; not an AMC file?")
    for i, frame in enumerate(frames):
        if "root" not in frame:
            raise MocapFormatError(f"{path}: frame {i} (counting from 0) has no root values")
    values: dict[str, F64] = {}
    widths = {"root": len(asf.root_order)} | {n: len(b.dof) for n, b in asf.bones.items()}
    for name, width in widths.items():
        values[name] = np.array(
            [frame.get(name, [0.0] * width) for frame in frames], dtype=np.float64
        ).reshape(len(frames), width)
    return values, degrees


def _fixed_euler(angles: Sequence[float], order: str, to_rad: float) -> F64:
    """ASF ``axis``/``orientation``: ``angles[i]`` about axis ``order[i]``, applied in that
    order, so "XYZ" gives Rz·Ry·Rx."""
    pairs = list(zip(order, angles, strict=True))[::-1]
    return compose_rotations([a for a, _ in pairs], [np.array(v * to_rad) for _, v in pairs])


def asf_amc_points(
    asf_path: str | os.PathLike[str], amc_path: str | os.PathLike[str], fps: float = 120.0
) -> PointTracks:
    """Forward kinematics of a CMU ASF skeleton driven by an AMC motion: every bone end over
    time, in metres, plus the ``root`` point.

    Raises:
        MocapFormatError: malformed or unsupported ASF or AMC content.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be finite and > 0, got {fps}")
    asf_file, amc_file = Path(asf_path), Path(amc_path)
    asf = _parse_asf(asf_file)
    values, amc_degrees = _parse_amc(amc_file, asf)
    scale = asf.length_m_per_unit
    asf_angle = math.radians(1.0) if asf.angles_in_degrees else 1.0
    amc_angle = math.radians(1.0) if amc_degrees else 1.0

    root = values["root"]
    t = root.shape[0]
    channel = {name: root[:, i] for i, name in enumerate(asf.root_order)}
    zero = np.zeros(t)
    translation = np.stack([channel.get(c, zero) for c in ("tx", "ty", "tz")], axis=-1)
    root_pos = (np.asarray(asf.root_position) + translation) * scale
    # An axis order "XYZ" means X is applied first: R = Rz·Ry·Rx.
    axes = asf.root_axis[::-1]
    m_root = compose_rotations(axes, [channel.get(f"r{a}", zero) * amc_angle for a in axes])
    c_root = _fixed_euler(asf.root_orientation, asf.root_axis, asf_angle)
    root_rot = c_root @ m_root @ c_root.T

    names = ["root"]
    parents = [-1]
    index = {"root": 0}
    ends: list[F64] = [root_pos]
    rots: list[F64] = [root_rot]
    parent_of = {child: parent for parent, kids in asf.children.items() for child in kids}
    for name in _asf_order(asf):
        bone = asf.bones[name]
        p = index[parent_of[name]]
        c = _fixed_euler(bone.axis, bone.axis_order, asf_angle)
        dof_values = values[name]
        angle = {d: dof_values[:, i] * amc_angle for i, d in enumerate(bone.dof)}
        m = compose_rotations("zyx", [angle.get(f"r{a}", zero) for a in "zyx"])
        local = c @ m @ c.T
        rot = rots[p] @ local
        # both checked by _check_bone
        assert bone.direction is not None
        assert bone.length is not None
        vector = bone.direction * (bone.length * scale)
        ends.append(ends[p] + rot @ vector)
        rots.append(rot)
        index[name] = len(names)
        names.append(name)
        parents.append(p)
    return PointTracks(
        names=tuple(names),
        parents=tuple(parents),
        positions=np.stack(ends, axis=1),
        fps=float(fps),
        source=f"{asf_file} + {amc_file}",
    )
