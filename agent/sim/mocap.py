"""Recorded human motion (CMU mocap: BVH and ASF/AMC) as Kinect v2 25-joint clips.

The loaders run forward kinematics over the file's own skeleton, then map its points onto the
Kinect v2 joint set (:class:`protocol.skeleton.JointId` order), in metres, world frame
(right-handed, +Y up, floor at y = 0). Pure numpy; no file is needed by the product itself.

Forward kinematics
------------------
BVH: the local rotation of a joint is the product of its rotation channels in the order of its
``CHANNELS`` line (``Zrotation Yrotation Xrotation`` gives R = Rz·Ry·Rx); its global rotation is
the parent's global rotation times that; a joint sits at parent position + parent R · OFFSET
(plus its own position channels, if any, added to OFFSET). ``End Site`` blocks become points
named ``<joint>.end``.

ASF/AMC: per bone C from ``axis`` (the i-th angle is about the i-th letter of the order, applied
in that order, so ``XYZ`` gives C = Rz(az)·Ry(ay)·Rx(ax)),
M = Rz(rz)·Ry(ry)·Rx(rx) from the frame's dof values (missing = 0), L = C·M·Cᵀ,
R_bone = R_parent·L, bone end = parent end + R_bone·(direction·length). The root takes its
values in its ``order`` (TX TY TZ RX RY RZ) and composes RX RY RZ in its ``axis`` order, with
``orientation`` as its C and ``position`` added to the translation. Lengths are converted with
``:units length`` (CMU: 1 unit = 1/length inch; 0.45 → 0.05644 m).

Joint mapping
-------------
ASF points are *bone ends* (``root`` is the root position); BVH points are *joint origins*
(``X.end`` is the End Site of joint X; names match case-insensitively). Both CMU layouts
describe the same body model: the BVH ``lhand`` joint sits on the wrist and ``LFingers`` one
hand bone further, like the ASF ``lwrist`` end and ``lhand`` end. Left/right are the person's
own (CMU: facing +Z, the left side is +X, which is also the Kinect world convention: left =
up × facing); the right-side joints mirror the left ones.

=============  =====================================  ===================================
Kinect v2      ASF bone ends (CMU ``02.asf``)          BVH joints (CMU cgspeed naming)
=============  =====================================  ===================================
SpineBase      ``root`` (pelvis centre)                ``Hips``
SpineMid       ½(``lowerback`` + ``upperback``):       ``Chest``: halfway along the
               halfway along the spine chain           spine chain Hips → Chest2
               root → thorax end (*derived*)
SpineShoulder  ``thorax`` (base of the neck; the       ``Chest2`` (where the neck and the
               clavicles start here)                   collars start)
Neck           ``lowerneck`` (middle of the neck)      ``Neck``
Head           ½(``upperneck`` + ``head``): middle     ½(``Head`` + ``Head.end``): middle
               of the head bone ≈ head centre          of the head bone (*derived*)
               (*derived*)
ShoulderLeft   ``lclavicle`` (upper arm start)         ``LeftShoulder``
ElbowLeft      ``lhumerus``                            ``LeftElbow``
WristLeft      ``lwrist`` (after the forearm-twist     ``LeftWrist``
               segment, where hand flexion happens)
HandLeft       ``lhand`` (finger base, ~4 cm past      ``LFingers``
               the wrist)
HandTipLeft    ``lfingers`` (end of the finger bone)   ``LFingers.end``
ThumbLeft      ``lthumb``                              ``LThumb.end``
HipLeft        ``lhipjoint`` (upper leg start)         ``LeftHip``
KneeLeft       ``lfemur``                              ``LeftKnee``
AnkleLeft      ``ltibia``                              ``LeftAnkle``
FootLeft       ``lfoot`` (toe base, ball of the foot)  ``LeftToe``
(right side)   ``r…`` bones likewise                   ``Right…`` / ``R…`` likewise
=============  =====================================  ===================================

Floor: after the mapping, the clip is shifted vertically so that the lowest Foot joint (toe
base) over the whole clip is at :data:`FOOT_JOINT_FLOOR_HEIGHT_M` (a joint centre inside the
foot, not the sole, so the soles touch y = 0). Horizontal position and heading are the file's.

Caveats: the CMU hand is coarse (wrist → "fingers" end is only ~7 cm, so HandTip lies short of
real fingertips); the SpineMid and Head points are derived, so their bones are only nearly
rigid (length CV ~0.05 %); ``centred`` clips keep their own walking path and heading.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

__all__ = [
    "ASF_RECIPE",
    "BVH_RECIPE",
    "FOOT_JOINT_FLOOR_HEIGHT_M",
    "MocapFormatError",
    "MotionClip",
    "PointTracks",
    "asf_amc_points",
    "bvh_points",
    "load_asf_amc",
    "load_bvh",
]

F64 = npt.NDArray[np.float64]

FOOT_JOINT_FLOOR_HEIGHT_M: Final = 0.04
"""Height of the lowest Foot (toe base) joint over a clip: the joint centre above the sole."""

_INCH_M: Final = 0.0254


class MocapFormatError(ValueError):
    """A mocap file is malformed or uses a feature or skeleton this loader does not support."""


# --- the clip -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MotionClip:
    """joints_m: (T, 25, 3) float32, metres, world frame (right-handed, +Y up, floor at y=0),
    Kinect v2 JointType order. fps: frames per second of the clip."""

    joints_m: npt.NDArray[np.float32]
    fps: float
    name: str

    def __post_init__(self) -> None:
        shape = self.joints_m.shape
        if len(shape) != 3 or shape[0] < 1 or shape[1:] != (JOINT_COUNT, 3):
            raise ValueError(f"joints_m must be (T >= 1, {JOINT_COUNT}, 3), got {shape}")
        if self.joints_m.dtype != np.float32:
            raise ValueError(f"joints_m must be float32, got {self.joints_m.dtype}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be finite and > 0, got {self.fps}")

    @property
    def frame_count(self) -> int:
        """Number of frames T."""
        return int(self.joints_m.shape[0])

    @property
    def duration_s(self) -> float:
        """Time of the last frame, (T - 1) / fps; 0 for a single frame."""
        return (self.frame_count - 1) / self.fps

    def at(self, t_s: float) -> F64:
        """(25, 3) float64 pose at ``t_s`` seconds after the first frame.

        Linear interpolation between the two neighbouring frames; ``t_s`` is clamped to
        [0, duration_s] (no looping).
        """
        last = self.frame_count - 1
        x = min(max(float(t_s), 0.0), self.duration_s) * self.fps
        if not math.isfinite(x):
            raise ValueError(f"t_s must be finite, got {t_s}")
        i = min(math.floor(x), last)
        w = x - i
        a: F64 = self.joints_m[i].astype(np.float64)
        if i >= last or w <= 0.0:
            return a
        b: F64 = self.joints_m[i + 1].astype(np.float64)
        out: F64 = a + (b - a) * w
        return out

    def centred(self) -> MotionClip:
        """The clip translated horizontally so the mean SpineBase x, z over it is (0, 0)."""
        mean = self.joints_m[:, JointId.SPINE_BASE, :].astype(np.float64).mean(axis=0)
        shift = np.array([mean[0], 0.0, mean[2]])
        joints = (self.joints_m.astype(np.float64) - shift).astype(np.float32)
        joints.flags.writeable = False
        return MotionClip(joints_m=joints, fps=self.fps, name=self.name)


@dataclass(frozen=True, slots=True)
class PointTracks:
    """Named points of a mocap file's own skeleton over time (forward kinematics output).

    positions: (T, P, 3) float64, in metres for ASF/AMC and in the file's units for BVH;
    parents: index of each point's parent point, -1 for roots.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    positions: F64
    fps: float
    source: str = ""
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {n.lower(): i for i, n in enumerate(self.names)})

    def point(self, name: str) -> F64:
        """(T, 3) track of the point called ``name`` (case-insensitive)."""
        try:
            index = self._index[name.lower()]
        except KeyError:
            raise MocapFormatError(
                f"{self.source}: unsupported skeleton, no point named {name!r} "
                f"(expected CMU naming; points: {', '.join(self.names)})"
            ) from None
        track: F64 = self.positions[:, index, :]
        return track


