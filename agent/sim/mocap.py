"""Recorded human motion (CMU mocap: BVH and ASF/AMC) as Kinect v2 25-joint clips.

The loaders run forward kinematics over the file's own skeleton (BVH: :mod:`protocol.bvh`;
ASF/AMC: :mod:`agent.sim.asf_amc`), then map its points onto the Kinect v2 joint set
(:data:`protocol.skeleton.CMU_BVH_TO_KINECT_V2` / :data:`~protocol.skeleton.CMU_ASF_TO_KINECT_V2`,
whose comments give the correspondence and its caveats), in metres, world frame (right-handed,
+Y up, floor at y = 0). Pure numpy; no file is needed by the product itself.

Floor: after the mapping, the clip is shifted vertically so that the lowest Foot joint (toe
base) over the whole clip is at :data:`FOOT_JOINT_FLOOR_HEIGHT_M` (a joint centre inside the
foot, not the sole, so the soles touch y = 0). Horizontal position and heading are the file's;
``centred`` clips keep their own walking path and heading.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.asf_amc import asf_amc_points
from skelfuse.agent.sim.clip import MocapFormatError, MotionClip, PointTracks
from skelfuse.protocol.bvh import BvhError, forward_kinematics, read_bvh
from skelfuse.protocol.skeleton import (
    CMU_ASF_TO_KINECT_V2,
    CMU_BVH_TO_KINECT_V2,
    JOINT_COUNT,
    JointId,
    JointRecipe,
)

F64 = npt.NDArray[np.float64]

FOOT_JOINT_FLOOR_HEIGHT_M: Final = 0.04
"""Height of the lowest Foot (toe base) joint over a clip: the joint centre above the sole."""


def bvh_points(path: str | os.PathLike[str]) -> PointTracks:
    """Forward kinematics of a BVH file: every joint and End Site over time, file units.

    Raises:
        MocapFormatError: malformed hierarchy or motion data, or unsupported channels.
    """
    try:
        bvh = read_bvh(path)
    except BvhError as exc:
        raise MocapFormatError(str(exc)) from exc
    return PointTracks(
        names=tuple(j.name for j in bvh.joints),
        parents=tuple(j.parent for j in bvh.joints),
        positions=forward_kinematics(bvh),
        fps=bvh.fps,
        source=str(path),
    )


def _to_kinect(points: PointTracks, recipe: JointRecipe) -> F64:
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
    feet = joints[:, [JointId.FOOT_LEFT, JointId.FOOT_RIGHT], 1]
    shifted: F64 = joints.copy()
    shifted[..., 1] += FOOT_JOINT_FLOOR_HEIGHT_M - float(feet.min())
    return shifted


def _clip(points: PointTracks, recipe: JointRecipe, units_to_m: float, name: str) -> MotionClip:
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
    return _clip(bvh_points(path), CMU_BVH_TO_KINECT_V2, units_to_m, Path(path).stem)


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
    points = asf_amc_points(asf_path, amc_path, fps)
    return _clip(points, CMU_ASF_TO_KINECT_V2, 1.0, Path(amc_path).stem)
