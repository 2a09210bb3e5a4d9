"""Recorded human motion as the simulator plays it, and a mocap file's own points over time.

:class:`MotionClip` holds Kinect v2 joints (what a performer replays); :class:`PointTracks` holds
the named points of a mocap file's skeleton after forward kinematics (what the loaders in
:mod:`agent.sim.mocap` map onto the Kinect v2 joints).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

F64 = npt.NDArray[np.float64]


class MocapFormatError(ValueError):
    """A mocap file is malformed or uses a feature or skeleton this loader does not support."""


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