# --- rotations ----------------------------------------------------------------------------------


def _axis_rotation(axis: str, angle_rad: F64) -> F64:
    """(..., 3, 3) right-handed rotation by ``angle_rad`` (...) about ``axis`` ('x'|'y'|'z')."""
    c = np.cos(angle_rad)
    s = np.sin(angle_rad)
    out = np.zeros((*np.shape(angle_rad), 3, 3))
    a, b = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    k = 3 - a - b
    out[..., k, k] = 1.0
    out[..., a, a] = c
    out[..., a, b] = -s
    out[..., b, a] = s
    out[..., b, b] = c
    return out


def _compose(axes: Sequence[str], angles_rad: Sequence[F64]) -> F64:
    """Product R(axes[0])·R(axes[1])·… of axis rotations, broadcast over the angle arrays."""
    result: F64 | None = None
    for axis, angle in zip(axes, angles_rad, strict=True):
        rot = _axis_rotation(axis, angle)
        result = rot if result is None else result @ rot
    if result is None:
        return np.eye(3)
    return result


# --- BVH ----------------------------------------------------------------------------------------


_BVH_ROT = {"xrotation": "x", "yrotation": "y", "zrotation": "z"}
_BVH_POS = {"xposition": 0, "yposition": 1, "zposition": 2}


