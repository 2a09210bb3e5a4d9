"""BVH (Biovision Hierarchy) motion files: the one reader, writer and forward kinematics.

The simulator reads CMU clips with it (``agent.sim.mocap``); the exporter writes fused takes
with it and reads them back to check the round trip (``recording.export_bvh``).

Model: a :class:`Bvh` is its joints in file order (depth-first, every parent before its
children) and a (T, channels) motion table whose columns are the joints' channels in that order.
``End Site`` blocks are joints named ``<joint>.end`` with ``end_site=True`` and no channels.
Channel names are kept as BVH spells them (``Xposition``, ``Zrotation``), whatever their case in
the file.

Forward kinematics: the local rotation of a joint is the product of its rotation channels in
the order of its ``CHANNELS`` line (``Zrotation Yrotation Xrotation`` gives R = Rz·Ry·Rx, angles
in degrees); its global rotation is the parent's global rotation times that; a joint sits at
parent position + parent R · (its local translation). The local translation is OFFSET, except
that a position channel *replaces* OFFSET's component on its axis: the BVH convention, as
Blender's importer and bvhio read it (a joint with ``Xposition Yposition Zposition`` sits at its
channels' values from the parent whatever its OFFSET says; OFFSET is then its rest pose). Where
a joint has only some position channels, bvhio keeps OFFSET on the other axes, as here, and
Blender takes 0 there; files with all three (ours, CMU's roots) read the same everywhere.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.transform import compose_rotations

F64 = npt.NDArray[np.float64]

_ROTATION_AXIS: Final = {"xrotation": "x", "yrotation": "y", "zrotation": "z"}
_POSITION_AXIS: Final = {"xposition": 0, "yposition": 1, "zposition": 2}
_HEADER_RE: Final = re.compile(r"^\s*(frames|frame\s+time)\s*:\s*(\S+)\s*$", re.IGNORECASE)


class BvhError(ValueError):
    """A BVH file that is malformed or uses an unsupported channel; the message gives the line."""


@dataclass(frozen=True, slots=True)
class BvhJoint:
    """One joint (or End Site) of the hierarchy.

    parent: index of the parent joint in :attr:`Bvh.joints`, -1 for a root.
    offset: (3,) float64 from the parent joint, file units, in the parent's frame.
    channels: ``Xposition`` ... ``Zrotation``, in file order (none for an End Site).
    """

    name: str
    parent: int
    offset: F64
    channels: tuple[str, ...] = ()
    end_site: bool = False


@dataclass(frozen=True, slots=True)
class Bvh:
    """A whole BVH file.

    joints: file order, depth-first. motion: (T, channels) float64, one row per frame, the
    joints' channels in file order (positions in file units, rotations in degrees).
    fps: 1 / frame_time_s, or the whole rate the printed frame time was rounded from (a file
    that says ``0.008333`` is at 120 fps exactly).
    """

    joints: tuple[BvhJoint, ...]
    frame_time_s: float
    fps: float
    motion: F64

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (exact spelling).

        Raises:
            KeyError: no such joint.
        """
        for i, joint in enumerate(self.joints):
            if joint.name == name:
                return i
        raise KeyError(name)


# --- reading ------------------------------------------------------------------------------------


