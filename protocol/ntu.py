"""NTU RGB+D ``.skeleton`` files (Kinect v2, 30 fps): the file format and its reader.

The format (text, whitespace-separated; full description in ``docs/recording.md``)::

    <frame count>
    per frame:  <body count>
      per body: bodyID clipedEdges handLeftConfidence handLeftState handRightConfidence
                handRightState isResticted leanX leanY trackingState
                <joint count = 25>
                per joint: x y z depthX depthY colorX colorY
                           orientationW orientationX orientationY orientationZ trackingState

x, y, z are Kinect v2 camera space (metres, +X sensor-left, +Y up, +Z forward: our sensor
frame as is); joints come in ``JointType`` order, so no mapping is needed. The files have no
timestamps: frame i is at i/30 s. The cameras' poses are not in the files: fusing the three
cameras of a performance needs each sensor's pose (``--pose``) or a calibration.

The agent plays a file as a live sensor (``skelfuse.agent.sources.ntu``); recording imports the
cameras of one performance into a recording (``skelfuse.recording.ntu_import``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.wire import Body

NTU_FPS: Final = 30.0
_NAME = re.compile(r"S(\d{3})C(\d{3})P(\d{3})R(\d{3})A(\d{3})")


class NtuFormatError(Exception):
    """A ``.skeleton`` file that does not follow the format; the message gives the line."""


@dataclass(frozen=True, slots=True)
class NtuName:
    """What an NTU file name (``S001C002P003R002A013``) says: setup, camera, performer,
    replication, action."""

    setup: int
    camera: int
    performer: int
    replication: int
    action: int

    @property
    def performance(self) -> str:
        """The key shared by the three cameras of one performance (camera left out)."""
        return f"S{self.setup:03d}P{self.performer:03d}R{self.replication:03d}A{self.action:03d}"


def parse_ntu_name(path: str | Path) -> NtuName | None:
    """What the file's name says, or None for a name not in the dataset's pattern."""
    match = _NAME.search(Path(path).name)
    return None if match is None else NtuName(*(int(g) for g in match.groups()))


def read_ntu_skeleton(path: str | Path) -> list[tuple[Body, ...]]:
    """Every frame's bodies (sensor frame, metres; tracking id = NTU bodyID).

    Raises:
        NtuFormatError: with the line number where the file stops making sense.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii", errors="replace").split("\n")
    except OSError as exc:
        raise NtuFormatError(f"{path}: cannot read ({exc.strerror})") from exc
    position = 0

    def line() -> list[str]:
        nonlocal position
        while position < len(lines) and not lines[position].strip():
            position += 1
        if position >= len(lines):
            raise NtuFormatError(f"{path}: ends early at line {position + 1}")
        position += 1
        return lines[position - 1].split()

    def integer(fields: list[str], what: str) -> int:
        try:
            return int(fields[0])
        except (IndexError, ValueError) as exc:
            raise NtuFormatError(f"{path}:{position}: expected {what}, got {fields!r}") from exc

    frames: list[tuple[Body, ...]] = []
    frame_count = integer(line(), "the frame count")
    for _ in range(frame_count):
        bodies = []
        for _ in range(integer(line(), "a body count")):
            info = line()
            if len(info) != 10:
                raise NtuFormatError(f"{path}:{position}: a body line has 10 values, got {info}")
            body_id = integer(info, "a bodyID")
            count = integer(line(), "the joint count")
            if count != JOINT_COUNT:
                raise NtuFormatError(f"{path}:{position}: {count} joints (expected 25)")
            joints = np.zeros((JOINT_COUNT, 3), dtype=np.float32)
            states = np.zeros(JOINT_COUNT, dtype=np.uint8)
            for j in range(JOINT_COUNT):
                values = line()
                if len(values) != 12:
                    raise NtuFormatError(f"{path}:{position}: a joint line has 12 values")
                try:
                    joints[j] = [float(v) for v in values[:3]]
                    state = int(values[11])
                except ValueError as exc:
                    raise NtuFormatError(f"{path}:{position}: not numbers: {values}") from exc
                states[j] = min(max(state, 0), 2)
            joints[~np.isfinite(joints).all(axis=1)] = np.nan
            states[~np.isfinite(joints).all(axis=1)] = 0
            bodies.append(Body(body_id % 2**64, joints, states))
        frames.append(tuple(bodies))
    return frames