@dataclass(slots=True)
class _BvhNode:
    name: str
    parent: int
    offset: F64
    channels: list[str]
    line: int


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


class _BvhHierarchyParser:
    def __init__(self, path: Path, lines: Sequence[str]) -> None:
        self.path = path
        self.tokens: list[tuple[str, int]] = [
            (tok, lineno) for lineno, line in enumerate(lines, 1) for tok in line.split()
        ]
        self.pos = 0
        self.nodes: list[_BvhNode] = []

    def where(self) -> str:
        line = self.tokens[self.pos][1] if self.pos < len(self.tokens) else "end of hierarchy"
        return f"{self.path}:{line}"

    def peek(self) -> str | None:
        return self.tokens[self.pos][0] if self.pos < len(self.tokens) else None

    def take(self, what: str) -> str:
        if self.pos >= len(self.tokens):
            raise MocapFormatError(f"{self.path}: hierarchy ends early, expected {what}")
        tok = self.tokens[self.pos][0]
        self.pos += 1
        return tok

    def expect(self, keyword: str) -> None:
        where = self.where()
        tok = self.take(repr(keyword))
        if tok.upper() != keyword.upper():
            raise MocapFormatError(f"{where}: expected {keyword!r}, got {tok!r}")

    def parse(self) -> list[_BvhNode]:
        self.expect("HIERARCHY")
        while self.peek() is not None:
            tok = self.peek()
            if tok is None or tok.upper() != "ROOT":
                raise MocapFormatError(f"{self.where()}: expected 'ROOT' or 'MOTION', got {tok!r}")
            self.pos += 1
            self.parse_joint(parent=-1)
        if not self.nodes:
            raise MocapFormatError(f"{self.path}: no ROOT joint in the hierarchy")
        return self.nodes

    def parse_joint(self, parent: int, end_site_of: str | None = None) -> None:
        line = self.tokens[self.pos - 1][1]
        if end_site_of is None:
            name_parts = []
            while self.peek() not in (None, "{") and self.tokens[self.pos][1] == line:
                name_parts.append(self.take("a joint name"))
            if not name_parts:
                raise MocapFormatError(f"{self.path}:{line}: joint without a name")
            name = " ".join(name_parts)
        else:
            name = f"{end_site_of}.end"
        self.expect("{")
        self.expect("OFFSET")
        where = self.where()
        offset = np.array([_float(self.take("OFFSET values"), where) for _ in range(3)])
        channels: list[str] = []
        if end_site_of is None:
            self.expect("CHANNELS")
            where = self.where()
            count_tok = self.take("the channel count")
            if not count_tok.isdigit():
                raise MocapFormatError(f"{where}: bad channel count {count_tok!r}")
            for _ in range(int(count_tok)):
                ch_where = self.where()
                ch = self.take("a channel name")
                if ch.lower() not in _BVH_ROT and ch.lower() not in _BVH_POS:
                    raise MocapFormatError(f"{ch_where}: unsupported channel {ch!r} of {name!r}")
                channels.append(ch.lower())
        index = len(self.nodes)
        self.nodes.append(_BvhNode(name, parent, offset, channels, line))
        while True:
            where = self.where()
            tok = self.take("'}'")
            upper = tok.upper()
            if tok == "}":
                return
            if end_site_of is not None:
                raise MocapFormatError(f"{where}: expected '}}' closing End Site, got {tok!r}")
            if upper == "JOINT":
                self.parse_joint(parent=index)
            elif upper == "END":
                self.expect("Site")
                self.parse_joint(parent=index, end_site_of=name)
            else:
                raise MocapFormatError(
                    f"{where}: expected 'JOINT', 'End Site' or '}}' in {name!r}, got {tok!r}"
                )