def read_bvh(path: str | os.PathLike[str]) -> Bvh:
    """Read a ``.bvh`` file.

    Raises:
        BvhError: not a text file, malformed hierarchy or motion, or an unsupported channel.
        OSError: the file cannot be read.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BvhError(f"{path}: not a text file ({exc})") from None
    return parse_bvh(text, str(path))


def parse_bvh(text: str, source: str = "<bvh>") -> Bvh:
    """Parse BVH text; ``source`` names it in error messages (``source:line: ...``).

    Raises:
        BvhError: malformed hierarchy or motion, or an unsupported channel.
    """
    lines = text.splitlines()
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise BvhError(f"{source}: no MOTION section; not a BVH file?")
    joints = _HierarchyParser(source, lines[:motion_at]).parse()

    frames: int | None = None
    frame_time_token: str | None = None
    cursor = motion_at + 1
    while cursor < len(lines) and (frames is None or frame_time_token is None):
        line = lines[cursor]
        cursor += 1
        if not line.strip():
            continue
        m = _HEADER_RE.match(line)
        if m is None:
            raise BvhError(
                f"{source}:{cursor}: expected 'Frames: N' and 'Frame Time: dt', got "
                f"{line.strip()!r}"
            )
        if m.group(1).lower() == "frames":
            if not m.group(2).isdigit() or int(m.group(2)) < 1:
                raise BvhError(f"{source}:{cursor}: bad frame count {m.group(2)!r}")
            frames = int(m.group(2))
        else:
            frame_time_token = m.group(2)
    if frames is None or frame_time_token is None:
        raise BvhError(f"{source}: MOTION lacks 'Frames:' or 'Frame Time:'")
    frame_time = _float(frame_time_token, f"{source}: Frame Time")
    fps = _snap_fps(frame_time, frame_time_token, f"{source}: Frame Time")

    channel_count = sum(len(j.channels) for j in joints)
    if channel_count == 0:
        raise BvhError(f"{source}: the hierarchy has no channels")
    rows: list[list[float]] = []
    for lineno in range(cursor + 1, len(lines) + 1):
        tokens = lines[lineno - 1].split()
        if not tokens:
            continue
        if len(tokens) != channel_count:
            raise BvhError(
                f"{source}:{lineno}: frame {len(rows)} has {len(tokens)} values, "
                f"expected {channel_count} (one per channel)"
            )
        rows.append([_float(t, f"{source}:{lineno}") for t in tokens])
    if len(rows) != frames:
        raise BvhError(f"{source}: header says {frames} frames, found {len(rows)}")
    return Bvh(tuple(joints), frame_time, fps, np.asarray(rows, dtype=np.float64))


def _float(token: str, where: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise BvhError(f"{where}: expected a number, got {token!r}") from None
    if not math.isfinite(value):
        raise BvhError(f"{where}: non-finite number {token!r}")
    return value


def _snap_fps(frame_time: float, token: str, where: str) -> float:
    """fps from a printed frame time; 0.008333 is 1/120 printed to 6 decimals, so 120 exactly."""
    if frame_time <= 0:
        raise BvhError(f"{where}: Frame Time must be > 0, got {token!r}")
    fps = 1.0 / frame_time
    whole = round(fps)
    decimals = len(token.split(".")[1]) if "." in token else 0
    precise = "e" not in token.lower() and 10.0**-decimals < 1e-3 * frame_time
    if precise and whole > 0 and round(1.0 / whole, decimals) == round(frame_time, decimals):
        return float(whole)
    return fps


class _HierarchyParser:
    """Recursive descent over the HIERARCHY tokens, each token kept with its line number."""

    def __init__(self, source: str, lines: Sequence[str]) -> None:
        self.source = source
        self.tokens: list[tuple[str, int]] = [
            (tok, lineno) for lineno, line in enumerate(lines, 1) for tok in line.split()
        ]
        self.pos = 0
        self.joints: list[BvhJoint] = []

    def where(self) -> str:
        line = self.tokens[self.pos][1] if self.pos < len(self.tokens) else "end of hierarchy"
        return f"{self.source}:{line}"

    def peek(self) -> str | None:
        return self.tokens[self.pos][0] if self.pos < len(self.tokens) else None

    def take(self, what: str) -> str:
        if self.pos >= len(self.tokens):
            raise BvhError(f"{self.source}: hierarchy ends early, expected {what}")
        tok = self.tokens[self.pos][0]
        self.pos += 1
        return tok

    def expect(self, keyword: str) -> None:
        where = self.where()
        tok = self.take(repr(keyword))
        if tok.upper() != keyword.upper():
            raise BvhError(f"{where}: expected {keyword!r}, got {tok!r}")

    def parse(self) -> list[BvhJoint]:
        self.expect("HIERARCHY")
        while self.peek() is not None:
            tok = self.peek()
            if tok is None or tok.upper() != "ROOT":
                raise BvhError(f"{self.where()}: expected 'ROOT' or 'MOTION', got {tok!r}")
            self.pos += 1
            self.parse_joint(parent=-1)
        if not self.joints:
            raise BvhError(f"{self.source}: no ROOT joint in the hierarchy")
        return self.joints

    def parse_joint(self, parent: int, end_site_of: str | None = None) -> None:
        line = self.tokens[self.pos - 1][1]
        if end_site_of is None:
            name_parts = []
            while self.peek() not in (None, "{") and self.tokens[self.pos][1] == line:
                name_parts.append(self.take("a joint name"))
            if not name_parts:
                raise BvhError(f"{self.source}:{line}: joint without a name")
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
                raise BvhError(f"{where}: bad channel count {count_tok!r}")
            for _ in range(int(count_tok)):
                ch_where = self.where()
                ch = self.take("a channel name")
                if ch.lower() not in _ROTATION_AXIS and ch.lower() not in _POSITION_AXIS:
                    raise BvhError(f"{ch_where}: unsupported channel {ch!r} of {name!r}")
                channels.append(ch[0].upper() + ch[1:].lower())
        index = len(self.joints)
        self.joints.append(
            BvhJoint(name, parent, offset, tuple(channels), end_site=end_site_of is not None)
        )
        while True:
            where = self.where()
            tok = self.take("'}'")
            upper = tok.upper()
            if tok == "}":
                return
            if end_site_of is not None:
                raise BvhError(f"{where}: expected '}}' closing End Site, got {tok!r}")
            if upper == "JOINT":
                self.parse_joint(parent=index)
            elif upper == "END":
                self.expect("Site")
                self.parse_joint(parent=index, end_site_of=name)
            else:
                raise BvhError(
                    f"{where}: expected 'JOINT', 'End Site' or '}}' in {name!r}, got {tok!r}"
                )


# --- forward kinematics -------------------------------------------------------------------------


def forward_kinematics(bvh: Bvh) -> F64:
    """(T, joints, 3) float64 position of every joint and End Site, file units, file order."""
    data = bvh.motion
    t = data.shape[0]
    positions = np.zeros((t, len(bvh.joints), 3))
    rotations = np.zeros((t, len(bvh.joints), 3, 3))
    column = 0
    for j, joint in enumerate(bvh.joints):
        translation = np.broadcast_to(joint.offset, (t, 3)).copy()
        rot_axes: list[str] = []
        rot_angles: list[F64] = []
        for ch in joint.channels:
            key = ch.lower()
            if key in _POSITION_AXIS:
                translation[:, _POSITION_AXIS[key]] = data[:, column]
            else:
                rot_axes.append(_ROTATION_AXIS[key])
                rot_angles.append(np.deg2rad(data[:, column]))
            column += 1
        local = (
            compose_rotations(rot_axes, rot_angles)
            if rot_axes
            else np.broadcast_to(np.eye(3), (t, 3, 3))
        )
        if joint.parent < 0:
            positions[:, j] = translation
            rotations[:, j] = local
        else:
            parent_r = rotations[:, joint.parent]
            positions[:, j] = positions[:, joint.parent] + np.einsum(
                "tij,tj->ti", parent_r, translation
            )
            rotations[:, j] = parent_r @ local
    return positions


# --- writing ------------------------------------------------------------------------------------


def format_bvh(bvh: Bvh) -> str:
    """BVH text: two-space indentation, offsets and motion values to 6 decimals, the frame time
    to 8.

    Raises:
        ValueError: the joints are not in depth-first order (a joint whose parent is not the
            joint or one of the ancestors just written, or a child under an End Site), or the
            motion table's width is not the channel count.
    """
    width = sum(len(j.channels) for j in bvh.joints)
    if bvh.motion.ndim != 2 or bvh.motion.shape[1] != width:
        raise ValueError(f"motion must be (T, {width}) for these joints, got {bvh.motion.shape}")
    lines = ["HIERARCHY"]
    open_joints: list[int] = []

    def close() -> None:
        open_joints.pop()
        lines.append("  " * len(open_joints) + "}")

    for i, joint in enumerate(bvh.joints):
        while open_joints and open_joints[-1] != joint.parent:
            close()
        if joint.parent >= 0 and not open_joints:
            raise ValueError(f"joint {i} ({joint.name!r}) does not follow its parent depth-first")
        pad = "  " * len(open_joints)
        x, y, z = joint.offset
        if joint.end_site:
            lines += [f"{pad}End Site", f"{pad}{{", f"{pad}  OFFSET {x:.6f} {y:.6f} {z:.6f}"]
            lines.append(f"{pad}}}")
            continue
        lines.append(f"{pad}{'ROOT' if joint.parent < 0 else 'JOINT'} {joint.name}")
        lines += [f"{pad}{{", f"{pad}  OFFSET {x:.6f} {y:.6f} {z:.6f}"]
        lines.append(f"{pad}  " + " ".join(["CHANNELS", str(len(joint.channels)), *joint.channels]))
        open_joints.append(i)
    while open_joints:
        close()
    lines.append("MOTION")
    lines.append(f"Frames: {bvh.motion.shape[0]}")
    lines.append(f"Frame Time: {bvh.frame_time_s:.8f}")
    for row in bvh.motion:
        lines.append(" ".join(f"{v:.6f}" for v in row))
    return "\n".join(lines) + "\n"