_HEADER_RE = re.compile(r"^\s*(frames|frame\s+time)\s*:\s*(\S+)\s*$", re.IGNORECASE)


def _snap_fps(frame_time_token: str, where: str) -> float:
    """fps from a printed frame time; 0.008333 is 1/120 printed to 6 decimals, so 120 exactly."""
    frame_time = _float(frame_time_token, where)
    if frame_time <= 0:
        raise MocapFormatError(f"{where}: Frame Time must be > 0, got {frame_time_token!r}")
    fps = 1.0 / frame_time
    whole = round(fps)
    decimals = len(frame_time_token.split(".")[1]) if "." in frame_time_token else 0
    precise = "e" not in frame_time_token.lower() and 10.0**-decimals < 1e-3 * frame_time
    if precise and whole > 0 and round(1.0 / whole, decimals) == round(frame_time, decimals):
        return float(whole)
    return fps


def bvh_points(path: str | os.PathLike[str]) -> PointTracks:
    """Forward kinematics of a BVH file: every joint and End Site over time, file units.

    Raises:
        MocapFormatError: malformed hierarchy or motion data, or unsupported channels.
    """
    path = Path(path)
    lines = _read_text(path).splitlines()
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise MocapFormatError(f"{path}: no MOTION section; not a BVH file?")
    nodes = _BvhHierarchyParser(path, lines[:motion_at]).parse()

    frames: int | None = None
    frame_time_token: str | None = None
    cursor = motion_at + 1
    while cursor < len(lines) and (frames is None or frame_time_token is None):
        text = lines[cursor]
        cursor += 1
        if not text.strip():
            continue
        m = _HEADER_RE.match(text)
        if m is None:
            raise MocapFormatError(
                f"{path}:{cursor}: expected 'Frames: N' and 'Frame Time: dt', got {text.strip()!r}"
            )
        if m.group(1).lower() == "frames":
            if not m.group(2).isdigit() or int(m.group(2)) < 1:
                raise MocapFormatError(f"{path}:{cursor}: bad frame count {m.group(2)!r}")
            frames = int(m.group(2))
        else:
            frame_time_token = m.group(2)
    if frames is None or frame_time_token is None:
        raise MocapFormatError(f"{path}: MOTION lacks 'Frames:' or 'Frame Time:'")
    fps = _snap_fps(frame_time_token, f"{path}: Frame Time")

    channel_count = sum(len(n.channels) for n in nodes)
    if channel_count == 0:
        raise MocapFormatError(f"{path}: the hierarchy has no channels")
    rows: list[list[float]] = []
    for lineno in range(cursor + 1, len(lines) + 1):
        tokens = lines[lineno - 1].split()
        if not tokens:
            continue
        if len(tokens) != channel_count:
            raise MocapFormatError(
                f"{path}:{lineno}: frame {len(rows)} has {len(tokens)} values, "
                f"expected {channel_count} (one per channel)"
            )
        rows.append([_float(t, f"{path}:{lineno}") for t in tokens])
    if len(rows) != frames:
        raise MocapFormatError(f"{path}: header says {frames} frames, found {len(rows)}")
    data = np.asarray(rows, dtype=np.float64)

    t = data.shape[0]
    positions = np.zeros((t, len(nodes), 3))
    rotations = np.zeros((t, len(nodes), 3, 3))
    column = 0
    for j, node in enumerate(nodes):
        translation = np.broadcast_to(node.offset, (t, 3)).copy()
        rot_axes: list[str] = []
        rot_angles: list[F64] = []
        for ch in node.channels:
            if ch in _BVH_POS:
                translation[:, _BVH_POS[ch]] += data[:, column]
            else:
                rot_axes.append(_BVH_ROT[ch])
                rot_angles.append(np.deg2rad(data[:, column]))
            column += 1
        local = (
            _compose(rot_axes, rot_angles) if rot_axes else np.broadcast_to(np.eye(3), (t, 3, 3))
        )
        if node.parent < 0:
            positions[:, j] = translation
            rotations[:, j] = local
        else:
            parent_r = rotations[:, node.parent]
            positions[:, j] = positions[:, node.parent] + np.einsum(
                "tij,tj->ti", parent_r, translation
            )
            rotations[:, j] = parent_r @ local
    return PointTracks(
        names=tuple(n.name for n in nodes),
        parents=tuple(n.parent for n in nodes),
        positions=positions,
        fps=fps,
        source=str(path),
    )


# --- ASF/AMC ------------------------------------------------------------------------------------


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
        elif section == ":root":
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
            elif key == "name":
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
    parented = [c for kids in asf.children.values() for c in kids]
    duplicates = sorted({c for c in parented if parented.count(c) > 1})
    if duplicates:
        raise MocapFormatError(f"{path}: bones with several parents: {duplicates}")
    reachable = _asf_order(asf)
    missing = sorted(set(asf.bones) - set(reachable))
    if missing:
        raise MocapFormatError(f"{path}: bones not connected to root in :hierarchy: {missing}")
    return asf


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
    return _compose([a for a, _ in pairs], [np.array(v * to_rad) for _, v in pairs])


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
    m_root = _compose(axes, [channel.get(f"r{a}", zero) * amc_angle for a in axes])
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
        m = _compose("zyx", [angle.get(f"r{a}", zero) for a in "zyx"])
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


# --- mapping onto Kinect v2 ---------------------------------------------------------------------

_Recipe = Mapping[JointId, tuple[tuple[str, float], ...]]

J = JointId


def _sided(
    left: Mapping[JointId, tuple[tuple[str, float], ...]], rename: Mapping[str, str]
) -> dict[JointId, tuple[tuple[str, float], ...]]:
    """Left-side recipe plus its mirror, renaming points through ``rename``."""
    right_of = {
        J.SHOULDER_LEFT: J.SHOULDER_RIGHT,
        J.ELBOW_LEFT: J.ELBOW_RIGHT,
        J.WRIST_LEFT: J.WRIST_RIGHT,
        J.HAND_LEFT: J.HAND_RIGHT,
        J.HAND_TIP_LEFT: J.HAND_TIP_RIGHT,
        J.THUMB_LEFT: J.THUMB_RIGHT,
        J.HIP_LEFT: J.HIP_RIGHT,
        J.KNEE_LEFT: J.KNEE_RIGHT,
        J.ANKLE_LEFT: J.ANKLE_RIGHT,
        J.FOOT_LEFT: J.FOOT_RIGHT,
    }
    out = dict(left)
    for joint, terms in left.items():
        out[right_of[joint]] = tuple((rename[name], w) for name, w in terms)
    return out


_ASF_LEFT: Final = {
    J.SHOULDER_LEFT: (("lclavicle", 1.0),),
    J.ELBOW_LEFT: (("lhumerus", 1.0),),
    J.WRIST_LEFT: (("lwrist", 1.0),),
    J.HAND_LEFT: (("lhand", 1.0),),
    J.HAND_TIP_LEFT: (("lfingers", 1.0),),
    J.THUMB_LEFT: (("lthumb", 1.0),),
    J.HIP_LEFT: (("lhipjoint", 1.0),),
    J.KNEE_LEFT: (("lfemur", 1.0),),
    J.ANKLE_LEFT: (("ltibia", 1.0),),
    J.FOOT_LEFT: (("lfoot", 1.0),),
}
ASF_RECIPE: Final[_Recipe] = MappingProxyType(
    {
        J.SPINE_BASE: (("root", 1.0),),
        J.SPINE_MID: (("lowerback", 0.5), ("upperback", 0.5)),
        J.SPINE_SHOULDER: (("thorax", 1.0),),
        J.NECK: (("lowerneck", 1.0),),
        J.HEAD: (("upperneck", 0.5), ("head", 0.5)),
        **_sided(_ASF_LEFT, {n: "r" + n[1:] for terms in _ASF_LEFT.values() for n, _ in terms}),
    }
)
"""Kinect v2 joint ← weighted sum of ASF bone ends (``root`` = root position)."""

_BVH_LEFT: Final = {
    J.SHOULDER_LEFT: (("LeftShoulder", 1.0),),
    J.ELBOW_LEFT: (("LeftElbow", 1.0),),
    J.WRIST_LEFT: (("LeftWrist", 1.0),),
    J.HAND_LEFT: (("LFingers", 1.0),),
    J.HAND_TIP_LEFT: (("LFingers.end", 1.0),),
    J.THUMB_LEFT: (("LThumb.end", 1.0),),
    J.HIP_LEFT: (("LeftHip", 1.0),),
    J.KNEE_LEFT: (("LeftKnee", 1.0),),
    J.ANKLE_LEFT: (("LeftAnkle", 1.0),),
    J.FOOT_LEFT: (("LeftToe", 1.0),),
}
BVH_RECIPE: Final[_Recipe] = MappingProxyType(
    {
        J.SPINE_BASE: (("Hips", 1.0),),
        J.SPINE_MID: (("Chest", 1.0),),
        J.SPINE_SHOULDER: (("Chest2", 1.0),),
        J.NECK: (("Neck", 1.0),),
        J.HEAD: (("Head", 0.5), ("Head.end", 0.5)),
        **_sided(
            _BVH_LEFT,
            {
                n: ("Right" + n[4:] if n.startswith("Left") else "R" + n[1:])
                for terms in _BVH_LEFT.values()
                for n, _ in terms
            },
        ),
    }
)
"""Kinect v2 joint ← weighted sum of BVH joint origins (``X.end`` = End Site of X)."""


def _to_kinect(points: PointTracks, recipe: _Recipe) -> F64:
    missing = [j.name for j in JointId if j not in recipe]
    if missing:
        raise AssertionError(f"recipe lacks {missing}")  # a bug here, not in the file
    t = points.positions.shape[0]
    joints = np.zeros((t, JOINT_COUNT, 3))
    for joint, terms in recipe.items():
        for name, weight in terms:
            joints[:, joint] += weight * points.point(name)
    return joints


def _on_floor(joints: F64) -> F64:
    feet = joints[:, [J.FOOT_LEFT, J.FOOT_RIGHT], 1]
    shifted: F64 = joints.copy()
    shifted[..., 1] += FOOT_JOINT_FLOOR_HEIGHT_M - float(feet.min())
    return shifted


def _clip(points: PointTracks, recipe: _Recipe, units_to_m: float, name: str) -> MotionClip:
    joints = _to_kinect(points, recipe) * units_to_m
    if not np.all(np.isfinite(joints)):
        raise MocapFormatError(f"{points.source}: forward kinematics gave non-finite positions")
    joints_m = _on_floor(joints).astype(np.float32)
    joints_m.flags.writeable = False  # clips are shared between performers
    return MotionClip(joints_m=joints_m, fps=points.fps, name=name)


def load_bvh(path: str | os.PathLike[str], *, units_to_m: float = 1.0) -> MotionClip:
    """Load a CMU BVH (cgspeed joint naming, e.g. ``scaled_131_01.bvh``) as a Kinect v2 clip.

    Args:
        path: the ``.bvh`` file, +Y up.
        units_to_m: metres per file length unit (1.0 for files already in metres).

    Raises:
        MocapFormatError: malformed file, unsupported channels, or a skeleton without the
            CMU joints the mapping needs.
    """
    if not (math.isfinite(units_to_m) and units_to_m > 0):
        raise ValueError(f"units_to_m must be finite and > 0, got {units_to_m}")
    return _clip(bvh_points(path), BVH_RECIPE, units_to_m, Path(path).stem)


def load_asf_amc(
    asf_path: str | os.PathLike[str], amc_path: str | os.PathLike[str], fps: float = 120.0
) -> MotionClip:
    """Load a CMU ASF skeleton + AMC motion (e.g. ``02.asf`` + ``02_01.amc``) as a Kinect v2 clip.

    Lengths use the ASF ``:units length`` (1 unit = 1/length inch); AMC files carry no frame
    rate, so ``fps`` gives it (CMU: 120).

    Raises:
        MocapFormatError: malformed or unsupported ASF or AMC content, or a skeleton without
            the CMU bones the mapping needs.
    """
    return _clip(asf_amc_points(asf_path, amc_path, fps), ASF_RECIPE, 1.0, Path(amc_path).stem)
